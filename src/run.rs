//! Run: one scene into one output folder.
//!
//! In: a validated [`Scene`] and an output folder. Out: the files described in
//! [`crate::output`] and the [`RunRecord`] also saved as `run.json`. The work itself is
//! [`prepare`] (scene to geometry and plan) and [`simulate`] (the step loop); this module
//! clears the folder of an earlier run, streams the history, writes the tables and the
//! record. Progress is reported through [`Progress`] so the CLI can draw a bar and a
//! service can track jobs. What is computed and written goes through [`Outputs`]: the
//! tables of a whole run ([`Tables`]), or a part's files ([`crate::shard`]), so that
//! both share this one loop.

use crate::bands::Bands;
use crate::budget::Budget;
use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::horizon::shadows::{BoundRecord, MapRecord};
use crate::illum::StepCounts;
use crate::output::record::ShardRecord;
use crate::output::record::{InputFile, RunRecord};
use crate::output::{self, HistoryWriter, NamedStats};
use crate::plan::Plan;
use crate::prepare::{prepare, Assembly, Prepared};
use crate::progress::{Progress, Timings};
use crate::scatter::ScatterRecord;
use crate::scene::Scene;
use crate::simulate::{simulate, OnStep, Options, Simulation, Slice, StepIrradiance};
use crate::stats::{Bins, FacetStats};
use crate::world::World;
use std::path::{Path, PathBuf};

/// Runs `scene` within `budget` (memory), writing results into `out_dir`.
pub fn run_scene(
    scene: &Scene,
    out_dir: &Path,
    budget: &Budget,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    run_with(scene, out_dir, budget, &Tables, progress)
}

/// A step's irradiance going to a history file as the run goes.
pub trait HistorySink {
    fn write_step(&mut self, state: &EpochState, step: StepIrradiance) -> Result<()>;
    /// Finishes the files; returns their paths.
    fn finish(self: Box<Self>) -> Result<Vec<PathBuf>>;
}

impl HistorySink for HistoryWriter {
    fn write_step(&mut self, state: &EpochState, step: StepIrradiance) -> Result<()> {
        HistoryWriter::write_step(self, state, step)
    }
    fn finish(self: Box<Self>) -> Result<Vec<PathBuf>> {
        HistoryWriter::finish(*self)
    }
}

/// What a finished step loop hands to [`Outputs::write`] and [`Outputs::shard`].
pub struct Results<'a> {
    pub scene: &'a Scene,
    pub world: &'a World,
    pub states: &'a [EpochState],
    /// The part of the run that was computed.
    pub slice: &'a Slice,
    /// Statistics of the total, and the named parts beside it (`direct`, `scattered`,
    /// `planet`, `band_NAME`, `bands`).
    pub total: &'a FacetStats,
    pub parts: NamedStats<'a>,
    /// Whether the history holds the direct and scattered parts too.
    pub scattered: bool,
}

/// How a run's results leave it: the tables of a whole run ([`Tables`]), or the files
/// of a part ([`crate::shard`]).
pub trait Outputs {
    /// The files this writes into a folder, refused when there and not written by slim.
    fn file_names(&self, scene: &Scene) -> Vec<String>;
    /// The part of a run of `steps` steps and `facets` facets with outputs to compute.
    fn slice(&self, steps: usize, facets: usize) -> Result<Slice>;
    /// Where the history goes, when the scene asks for it.
    fn history(&self, dir: &Path, scene: &Scene, world: &World) -> Result<Box<dyn HistorySink>>;
    /// Writes the results and finishes `history`; returns the files written.
    fn write(
        &self,
        dir: &Path,
        results: &Results,
        history: Option<Box<dyn HistorySink>>,
    ) -> Result<Vec<PathBuf>>;
    /// What `run.json` says of the part (`None` for a whole run).
    fn shard(&self, results: &Results) -> Option<ShardRecord>;
}

/// The tables of a whole run ([`crate::output`]).
pub struct Tables;

impl Outputs for Tables {
    fn file_names(&self, scene: &Scene) -> Vec<String> {
        let bodies: Vec<&str> = scene
            .bodies
            .iter()
            .filter(|b| b.outputs)
            .map(|b| b.name.as_str())
            .collect();
        let o = &scene.output;
        output::file_names(o.csv, o.history, o.ply, &bodies)
    }

    fn slice(&self, _: usize, _: usize) -> Result<Slice> {
        Ok(Slice::default())
    }

    fn history(&self, dir: &Path, scene: &Scene, world: &World) -> Result<Box<dyn HistorySink>> {
        Ok(Box::new(HistoryWriter::new(dir, scene.output.csv, world)))
    }

    fn write(
        &self,
        dir: &Path,
        r: &Results,
        history: Option<Box<dyn HistorySink>>,
    ) -> Result<Vec<PathBuf>> {
        write_results(dir, r.scene, r.world, r.states, r.total, r.parts, history)
    }

    fn shard(&self, _: &Results) -> Option<ShardRecord> {
        None
    }
}

/// Runs `scene` (the part `outputs` says) within `budget` into `out_dir`, writing what
/// `outputs` writes.
pub fn run_with(
    scene: &Scene,
    out_dir: &Path,
    budget: &Budget,
    outputs: &dyn Outputs,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    let mut timings = Timings::default();
    let previous = previous_outputs(out_dir)?;
    refuse_foreign_files(out_dir, &outputs.file_names(scene), &previous)?;
    let Prepared {
        assembly,
        states,
        scatter,
        bins,
        plan,
        tracer,
        shadows,
        horizon_maps,
    } = prepare(scene, budget, &mut timings)?;
    let world = &assembly.world;
    let slice = outputs.slice(states.len(), world.output_facet_count())?;
    // Only now that the scene is known to run is the earlier run cleared away.
    clear_previous_run(out_dir, previous)?;
    for w in &assembly.warnings {
        progress.note(&format!("warning: {w}"));
    }
    progress.note(&plan.to_string());
    let mut history = match scene.output.history {
        true => Some(outputs.history(out_dir, scene, world)?),
        false => None,
    };
    let mut bands = Bands::from_scene(scene, world, scatter.as_ref(), bins, slice.kept(world))?;
    let options = Options {
        tracer,
        bins,
        shadows,
        horizon_maps,
        scatter,
        bands: bands.as_mut(),
        slice: slice.clone(),
    };
    let mut write_step =
        |s: &EpochState, e: StepIrradiance| history.as_mut().map_or(Ok(()), |h| h.write_step(s, e));
    let on_step: Option<&mut OnStep> = match scene.output.history {
        true => Some(&mut write_step),
        false => None,
    };
    let sim = simulate(world, &states, options, &mut timings, progress, on_step)?;
    let band_parts = bands.map(Bands::into_parts).unwrap_or_default();
    let parts = named_parts(&sim, &band_parts);
    let results = Results {
        scene,
        world,
        states: &states,
        slice: &slice,
        total: &sim.stats,
        parts: &parts,
        scattered: sim.parts.is_some(),
    };
    let outputs_written = timings.time("output", || outputs.write(out_dir, &results, history))?;
    let shard = outputs.shard(&results);
    let record = run_record(
        scene,
        assembly,
        plan,
        Outcome {
            counts: sim.counts,
            horizon_maps: sim.horizon_maps,
            horizon_bounds: sim.horizon_bounds,
            scatter: sim.parts.map(|p| p.record),
        },
        bins,
        timings,
        outputs_written,
        shard,
        progress,
    )?;
    record.write(out_dir)?;
    Ok(record)
}

/// Writes the result tables of a whole run (summary, cdf, geometry, the history `history`
/// has streamed, and the PLYs when asked for); returns their paths in that order.
pub(crate) fn write_results(
    out_dir: &Path,
    scene: &Scene,
    world: &World,
    states: &[EpochState],
    stats: &FacetStats,
    parts: NamedStats,
    history: Option<Box<dyn HistorySink>>,
) -> Result<Vec<PathBuf>> {
    let csv = scene.output.csv;
    let step_s = even_step_s(states);
    // The CDF table is the largest by far (facets × thresholds rows): it is built beside
    // the summary rather than after it.
    let (summary, cdf) = rayon::join(
        || output::write_summary(out_dir, csv, world, stats, parts, step_s),
        || output::write_cdf(out_dir, csv, world, stats, parts),
    );
    let mut files = summary?;
    files.extend(cdf?);
    files.extend(output::write_geometry(out_dir, csv, world, states)?);
    if let Some(h) = history {
        files.extend(h.finish()?);
    }
    if scene.output.ply {
        files.extend(write_plys(out_dir, world, stats)?);
    }
    Ok(files)
}

/// What the step loop did, for `run.json`.
pub(crate) struct Outcome {
    pub counts: StepCounts,
    pub horizon_maps: Vec<MapRecord>,
    pub horizon_bounds: Vec<BoundRecord>,
    pub scatter: Option<ScatterRecord>,
}

/// The record of a run (or part, or merge) that wrote `outputs` into its folder:
/// `run.json` itself is added to them. Warnings are the assembly's and, with scattered
/// light, the solver's (each also given to `progress`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_record(
    scene: &Scene,
    assembly: Assembly,
    plan: Plan,
    outcome: Outcome,
    bins: Bins,
    timings: Timings,
    outputs: Vec<PathBuf>,
    shard: Option<ShardRecord>,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    let kernels = assembly.kernel_files()?;
    let duration_s = assembly.ephemeris.duration_s();
    let mut warnings = assembly.warnings;
    let unconverged = outcome
        .scatter
        .as_ref()
        .zip(scene.scatter.as_ref())
        .and_then(|(p, s)| p.convergence_warning(s.max_orders, s.tolerance));
    if let Some(w) = unconverged {
        progress.note(&format!("warning: {w}"));
        warnings.push(w);
    }
    let (bodies, occluders) = assembly
        .bodies
        .into_iter()
        .zip(&assembly.world.bodies)
        .partition::<Vec<_>, _>(|(_, b)| b.outputs);
    let records = |v: Vec<(_, _)>| v.into_iter().map(|(r, _)| r).collect();
    let (bodies, occluders) = (records(bodies), records(occluders));
    Ok(RunRecord {
        program: "slim".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        name: scene.name.clone(),
        scene: InputFile {
            path: scene.path.clone(),
            sha256: output::record::sha256_hex(&scene.source),
        },
        kernels,
        bodies,
        occluders,
        plan,
        counts: outcome.counts,
        horizon_maps: outcome.horizon_maps,
        horizon_bounds: outcome.horizon_bounds,
        scatter: outcome.scatter,
        bins_w_m2: bins,
        duration_s,
        threads: rayon::current_num_threads(),
        timings_s: timings.0,
        warnings,
        outputs: outputs
            .iter()
            .chain(std::iter::once(&PathBuf::from("run.json")))
            .filter_map(|p| Some(p.file_name()?.to_string_lossy().into_owned()))
            .collect(),
        shard,
        merged_from: None,
    })
}

/// The statistics written beside the total: `direct` and `scattered` with scattered
/// light, then each band's.
fn named_parts<'a>(
    sim: &'a Simulation,
    bands: &'a [(String, FacetStats)],
) -> Vec<(String, &'a FacetStats)> {
    let scatter = sim.parts.iter().flat_map(|p| {
        [
            ("direct".to_string(), &p.direct),
            ("scattered".to_string(), &p.scattered),
        ]
        .into_iter()
        .chain(p.planet.iter().map(|s| ("planet".to_string(), s)))
    });
    scatter
        .chain(bands.iter().map(|(name, stats)| (name.clone(), stats)))
        .collect()
}

/// One `BODY.ply` per body with its facets' statistics.
fn write_plys(out_dir: &Path, world: &World, stats: &FacetStats) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for (body, offset) in world.bodies.iter().zip(world.output_offsets()) {
        if !body.outputs {
            continue;
        }
        let path = out_dir.join(format!("{}.ply", body.name));
        output::ply::write_ply(&path, &body.mesh, stats, offset)?;
        files.push(path);
    }
    Ok(files)
}

/// Creates the output folder and lists what an earlier run in it wrote: the files its
/// `run.json` lists (bare file names only) and unfinished `.partial` files.
pub(crate) fn previous_outputs(dir: &Path) -> Result<Vec<String>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let listed = RunRecord::read(dir).map_or_else(|_| Vec::new(), |r| r.outputs);
    let partial = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|entry| entry.ok()?.file_name().into_string().ok())
        .filter(|name| name.ends_with(".partial"));
    Ok(listed
        .into_iter()
        .filter(|n| n != "run.json")
        .chain(partial)
        .filter(|name| Path::new(name).file_name() == Some(std::ffi::OsStr::new(name)))
        .collect())
}

/// Removes an earlier run's files ([`previous_outputs`]), then its `run.json`, so the
/// folder never vouches for files this run has not written; nothing else is touched.
pub(crate) fn clear_previous_run(dir: &Path, previous: Vec<String>) -> Result<()> {
    for name in previous {
        remove_if_present(&dir.join(name))?;
    }
    remove_if_present(&dir.join("run.json"))
}

/// Refuses to start when a file this run would write is already in the folder and the
/// earlier run's `run.json` does not list it: slim did not write it (an input mesh named
/// like a body's PLY, say) and will not overwrite it.
pub(crate) fn refuse_foreign_files(
    dir: &Path,
    names: &[String],
    previous: &[String],
) -> Result<()> {
    for name in names {
        let path = dir.join(name);
        if path.exists() && !previous.contains(name) {
            return Err(Error::file(
                &path,
                "is in the output folder but no run.json of slim lists it: slim does not \
                 overwrite a file it did not write; choose another output folder (-o) or \
                 move the file",
            ));
        }
    }
    Ok(())
}

fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(path, e)),
    }
}

/// The time between steps (s) when every step follows the one before by the same
/// positive interval (to a microsecond); `None` otherwise (one step, listed Suns).
pub(crate) fn even_step_s(states: &[crate::ephemeris::EpochState]) -> Option<f64> {
    let t: Vec<f64> = states.iter().map(|s| s.epoch.to_tdb_seconds()).collect();
    let first = *t.get(1)? - t[0];
    let even = t.windows(2).all(|w| ((w[1] - w[0]) - first).abs() <= 1e-6);
    (first > 0.0 && even).then_some(first)
}
