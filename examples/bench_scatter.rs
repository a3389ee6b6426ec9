//! Benchmark of scattered light: form factors with visibility, memory, per-step solve.
//!
//! ```text
//! cargo run --release --example bench_scatter -- [MESH] [--subdivide N] [--steps N]
//!     [--albedo A] [--threads N]
//! ```
//! Default: the 49,152-facet Itokawa model, 12 steps over one spin, albedo 0.1 (the
//! Jacobi regime) and 0.9 (CG). Prints the form-factor build time, the stored entries and
//! bytes, the process's peak resident memory (VmHWM), and the time of each step's solve
//! to 1e-6 relative (the direct irradiance is computed first and not timed): one step at
//! a time, and up to `LANES` steps side by side as `slim run` does for a single body
//! (whose results must be identical).

// Shared by several benchmarks; each uses part of it.
#[allow(dead_code)]
mod common;

use common::peak_rss_mb;
use glam::DVec3;
use slim::illum::Direct;
use slim::scatter::solve::SolverKind;
use slim::scatter::{Lambertian, Scatter, Settings, LANES};
use slim::trace::TracerKind;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let options = common::Options::from_env(&["--subdivide", "--steps", "--albedo", "--threads"]);
    options.apply_threads()?;
    let steps: usize = options.value("--steps", 12)?;
    // One albedo when given; else the Jacobi (0.1) and the CG (0.9) regime.
    let albedos = match options.optional::<f64>("--albedo")? {
        Some(a) => vec![a],
        None => vec![0.1, 0.9],
    };
    let world = options.world(0)?;
    let n = world.facet_count();
    let states = common::spin_states(steps, DVec3::new(1.0, 0.0, 0.3))?;
    println!(
        "mesh {} ({n} facets), {} steps, {} threads, peak RSS after loading {:.0} MB",
        options.mesh().display(),
        steps,
        rayon::current_num_threads(),
        peak_rss_mb()
    );
    let direct = Direct::new(&world, TracerKind::Sunview);
    let settings = Settings {
        max_orders: 1000,
        inter_body_tolerance: 1e-4,
        ..Settings::lambertian(vec![albedos[0]; n], SolverKind::Auto, 1e-6)
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
    let mut directs = vec![vec![0.0; n]; states.len()];
    for (st, d) in states.iter().zip(&mut directs) {
        direct.compute(st, d)?;
    }
    for &albedo in &albedos {
        stage.set_albedo(vec![albedo; n]);
        // One step at a time.
        let mut alone = vec![vec![0.0; n]; states.len()];
        let mut times = Vec::new();
        let mut reports = Vec::new();
        for ((st, d), out) in states.iter().zip(&directs).zip(&mut alone) {
            let t = Instant::now();
            reports.push(stage.step(st, d, out));
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let iters = reports.iter().map(|r| r.iterations).max().unwrap_or(0);
        let residual = reports.iter().map(|r| r.residual).fold(0.0, f64::max);
        println!(
            "albedo {albedo}: {} solve, ≤ {iters} iterations, residual ≤ {residual:.1e}",
            reports[0].method
        );
        print_times("  one step at a time", &times, 1);
        // Up to LANES steps side by side, as `slim run` does for one body.
        let mut together = vec![vec![0.0; n]; states.len()];
        let mut times = Vec::new();
        for (chunk, (d, out)) in states
            .chunks(LANES)
            .zip(directs.chunks(LANES).zip(together.chunks_mut(LANES)))
        {
            let d: Vec<&[f64]> = d.iter().map(Vec::as_slice).collect();
            let mut out: Vec<&mut [f64]> = out.iter_mut().map(Vec::as_mut_slice).collect();
            let t = Instant::now();
            stage.step_many(chunk, &d, &mut out);
            times.push(t.elapsed().as_secs_f64() * 1e3 / chunk.len() as f64);
        }
        print_times(&format!("  {LANES} steps side by side"), &times, LANES);
        if together != alone {
            return Err("steps solved side by side differ from one at a time".into());
        }
    }
    println!("peak RSS {:.0} MB", peak_rss_mb());
    Ok(())
}

/// Mean and worst solve time per step; `times` holds one entry per call, each already
/// divided by the steps it solved.
fn print_times(label: &str, times: &[f64], lanes: usize) {
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    let worst = times.iter().copied().fold(0.0, f64::max);
    let per = if lanes > 1 {
        " (call time / steps)"
    } else {
        ""
    };
    println!("{label}: {mean:.1} ms mean, {worst:.1} ms worst per step{per}");
}
