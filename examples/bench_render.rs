//! Benchmark of the renderer: a 1024 × 1024 image of a large mesh with shadows.
//!
//! ```text
//! cargo run --release --example bench_render -- [MESH] [--subdivide N] [--size PIXELS]
//!     [--threads N] [--repeat N]
//! ```
//! Default: the 49,152-facet Itokawa model subdivided twice (786,432 facets), 1024 × 1024
//! pixels, camera 2 km from the centre with the body filling the frame, 45° phase, Hapke
//! material. Timed: the tracer build (once), then per image the geometry pass (projection,
//! z-buffer, shadow queries at every hit; the Sun-view build of the step included) and the
//! shading pass. Mesh loading is not timed.

// Shared by several benchmarks; each uses part of it.
#[allow(dead_code)]
mod common;

use glam::{DMat3, DVec3};
use slim::ephemeris::{BodyState, EpochState};
use slim::photometry::hapke::{HFunction, Hapke, PhaseFunction};
use slim::photometry::Reflectance;
use slim::render::camera::Camera;
use slim::render::Renderer;
use slim::trace::TracerKind;
use slim::world::Pose;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let options = common::Options::from_env(&["--subdivide", "--size", "--threads", "--repeat"]);
    options.apply_threads()?;
    let size: usize = options.value("--size", 1024)?;
    let repeat = options.value("--repeat", 3usize)?.max(1);
    // Midpoint subdivision, as bench_direct does: ×4 facets per level, same shape.
    let world = options.world(2)?;
    let convex = world.bodies[0].convex;
    let phase = 45f64.to_radians();
    let eye = DVec3::new(0.0, -2000.0, 300.0);
    let sun = (DMat3::from_rotation_z(phase) * eye.normalize()).normalize();
    let state = EpochState {
        step: 0,
        epoch: hifitime::Epoch::from_tdb_seconds(0.0),
        bodies: vec![BodyState {
            sun_dir: sun,
            sun_distance_m: 1.2 * slim::AU_M,
            flux_w_m2: slim::SOLAR_CONSTANT_W_M2 / 1.44,
            pose: Pose::IDENTITY,
        }],
    };
    let camera = Camera::with_fov(size, size, 18.0)?.looking_at(eye, DVec3::ZERO, DVec3::Z)?;
    let hapke = Hapke {
        w: 0.42,
        b0: 1.0,
        h: 0.05,
        phase: PhaseFunction::HenyeyGreenstein1 { xi: -0.3 },
        theta_bar: 20f64.to_radians(),
        h_function: HFunction::Hapke2002,
    };
    let materials: [&dyn Reflectance; 1] = [&hapke];
    println!(
        "mesh {} ({} facets, convex: {convex}), {size}×{size} pixels, {} threads",
        options.mesh().display(),
        world.facet_count(),
        rayon::current_num_threads(),
        size = size,
    );
    let t0 = Instant::now();
    let renderer = Renderer::new(&world, TracerKind::Sunview);
    println!("tracer build: {:.3} s", t0.elapsed().as_secs_f64());
    for k in 0..repeat {
        let t1 = Instant::now();
        let geometry = renderer.geometry(&state, &camera)?;
        let t_geometry = t1.elapsed().as_secs_f64();
        let t2 = Instant::now();
        let image = geometry.radiance(&materials, 1.0);
        let t_shade = t2.elapsed().as_secs_f64();
        let covered = geometry.covered();
        let lit = geometry.samples.iter().flatten().filter(|s| s.lit).count();
        println!(
            "image {k}: geometry {:.3} s, shading {:.3} s, {covered} pixels on the body \
             ({lit} lit), max radiance {:.2} W/m2/sr",
            t_geometry,
            t_shade,
            image.max()
        );
    }
    Ok(())
}
