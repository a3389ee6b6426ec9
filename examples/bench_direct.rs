//! Benchmark of the direct-irradiance stage: time per step and shadow queries per second.
//!
//! ```text
//! cargo run --release --example bench_direct -- [MESH] [--subdivide N] [--steps N]
//!     [--tracer sunview|bvh|grid|both|all] [--threads N]
//! ```
//! Default: the 49,152-facet Itokawa model, 360 steps over one spin, Sun in the equator
//! plane, both tracers. `--subdivide 2` splits every facet into 16 (786,432 facets).
//! Only the step loop is timed (the Sun-view build per step included; mesh loading and the
//! BVH tracer's one-off build with its horizon bound are not: they are the `build s`).

// Shared by several benchmarks; each uses part of it.
#[allow(dead_code)]
mod common;

use glam::DVec3;
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
    let options = common::Options::from_env(&["--subdivide", "--steps", "--tracer", "--threads"]);
    options.apply_threads()?;
    let steps: usize = options.value("--steps", 360)?;
    let tracers = tracers(&options)?;
    let world = options.world(0)?;
    let states = common::spin_states(steps, DVec3::X)?;
    println!(
        "mesh {} ({} facets), {} steps, {} threads",
        options.mesh().display(),
        world.facet_count(),
        steps,
        rayon::current_num_threads()
    );
    println!(
        "{:<8} {:>12} {:>14} {:>16} {:>10}",
        "tracer", "build s", "ms per step", "queries per s", "shadowed"
    );
    let mut out = vec![0.0; world.facet_count()];
    for &kind in &tracers {
        let t0 = Instant::now();
        let direct = Direct::new(&world, kind);
        let build = t0.elapsed().as_secs_f64();
        let mut counts = StepCounts::default();
        let t1 = Instant::now();
        for s in &states {
            counts += direct.compute(s, &mut out)?;
        }
        let loop_s = t1.elapsed().as_secs_f64();
        println!(
            "{:<8} {:>12.3} {:>14.3} {:>16.3e} {:>10}",
            format!("{kind:?}").to_lowercase(),
            build,
            1e3 * loop_s / steps as f64,
            counts.rays as f64 / loop_s,
            counts.shadowed
        );
    }
    Ok(())
}
