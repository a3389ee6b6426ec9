//! Benchmark of SPICE geometry: 10,000 epochs for the Phobos example's two bodies.
//!
//! ```text
//! cargo run --release --example bench_ephemeris
//! ```
//! Loads `data/phobos.toml`'s kernels (Phobos and Mars, LT+S), then times computing the
//! Sun direction, distance and poses at 10,000 epochs spread over the kernels' window,
//! in parallel (rayon), and reports epochs per second.

use slim::ephemeris::spice::{parse_aberration, SpiceBody, SpiceEphemeris};
use slim::prepare::{epoch_states, load_kernels};
use slim::scene::Scene;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/phobos.toml");
    let scene = Scene::load(&path)?;
    let kernels = load_kernels(&scene)?.ok_or("data/phobos.toml is a SPICE scene")?;
    let bodies = vec![
        SpiceBody::new(&kernels, "phobos", 401)?.into(),
        SpiceBody::new(&kernels, "mars", 499)?.into(),
    ];
    let n = 10_000;
    let window_s = 4.0 * 86_400.0;
    let epochs = (0..n)
        .map(|k| scene.start + hifitime::Duration::from_seconds(window_s * k as f64 / n as f64))
        .collect();
    let eph = SpiceEphemeris::new(
        kernels,
        bodies,
        epochs,
        window_s / n as f64,
        parse_aberration("LT+S").flatten(),
        1361.0,
    )?;
    let t0 = Instant::now();
    let states = epoch_states(&eph)?;
    let seconds = t0.elapsed().as_secs_f64();
    println!(
        "{} epochs x 2 bodies (LT+S) in {:.3} s on {} threads: {:.0} epochs/s",
        states.len(),
        seconds,
        rayon::current_num_threads(),
        states.len() as f64 / seconds
    );
    Ok(())
}
