//! Planet-shine: sunlight that a large convex body, given as an ellipsoid, reflects onto
//! the facets of the other bodies (Mars-shine on Phobos, Earth-shine on the Moon).
//!
//! In: the planet's semi-axes (metres, along its frame's axes), its Lambertian albedo ρ,
//! each step's poses, Sun direction and flux, and a receiving body's mesh with its
//! [`Bvh`] (and [`HorizonBound`] when it can hide part of the sky from itself). Out: per
//! receiving facet, the irradiance (W/m²) arriving from the planet:
//!
//! `E_i = Σ_k L_k · cos θ_ik · dΩ_ik · V_ik`, with `L_k = ρ F max(0, n_k·s) / π`
//!
//! over quadrature points k on the part of the planet seen from the receiver's centre:
//! the visible cap of the planet scaled to a unit sphere, `2n²` points (Gauss–Legendre in
//! the cosine from the sub-observer point, `2n` azimuths), mapped back onto the ellipsoid
//! with its area element. For each facet the solid angle `dΩ_ik = dA_k cos e_ik / r_ik²`
//! and the incidence `cos θ_ik` are exact; `V_ik` is 0 where the receiver itself hides the
//! point (a ray through its BVH, traced only where the horizon bound cannot clear it).
//! Points behind the facet's plane or beyond the planet's limb seen from the facet count
//! 0. This is the closed-form-matched model the planet's size calls for: the planet's
//! own facets never enter, so its mesh resolution and rotation cost nothing.
//!
//! The weights `cos θ_ik dΩ_ik V_ik` depend only on where the planet is in the
//! receiver's frame. They are kept while the planet's centre direction moves by less
//! than `reuse` radians and its distance by less than the fraction `reuse` since they
//! were built, and scaled by `(d_built / d)²` meanwhile; the radiances follow the Sun at
//! every step. Left out: light the receiver sends back to the planet and on again (at
//! most `ρ_receiver · (R_receiver / d)²` of the planet-shine), and the receiver's shadow
//! on the planet.

use super::visibility::{facets, rounding_margin, SAME_FRAME};
use crate::ephemeris::EpochState;
use crate::horizon::bound::HorizonBound;
use crate::mesh::Mesh;
use crate::quadrature::gauss_legendre;
use crate::scene::{DEFAULT_PLANET_ORDER, DEFAULT_PLANET_REUSE};
use crate::trace::bvh::Bvh;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::Arc;

/// How planet-shine is computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanetSettings {
    /// Gauss–Legendre nodes across the visible cap; `2n²` points in all.
    pub order: usize,
    /// Largest move of the planet (radians of direction, fraction of distance) before
    /// the weights are rebuilt.
    pub reuse: f64,
}

impl Default for PlanetSettings {
    fn default() -> Self {
        PlanetSettings {
            order: DEFAULT_PLANET_ORDER,
            reuse: DEFAULT_PLANET_REUSE,
        }
    }
}

/// A planet's light on the other bodies.
pub struct PlanetShine {
    /// The planet's body index.
    pub planet: usize,
    radii_m: DVec3,
    settings: PlanetSettings,
    /// Per body (scene order): the weights it receives with, once built.
    kernels: Vec<Option<Arc<Kernel>>>,
    /// The weights each (step, receiver) of the current batch of steps was lit with:
    /// spectral bands replay the broadband light's steps with these, so that every band
    /// sees the same weights and no result depends on how steps are batched.
    used: Vec<(usize, usize, Arc<Kernel>)>,
    /// Weights built and reused, over the run.
    pub built: u64,
    pub reused: u64,
}

/// The weights of one receiving body for the planet where it was when they were built.
struct Kernel {
    /// Planet centre in the receiver's frame, metres.
    centre_m: DVec3,
    /// Planet surface normal at each point, receiver frame.
    normals: Vec<DVec3>,
    /// `cos θ_ik · dΩ_ik · V_ik` (sr), facet by facet, `normals.len()` per facet.
    weights: Vec<f32>,
}

/// A receiving body: its mesh and what can hide the planet from its facets.
pub struct Receiver<'a> {
    pub mesh: &'a Mesh,
    pub bvh: &'a Bvh<'a>,
    /// `None` for a closed convex body, which hides nothing above a facet's plane.
    pub bound: Option<&'a HorizonBound>,
}

impl PlanetShine {
    /// The planet `planet` of semi-axes `radii_m` among `bodies` bodies.
    pub fn new(planet: usize, radii_m: DVec3, bodies: usize, settings: PlanetSettings) -> Self {
        PlanetShine {
            planet,
            radii_m,
            settings,
            kernels: (0..bodies).map(|_| None).collect(),
            used: Vec::new(),
            built: 0,
            reused: 0,
        }
    }

    /// Forgets the weights of the last batch of steps (a new batch begins).
    pub fn begin_batch(&mut self) {
        self.used.clear();
    }

    /// Adds to `out` (receiver `r`'s facets) the irradiance the planet of albedo `albedo`
    /// sends at `state`, for a share `flux_share` of the solar flux (1 for broadband).
    /// With `replay` (a spectral band going over steps the broadband light has seen in
    /// this batch), the weights that light used at `state` serve again.
    #[allow(clippy::too_many_arguments)]
    pub fn add(
        &mut self,
        state: &EpochState,
        r: usize,
        receiver: &Receiver,
        albedo: f64,
        flux_share: f64,
        replay: bool,
        out: &mut [f64],
    ) {
        let to_receiver = state.bodies[self.planet]
            .pose
            .relative_to(&state.bodies[r].pose);
        let centre = to_receiver.offset_m;
        let seen = replay
            .then(|| {
                self.used
                    .iter()
                    .find(|(step, at, _)| (*step, *at) == (state.step, r))
            })
            .flatten()
            .map(|(_, _, k)| Arc::clone(k));
        let kernel = match seen {
            Some(kernel) => {
                self.reused += 1;
                kernel
            }
            None => {
                let current = self.kernels[r].as_ref();
                if current.is_none_or(|k| !self.close_enough(k.centre_m, centre)) {
                    self.kernels[r] = Some(Arc::new(self.build(receiver, &to_receiver)));
                    self.built += 1;
                } else {
                    self.reused += 1;
                }
                let kernel = Arc::clone(self.kernels[r].as_ref().expect("built"));
                self.used.push((state.step, r, Arc::clone(&kernel)));
                kernel
            }
        };
        let sun = state.bodies[r].sun_dir;
        let flux = state.bodies[self.planet].flux_w_m2 * flux_share;
        let scale = kernel.centre_m.length_squared() / centre.length_squared();
        let radiance: Vec<f32> = kernel
            .normals
            .iter()
            .map(|n| (albedo * flux * n.dot(sun).max(0.0) / PI * scale) as f32)
            .collect();
        let points = radiance.len();
        out.par_iter_mut()
            .zip(kernel.weights.par_chunks(points.max(1)))
            .for_each(|(e, w)| {
                let sum: f32 = w.iter().zip(&radiance).map(|(w, l)| w * l).sum();
                *e += sum as f64;
            });
    }

    /// Builds receiver `r`'s weights where a run through `earlier` would hold them: at
    /// the last of those steps at which [`PlanetShine::add`] would have rebuilt them. The
    /// counts are left alone (a time shard's counts add up to one run's).
    pub fn prime(&mut self, earlier: &[EpochState], r: usize, receiver: &Receiver) {
        let to_receiver =
            |s: &EpochState| s.bodies[self.planet].pose.relative_to(&s.bodies[r].pose);
        let mut anchor: Option<(DVec3, &EpochState)> = None;
        for state in earlier {
            let centre = to_receiver(state).offset_m;
            if anchor.is_none_or(|(built, _)| !self.close_enough(built, centre)) {
                anchor = Some((centre, state));
            }
        }
        if let Some((_, state)) = anchor {
            self.kernels[r] = Some(Arc::new(self.build(receiver, &to_receiver(state))));
        }
    }

    /// Whether weights built with the planet at `built` still serve it at `now`.
    fn close_enough(&self, built: DVec3, now: DVec3) -> bool {
        let turn = built.angle_between(now);
        let stretch = (now.length() / built.length() - 1.0).abs();
        turn <= self.settings.reuse && stretch <= self.settings.reuse
    }

    /// The weights of `receiver` with the planet where `to_receiver` puts it.
    fn build(&self, receiver: &Receiver, to_receiver: &crate::world::FrameTransform) -> Kernel {
        let points = self.cap_points(to_receiver);
        let mesh = receiver.mesh;
        let margin = rounding_margin(&facets(mesh, &SAME_FRAME));
        let count = points.len();
        let mut weights = vec![0.0f32; mesh.len() * count];
        weights
            .par_chunks_mut(count.max(1))
            .enumerate()
            .for_each(|(i, row)| {
                let (c, n) = (mesh.centroids[i], mesh.normals[i]);
                for (w, p) in row.iter_mut().zip(&points) {
                    let v = p.position - c;
                    let r2 = v.length_squared();
                    let dir = v / r2.sqrt();
                    let (incidence, emission) = (n.dot(dir), -p.normal.dot(dir));
                    if incidence <= 0.0 || emission <= 0.0 {
                        continue;
                    }
                    let clear = receiver
                        .bound
                        .is_none_or(|b| b.clears(i, n, dir, incidence))
                        || !receiver.bvh.segment_blocked(
                            c,
                            p.position,
                            [i as u32, u32::MAX],
                            margin,
                        );
                    if clear {
                        *w = (incidence * p.area_m2 * emission / r2) as f32;
                    }
                }
            });
        Kernel {
            centre_m: to_receiver.offset_m,
            normals: points.iter().map(|p| p.normal).collect(),
            weights,
        }
    }

    /// Quadrature points on the cap of the planet visible from the receiver's centre, in
    /// the receiver's frame.
    fn cap_points(&self, to_receiver: &crate::world::FrameTransform) -> Vec<CapPoint> {
        let rotation = to_receiver.rotation;
        let observer = rotation.transpose() * -to_receiver.offset_m;
        let scaled = observer / self.radii_m;
        let distance = scaled.length();
        if distance <= 1.0 {
            return Vec::new();
        }
        let up = scaled / distance;
        let (e1, e2) = up.any_orthonormal_pair();
        let (lowest, azimuths) = (1.0 / distance, 2 * self.settings.order);
        let volume = self.radii_m.x * self.radii_m.y * self.radii_m.z;
        let mut points = Vec::with_capacity(self.settings.order * azimuths);
        for (node, weight) in gauss_legendre(self.settings.order) {
            // cos β from the limb seen from the centre (1/distance) to the sub-observer point.
            let mu = lowest + (1.0 - lowest) * (node + 1.0) / 2.0;
            let d_mu = (1.0 - lowest) / 2.0 * weight;
            let across = (1.0 - mu * mu).max(0.0).sqrt();
            for m in 0..azimuths {
                let phi = (m as f64 + 0.5) * 2.0 * PI / azimuths as f64;
                let x = mu * up + across * (phi.cos() * e1 + phi.sin() * e2);
                let inward = x / self.radii_m;
                let area_m2 = volume * inward.length() * d_mu * 2.0 * PI / azimuths as f64;
                points.push(CapPoint {
                    position: to_receiver.point(x * self.radii_m),
                    normal: rotation * inward.normalize(),
                    area_m2,
                });
            }
        }
        points
    }
}

/// A quadrature point on the planet, receiver frame.
struct CapPoint {
    position: DVec3,
    normal: DVec3,
    area_m2: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ephemeris::BodyState;
    use crate::world::Pose;
    use glam::DMat3;

    const FLUX: f64 = 600.0;
    const ALBEDO: f64 = 0.25;

    use crate::mesh::in_metres as mesh;

    /// A 2 m triangle at the origin facing `normal`.
    fn small_facet(normal: DVec3) -> Mesh {
        let (a, b) = normal.any_orthonormal_pair();
        let b = if a.cross(b).dot(normal) > 0.0 { b } else { -b };
        mesh(vec![-a - b, a - b, b * 2.0], vec![[0, 1, 2]])
    }

    /// The receiver at the origin and the planet at `planet_at`, both unrotated, with the
    /// Sun along `sun` (unit) for both.
    fn state(planet_at: DVec3, sun: DVec3) -> EpochState {
        let body = |position_m| BodyState {
            sun_dir: sun,
            sun_distance_m: 2.0e11,
            flux_w_m2: FLUX,
            pose: Pose {
                body_to_scene: DMat3::IDENTITY,
                position_m,
            },
        };
        EpochState {
            step: 0,
            epoch: hifitime::Epoch::from_tai_seconds(0.0),
            bodies: vec![body(DVec3::ZERO), body(planet_at)],
        }
    }

    /// Planet-shine on facet 0 of `receiver` from a sphere of radius `radius` at
    /// `planet_at`.
    fn shine(
        receiver: &Mesh,
        bound: Option<&HorizonBound>,
        radius: f64,
        planet_at: DVec3,
        sun: DVec3,
        order: usize,
    ) -> f64 {
        let bvh = Bvh::build(receiver);
        let settings = PlanetSettings { order, reuse: 0.0 };
        let mut planet = PlanetShine::new(1, DVec3::splat(radius), 2, settings);
        let mut out = vec![0.0; receiver.len()];
        let r = Receiver {
            mesh: receiver,
            bvh: &bvh,
            bound,
        };
        planet.add(&state(planet_at, sun), 0, &r, ALBEDO, 1.0, false, &mut out);
        out[0]
    }

    /// The same irradiance by brute force: 400,000 points spread evenly over the sphere
    /// (a Fibonacci lattice), each adding `L cos e cos θ dA / r²` when it faces both the
    /// Sun and the facet and lies in front of the facet's plane.
    fn brute_force(normal: DVec3, radius: f64, centre: DVec3, sun: DVec3) -> f64 {
        let n = 400_000;
        let area = 4.0 * PI * radius * radius / n as f64;
        let golden = PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|k| {
                let z = 1.0 - (2.0 * k as f64 + 1.0) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let up = DVec3::new(
                    r * (golden * k as f64).cos(),
                    r * (golden * k as f64).sin(),
                    z,
                );
                let to_facet = -(centre + radius * up);
                let dist = to_facet.length();
                let (cos_e, cos_t) = (up.dot(to_facet) / dist, -normal.dot(to_facet) / dist);
                let lit = up.dot(sun).max(0.0);
                if cos_e > 0.0 && cos_t > 0.0 {
                    ALBEDO * FLUX * lit / PI * cos_e * cos_t * area / (dist * dist)
                } else {
                    0.0
                }
            })
            .sum()
    }

    #[test]
    fn a_lambert_sphere_far_away_gives_the_closed_form_at_every_phase() {
        // E = (2/3) ρ F (R/d)² Φ(α), Φ(α) = (sin α + (π − α) cos α)/π, for a facet facing
        // the planet's centre, in the limit d ≫ R; at d = 10⁴ R the nearer half of the
        // planet being closer changes E by about R/d = 1e-4.
        let (radius, d): (f64, f64) = (3.4e6, 3.4e10);
        let facet = small_facet(DVec3::X);
        for degrees in [0.0f64, 45.0, 90.0, 135.0] {
            let alpha = degrees.to_radians();
            let sun = DVec3::new(-alpha.cos(), alpha.sin(), 0.0);
            let phase = (alpha.sin() + (PI - alpha) * alpha.cos()) / PI;
            let closed = 2.0 / 3.0 * ALBEDO * FLUX * (radius / d).powi(2) * phase;
            let e = shine(&facet, None, radius, DVec3::new(d, 0.0, 0.0), sun, 16);
            // The terminator's kink across the cap (at any phase but 0) holds 16 Gauss–
            // Legendre nodes to about 2e-3 (seen: 7e-5 at 0°, 1.6e-3 at 90°).
            assert!(
                (e - closed).abs() < 3e-3 * closed,
                "α {degrees}: {e} vs {closed}"
            );
        }
    }

    #[test]
    fn mars_seen_from_phobos_matches_a_brute_force_integral_for_any_facet() {
        // R/d = 0.36 (Mars from Phobos): the finite size matters; facets tilted so that
        // the planet is cut by their plane.
        let (radius, d) = (3.39e6, 9.38e6);
        let centre = DVec3::new(d, 0.0, 0.0);
        for (normal, sun) in [
            (DVec3::X, DVec3::new(-0.5, 0.866, 0.0)),
            (
                DVec3::new(0.3, 0.95, 0.0).normalize(),
                DVec3::new(0.0, 0.6, 0.8),
            ),
            (
                DVec3::new(0.2, 0.0, 0.98).normalize(),
                DVec3::new(-0.9, 0.0, 0.436).normalize(),
            ),
        ] {
            let e = shine(&small_facet(normal), None, radius, centre, sun, 16);
            let exact = brute_force(normal, radius, centre, sun);
            assert!((e - exact).abs() < 5e-3 * exact, "{normal}: {e} vs {exact}");
        }
    }

    #[test]
    fn a_wall_between_facet_and_planet_hides_it() {
        // A floor facet at the origin facing +z, the planet low in the +x sky (10° up),
        // and a wall at x = 5 m rising 30° above the facet: no planet-shine. Without the
        // wall the same facet gets some.
        let (radius, d) = (1e6, 1e8);
        let up = 10f64.to_radians();
        let centre = DVec3::new(up.cos(), 0.0, up.sin()) * d;
        let sun = DVec3::new(-0.3, 0.2, 0.93).normalize();
        let floor = mesh(
            vec![
                DVec3::new(-1.0, -1.0, 0.0),
                DVec3::new(1.0, -1.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2]],
        );
        let open = shine(&floor, None, radius, centre, sun, 8);
        assert!(open > 0.0);
        let h = 5.0 * 30f64.to_radians().tan();
        let walled = mesh(
            [
                floor.vertices.clone(),
                vec![
                    DVec3::new(5.0, -50.0, 0.0),
                    DVec3::new(5.0, 50.0, 0.0),
                    DVec3::new(5.0, 50.0, h),
                    DVec3::new(5.0, -50.0, h),
                ],
            ]
            .concat(),
            vec![[0, 1, 2], [3, 5, 4], [3, 6, 5]],
        );
        let bvh = Bvh::build(&walled);
        let bound = HorizonBound::new(
            &walled,
            walled.len(),
            &bvh,
            crate::horizon::bound::BoundDetail::Whole,
        );
        assert_eq!(shine(&walled, Some(&bound), radius, centre, sun, 8), 0.0);
    }

    #[test]
    fn weights_are_reused_within_the_tolerance_and_rebuilt_beyond_it() {
        let facet = small_facet(DVec3::X);
        let bvh = Bvh::build(&facet);
        let receiver = Receiver {
            mesh: &facet,
            bvh: &bvh,
            bound: None,
        };
        let sun = DVec3::new(-0.6, 0.8, 0.0);
        let settings = PlanetSettings {
            order: 8,
            reuse: 0.01,
        };
        let mut planet = PlanetShine::new(1, DVec3::splat(3.4e6), 2, settings);
        let mut fresh = PlanetShine::new(
            1,
            DVec3::splat(3.4e6),
            2,
            PlanetSettings {
                reuse: 0.0,
                ..settings
            },
        );
        for (x, y) in [(9.4e6, 0.0), (9.45e6, 3e4), (9.6e6, 0.0)] {
            let at = state(DVec3::new(x, y, 0.0), sun);
            let (mut kept, mut rebuilt) = ([0.0], [0.0]);
            planet.add(&at, 0, &receiver, ALBEDO, 1.0, false, &mut kept);
            fresh.add(&at, 0, &receiver, ALBEDO, 1.0, false, &mut rebuilt);
            // Within 1 % of distance and 0.01 rad of direction, kept weights scaled by
            // distance stay within a few tenths of a percent of fresh ones.
            assert!(
                (kept[0] - rebuilt[0]).abs() < 5e-3 * rebuilt[0],
                "{kept:?} {rebuilt:?}"
            );
        }
        assert_eq!((planet.built, planet.reused), (2, 1));
    }
}
