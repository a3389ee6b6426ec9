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
use crate::error::{Error, Result};
use crate::output::record::{InputFile, RunRecord};
use crate::output::{self, HistoryWriter};
use crate::prepare::{prepare, Prepared};
use crate::progress::{Progress, Timings};
use crate::scene::Scene;
use crate::simulate::{simulate, Options, Simulation};
use crate::stats::FacetStats;
use crate::world::World;
use std::path::{Path, PathBuf};

/// Runs `scene` within `budget` (memory), writing results into `out_dir`.
pub fn run_scene(
    scene: &Scene,
    out_dir: &Path,
    budget: &Budget,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    let mut timings = Timings::default();
    let previous = previous_outputs(out_dir)?;
    refuse_foreign_files(out_dir, scene, &previous)?;
    let Prepared {
        assembly,
        states,
        scatter,
        bins,
        plan,
        shadows,
        horizon_maps,
    } = prepare(scene, budget, &mut timings)?;
    // Only now that the scene is known to run is the earlier run cleared away.
    clear_previous_run(out_dir, previous)?;
    let kernels = assembly.kernel_files()?;
    let world = &assembly.world;
    for w in &assembly.warnings {
        progress.note(&format!("warning: {w}"));
    }
    progress.note(&plan.to_string());
    let csv = scene.output.csv;
    let mut history = scene
        .output
        .history
        .then(|| HistoryWriter::new(out_dir, csv, world));
    let mut bands = Bands::from_scene(scene, world, scatter.as_ref(), bins)?;
    let options = Options {
        tracer: scene.run.tracer,
        bins,
        shadows,
        horizon_maps,
        scatter,
        bands: bands.as_mut(),
    };
    let sim = simulate(world, &states, options, &mut timings, progress, |s, e| {
        history.as_mut().map_or(Ok(()), |h| h.write_step(s, e))
    })?;
    let mut warnings = assembly.warnings;
    let unconverged = sim
        .parts
        .as_ref()
        .zip(scene.scatter.as_ref())
        .and_then(|(p, s)| p.record.convergence_warning(s.max_orders, s.tolerance));
    if let Some(w) = unconverged {
        progress.note(&format!("warning: {w}"));
        warnings.push(w);
    }
    let band_parts = bands.map(Bands::into_parts).unwrap_or_default();
    let parts = named_parts(&sim, &band_parts);
    let mut outputs = timings.time("output", || -> Result<Vec<_>> {
        let step_s = even_step_s(&states);
        let mut files = output::write_summary(out_dir, csv, world, &sim.stats, &parts, step_s)?;
        files.extend(output::write_cdf(out_dir, csv, world, &sim.stats, &parts)?);
        files.extend(output::write_geometry(out_dir, csv, world, &states)?);
        if let Some(h) = history.take() {
            files.extend(h.finish()?);
        }
        if scene.output.ply {
            files.extend(write_plys(out_dir, world, &sim.stats)?);
        }
        Ok(files)
    })?;
    outputs.push(out_dir.join("run.json"));
    let (bodies, occluders) = assembly
        .bodies
        .into_iter()
        .zip(&world.bodies)
        .partition::<Vec<_>, _>(|(_, b)| b.outputs);
    let records = |v: Vec<(_, _)>| v.into_iter().map(|(r, _)| r).collect();
    let (bodies, occluders) = (records(bodies), records(occluders));
    let record = RunRecord {
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
        counts: sim.counts,
        horizon_maps: sim.horizon_maps,
        scatter: sim.parts.map(|p| p.record),
        bins_w_m2: bins,
        duration_s: assembly.ephemeris.duration_s(),
        threads: rayon::current_num_threads(),
        timings_s: timings.0,
        warnings,
        outputs: outputs
            .iter()
            .filter_map(|p| Some(p.file_name()?.to_string_lossy().into_owned()))
            .collect(),
    };
    record.write(out_dir)?;
    Ok(record)
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
fn previous_outputs(dir: &Path) -> Result<Vec<String>> {
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
fn clear_previous_run(dir: &Path, previous: Vec<String>) -> Result<()> {
    for name in previous {
        remove_if_present(&dir.join(name))?;
    }
    remove_if_present(&dir.join("run.json"))
}

/// Refuses to start when a file this run would write is already in the folder and the
/// earlier run's `run.json` does not list it: slim did not write it (an input mesh named
/// like a body's PLY, say) and will not overwrite it.
fn refuse_foreign_files(dir: &Path, scene: &Scene, previous: &[String]) -> Result<()> {
    let bodies: Vec<&str> = scene
        .bodies
        .iter()
        .filter(|b| b.outputs)
        .map(|b| b.name.as_str())
        .collect();
    let o = &scene.output;
    for name in output::file_names(o.csv, o.history, o.ply, &bodies) {
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
