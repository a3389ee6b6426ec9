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

use slim::stats::{Bins, FacetStats};
use std::time::Instant;

fn main() -> Result<(), String> {
    let (mut facets, mut steps, mut blocks) = (786_432usize, 240usize, vec![1usize, 4, 8, 16, 32]);
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let value = args.next().ok_or(format!("{flag} needs a value"))?;
        let bad = |e: std::num::ParseIntError| format!("{flag} {value}: {e}");
        match flag.as_str() {
            "--facets" => facets = value.parse().map_err(bad)?,
            "--steps" => steps = value.parse().map_err(bad)?,
            "--blocks" => {
                blocks = value
                    .split(',')
                    .map(|b| b.parse().map_err(bad))
                    .collect::<Result<_, _>>()?
            }
            _ => return Err(format!("unknown option {flag}")),
        }
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
