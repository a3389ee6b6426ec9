//! Benchmark of the direct-irradiance stage: time per step and shadow queries per second.
//!
//! ```text
//! cargo run --release --example bench_direct -- [MESH] [--subdivide N] [--steps N]
//!     [--tracer sunview|bvh|grid|both|all] [--threads N] [--sun point|disk]
//!     [--horizon exact|approximate [--azimuths A] [--whole-map]] [--cache DIR] [--block K]
//! ```
//! Steps are computed in blocks of K (`Direct::compute_steps`), as `slim run` does:
//! by default the block `slim run` takes for this mesh (16 steps up to a million facets);
//! `--block 1` computes one step at a time.
//! With `--horizon`, the step loop looks the Sun up in the body's horizon map (A wedges,
//! default 128) instead of tracing every ray: `exact` traces only where the Sun is not
//! above the wedge's upper bound, `approximate` traces nothing. The map is built for the
//! band of the steps' Suns, as `slim run` builds it (`--whole-map`: for every direction),
//! read from `--cache DIR` when there, else built (and stored there); its time is the
//! `build s`.
//! Without `--horizon`, `--cache DIR` keeps the `bvh` tracer's horizon bound the same
//! way, so that only its first run builds it.
//! `--sun disk` takes the Sun as a disk: its visible share from the map, or without
//! `--horizon` from rays toward 32 points of the disk wherever the facet's plane or
//! (`bvh`) its horizon bound leaves the disk in doubt.
//! Default: the 49,152-facet Itokawa model, 360 steps over one spin, Sun in the equator
//! plane, both tracers. `--subdivide 2` splits every facet into 16 (786,432 facets).
//! Only the step loop is timed (the Sun-view build per step included; mesh loading and the
//! BVH tracer's one-off build with its horizon bound are not: they are the `build s`).

// Shared by several benchmarks; each uses part of it.
#[allow(dead_code)]
mod common;

use glam::DVec3;
use slim::budget::Budget;
use slim::horizon::shadows::{
    recall_for_run, HorizonMode, ShadowMethod, Shadows, SunShape, DEFAULT_AZIMUTHS,
};
use slim::illum::{Direct, StepCounts};
use slim::trace::TracerKind;
use std::time::Instant;

/// The tracers `--tracer sunview|grid|both` asks for (default both).
fn tracers(options: &common::Options) -> Result<Vec<TracerKind>, String> {
    Ok(
        match options.value("--tracer", "both".to_string())?.as_str() {
            "sunview" => vec![TracerKind::Sunview],
            "grid" => vec![TracerKind::Grid],
            "bvh" => vec![TracerKind::Bvh],
            "both" => vec![TracerKind::Sunview, TracerKind::Grid],
            "all" => vec![TracerKind::Sunview, TracerKind::Bvh, TracerKind::Grid],
            t => return Err(format!("unknown tracer {t}")),
        },
    )
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let options = common::Options::from_env(&[
        "--subdivide",
        "--steps",
        "--tracer",
        "--threads",
        "--horizon",
        "--azimuths",
        "--sun",
        "--cache",
        "--block",
    ]);
    options.apply_threads()?;
    let steps: usize = options.value("--steps", 360)?;
    let world = options.world(0)?;
    let run_block = slim::simulate::steps_per_batch(None, false, false, world.facet_count());
    let block: usize = options.value("--block", run_block)?;
    let states = common::spin_states(steps, DVec3::X)?;
    println!(
        "mesh {} ({} facets), {} steps in blocks of {}, {} threads",
        options.mesh().display(),
        world.facet_count(),
        steps,
        block.max(1),
        rayon::current_num_threads()
    );
    println!(
        "{:<8} {:>12} {:>14} {:>16} {:>10} {:>11}",
        "tracer", "build s", "ms per step", "queries per s", "shadowed", "remembered"
    );
    // The earlier step whose blockers the rays recall, as `slim run` finds it.
    let recall = recall_for_run(
        &world,
        &states,
        Budget::machine().remembered_blocker_bytes(),
    );
    match options.optional::<String>("--horizon")? {
        Some(mode) => {
            let mut shadows = Shadows {
                recall,
                ..horizon_shadows(&options, &mode)?
            };
            if !options.has("--whole-map") {
                shadows.bands = shadows.bands_for_run(&world, &states);
            }
            let t0 = Instant::now();
            let direct = common::mapped_direct(&world, &shadows)?;
            let name = format!("map {mode}");
            time_steps(&name, t0, direct, &states, world.facet_count(), block)?;
        }
        None => {
            let shadows = Shadows {
                sun: sun_shape(&options)?,
                cache_dir: options.optional("--cache")?,
                recall,
                ..Shadows::default()
            };
            for kind in tracers(&options)? {
                let t0 = Instant::now();
                let none = world.bodies.iter().map(|_| None).collect();
                let direct = Direct::with_maps(&world, kind, none, &shadows);
                let name = format!("{kind:?}").to_lowercase();
                time_steps(&name, t0, direct, &states, world.facet_count(), block)?;
            }
        }
    }
    Ok(())
}

/// The shadows `--horizon MODE` with `--azimuths`, `--sun` and `--cache` ask for.
fn horizon_shadows(options: &common::Options, mode: &str) -> Result<Shadows, String> {
    Ok(Shadows {
        method: ShadowMethod::Horizon,
        mode: match mode {
            "exact" => HorizonMode::Exact,
            "approximate" => HorizonMode::Approximate,
            m => return Err(format!("unknown horizon mode {m}")),
        },
        azimuths: options.value("--azimuths", DEFAULT_AZIMUTHS)?,
        sun: sun_shape(options)?,
        cache_dir: options.optional("--cache")?,
        ..Shadows::default()
    })
}

/// The Sun `--sun point|disk` asks for (default point).
fn sun_shape(options: &common::Options) -> Result<SunShape, String> {
    match options.value("--sun", "point".to_string())?.as_str() {
        "point" => Ok(SunShape::Point),
        "disk" => Ok(SunShape::Disk),
        s => Err(format!("unknown Sun shape {s}")),
    }
}

/// Runs `direct` over `states` in blocks of `block` steps and prints its line (`t0`:
/// when its setup began).
fn time_steps(
    name: &str,
    t0: Instant,
    direct: Direct,
    states: &[slim::ephemeris::EpochState],
    facets: usize,
    block: usize,
) -> Result<(), slim::Error> {
    let build = t0.elapsed().as_secs_f64();
    let mut buffers = vec![vec![0.0; facets]; block.max(1)];
    let mut counts = StepCounts::default();
    let t1 = Instant::now();
    for chunk in states.chunks(block.max(1)) {
        let mut outs: Vec<&mut [f64]> = buffers.iter_mut().map(Vec::as_mut_slice).collect();
        counts += direct.compute_steps(chunk, &mut outs[..chunk.len()])?;
    }
    let loop_s = t1.elapsed().as_secs_f64();
    println!(
        "{:<8} {:>12.3} {:>14.3} {:>16.3e} {:>10} {:>11}",
        name,
        build,
        1e3 * loop_s / states.len() as f64,
        counts.rays as f64 / loop_s,
        counts.shadowed,
        counts.remembered
    );
    Ok(())
}
