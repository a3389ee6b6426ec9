//! Ingersoll's spherical bowl crater (Ingersoll, Svitek & Murray 1992, Icarus 100, 40):
//! a mesh generator and the closed form of its scattered light, for validation.
//!
//! In: the sphere radius R (metres), the cap half-angle β and a ring count. Out: a
//! [`RawMesh`] of the cap `θ ≤ β` (θ measured from the bottom) of the sphere centred at
//! the origin, facets facing the centre, rim in the plane z = −R cos β, opening toward +z;
//! and [`scattered_irradiance`]. In a spherical cap every pair of points has the same
//! form factor per unit area, 1/(4πR²), so the scattered irradiance is uniform over the
//! whole bowl: `S = F₀ sin e₀ ρ f (1 − f)/(1 − ρ f)` with `f = (1 − cos β)/2` for the Sun
//! at elevation e₀ above the rim plane, flux F₀ (W/m²).
//!
//! The mesh is a disc of `rings` concentric rings (ring k holds 6k vertices) mapped onto
//! the cap by the equal-area map `1 − cos θ = (k/rings)² (1 − cos β)`, so facets are near
//! equilateral and of near equal area: 6·rings² facets. [`BowlCase`] runs the whole
//! validation (direct light, form factors, solve) and reports the error against the
//! closed form; the tests and the error table (`examples/scatter_error.rs`) use it.

use super::solve::{SolveReport, SolverKind};
use super::{form_factor::NearField, FirstBounce, Lambertian, Scatter, Settings};
use crate::ephemeris::{BodyState, EpochState};
use crate::illum::Direct;
use crate::mesh::{LengthUnit, Mesh, RawMesh};
use crate::trace::TracerKind;
use crate::world::{Body, Pose, World};
use glam::DVec3;
use std::f64::consts::PI;
use std::time::Instant;

/// The cap mesh (see the module doc).
pub fn bowl_mesh(radius_m: f64, beta_rad: f64, rings: u32) -> RawMesh {
    let mut vertices = vec![DVec3::new(0.0, 0.0, -radius_m)];
    let mut first = vec![0u32];
    for k in 1..=rings {
        first.push(vertices.len() as u32);
        let cos_theta = 1.0 - (k as f64 / rings as f64).powi(2) * (1.0 - beta_rad.cos());
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        for m in 0..6 * k {
            let phi = 2.0 * PI * m as f64 / (6 * k) as f64;
            vertices.push(
                radius_m * DVec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), -cos_theta),
            );
        }
    }
    let ring_len = |k: u32| if k == 0 { 1 } else { 6 * k };
    let mut triangles = Vec::with_capacity(6 * (rings * rings) as usize);
    for k in 1..=rings {
        let (ni, no) = (ring_len(k - 1), ring_len(k));
        let inner = |a: u32| first[k as usize - 1] + a % ni;
        let outer = |b: u32| first[k as usize] + b % no;
        let (mut a, mut b) = (0, 0);
        // Walk both rings counter-clockwise, always advancing the one whose next vertex
        // comes first; each advance closes one counter-clockwise (seen from +z) triangle.
        while b < no || (a < ni && k > 1) {
            let next_inner = (a + 1) as f64 / ni as f64;
            let next_outer = (b + 1) as f64 / no as f64;
            if b < no && (k == 1 || a == ni || next_outer <= next_inner) {
                triangles.push([inner(a), outer(b), outer(b + 1)]);
                b += 1;
            } else {
                triangles.push([inner(a), outer(b), inner(a + 1)]);
                a += 1;
            }
        }
    }
    RawMesh {
        vertices,
        triangles,
    }
}

/// Ingersoll's uniform scattered irradiance in the bowl (W/m²).
pub fn scattered_irradiance(flux_w_m2: f64, elevation_rad: f64, albedo: f64, beta_rad: f64) -> f64 {
    let f = (1.0 - beta_rad.cos()) / 2.0;
    flux_w_m2 * elevation_rad.sin() * albedo * f * (1.0 - f) / (1.0 - albedo * f)
}

/// Ingersoll's validation case: a bowl of R = 100 m, β = 40°, albedo 0.3, the Sun 20°
/// above the rim plane at 1000 W/m², direct light from the sunview tracer.
#[derive(Debug, Clone, Copy)]
pub struct BowlCase {
    pub rings: u32,
    pub solver: SolverKind,
    pub tolerance: f64,
}

/// What a [`BowlCase`] gave.
#[derive(Debug, Clone, Copy)]
pub struct BowlResult {
    pub facets: usize,
    /// Mean and largest |S/S_exact − 1| over the shadowed facets.
    pub mean_error: f64,
    pub max_error: f64,
    /// Form factors (with visibility) and the solve, seconds.
    pub form_factor_s: f64,
    pub solve_s: f64,
    pub report: SolveReport,
}

impl BowlCase {
    /// Runs the case.
    pub fn run(&self) -> crate::error::Result<BowlResult> {
        let (beta, elevation, albedo, flux) = (40f64.to_radians(), 20f64.to_radians(), 0.3, 1000.0);
        let mesh = Mesh::from_raw(bowl_mesh(100.0, beta, self.rings), LengthUnit::M);
        let n = mesh.len();
        let world = World {
            bodies: vec![Body::new("bowl", mesh, false)],
        };
        let state = EpochState {
            step: 0,
            epoch: hifitime::Epoch::from_tai_seconds(0.0),
            bodies: vec![BodyState {
                sun_dir: DVec3::new(elevation.cos(), 0.0, elevation.sin()),
                sun_distance_m: crate::AU_M,
                flux_w_m2: flux,
                pose: Pose::IDENTITY,
            }],
        };
        let mut direct = vec![0.0; n];
        Direct::new(&world, TracerKind::Sunview).compute(&state, &mut direct)?;
        let settings = Settings {
            albedo: vec![albedo; n],
            solver: self.solver,
            max_orders: 10_000,
            tolerance: self.tolerance,
            inter_body_tolerance: 0.0,
            near_field: NearField::default(),
            first_bounce: FirstBounce::Lambertian,
            planets: Vec::new(),
            planet: Default::default(),
        };
        let t0 = Instant::now();
        let mut stage = Scatter::new(&world, settings, Box::new(Lambertian));
        let form_factor_s = t0.elapsed().as_secs_f64();
        let mut scattered = vec![0.0; n];
        let t1 = Instant::now();
        let report = stage.step(&state, &direct, &mut scattered);
        let solve_s = t1.elapsed().as_secs_f64();
        let exact = scattered_irradiance(flux, elevation, albedo, beta);
        let errors: Vec<f64> = (0..n)
            .filter(|&i| direct[i] == 0.0)
            .map(|i| (scattered[i] / exact - 1.0).abs())
            .collect();
        Ok(BowlResult {
            facets: n,
            mean_error: errors.iter().sum::<f64>() / errors.len().max(1) as f64,
            max_error: errors.iter().copied().fold(0.0, f64::max),
            form_factor_s,
            solve_s,
            report,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bowl_has_the_cap_area_and_faces_the_centre() {
        let beta = 40f64.to_radians();
        let mesh = Mesh::from_raw(bowl_mesh(1.0, beta, 20), LengthUnit::M);
        assert_eq!(mesh.len(), 6 * 400);
        let area: f64 = mesh.areas.iter().sum();
        let cap = 2.0 * PI * (1.0 - beta.cos());
        // Flat facets inscribed in the sphere: area short by O(h²), h ≈ 0.7/20.
        assert!((area / cap - 1.0).abs() < 2e-3, "{area} vs {cap}");
        for i in 0..mesh.len() {
            assert!(mesh.normals[i].dot(-mesh.centroids[i]) > 0.9);
        }
    }
}
