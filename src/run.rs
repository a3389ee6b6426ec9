//! Run: one scene into one output folder.
//!
//! In: a validated [`Scene`] and an output folder. Out: the files described in
//! [`crate::output`] and the [`RunRecord`] also saved as `run.json`. The work itself is
//! [`prepare`] (scene to geometry and plan) and [`simulate`] (the step loop); this module
//! clears the folder of an earlier run, streams the history, writes the tables and the
//! record. Progress is reported through [`Progress`] so the CLI can draw a bar and a
//! service can track jobs.

use crate::bands::Bands;
use crate::budget::Budget;
use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::horizon::shadows::MapRecord;
use crate::illum::StepCounts;
use crate::output::record::{InputFile, RunRecord};
use crate::output::{self, HistoryWriter, NamedStats};
use crate::plan::Plan;
use crate::prepare::{prepare, Assembly, Prepared};
use crate::progress::{Progress, Timings};
use crate::scatter::ScatterRecord;
use crate::scene::Scene;
use crate::shard::part::{write_part, HistoryPart, FORMAT_VERSION, HISTORY_FILE, PART_FILE};
use crate::shard::{geometry_sha256, Shard, ShardRecord};
use crate::simulate::{simulate, Options, Simulation, Slice, StepIrradiance};
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
    run_part(scene, out_dir, budget, None, progress)
}

/// Runs part `shard` of `scene` into the part folder `out_dir`, for [`crate::shard::merge`].
pub fn run_shard(
    scene: &Scene,
    out_dir: &Path,
    budget: &Budget,
    shard: Shard,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    run_part(scene, out_dir, budget, Some(shard), progress)
}

/// Where the history goes: the tables of a whole run, or a part's raw file.
pub(crate) enum History {
    Tables(Box<HistoryWriter>),
    Part(HistoryPart),
}

impl History {
    pub(crate) fn write_step(&mut self, state: &EpochState, step: StepIrradiance) -> Result<()> {
        match self {
            History::Tables(h) => h.write_step(state, step),
            History::Part(h) => h.write_step(step),
        }
    }

    fn finish(self) -> Result<Vec<PathBuf>> {
        match self {
            History::Tables(h) => h.finish(),
            History::Part(h) => h.finish(),
        }
    }
}

/// [`run_scene`] or, with `shard`, [`run_shard`].
fn run_part(
    scene: &Scene,
    out_dir: &Path,
    budget: &Budget,
    shard: Option<Shard>,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    let mut timings = Timings::default();
    let previous = previous_outputs(out_dir)?;
    refuse_foreign_files(out_dir, scene, shard.is_some(), &previous)?;
    let Prepared {
        assembly,
        states,
        scatter,
        bins,
        plan,
        shadows,
        horizon_maps,
    } = prepare(scene, budget, &mut timings)?;
    let world = &assembly.world;
    let slice = match shard {
        Some(s) => s
            .slice(states.len(), world.output_facet_count())
            .map_err(|e| Error::Usage(format!("--shard {}/{}: {e}", s.index, s.count)))?,
        None => Slice::default(),
    };
    // Only now that the scene is known to run is the earlier run cleared away.
    clear_previous_run(out_dir, previous)?;
    for w in &assembly.warnings {
        progress.note(&format!("warning: {w}"));
    }
    progress.note(&plan.to_string());
    let csv = scene.output.csv;
    let mut history = match (scene.output.history, shard) {
        (false, _) => None,
        (true, None) => Some(History::Tables(Box::new(HistoryWriter::new(
            out_dir, csv, world,
        )))),
        (true, Some(_)) => Some(History::Part(HistoryPart::create(out_dir)?)),
    };
    let mut bands = Bands::from_scene(scene, world, scatter.as_ref(), bins, slice.kept(world))?;
    let options = Options {
        tracer: scene.run.tracer,
        bins,
        shadows,
        horizon_maps,
        scatter,
        bands: bands.as_mut(),
        slice: slice.clone(),
    };
    let sim = simulate(world, &states, options, &mut timings, progress, |s, e| {
        history.as_mut().map_or(Ok(()), |h| h.write_step(s, e))
    })?;
    let band_parts = bands.map(Bands::into_parts).unwrap_or_default();
    let parts = named_parts(&sim, &band_parts);
    let outputs = timings.time("output", || -> Result<Vec<_>> {
        match shard {
            None => write_results(out_dir, scene, world, &states, &sim.stats, &parts, history),
            Some(_) => {
                let all: Vec<(String, &FacetStats)> = std::iter::once(("total".into(), &sim.stats))
                    .chain(parts.iter().map(|(n, s)| (n.clone(), *s)))
                    .collect();
                let mut files = vec![write_part(out_dir, &all)?];
                if let Some(h) = history.take() {
                    files.extend(h.finish()?);
                }
                Ok(files)
            }
        }
    })?;
    let shard_record = shard.map(|s| ShardRecord {
        index: s.index,
        count: s.count,
        by: s.by,
        steps: bounds(slice.steps.clone(), states.len()),
        facets: bounds(slice.facets.clone(), world.output_facet_count()),
        total_steps: states.len(),
        total_facets: world.output_facet_count(),
        scene_file: std::path::absolute(&scene.path).unwrap_or_else(|_| scene.path.clone()),
        geometry_sha256: {
            let [first, end] = bounds(slice.steps.clone(), states.len());
            geometry_sha256(&states[first..end])
        },
        statistics: std::iter::once("total".to_string())
            .chain(parts.iter().map(|(n, _)| n.clone()))
            .collect(),
        history_values: if scene.output.history {
            1 + 2 * usize::from(sim.parts.is_some())
        } else {
            0
        },
        format_version: FORMAT_VERSION,
    });
    let record = run_record(
        scene,
        assembly,
        plan,
        Outcome {
            counts: sim.counts,
            horizon_maps: sim.horizon_maps,
            scatter: sim.parts.map(|p| p.record),
        },
        bins,
        timings,
        outputs,
        shard_record,
        progress,
    )?;
    record.write(out_dir)?;
    Ok(record)
}

/// `[start, end]` of `range`, or of `0..total` for `None`.
fn bounds(range: Option<std::ops::Range<usize>>, total: usize) -> [usize; 2] {
    let r = range.unwrap_or(0..total);
    [r.start, r.end]
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
    history: Option<History>,
) -> Result<Vec<PathBuf>> {
    let csv = scene.output.csv;
    let step_s = even_step_s(states);
    let mut files = output::write_summary(out_dir, csv, world, stats, parts, step_s)?;
    files.extend(output::write_cdf(out_dir, csv, world, stats, parts)?);
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
    scene: &Scene,
    part: bool,
    previous: &[String],
) -> Result<()> {
    let bodies: Vec<&str> = scene
        .bodies
        .iter()
        .filter(|b| b.outputs)
        .map(|b| b.name.as_str())
        .collect();
    let o = &scene.output;
    let names = if part {
        vec![PART_FILE.to_string(), HISTORY_FILE.to_string()]
    } else {
        output::file_names(o.csv, o.history, o.ply, &bodies)
    };
    for name in names {
        let path = dir.join(&name);
        if path.exists() && !previous.contains(&name) {
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
