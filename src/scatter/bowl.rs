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
//!
//! Topo3D's test crater (Schörghofer's Planetary-Code-Collection) is the same sphere cut
//! into a plain and sampled as a DEM: [`topo3d_height`] reproduces its `topo81.xyz` at any
//! pixel size, and [`topo3d_run`] compares a DEM's scattered light with Ingersoll's,
//! separating the facets of the DEM's rim cells from the rest (`examples/crater_refinement.rs`
//! prints the table in docs/accuracy.md). [`Terrain`] lights any such single mesh once.

use super::solve::{SolveReport, SolverKind};
use super::{Lambertian, Scatter, Settings};
use crate::ephemeris::{BodyState, EpochState};
use crate::illum::Direct;
use crate::mesh::generate::height_field;
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

/// Radius of the sphere of Topo3D's bowl crater (m).
pub const TOPO3D_SPHERE_RADIUS_M: f64 = 250.0;

/// Half-angle β of the cap of Topo3D's bowl crater: depth/diameter = tan(β/2)/2 = 1/5.
pub fn topo3d_beta() -> f64 {
    2.0 * 0.4f64.atan()
}

/// Height (m) at (x, y) of Topo3D's bowl crater (Schörghofer's Planetary-Code-Collection,
/// `Topo3D/Test/topo81.xyz`, 81 × 81 heights 5 m apart): the plain z = 0 with a spherical
/// bowl of radius [`TOPO3D_SPHERE_RADIUS_M`] and depth/diameter 1:5 centred on the origin
/// (344.8 m wide, 68.97 m deep). Sampling it on a finer grid refines that DEM.
pub fn topo3d_height(x_m: f64, y_m: f64) -> f64 {
    let r = TOPO3D_SPHERE_RADIUS_M;
    let centre_height = r * topo3d_beta().cos();
    let r2 = x_m * x_m + y_m * y_m;
    if r2 < r * r {
        (centre_height - (r * r - r2).sqrt()).min(0.0)
    } else {
        0.0
    }
}

/// A DEM of Topo3D's crater over its 400 m square centred on the origin: `cells` × `cells`
/// squares of two triangles, `height(x, y)` (m) at the nodes (see [`height_field`]).
pub fn topo3d_dem(cells: usize, height: impl FnMut(f64, f64) -> f64) -> RawMesh {
    height_field((cells, cells), (-200.0, 200.0), (-200.0, 200.0), height)
}

/// Topo3D's run 1 on a DEM of its crater, against Ingersoll. Facets below the plain are
/// split into *interior* ones (every corner below the plain) and *rim* ones (some corner
/// on it: the cells the DEM's sampling turns into a ramp between the 43.6° wall and the
/// plain). Errors are relative: mean over the group / closed form − 1.
#[derive(Debug, Clone, Copy)]
pub struct CraterLight {
    pub facets: usize,
    /// Scattered irradiance: interior facets in shadow and in sunlight, then every facet
    /// below the plain (rim included) in shadow and in sunlight.
    pub shadowed_interior: f64,
    pub sunlit_interior: f64,
    pub shadowed_all: f64,
    pub sunlit_all: f64,
    /// View factor to the rest of the DEM against the sphere's f = (1 − cos β)/2.
    pub view_interior: f64,
    pub view_rim: f64,
    /// Share of the sunlit facets below the plain that are rim facets.
    pub rim_share_of_sunlit: f64,
    /// Form factors (with visibility), seconds.
    pub form_factor_s: f64,
}

/// Runs Topo3D's run 1 on `raw` (a DEM in metres, +z up): the Sun 10° above the plain
/// along +x (rays in the grid's planes), 1365 W/m², albedo 0.12, Lambertian, all orders.
pub fn topo3d_run(raw: RawMesh) -> crate::error::Result<CraterLight> {
    let on_plain = |v: u32| raw.vertices[v as usize].z == 0.0;
    let rim: Vec<bool> = raw
        .triangles
        .iter()
        .map(|t| t.iter().any(|&v| on_plain(v)))
        .collect();
    let mesh = Mesh::from_raw(raw, LengthUnit::M);
    let n = mesh.len();
    let below: Vec<bool> = mesh.centroids.iter().map(|c| c.z < 0.0).collect();
    let (elevation, flux, albedo) = (10f64.to_radians(), 1365.0, 0.12);
    let sun = Sunlight {
        elevation_rad: elevation,
        azimuth_rad: 0.0,
        flux_w_m2: flux,
    };
    let terrain = Terrain::new(mesh, sun);
    let direct = terrain.direct()?;
    let t0 = Instant::now();
    let settings = Settings::lambertian(vec![albedo; n], SolverKind::Jacobi, 1e-10);
    let mut stage = terrain.stage(settings);
    let form_factor_s = t0.elapsed().as_secs_f64();
    let mut scattered = vec![0.0; n];
    stage.step(terrain.state(), &direct, &mut scattered);
    // With an albedo of 1e-6 every order past the first is below 1e-6 of it: a uniform
    // direct field of 1 then scatters into 1e-6 times each facet's view factor.
    let tiny = 1e-6;
    stage.set_albedo(vec![tiny; n]);
    let mut view = vec![0.0; n];
    stage.step(terrain.state(), &vec![1.0; n], &mut view);
    view.iter_mut().for_each(|v| *v /= tiny);

    let beta = topo3d_beta();
    let exact = scattered_irradiance(flux, elevation, albedo, beta);
    let f = (1.0 - beta.cos()) / 2.0;
    let mean_error = |pick: &dyn Fn(usize) -> bool, values: &[f64], reference: f64| {
        let chosen: Vec<usize> = (0..n).filter(|&i| below[i] && pick(i)).collect();
        let sum: f64 = chosen.iter().map(|&i| values[i]).sum();
        sum / chosen.len().max(1) as f64 / reference - 1.0
    };
    let lit = |i: usize| direct[i] > 0.0;
    let sunlit = (0..n).filter(|&i| below[i] && lit(i)).count();
    let sunlit_rim = (0..n).filter(|&i| below[i] && lit(i) && rim[i]).count();
    Ok(CraterLight {
        facets: n,
        shadowed_interior: mean_error(&|i| !rim[i] && !lit(i), &scattered, exact),
        sunlit_interior: mean_error(&|i| !rim[i] && lit(i), &scattered, exact),
        shadowed_all: mean_error(&|i| !lit(i), &scattered, exact),
        sunlit_all: mean_error(&|i| lit(i), &scattered, exact),
        view_interior: mean_error(&|i| !rim[i], &view, f),
        view_rim: mean_error(&|i| rim[i], &view, f),
        rim_share_of_sunlit: sunlit_rim as f64 / sunlit.max(1) as f64,
        form_factor_s,
    })
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
        let terrain = Terrain::new(
            mesh,
            Sunlight {
                elevation_rad: elevation,
                azimuth_rad: 0.0,
                flux_w_m2: flux,
            },
        );
        let direct = terrain.direct()?;
        let t0 = Instant::now();
        let mut stage = terrain.stage(Settings::lambertian(
            vec![albedo; n],
            self.solver,
            self.tolerance,
        ));
        let form_factor_s = t0.elapsed().as_secs_f64();
        let mut scattered = vec![0.0; n];
        let t1 = Instant::now();
        let report = stage.step(terrain.state(), &direct, &mut scattered);
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

/// A distant Sun over terrain whose +z is up: elevation above the x–y plane, azimuth
/// from +x toward +y, and the flux (W/m²).
#[derive(Debug, Clone, Copy)]
pub struct Sunlight {
    pub elevation_rad: f64,
    pub azimuth_rad: f64,
    pub flux_w_m2: f64,
}

impl Sunlight {
    /// Unit vector toward the Sun in the terrain's frame.
    pub fn direction(&self) -> DVec3 {
        let (se, ce) = self.elevation_rad.sin_cos();
        let (sa, ca) = self.azimuth_rad.sin_cos();
        DVec3::new(ce * ca, ce * sa, se)
    }
}

/// One mesh at rest under one Sun: the single-step world the validation cases light.
pub struct Terrain {
    world: World,
    state: EpochState,
}

impl Terrain {
    pub fn new(mesh: Mesh, sun: Sunlight) -> Terrain {
        Terrain {
            world: World {
                bodies: vec![Body::new("terrain", mesh, false)],
            },
            state: EpochState {
                step: 0,
                epoch: hifitime::Epoch::from_tai_seconds(0.0),
                bodies: vec![BodyState {
                    sun_dir: sun.direction(),
                    sun_distance_m: crate::AU_M,
                    flux_w_m2: sun.flux_w_m2,
                    pose: Pose::IDENTITY,
                }],
            },
        }
    }

    pub fn mesh(&self) -> &Mesh {
        &self.world.bodies[0].mesh
    }

    /// Direct irradiance (W/m², per facet) from the sunview tracer.
    pub fn direct(&self) -> crate::error::Result<Vec<f64>> {
        let mut direct = vec![0.0; self.mesh().len()];
        Direct::new(&self.world, TracerKind::Sunview).compute(&self.state, &mut direct)?;
        Ok(direct)
    }

    /// The scattered-light stage (form factors built) for this terrain.
    pub fn stage(&self, settings: Settings) -> Scatter<'_> {
        Scatter::new(&self.world, settings, Box::new(Lambertian))
    }

    /// The one step's geometry, for [`Scatter::step`].
    pub fn state(&self) -> &EpochState {
        &self.state
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
