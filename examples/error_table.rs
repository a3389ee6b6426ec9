//! Error against run time: how many steps per spin are enough.
//!
//! ```text
//! cargo run --release --example error_table
//! ```
//! Prints two Markdown tables of the error in the per-facet mean, maximum and CDF F(x)
//! versus steps per spin, with the run time of each row:
//! 1. a rotating icosphere (20,480 facets, sub-solar latitude 20°) against the closed form
//!    of [`slim::analytic::SphereLatitude`] at each facet's normal latitude;
//! 2. the shipped Phobos example (`data/phobos-spin.toml`) against the same run with 10×
//!    more steps than the finest row.

use glam::DVec3;
use slim::analytic::SphereLatitude;
use slim::ephemeris::spin::{Spin, SpinModel};
use slim::mesh::{generate::icosphere, LengthUnit, Mesh};
use slim::prepare::{bins_for, build_ephemeris, build_world, epoch_states};
use slim::scene::{EphemerisSection, Scene};
use slim::simulate::statistics;
use slim::stats::{Bins, FacetStats};
use slim::trace::TracerKind;
use slim::world::{Body, World};
use std::time::Instant;

type Error = Box<dyn std::error::Error>;

/// Largest errors of a run: mean and max in W/m², CDF as a share of time.
struct Errors {
    mean: f64,
    max: f64,
    cdf: f64,
}

fn main() -> Result<(), Error> {
    sphere_table()?;
    phobos_table()
}

fn header(title: &str) {
    println!("\n{title}\n");
    println!("| steps per spin | run time (s) | max error of mean (W/m²) | max error of max (W/m²) | max error of F(x) |");
    println!("|---:|---:|---:|---:|---:|");
}

fn row(steps: usize, seconds: f64, e: &Errors) {
    println!(
        "| {steps} | {seconds:.3} | {:.3e} | {:.3e} | {:.4} |",
        e.mean, e.max, e.cdf
    );
}

fn sphere_table() -> Result<(), Error> {
    let mesh = Mesh::from_raw(icosphere(5, 1000.0, DVec3::ZERO), LengthUnit::M);
    let world = World {
        bodies: vec![Body::new("sphere", mesh, true)],
    };
    let subsolar = 20f64.to_radians();
    let flux = slim::SOLAR_CONSTANT_W_M2;
    header("Rotating sphere, 20,480 facets, sub-solar latitude 20°, S = 1361 W/m², against the closed form");
    for steps in [12, 24, 48, 96, 192, 360, 720, 1440] {
        let spin = SpinModel {
            start: hifitime::Epoch::from_tdb_seconds(0.0),
            duration_s: 3600.0,
            steps,
            sun_dir_scene: SpinModel::sun_dir_for_subsolar_latitude(subsolar),
            sun_distance_m: slim::AU_M,
            solar_constant_w_m2: flux,
            bodies: vec![Spin {
                period_s: Some(3600.0),
                initial_angle_rad: 0.0,
                position_m: DVec3::ZERO,
            }],
        };
        let t0 = Instant::now();
        let states = epoch_states(&spin)?;
        let bins = Bins::covering(10.0, flux);
        let sim = statistics(&world, &states, TracerKind::Sunview, bins)?;
        let seconds = t0.elapsed().as_secs_f64();
        let normals = &world.bodies[0].mesh.normals;
        let exact = |i: usize| SphereLatitude::from_normal_z(normals[i].z, subsolar, flux);
        row(
            steps,
            seconds,
            &errors(&sim.stats, |i| {
                let e = exact(i);
                (
                    e.mean(),
                    e.max(),
                    (0..bins.count).map(|b| e.cdf(bins.threshold(b))).collect(),
                )
            }),
        );
    }
    Ok(())
}

fn phobos_table() -> Result<(), Error> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/phobos-spin.toml");
    let scene = Scene::load(&path)?;
    let (world, _, _) = build_world(&scene, None)?;
    let run = |steps: usize| -> Result<(FacetStats, f64), Error> {
        let mut s = scene.clone();
        if let EphemerisSection::Spin(spin) = &mut s.ephemeris {
            spin.steps_per_period = steps;
        }
        let t0 = Instant::now();
        let states = epoch_states(build_ephemeris(&s, None)?.as_ref())?;
        let bins = bins_for(&s, &states)?;
        let sim = statistics(&world, &states, TracerKind::Sunview, bins)?;
        Ok((sim.stats, t0.elapsed().as_secs_f64()))
    };
    let rows = [36, 72, 144, 360, 720, 1440];
    let (reference, ref_seconds) = run(10 * rows[rows.len() - 1])?;
    header(&format!(
        "Phobos (m1phobos, 32,070 facets, 1.52 AU) against {} steps per spin ({ref_seconds:.1} s)",
        10 * rows[rows.len() - 1]
    ));
    for steps in rows {
        let (stats, seconds) = run(steps)?;
        row(
            steps,
            seconds,
            &errors(&stats, |i| {
                (reference.mean(i), reference.max(i), reference.cdf(i))
            }),
        );
    }
    Ok(())
}

/// Largest errors over facets against `truth(i) = (mean, max, cdf at every threshold)`.
fn errors(stats: &FacetStats, truth: impl Fn(usize) -> (f64, f64, Vec<f64>)) -> Errors {
    let mut e = Errors {
        mean: 0.0,
        max: 0.0,
        cdf: 0.0,
    };
    for i in 0..stats.facets() {
        let (mean, max, cdf) = truth(i);
        e.mean = e.mean.max((stats.mean(i) - mean).abs());
        e.max = e.max.max((stats.max(i) - max).abs());
        for (a, b) in stats.cdf(i).iter().zip(&cdf) {
            e.cdf = e.cdf.max((a - b).abs());
        }
    }
    e
}
