//! Inversion: Hapke parameters recovered from synthetic noisy images of a sphere within
//! the uncertainties the fit reports, and clean failures when the data cannot constrain
//! what is asked. Images: 48 × 48 pixels, three phase angles (3°, 30°, 65°), Gaussian noise
//! of a known σ from a seeded generator (the test is deterministic).

use glam::{DMat3, DVec3};
use hifitime::Epoch;
use slim::ephemeris::{BodyState, EpochState};
use slim::fit::{fit, Observation};
use slim::image::Image;
use slim::mesh::generate::icosphere;
use slim::mesh::{LengthUnit, Mesh};
use slim::photometry::hapke::{HFunction, Hapke, PhaseFunction};
use slim::photometry::{Material, Reflectance};
use slim::render::camera::Camera;
use slim::render::{GeometryImage, Renderer};
use slim::trace::TracerKind;
use slim::world::{Body, Pose, World};

const FLUX: f64 = 270.0;

fn truth() -> Material {
    Material::Hapke(Hapke {
        w: 0.45,
        b0: 1.2,
        h: 0.08,
        phase: PhaseFunction::HenyeyGreenstein1 { xi: -0.3 },
        theta_bar: 15f64.to_radians(),
        h_function: HFunction::Hapke2002,
    })
}

/// xorshift64* and Box–Muller: standard normal deviates from a fixed seed.
struct Normal(u64);

impl Normal {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn next(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

fn world() -> World {
    World {
        bodies: vec![Body::new(
            "ball",
            Mesh::from_raw(icosphere(3, 1000.0, DVec3::ZERO), LengthUnit::M),
            true,
        )],
    }
}

/// Geometry of one view with the Sun `phase_deg` from the line of sight.
fn view(world: &World, phase_deg: f64, far: bool) -> GeometryImage {
    let eye = DVec3::new(0.0, if far { -2e6 } else { -20_000.0 }, 0.0);
    let fov = if far { 0.07 } else { 7.0 };
    let camera = Camera::with_fov(48, 48, fov)
        .unwrap()
        .looking_at(eye, DVec3::ZERO, DVec3::Z)
        .unwrap();
    let g = phase_deg.to_radians();
    let sun = DVec3::new(g.sin(), -g.cos(), 0.0);
    let state = EpochState {
        step: 0,
        epoch: Epoch::from_tdb_seconds(0.0),
        bodies: vec![BodyState {
            sun_dir: sun,
            sun_distance_m: 2.2 * slim::AU_M,
            flux_w_m2: FLUX,
            pose: Pose {
                body_to_scene: DMat3::IDENTITY,
                position_m: DVec3::ZERO,
            },
        }],
    };
    Renderer::new(world, TracerKind::Sunview)
        .geometry(&state, &camera)
        .unwrap()
}

/// A radiance image of `material` with noise of standard deviation `sigma`.
fn observe(g: &GeometryImage, material: &Material, sigma: f64, rng: &mut Normal) -> Image {
    let refs: [&dyn Reflectance; 1] = [material];
    let mut image = g.radiance(&refs, 1.0);
    for p in image.pixels.iter_mut() {
        *p += sigma * rng.next();
    }
    image
}

fn names(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

#[test]
fn recovers_hapke_parameters_within_reported_uncertainties() {
    let world = world();
    let geometries: Vec<GeometryImage> = [3.0, 30.0, 65.0]
        .iter()
        .map(|&p| view(&world, p, false))
        .collect();
    let truth = truth();
    let mut rng = Normal(0x5eed_1234_abcd_ef01);
    let sigma = 0.05; // W m⁻² sr⁻¹: about 0.5 % of the brightest pixel
    let images: Vec<Image> = geometries
        .iter()
        .map(|g| observe(g, &truth, sigma, &mut rng))
        .collect();
    let materials = [truth.clone()];
    let observations: Vec<Observation<'_>> = geometries
        .iter()
        .zip(&images)
        .map(|(g, observed)| Observation {
            geometry: g,
            observed,
            flux_scale: 1.0,
            materials: &materials,
        })
        .collect();
    let fitted = names(&["w", "xi", "b0", "theta_bar_deg"]);
    let mut start = truth.clone();
    for (n, v) in [
        ("w", 0.3),
        ("xi", -0.1),
        ("b0", 0.5),
        ("theta_bar_deg", 5.0),
    ] {
        start.set(n, v).unwrap();
    }
    let result = fit(&observations, 0, &start, &fitted).unwrap();
    // The noise estimate from the residuals must match the noise put in.
    assert!(
        (result.rms / sigma - 1.0).abs() < 0.05,
        "rms {}",
        result.rms
    );
    for (j, name) in fitted.iter().enumerate() {
        let true_value = truth.get(name).unwrap();
        let (value, s) = (result.values[j], result.sigmas[j]);
        assert!(s > 0.0 && s.is_finite(), "{name}: σ = {s}");
        // 4σ: with four parameters a 3σ excursion has a few per cent chance; 4σ ~0.03 %.
        assert!(
            (value - true_value).abs() < 4.0 * s,
            "{name}: {value} ± {s}, true {true_value}"
        );
        assert!(!result.at_bound[j]);
        assert!((result.correlation[j][j] - 1.0).abs() < 1e-12);
    }
    // Uncertainties small enough to mean something.
    assert!(result.sigmas[0] < 0.02, "σ_w = {}", result.sigmas[0]);
    // Residual images hold observed − model: their RMS over all pixels is the noise.
    let all: Vec<f64> = result
        .residuals
        .iter()
        .flat_map(|r| r.pixels.clone())
        .collect();
    let rms_all = (all.iter().map(|x| x * x).sum::<f64>() / all.len() as f64).sqrt();
    assert!((rms_all / sigma - 1.0).abs() < 0.05, "{rms_all}");
}

#[test]
fn lambert_albedo_is_recovered_from_i_over_f() {
    let world = world();
    let g = view(&world, 40.0, false);
    let truth = Material::from_params("lambert", &[("albedo".into(), 0.23)], None).unwrap();
    let refs: [&dyn Reflectance; 1] = [&truth];
    let mut observed = g.i_over_f(&refs);
    observed.set("BUNIT", slim::image::Value::Text("I/F".into()), "");
    let mut rng = Normal(7);
    observed
        .pixels
        .iter_mut()
        .for_each(|p| *p += 0.002 * rng.next());
    let materials = [truth.clone()];
    let obs = [Observation {
        geometry: &g,
        observed: &observed,
        flux_scale: 1.0,
        materials: &materials,
    }];
    let start = Material::from_params("lambert", &[("albedo".into(), 0.9)], None).unwrap();
    let r = fit(&obs, 0, &start, &names(&["albedo"])).unwrap();
    assert!(
        (r.values[0] - 0.23).abs() < 4.0 * r.sigmas[0],
        "{:?}",
        r.values
    );
}

#[test]
fn unconstrained_parameters_fail_cleanly() {
    let world = world();
    let g = view(&world, 30.0, false);
    let mut truth = truth();
    truth.set("b0", 0.0).unwrap();
    let mut rng = Normal(99);
    let observed = observe(&g, &truth, 0.05, &mut rng);
    let materials = [truth.clone()];
    let obs = [Observation {
        geometry: &g,
        observed: &observed,
        flux_scale: 1.0,
        materials: &materials,
    }];
    // With b0 = 0 the surge width h changes nothing.
    let e = fit(&obs, 0, &truth, &names(&["w", "h"]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("parameter h is not constrained"), "{e}");
    // Seen from afar every pixel has the same phase angle: B₀ and h act only through B(g),
    // one number, so only a combination of them is constrained.
    let far = view(&world, 30.0, true);
    let mut surge = truth.clone();
    surge.set("b0", 1.0).unwrap();
    let observed = observe(&far, &surge, 0.0, &mut rng);
    let obs = [Observation {
        geometry: &far,
        observed: &observed,
        flux_scale: 1.0,
        materials: &materials,
    }];
    let e = fit(&obs, 0, &surge, &names(&["b0", "h"]))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("not constrained separately") && e.contains("b0"),
        "{e}"
    );
    // Unknown names, and a body nobody sees, are errors too.
    assert!(fit(&obs, 0, &surge, &names(&["albedo"])).is_err());
}
