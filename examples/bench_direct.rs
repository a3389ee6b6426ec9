//! Benchmark of the direct-irradiance stage: time per step and shadow queries per second.
//!
//! ```text
//! cargo run --release --example bench_direct -- [MESH] [--subdivide N] [--steps N]
//!     [--tracer sunview|grid|both] [--threads N]
//! ```
//! Default: the 49,152-facet Itokawa model, 360 steps over one spin, Sun in the equator
//! plane, both tracers. `--subdivide 2` splits every facet into 16 (786,432 facets).
//! Only the step loop is timed (tracer build per step included; mesh loading is not).

use glam::DVec3;
use slim::ephemeris::spin::{Spin, SpinModel};
use slim::illum::{Direct, StepCounts};
use slim::mesh::{generate::subdivide, read_mesh, LengthUnit, Mesh};
use slim::run::epoch_states;
use slim::trace::TracerKind;
use slim::world::{Body, World};
use std::path::PathBuf;
use std::time::Instant;

struct Args {
    mesh: PathBuf,
    subdivide: u32,
    steps: usize,
    tracers: Vec<TracerKind>,
    threads: Option<usize>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        mesh: PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("data/shapes/itokawa/ItokawaHayabusa.obj"),
        subdivide: 0,
        steps: 360,
        tracers: vec![TracerKind::Sunview, TracerKind::Grid],
        threads: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--subdivide" => args.subdivide = value()?.parse().map_err(|e| format!("{e}"))?,
            "--steps" => args.steps = value()?.parse().map_err(|e| format!("{e}"))?,
            "--threads" => args.threads = Some(value()?.parse().map_err(|e| format!("{e}"))?),
            "--tracer" => {
                args.tracers = match value()?.as_str() {
                    "sunview" => vec![TracerKind::Sunview],
                    "grid" => vec![TracerKind::Grid],
                    "both" => vec![TracerKind::Sunview, TracerKind::Grid],
                    t => return Err(format!("unknown tracer {t}")),
                }
            }
            "--bench" => {}
            path => args.mesh = PathBuf::from(path),
        }
    }
    Ok(args)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()?;
    }
    let mut raw = read_mesh(&args.mesh, None)?;
    for _ in 0..args.subdivide {
        raw = subdivide(&raw);
    }
    let mesh = Mesh::from_raw(raw, LengthUnit::Km);
    let world = World {
        bodies: vec![Body::new("body", mesh, false)],
    };
    let spin = SpinModel {
        start: hifitime::Epoch::from_tdb_seconds(0.0),
        duration_s: 12.13 * 3600.0,
        steps: args.steps,
        sun_dir_scene: DVec3::X,
        sun_distance_m: slim::AU_M,
        solar_constant_w_m2: slim::SOLAR_CONSTANT_W_M2,
        bodies: vec![Spin {
            period_s: Some(12.13 * 3600.0),
            initial_angle_rad: 0.0,
            position_m: DVec3::ZERO,
        }],
    };
    let states = epoch_states(&spin)?;
    println!(
        "mesh {} ({} facets), {} steps, {} threads",
        args.mesh.display(),
        world.facet_count(),
        args.steps,
        rayon::current_num_threads()
    );
    println!(
        "{:<8} {:>12} {:>14} {:>16} {:>10}",
        "tracer", "build s", "ms per step", "queries per s", "shadowed"
    );
    let mut out = vec![0.0; world.facet_count()];
    for &kind in &args.tracers {
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
            1e3 * loop_s / args.steps as f64,
            counts.rays as f64 / loop_s,
            counts.shadowed
        );
    }
    Ok(())
}
