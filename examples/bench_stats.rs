//! Benchmark of the statistics stage: min, max, the exact sums, darkness runs and the CDF
//! counts of every facet, added step by step or in blocks of consecutive steps.
//!
//! ```text
//! cargo run --release --example bench_stats                       # 786,432 facets, 10 W/m² bins
//! cargo run --release --example bench_stats -- --facets 49152 --steps 2000 --blocks 1,4,16
//! ```
//! The irradiance is synthetic and made once before timing: a spin of 12 steps, each
//! facet at its own phase and tilt (changing slowly from facet to facet, as on a mesh), dark half the time, up to 1,125 W/m² (the Sun at
//! 1.1 AU), so the CDF counts see about 114 thresholds as in a real run. For each block
//! size it times adding all steps (blocks of that many steps, `FacetStats::add_steps`)
//! and prints nanoseconds per facet and step; every block size must give statistics
//! identical to one step at a time (checked).

// Shared by several benchmarks; each uses part of it.
#[allow(dead_code)]
mod common;

use slim::stats::{Bins, FacetStats};
use std::time::Instant;

fn main() -> Result<(), String> {
    let options = common::Options::from_env(&["--facets", "--steps", "--blocks"]);
    options.check(&[])?;
    let facets: usize = options.value("--facets", 786_432)?;
    let steps: usize = options.value("--steps", 240)?;
    let blocks = options
        .value("--blocks", "1,4,8,16,32".to_string())?
        .split(',')
        .map(|b| b.parse().map_err(|e| format!("--blocks {b}: {e}")))
        .collect::<Result<Vec<usize>, _>>()?;
    if blocks.contains(&0) {
        return Err("--blocks: a block holds at least one step".into());
    }
    let peak = 1361.0 / 1.21;
    let series: Vec<Vec<f64>> = (0..12)
        .map(|k| {
            (0..facets)
                .map(|i| {
                    // Neighbouring facets see nearly the same light, as on a mesh.
                    let phase = i as f64 * std::f64::consts::TAU / 1000.0;
                    let tilt = 0.65 + 0.35 * (i as f64 / 337.0).sin();
                    let angle = phase + std::f64::consts::TAU * k as f64 / 12.0;
                    (peak * tilt * angle.cos()).max(0.0)
                })
                .collect()
        })
        .collect();
    let bins = Bins::covering(10.0, peak);
    println!(
        "{facets} facets, {steps} steps, {} thresholds, {} threads",
        bins.count,
        rayon::current_num_threads()
    );
    let mut reference: Option<FacetStats> = None;
    for &block in &blocks {
        let mut stats = FacetStats::new(facets, bins);
        let start = Instant::now();
        let mut k = 0;
        while k < steps {
            let len = block.min(steps - k);
            let views: Vec<&[f64]> = (k..k + len).map(|s| series[s % 12].as_slice()).collect();
            stats.add_steps(&views);
            k += len;
        }
        let seconds = start.elapsed().as_secs_f64();
        println!(
            "block {block:>3}: {seconds:.2} s, {:.2} ns per facet and step",
            seconds * 1e9 / (facets * steps) as f64
        );
        match &reference {
            None => reference = Some(stats),
            Some(r) if *r != stats => {
                return Err(format!("block {block} differs from block {}", blocks[0]))
            }
            Some(_) => {}
        }
    }
    Ok(())
}
