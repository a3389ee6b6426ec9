//! Benchmark of scattered light: form factors with visibility, memory, per-step solve.
//!
//! ```text
//! cargo run --release --example bench_scatter -- [MESH] [--subdivide N] [--steps N]
//!     [--albedo A] [--threads N]
//! ```
//! Default: the 49,152-facet Itokawa model, 12 steps over one spin, albedo 0.1 (the
//! Jacobi regime) and 0.9 (CG). Prints the form-factor build time, the stored entries and
//! bytes, the process's peak resident memory (VmHWM), and the time of each step's solve
//! to 1e-6 relative (the direct irradiance is computed first and not timed).

use glam::DVec3;
use slim::ephemeris::spin::{Spin, SpinModel};
use slim::illum::Direct;
use slim::mesh::{generate::subdivide, read_mesh, LengthUnit, Mesh};
use slim::run::epoch_states;
use slim::scatter::form_factor::NearField;
use slim::scatter::solve::SolverKind;
use slim::scatter::{FirstBounce, Lambertian, Scatter, Settings};
use slim::trace::TracerKind;
use slim::world::{Body, World};
use std::path::PathBuf;
use std::time::Instant;

struct Args {
    mesh: PathBuf,
    subdivide: u32,
    steps: usize,
    albedo: Vec<f64>,
    threads: Option<usize>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        mesh: PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("data/shapes/itokawa/ItokawaHayabusa.obj"),
        subdivide: 0,
        steps: 12,
        albedo: vec![0.1, 0.9],
        threads: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--subdivide" => args.subdivide = value()?.parse().map_err(|e| format!("{e}"))?,
            "--steps" => args.steps = value()?.parse().map_err(|e| format!("{e}"))?,
            "--albedo" => args.albedo = vec![value()?.parse().map_err(|e| format!("{e}"))?],
            "--threads" => args.threads = Some(value()?.parse().map_err(|e| format!("{e}"))?),
            "--bench" => {}
            path => args.mesh = PathBuf::from(path),
        }
    }
    Ok(args)
}

/// Peak resident memory of this process, MB (Linux; 0 elsewhere).
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
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
    let world = World {
        bodies: vec![Body::new(
            "body",
            Mesh::from_raw(raw, LengthUnit::Km),
            false,
        )],
    };
    let n = world.facet_count();
    let spin = SpinModel {
        start: hifitime::Epoch::from_tdb_seconds(0.0),
        duration_s: 12.13 * 3600.0,
        steps: args.steps,
        sun_dir_scene: DVec3::new(1.0, 0.0, 0.3).normalize(),
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
        "mesh {} ({n} facets), {} steps, {} threads, peak RSS after loading {:.0} MB",
        args.mesh.display(),
        args.steps,
        rayon::current_num_threads(),
        peak_rss_mb()
    );
    let direct = Direct::new(&world, TracerKind::Sunview);
    let settings = Settings {
        albedo: vec![args.albedo[0]; n],
        solver: SolverKind::Auto,
        max_orders: 1000,
        tolerance: 1e-6,
        inter_body_tolerance: 1e-4,
        near_field: NearField::default(),
        first_bounce: FirstBounce::Lambertian,
    };
    let t0 = Instant::now();
    let mut stage = Scatter::new(&world, settings, Box::new(Lambertian));
    let build = t0.elapsed().as_secs_f64();
    let ff = &stage.record.form_factors[0];
    println!(
        "form factors: {build:.2} s, {} entries ({:.1} per facet), {:.1} MB stored, \
         max row sum {:.4}, {} rows capped, peak RSS {:.0} MB",
        ff.entries,
        ff.entries as f64 / n as f64,
        ff.bytes as f64 / 1e6,
        ff.max_row_sum,
        ff.rows_capped,
        peak_rss_mb()
    );
    let mut d = vec![0.0; n];
    let mut out = vec![0.0; n];
    for &albedo in &args.albedo {
        stage.set_albedo(vec![albedo; n]);
        let mut times = Vec::new();
        let mut reports = Vec::new();
        for st in &states {
            direct.compute(st, &mut d)?;
            let t = Instant::now();
            reports.push(stage.step(st, &d, &mut out));
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let mean = times.iter().sum::<f64>() / times.len() as f64;
        let worst = times.iter().copied().fold(0.0, f64::max);
        let iters = reports.iter().map(|r| r.iterations).max().unwrap_or(0);
        let residual = reports.iter().map(|r| r.residual).fold(0.0, f64::max);
        println!(
            "albedo {albedo}: {} solve {mean:.1} ms mean, {worst:.1} ms worst per step, \
             ≤ {iters} iterations, residual ≤ {residual:.1e}",
            reports[0].method
        );
    }
    println!("peak RSS {:.0} MB", peak_rss_mb());
    Ok(())
}
