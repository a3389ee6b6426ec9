//! Scatter: sunlight scattered between facets, to all orders (SLIM paper, section 6.2).
//!
//! In: the [`World`], each facet's albedo ρ (Lambertian), and per step the direct
//! irradiance `D` (W/m², global facet ids) with the step's poses. Out: the scattered
//! irradiance `S` (W/m²) arriving at every facet — light that reached it after one or
//! more diffuse reflections — and a [`solve::SolveReport`]. With radiosity `B = ρ (D + S)`
//! and form factors `F_ij`, `S_i = Σ_j F_ij B_j`, i.e. `S = S1 + F ρ S` with the first
//! order `S1 = F ρ D` (the [`FirstScatter`] seam: a non-Lambertian first bounce replaces
//! it, higher orders stay Lambertian).
//!
//! Stages, one file each:
//! - [`form_factor`]: exchange area `A_i F_ij` of two facets, exact near field;
//! - [`visibility`]: which pairs see each other (the tracer's exact predicate on a
//!   [`Bvh`]), assembled into blocks;
//! - [`csr`]: compact storage (u32 columns, f32 values);
//! - [`solve`]: Jacobi (iterate = scattering order) and conjugate gradients.
//!
//! A body's own block is computed once (bodies are rigid). A block between two bodies is
//! recomputed only when their relative pose changes, and left out for the whole step when
//! a bound on its effect is below the scene's tolerance: light from body b reaching any
//! point of body a is at most `ρ_b/(1−ρ_b) · (R_b/(d − R_a))²` of the solar flux (b's
//! bounding sphere of radius R_b seen from at least d − R_a, d the centre distance).
//!
//! Row sums of `F` are capped at 1 (rows above 1 by quadrature or visibility error are
//! scaled symmetrically, `G_ij ← G_ij · min(c_i, c_j)`), which keeps the iteration
//! contractive and the CG matrix positive definite for every ρ < 1.

pub mod albedo;
pub mod bowl;
pub mod csr;
pub mod form_factor;
pub mod photometric;
pub mod planet;
pub mod solve;
pub mod stored;
pub mod to_panel;
pub mod visibility;

use crate::cache::Lookup;
use crate::ephemeris::EpochState;
use crate::error::Result;
use crate::horizon::bound::{BoundDetail, HorizonBound};
use crate::plan::Decision;
use crate::scene::{FirstBounceKind, PlanetShineKind, Scene};
use crate::trace::bvh::Bvh;
use crate::world::{Body, FrameTransform, World};
use csr::{Csr, Lanes};
use form_factor::NearField;
use planet::{PlanetSettings, PlanetShine, Receiver};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use solve::{Exchange, SolveReport, SolverKind, Stopping};
use std::borrow::Cow;
use std::f64::consts::{PI, SQRT_2};
use std::path::PathBuf;
use std::time::Instant;
use visibility::{cross_block, facets, facing_pairs, own_block, Occluder, SAME_FRAME};

/// One spectral band's inputs to a solve: its albedo (global ids), its first bounce and
/// its share of the solar flux.
#[derive(Clone, Copy)]
pub struct BandInput<'a> {
    pub albedo: &'a [f64],
    pub first: &'a dyn FirstScatter,
    pub flux_share: f64,
}

/// How scattered light is computed.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Albedo of every facet (global ids), in [0, 1).
    pub albedo: Vec<f64>,
    pub solver: SolverKind,
    /// Jacobi: most scattering orders; CG: most iterations.
    pub max_orders: u32,
    /// Relative tolerance of the solve.
    pub tolerance: f64,
    /// Inter-body blocks whose bound on scattered light is below this share of the solar
    /// flux are left out.
    pub inter_body_tolerance: f64,
    /// An inter-body block is kept while its bound of change since it was computed
    /// (`PairSizes::reuse_bound`) stays at or below this share of the solar flux; 0
    /// recomputes it whenever the bodies move.
    pub inter_body_reuse: f64,
    pub near_field: NearField,
    /// The first bounce: Lambertian, or each body's reflectance model.
    pub first_bounce: FirstBounce,
    /// Bodies whose light reaches the others through [`planet::PlanetShine`] instead of
    /// facet-to-facet blocks, with how.
    pub planets: Vec<usize>,
    pub planet: PlanetSettings,
    /// Where bodies' own form factors are kept between runs ([`stored`]); `None` builds
    /// them every time.
    pub cache_dir: Option<PathBuf>,
}

/// How the first bounce reflects sunlight.
#[derive(Debug, Clone, PartialEq)]
pub enum FirstBounce {
    /// Lambert's law with the albedo.
    Lambertian,
    /// Each body's reflectance model (one per body, world order).
    Materials(Vec<crate::photometry::Material>),
}

impl FirstBounce {
    /// The first-bounce stage for these settings.
    pub fn scatterer(&self) -> Box<dyn FirstScatter> {
        match self {
            FirstBounce::Lambertian => Box::new(Lambertian),
            FirstBounce::Materials(m) => Box::new(photometric::Photometric {
                materials: m.clone(),
            }),
        }
    }

    fn describe(&self) -> &'static str {
        match self {
            FirstBounce::Lambertian => "Lambertian, all orders",
            FirstBounce::Materials(_) => {
                "first bounce with each body's reflectance model, higher orders Lambertian"
            }
        }
    }
}

impl Settings {
    /// Lambertian scattering to all orders with these albedos (global ids), solver and
    /// tolerance; every body's light through facet blocks, the default near field, no
    /// inter-body cut-off. What validation cases and benchmarks start from.
    pub fn lambertian(albedo: Vec<f64>, solver: SolverKind, tolerance: f64) -> Settings {
        Settings {
            albedo,
            solver,
            max_orders: 10_000,
            tolerance,
            inter_body_tolerance: 0.0,
            inter_body_reuse: 0.0,
            near_field: NearField::default(),
            first_bounce: FirstBounce::Lambertian,
            planets: Vec::new(),
            planet: PlanetSettings::default(),
            cache_dir: None,
        }
    }

    /// The scene's settings, or `None` when it asks for no scattering.
    pub fn from_scene(scene: &Scene, world: &World) -> Result<Option<Settings>> {
        let (Some(section), Some(albedo)) = (&scene.scatter, albedo::facet_albedo(scene, world)?)
        else {
            return Ok(None);
        };
        Ok(Some(Settings {
            albedo,
            solver: section.solver,
            max_orders: section.max_orders,
            tolerance: section.tolerance,
            inter_body_tolerance: section.inter_body_tolerance,
            inter_body_reuse: section.inter_body_reuse,
            near_field: NearField {
                far_ratio: section.near_field_ratio,
                ..NearField::default()
            },
            first_bounce: match section.first_bounce {
                FirstBounceKind::Lambert => FirstBounce::Lambertian,
                FirstBounceKind::Material => FirstBounce::Materials(
                    (0..scene.bodies.len())
                        .map(|i| scene.material(i, None))
                        .collect::<Result<_>>()?,
                ),
            },
            planets: match section.planet_shine {
                PlanetShineKind::Facets => Vec::new(),
                PlanetShineKind::Quadrature => world
                    .bodies
                    .iter()
                    .enumerate()
                    .filter(|(_, b)| b.ellipsoid_radii_m.is_some() && !b.outputs)
                    .map(|(i, _)| i)
                    .collect(),
            },
            planet: PlanetSettings {
                order: section.planet_order,
                reuse: section.planet_reuse,
            },
            cache_dir: scene.cache_dir(),
        }))
    }

    /// Whether body `b` sends its light through the planet-shine model.
    pub fn is_planet(&self, b: usize) -> bool {
        self.planets.contains(&b)
    }

    /// The plan's decisions: whether scattering runs, and for every pair of bodies whether
    /// their block is needed at some step and how often it is recomputed.
    pub fn decisions(&self, world: &World, states: &[EpochState]) -> Vec<Decision> {
        let max_albedo = self.albedo.iter().copied().fold(0.0, f64::max);
        if max_albedo == 0.0 {
            return vec![Decision {
                stage: "scattered light".into(),
                runs: false,
                reason: "albedo 0 everywhere: nothing is reflected".into(),
            }];
        }
        let method = solve::resolve(self.solver, max_albedo);
        let mut out = vec![Decision {
            stage: "scattered light".into(),
            runs: true,
            reason: format!(
                "{}: S = F ρ (D + S) solved each step by {} to {:e} \
                 relative (at most {} iterations); form factors with visibility computed once \
                 per body, exact near field within {} facet sizes{}",
                self.first_bounce.describe(),
                match method {
                    SolverKind::Cg => "conjugate gradients (albedo above 0.5)",
                    _ => "Jacobi (iteration k = scattering orders ≤ k)",
                },
                self.tolerance,
                self.max_orders,
                self.near_field.far_ratio,
                match &self.cache_dir {
                    Some(dir) => format!(
                        ", kept in {} and read back while mesh and settings are the same",
                        dir.display()
                    ),
                    None => String::new(),
                }
            ),
        }];
        let n = world.bodies.len();
        for &p in &self.planets {
            out.push(Decision {
                stage: format!("light of the planet '{}'", world.bodies[p].name),
                runs: true,
                reason: format!(
                    "a Lambertian ellipsoid, not facets: its visible cap by {} points per \
                     receiving facet, exact solid angles, the receivers' own shadows by ray \
                     where their horizon bound cannot clear a point; weights rebuilt when it \
                     moves by more than {} (radians or fraction of distance), scaled by \
                     distance in between ({:.0} MB per receiving body of 10⁵ facets)",
                    2 * self.planet.order * self.planet.order,
                    self.planet.reuse,
                    1e5 * 8.0 * (self.planet.order * self.planet.order) as f64 / 1e6
                ),
            });
        }
        for a in 0..n {
            for b in a + 1..n {
                if self.is_planet(a) || self.is_planet(b) {
                    continue;
                }
                let needed = self.needed_steps(world, states, a, b);
                let computed = self.block_computations(world, &needed, a, b);
                let stage = format!(
                    "scattered light between '{}' and '{}'",
                    world.bodies[a].name, world.bodies[b].name
                );
                out.push(Decision {
                    stage,
                    runs: !needed.is_empty(),
                    reason: if needed.is_empty() {
                        format!(
                            "left out: at every step its bound ρ/(1−ρ)·(R/(d−R'))² is below the \
                             tolerance {:e} of the solar flux",
                            self.inter_body_tolerance
                        )
                    } else {
                        format!(
                            "needed at {} of {} steps (bound ≥ {:e} of the flux); the block is \
                             computed {} time(s): again only when the bodies move relative to \
                             each other{}",
                            needed.len(),
                            states.len(),
                            self.inter_body_tolerance,
                            computed,
                            if self.inter_body_reuse > 0.0 {
                                format!(
                                    " by more than changes its light by {:e} of the flux",
                                    self.inter_body_reuse
                                )
                            } else {
                                String::new()
                            }
                        )
                    },
                });
            }
        }
        out
    }
}

impl Settings {
    /// The steps at which the block between bodies a and b is needed: its bound is at or
    /// above the inter-body tolerance.
    fn needed_steps<'s>(
        &self,
        world: &World,
        states: &'s [EpochState],
        a: usize,
        b: usize,
    ) -> Vec<&'s EpochState> {
        let offsets = world.offsets();
        states
            .iter()
            .filter(|s| {
                inter_body_bound(world, &self.albedo, &offsets, s, a, b)
                    >= self.inter_body_tolerance
            })
            .collect()
    }

    /// How many times the block between bodies a and b is computed over the steps it is
    /// `needed` at: first, then whenever the pose moved beyond what `inter_body_reuse`
    /// lets a kept block miss (as [`Scatter`] decides it).
    fn block_computations(
        &self,
        world: &World,
        needed: &[&EpochState],
        a: usize,
        b: usize,
    ) -> usize {
        self.block_anchors(world, needed, a, b).len()
    }

    /// The steps among `needed` at which the block between bodies a and b is computed.
    fn block_anchors<'s>(
        &self,
        world: &World,
        needed: &[&'s EpochState],
        a: usize,
        b: usize,
    ) -> Vec<&'s EpochState> {
        let sizes = PairSizes::new(world, &self.albedo, &world.offsets(), a, b);
        let mut cached: Option<FrameTransform> = None;
        let mut anchors = Vec::new();
        for &state in needed {
            let pose = relative_pose(state, a, b);
            let keep = cached.map_or(Keep::No, |c| sizes.keeps(&c, &pose, self.inter_body_reuse));
            if keep == Keep::No {
                cached = Some(pose);
                anchors.push(state);
            }
        }
        anchors
    }

    /// The form-factor entries the run will store, estimated before they are computed: for
    /// every body its own block, and for every pair of bodies needed at some step their
    /// block at the first such step (forward and backward), each from the pairs of facets
    /// that face each other ([`visibility::facing_pairs`]).
    pub fn estimated_entries(&self, world: &World, states: &[EpochState]) -> f64 {
        let own: f64 = world
            .bodies
            .iter()
            .map(|b| {
                let f = facets(&b.mesh, &SAME_FRAME);
                facing_pairs(&f, &f, true)
            })
            .sum();
        let n = world.bodies.len();
        let planet_weights: f64 = self
            .planets
            .iter()
            .map(|&p| {
                let receivers = world.facet_count() - world.bodies[p].mesh.len();
                // A 4-byte weight is a sixth of a 24-byte form-factor entry.
                receivers as f64 * (2 * self.planet.order * self.planet.order) as f64 / 6.0
            })
            .sum();
        let between: f64 = (0..n)
            .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
            .filter(|&(a, b)| !self.is_planet(a) && !self.is_planet(b))
            .filter_map(|(a, b)| {
                let first = *self.needed_steps(world, states, a, b).first()?;
                let rows = facets(&world.bodies[a].mesh, &SAME_FRAME);
                let cols = facets(&world.bodies[b].mesh, &relative_pose(first, a, b));
                Some(2.0 * facing_pairs(&rows, &cols, false))
            })
            .sum();
        own + between + planet_weights
    }
}

fn relative_pose(state: &EpochState, a: usize, b: usize) -> FrameTransform {
    state.bodies[b].pose.relative_to(&state.bodies[a].pose)
}

/// The bound of the module doc, both ways, for bodies a and b at `state`.
fn inter_body_bound(
    world: &World,
    albedo: &[f64],
    offsets: &[usize],
    state: &EpochState,
    a: usize,
    b: usize,
) -> f64 {
    let bodies = &world.bodies;
    let d = (state.bodies[a].pose.position_m - state.bodies[b].pose.position_m).length();
    let bound = |from: usize, to: usize| {
        let range = offsets[from]..offsets[from] + bodies[from].mesh.len();
        let rho = albedo[range].iter().copied().fold(0.0, f64::max);
        let r_from = bodies[from].bounding_radius_m;
        let gap = d - bodies[to].bounding_radius_m;
        if gap <= r_from {
            return f64::INFINITY;
        }
        rho / (1.0 - rho) * (r_from / gap).powi(2)
    };
    bound(a, b).max(bound(b, a))
}

/// What the reuse bound needs of two bodies a and b: bounding radii (m), total facet
/// areas (m²) and largest albedos.
#[derive(Debug, Clone, Copy)]
struct PairSizes {
    radius_m: [f64; 2],
    area_m2: [f64; 2],
    albedo: [f64; 2],
}

impl PairSizes {
    fn new(world: &World, albedo: &[f64], offsets: &[usize], a: usize, b: usize) -> PairSizes {
        let body = |x: usize| &world.bodies[x];
        let largest = |x: usize| {
            let range = offsets[x]..offsets[x] + body(x).mesh.len();
            albedo[range].iter().copied().fold(0.0, f64::max)
        };
        PairSizes {
            radius_m: [a, b].map(|x| body(x).bounding_radius_m),
            area_m2: [a, b].map(|x| body(x).mesh.areas.iter().sum()),
            albedo: [a, b].map(largest),
        }
    }

    /// A bound (share of the solar flux, at any facet of either body) on how much the
    /// light exchanged between the two changes when b's pose in a's frame goes from
    /// `then` to `now`. Every point of b moves by at most ε = |Δc| + α R_b (Δc the move
    /// of b's centre, α the turn), and every pair of points stays at least the gap
    /// g = d − R_a − R_b apart, so each pair's `cos θ_i cos θ_j / r²` changes by at most
    /// (6ε/g + α)/r²: the directions turn by at most (π/2)ε/g, b's normals also by α,
    /// and 1/r² changes by at most 2ε/g of itself. Summed over the sender's facets (area
    /// A, radiance at most ρ/(1−ρ)/π of the flux, each at least g away) that is
    /// `ρ/(1−ρ) · A/(π g²) · (6ε/g + α)`, the larger of the two directions. Pairs whose
    /// visibility changes (b crossing a facet's local horizon or another body's shadow)
    /// are outside this bound.
    fn reuse_bound(&self, then: &FrameTransform, now: &FrameTransform) -> f64 {
        let [ra, rb] = self.radius_m;
        let gap = now.offset_m.length().min(then.offset_m.length()) - ra - rb;
        if gap <= 0.0 {
            return f64::INFINITY;
        }
        let alpha = rotation_angle(now.rotation * then.rotation.transpose());
        let moved = (now.offset_m - then.offset_m).length() + alpha * rb;
        let change = 6.0 * moved / gap + alpha;
        let light = |k: usize| {
            let rho = self.albedo[k];
            rho / (1.0 - rho) * self.area_m2[k] / (PI * gap * gap)
        };
        change * light(0).max(light(1))
    }
}

/// Whether an inter-body block computed at one pose still serves at another.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Keep {
    /// The same pose.
    Same,
    /// A pose whose change misses at most this share of the flux, within the tolerance.
    Within(f64),
    /// Compute it again.
    No,
}

impl PairSizes {
    /// Whether the block computed at `then` serves at `now` with `inter_body_reuse`
    /// `reuse` (0: only the same pose).
    fn keeps(&self, then: &FrameTransform, now: &FrameTransform, reuse: f64) -> Keep {
        if then == now {
            return Keep::Same;
        }
        if reuse > 0.0 {
            let bound = self.reuse_bound(then, now);
            if bound <= reuse {
                return Keep::Within(bound);
            }
        }
        Keep::No
    }
}

/// The angle (radians) of a rotation matrix, accurate for small angles:
/// ‖M − I‖_F = 2√2 sin(α/2).
fn rotation_angle(m: glam::DMat3) -> f64 {
    let d = m - glam::DMat3::IDENTITY;
    let frobenius =
        (d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared()).sqrt();
    2.0 * (frobenius / (2.0 * SQRT_2)).min(1.0).asin()
}

/// The first bounce: irradiance scattered once, from the direct irradiance.
///
/// This is the seam for non-Lambertian scattering: an implementation may weight each pair
/// (i, j) of `exchange` by a reflectance depending on the Sun direction at j and the
/// direction j → i. Higher orders are always Lambertian.
pub trait FirstScatter: Sync {
    /// First-order scattered irradiance at every facet, W/m², into `out`.
    fn first_order(&self, input: &FirstOrderInput, out: &mut [f64]);

    /// True for Lambert's law, `S1 = F ρ D`, which the solver then applies to several
    /// steps in one pass over the form factors.
    fn is_lambertian(&self) -> bool {
        false
    }
}

/// What a first bounce may use.
pub struct FirstOrderInput<'a> {
    pub world: &'a World,
    pub state: &'a EpochState,
    /// Direct irradiance, W/m², global ids.
    pub direct: &'a [f64],
    pub albedo: &'a [f64],
    /// The exchange areas `A_i F_ij` of this step.
    pub exchange: &'a Blocks<'a>,
}

/// Lambertian reflection: `S1 = F ρ D`.
pub struct Lambertian;

impl FirstScatter for Lambertian {
    fn is_lambertian(&self) -> bool {
        true
    }

    fn first_order(&self, input: &FirstOrderInput, out: &mut [f64]) {
        let mut lane = vec![[0.0; 1]; out.len()];
        lambertian_first_orders(input.exchange, input.albedo, &[input.direct], &mut lane);
        out.iter_mut().zip(&lane).for_each(|(s, l)| *s = l[0]);
    }
}

/// One block of the global exchange matrix.
#[derive(Debug, Clone, Copy)]
pub struct Block<'a> {
    pub row_offset: usize,
    pub col_offset: usize,
    pub matrix: &'a Csr,
}

/// The global exchange-area matrix `G` (m²) as blocks, with the facet areas (m²).
#[derive(Debug, Clone, Default)]
pub struct Blocks<'a> {
    pub blocks: Vec<Block<'a>>,
    pub areas: &'a [f64],
}

impl Exchange for Blocks<'_> {
    fn apply<L: Lanes>(&self, x: &[L], y: &mut [L]) {
        y.fill(L::ZERO);
        for b in &self.blocks {
            let rows = b.row_offset..b.row_offset + b.matrix.rows();
            let cols = b.col_offset..b.col_offset + b.matrix.cols;
            b.matrix.mul_add(&x[cols], &mut y[rows]);
        }
    }

    fn areas(&self) -> &[f64] {
        self.areas
    }
}

/// A body's own form factors, as built.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FormFactorReport {
    pub body: String,
    pub facets: usize,
    /// Stored entries (both triangles).
    pub entries: usize,
    pub bytes: usize,
    pub build_s: f64,
    /// Largest row sum Σ_j F_ij before capping (≤ 1 up to quadrature and visibility error).
    pub max_row_sum: f64,
    /// Rows whose sum exceeded 1 and were scaled down.
    pub rows_capped: usize,
    /// "built", "cache", or "built" with why a cache file was not used or written.
    #[serde(default)]
    pub source: String,
    /// The cache file read or written.
    #[serde(default)]
    pub file: Option<PathBuf>,
}

/// What the stage did over a run (stored in `run.json`).
#[derive(Debug, Clone, Serialize, Deserialize, Default)]
pub struct ScatterRecord {
    pub form_factors: Vec<FormFactorReport>,
    /// Solves done (steps).
    pub solves: u64,
    /// Method of the last solve ("jacobi" or "cg").
    pub method: Cow<'static, str>,
    pub iterations_total: u64,
    pub iterations_max: u32,
    pub residual_max: f64,
    /// Solves that hit the iteration cap before the tolerance.
    pub not_converged: u64,
    /// Inter-body blocks computed, reused (pose unchanged) and left out (below tolerance).
    pub inter_body_computed: u64,
    pub inter_body_reused: u64,
    pub inter_body_skipped: u64,
    /// Inter-body blocks kept although the bodies moved, within `inter_body_reuse`, and
    /// the largest bound on the light they missed (share of the solar flux).
    #[serde(default)]
    pub inter_body_kept: u64,
    #[serde(default)]
    pub inter_body_kept_bound: f64,
    /// Planet-shine weights built and reused (summed over planets and receivers).
    #[serde(default)]
    pub planet_weights_built: u64,
    #[serde(default)]
    pub planet_weights_reused: u64,
}

impl ScatterRecord {
    /// A warning when some solves stopped at the iteration cap above the tolerance: their
    /// scattered light is less accurate than asked for, which the counts alone hide.
    pub fn convergence_warning(&self, max_orders: u32, tolerance: f64) -> Option<String> {
        (self.not_converged > 0).then(|| {
            format!(
                "scattered light: {} of {} solves ({}) stopped at max_orders = {max_orders} \
                 above the tolerance {tolerance:e} (largest relative residual {:.3e}); raise \
                 [scatter] max_orders, or use solver = \"cg\" for albedos near 1",
                self.not_converged, self.solves, self.method, self.residual_max
            )
        })
    }

    /// Adds the record of the steps that follow this one's (a later time part of the
    /// same run): counts add up, maxima are the larger, the method is the later one's.
    pub fn merge_later(&mut self, later: &ScatterRecord) {
        self.solves += later.solves;
        if later.solves > 0 {
            self.method = later.method.clone();
        }
        self.iterations_total += later.iterations_total;
        self.iterations_max = self.iterations_max.max(later.iterations_max);
        self.residual_max = self.residual_max.max(later.residual_max);
        self.not_converged += later.not_converged;
        self.inter_body_computed += later.inter_body_computed;
        self.inter_body_reused += later.inter_body_reused;
        self.inter_body_skipped += later.inter_body_skipped;
        self.inter_body_kept += later.inter_body_kept;
        self.inter_body_kept_bound = self.inter_body_kept_bound.max(later.inter_body_kept_bound);
        self.planet_weights_built += later.planet_weights_built;
        self.planet_weights_reused += later.planet_weights_reused;
    }

    fn add(&mut self, report: &SolveReport) {
        self.solves += 1;
        self.method = Cow::Borrowed(report.method);
        self.iterations_total += report.iterations as u64;
        self.iterations_max = self.iterations_max.max(report.iterations);
        self.residual_max = self.residual_max.max(report.residual);
        self.not_converged += !report.converged as u64;
    }
}

/// An inter-body block as last computed.
struct Cached {
    pose: FrameTransform,
    sizes: PairSizes,
    forward: Csr,
    backward: Csr,
}

/// Every body that receives planet-shine (every one that is not a planet), with what
/// can hide the planet from its facets.
fn planet_receivers<'a>(
    world: &'a World,
    settings: &Settings,
    bvhs: &'a [Bvh],
    bounds: &'a [Option<HorizonBound>],
) -> Vec<(usize, Receiver<'a>)> {
    world
        .bodies
        .iter()
        .enumerate()
        .filter(|(r, _)| !settings.is_planet(*r))
        .map(|(r, body)| {
            let receiver = Receiver {
                mesh: &body.mesh,
                bvh: &bvhs[r],
                bound: bounds[r].as_ref(),
            };
            (r, receiver)
        })
        .collect()
}

/// Most steps that [`Scatter::step_many`] solves side by side.
pub const LANES: usize = 8;

/// The scattered-light stage.
pub struct Scatter<'w> {
    world: &'w World,
    settings: Settings,
    method: SolverKind,
    bvhs: Vec<Bvh<'w>>,
    offsets: Vec<usize>,
    own: Vec<Csr>,
    own_row_sums: Vec<f64>,
    areas: Vec<f64>,
    cache: Vec<Option<Cached>>,
    first: Box<dyn FirstScatter + 'w>,
    /// The planets' light, one per planet.
    planets: Vec<PlanetShine>,
    /// Per body, its horizon bound when planet-shine reaches it and it can shadow itself.
    bounds: Vec<Option<HorizonBound>>,
    /// The planet-shine of each step of the last `step_many`.
    last_shine: Vec<Vec<f64>>,
    pub record: ScatterRecord,
}

impl<'w> Scatter<'w> {
    /// Builds every body's own form factors (the expensive part, done once).
    pub fn new(
        world: &'w World,
        settings: Settings,
        first: Box<dyn FirstScatter + 'w>,
    ) -> Scatter<'w> {
        let bvhs: Vec<Bvh> = world.bodies.iter().map(|b| Bvh::build(&b.mesh)).collect();
        let areas = all_areas(world);
        let mut record = ScatterRecord::default();
        let mut own = Vec::new();
        for (b, body) in world.bodies.iter().enumerate() {
            let (block, report) = own_form_factors(body, &bvhs[b], &settings);
            record.form_factors.push(report);
            own.push(block);
        }
        let offsets = world.offsets();
        let mut own_row_sums = vec![0.0; areas.len()];
        for (b, block) in own.iter().enumerate() {
            let range = offsets[b]..offsets[b] + block.rows();
            own_row_sums[range.clone()].copy_from_slice(&block.row_sums());
            own_row_sums[range]
                .iter_mut()
                .zip(&world.bodies[b].mesh.areas)
                .for_each(|(s, a)| *s = if *a > 0.0 { *s / a } else { 0.0 });
        }
        let max_albedo = settings.albedo.iter().copied().fold(0.0, f64::max);
        let n = world.bodies.len();
        let planets: Vec<PlanetShine> = settings
            .planets
            .iter()
            .filter_map(|&p| {
                let radii = world.bodies[p].ellipsoid_radii_m?;
                Some(PlanetShine::new(p, radii, n, settings.planet))
            })
            .collect();
        let bounds = world
            .bodies
            .iter()
            .enumerate()
            .map(|(b, body)| {
                (!planets.is_empty() && !body.convex && !settings.is_planet(b)).then(|| {
                    HorizonBound::new(&body.mesh, body.mesh.len(), &bvhs[b], BoundDetail::Whole)
                })
            })
            .collect();
        Scatter {
            world,
            planets,
            bounds,
            last_shine: Vec::new(),
            method: solve::resolve(settings.solver, max_albedo),
            settings,
            bvhs,
            offsets,
            own,
            own_row_sums,
            areas,
            cache: (0..n * n).map(|_| None).collect(),
            first,
            record,
        }
    }

    /// Changes the albedo of every facet (global ids), keeping the form factors: for
    /// sweeps over albedo. Inter-body blocks are recomputed (their caps depend on it).
    pub fn set_albedo(&mut self, albedo: Vec<f64>) {
        let max_albedo = albedo.iter().copied().fold(0.0, f64::max);
        self.method = solve::resolve(self.settings.solver, max_albedo);
        self.settings.albedo = albedo;
        self.cache.iter_mut().for_each(|c| *c = None);
    }

    /// The method `Auto` resolved to.
    pub fn method(&self) -> SolverKind {
        self.method
    }

    /// Scattered irradiance (W/m², global ids) at `state` from the direct irradiance.
    pub fn step(
        &mut self,
        state: &EpochState,
        direct: &[f64],
        scattered: &mut [f64],
    ) -> SolveReport {
        let ([report], _) = self.solve_steps::<1>(
            std::slice::from_ref(state),
            &[direct],
            None,
            &mut [scattered],
        );
        report
    }

    /// [`Scatter::step`] for consecutive steps: `directs[k]` and `scattered[k]` belong to
    /// `states[k]`, with the same results and reports as one step at a time. For a single
    /// body, whose exchange areas are the same at every step, up to [`LANES`] steps are
    /// solved side by side ([`solve::solve_lanes`]), so that each product with the stored
    /// matrix serves all of them.
    pub fn step_many(
        &mut self,
        states: &[EpochState],
        directs: &[&[f64]],
        scattered: &mut [&mut [f64]],
    ) -> Vec<SolveReport> {
        self.step_many_band(states, directs, None, scattered)
    }

    /// [`Scatter::step_many`] for one spectral band: `band` gives the band's albedo
    /// (global ids), first bounce and share of the flux instead of the broadband ones;
    /// `directs` are the band's direct irradiance. The form factors are shared by every
    /// band, and the band's steps are solved side by side like the broadband ones.
    pub fn step_many_band(
        &mut self,
        states: &[EpochState],
        directs: &[&[f64]],
        band: Option<BandInput>,
        scattered: &mut [&mut [f64]],
    ) -> Vec<SolveReport> {
        self.last_shine.clear();
        if band.is_none() {
            self.planets.iter_mut().for_each(PlanetShine::begin_batch);
        }
        let mut reports = Vec::with_capacity(states.len());
        let mut done = 0;
        while done < states.len() {
            let left = states.len() - done;
            let lanes = if self.has_inter_body_pairs() {
                1 // inter-body blocks change with the poses
            } else {
                [LANES, 4, 2].into_iter().find(|&k| k <= left).unwrap_or(1)
            };
            let range = done..done + lanes;
            let (states, directs) = (&states[range.clone()], &directs[range.clone()]);
            let out = &mut scattered[range];
            let shine = match lanes {
                LANES => self.solve_lanes_of::<LANES>(states, directs, band, out, &mut reports),
                4 => self.solve_lanes_of::<4>(states, directs, band, out, &mut reports),
                2 => self.solve_lanes_of::<2>(states, directs, band, out, &mut reports),
                _ => self.solve_lanes_of::<1>(states, directs, band, out, &mut reports),
            };
            self.last_shine.extend(shine);
            done += lanes;
        }
        reports
    }

    /// K steps of [`Scatter::step_many`] side by side: their reports go to `reports`; the
    /// planet-shine of each is returned.
    fn solve_lanes_of<const K: usize>(
        &mut self,
        states: &[EpochState],
        directs: &[&[f64]],
        band: Option<BandInput>,
        scattered: &mut [&mut [f64]],
        reports: &mut Vec<SolveReport>,
    ) -> Vec<Vec<f64>> {
        let (done, shine) = self.solve_steps::<K>(states, directs, band, scattered);
        reports.extend(done);
        shine
    }

    /// The area-weighted mean of body `b`'s facet albedos: a planet reflects as a
    /// uniform Lambertian ellipsoid.
    fn mean_albedo(&self, b: usize, albedo: &[f64]) -> f64 {
        let areas = &self.world.bodies[b].mesh.areas;
        let mine = &albedo[self.offsets[b]..self.offsets[b] + areas.len()];
        let area: f64 = areas.iter().sum();
        let weighted: f64 = mine.iter().zip(areas).map(|(r, a)| r * a).sum();
        if area > 0.0 {
            weighted / area
        } else {
            0.0
        }
    }

    /// Whether some body's light comes through [`PlanetShine`].
    pub fn has_planets(&self) -> bool {
        !self.planets.is_empty()
    }

    /// Takes the planet-shine (W/m², global ids) of each step of the last
    /// [`Scatter::step_many`], as it arrived before scattering on; empty without planets.
    pub fn take_planet_shine(&mut self) -> Vec<Vec<f64>> {
        std::mem::take(&mut self.last_shine)
    }

    /// Whether two bodies that are not planets may exchange light through a block.
    pub fn has_inter_body_pairs(&self) -> bool {
        let others = (0..self.world.bodies.len()).filter(|&b| !self.settings.is_planet(b));
        others.count() > 1
    }

    /// K steps with the same exchange areas (those at `states[0]`), solved side by side.
    fn solve_steps<const K: usize>(
        &mut self,
        states: &[EpochState],
        directs: &[&[f64]],
        band: Option<BandInput>,
        scattered: &mut [&mut [f64]],
    ) -> ([SolveReport; K], Vec<Vec<f64>>) {
        debug_assert!(states.len() == K && directs.len() == K && scattered.len() == K);
        let albedo = band.map_or(&self.settings.albedo[..], |b| b.albedo);
        let planet_albedos: Vec<f64> = self
            .planets
            .iter()
            .map(|p| self.mean_albedo(p.planet, albedo))
            .collect();
        let share = band.map_or(1.0, |b| b.flux_share);
        let shine: Vec<Vec<f64>> = states
            .iter()
            .map(|state| self.planet_shine(state, &planet_albedos, share, band.is_some()))
            .collect();
        let active = self.refresh_inter_blocks(&states[0]);
        let exchange = self.blocks(&active);
        let (albedo, first, method) = match band {
            Some(b) => {
                let max_albedo = b.albedo.iter().copied().fold(0.0, f64::max);
                let method = solve::resolve(self.settings.solver, max_albedo);
                (b.albedo, b.first, method)
            }
            None => (&self.settings.albedo[..], self.first.as_ref(), self.method),
        };
        let n = self.areas.len();
        let mut s1 = vec![[0.0; K]; n];
        if first.is_lambertian() {
            lambertian_first_orders(&exchange, albedo, directs, &mut s1);
        } else {
            let mut one = vec![0.0; n];
            for (k, (state, direct)) in states.iter().zip(directs).enumerate() {
                let input = FirstOrderInput {
                    world: self.world,
                    state,
                    direct,
                    albedo,
                    exchange: &exchange,
                };
                first.first_order(&input, &mut one);
                s1.iter_mut().zip(&one).for_each(|(lanes, v)| lanes[k] = *v);
            }
        }
        // Planet-shine arrives like a first order and scatters on like one.
        for (k, shine) in shine.iter().enumerate() {
            s1.iter_mut()
                .zip(shine)
                .for_each(|(lanes, p)| lanes[k] += p);
        }
        let stop = Stopping {
            tolerance: self.settings.tolerance,
            max_iterations: self.settings.max_orders,
        };
        let mut out = vec![[0.0; K]; n];
        let reports = solve::solve_lanes(&exchange, albedo, &s1, method, stop, &mut out);
        drop(exchange);
        for (k, scattered) in scattered.iter_mut().enumerate() {
            scattered
                .iter_mut()
                .zip(&out)
                .for_each(|(s, lanes)| *s = lanes[k]);
        }
        reports.iter().for_each(|report| self.record.add(report));
        (reports, shine)
    }

    /// Puts the stage where a run from the first step stands after `earlier` (the steps
    /// before a time shard's first): every inter-body block and planet weight that run
    /// would hold is built at the step it would have been built at. Only the poses of the
    /// earlier steps are looked at. A time shard then computes bit-identical light and
    /// counts to one run's.
    pub fn prime(&mut self, earlier: &[EpochState]) {
        let world = self.world;
        let n = world.bodies.len();
        for a in 0..n {
            for b in a + 1..n {
                if self.settings.is_planet(a) || self.settings.is_planet(b) {
                    continue;
                }
                let needed = self.settings.needed_steps(world, earlier, a, b);
                if let Some(&state) = self.settings.block_anchors(world, &needed, a, b).last() {
                    let pose = relative_pose(state, a, b);
                    self.cache[a * n + b] = Some(self.inter_block(state, a, b, pose));
                }
            }
        }
        let receivers = planet_receivers(world, &self.settings, &self.bvhs, &self.bounds);
        for shine in &mut self.planets {
            for (r, receiver) in &receivers {
                shine.prime(earlier, *r, receiver);
            }
        }
    }

    /// The irradiance (W/m², global ids; empty without planets) every planet sends to
    /// the other bodies at `state`, the planets of albedos `albedos` (in the order of
    /// `self.planets`) lit by a share `flux_share` of the solar flux; with `replay` (a
    /// band), with the weights the broadband light used at `state`.
    fn planet_shine(
        &mut self,
        state: &EpochState,
        albedos: &[f64],
        flux_share: f64,
        replay: bool,
    ) -> Vec<f64> {
        if self.planets.is_empty() {
            return Vec::new();
        }
        let mut out = vec![0.0; self.areas.len()];
        let world = self.world;
        let receivers = planet_receivers(world, &self.settings, &self.bvhs, &self.bounds);
        for (shine, &planet_albedo) in self.planets.iter_mut().zip(albedos) {
            for &(r, ref receiver) in &receivers {
                let range = self.offsets[r]..self.offsets[r] + receiver.mesh.len();
                shine.add(
                    state,
                    r,
                    receiver,
                    planet_albedo,
                    flux_share,
                    replay,
                    &mut out[range],
                );
            }
        }
        self.record.planet_weights_built = self.planets.iter().map(|p| p.built).sum();
        self.record.planet_weights_reused = self.planets.iter().map(|p| p.reused).sum();
        out
    }

    /// Brings the inter-body blocks up to date for this step: recomputed if their bodies
    /// moved relative to each other. Returns the pairs that take part (never a planet's:
    /// its light comes from [`Scatter::planet_shine`]).
    fn refresh_inter_blocks(&mut self, state: &EpochState) -> Vec<(usize, usize)> {
        let n = self.world.bodies.len();
        let mut active = Vec::new();
        for a in 0..n {
            for b in a + 1..n {
                if self.settings.is_planet(a) || self.settings.is_planet(b) {
                    continue;
                }
                if self.negligible(state, a, b) {
                    self.record.inter_body_skipped += 1;
                    continue;
                }
                let pose = state.bodies[b].pose.relative_to(&state.bodies[a].pose);
                let reuse = self.settings.inter_body_reuse;
                let keep = self.cache[a * n + b]
                    .as_ref()
                    .map_or(Keep::No, |c| c.sizes.keeps(&c.pose, &pose, reuse));
                match keep {
                    Keep::Same => self.record.inter_body_reused += 1,
                    Keep::Within(bound) => {
                        self.record.inter_body_kept += 1;
                        self.record.inter_body_kept_bound =
                            self.record.inter_body_kept_bound.max(bound);
                    }
                    Keep::No => {
                        self.cache[a * n + b] = Some(self.inter_block(state, a, b, pose));
                        self.record.inter_body_computed += 1;
                    }
                }
                active.push((a, b));
            }
        }
        active
    }

    /// The global exchange matrix: own blocks plus the `active` inter-body blocks.
    fn blocks(&self, active: &[(usize, usize)]) -> Blocks<'_> {
        let n = self.world.bodies.len();
        let own = self.own.iter().enumerate().map(|(b, m)| Block {
            row_offset: self.offsets[b],
            col_offset: self.offsets[b],
            matrix: m,
        });
        let inter = active.iter().flat_map(|&(a, b)| {
            let c = self.cache[a * n + b].as_ref().expect("refreshed");
            [
                Block {
                    row_offset: self.offsets[a],
                    col_offset: self.offsets[b],
                    matrix: &c.forward,
                },
                Block {
                    row_offset: self.offsets[b],
                    col_offset: self.offsets[a],
                    matrix: &c.backward,
                },
            ]
        });
        Blocks {
            blocks: own.chain(inter).collect(),
            areas: &self.areas,
        }
    }

    /// The bound of the module doc is below the tolerance both ways.
    fn negligible(&self, state: &EpochState, a: usize, b: usize) -> bool {
        let bound = inter_body_bound(
            self.world,
            &self.settings.albedo,
            &self.offsets,
            state,
            a,
            b,
        );
        bound < self.settings.inter_body_tolerance
    }

    /// The block between bodies a (rows) and b (columns), computed in a's frame with every
    /// body as an occluder, row sums capped so that own plus inter-body sums stay ≤ 1.
    fn inter_block(
        &self,
        state: &EpochState,
        a: usize,
        b: usize,
        b_to_a: FrameTransform,
    ) -> Cached {
        let world = self.world;
        let rows = facets(&world.bodies[a].mesh, &SAME_FRAME);
        let cols = facets(&world.bodies[b].mesh, &b_to_a);
        let occluders: Vec<Occluder> = (0..world.bodies.len())
            .map(|c| Occluder {
                bvh: &self.bvhs[c],
                to_own: state.bodies[a].pose.relative_to(&state.bodies[c].pose),
                holds_rows: c == a,
                holds_cols: c == b,
            })
            .collect();
        let mut forward = cross_block(&rows, &cols, &occluders, &self.settings.near_field);
        let (ra, rb) = (self.offsets[a], self.offsets[b]);
        let allowance = |offset: usize, sums: Vec<f64>, areas: &[f64]| -> Vec<f64> {
            sums.iter()
                .enumerate()
                .map(|(i, s)| {
                    let f = if areas[i] > 0.0 { s / areas[i] } else { 0.0 };
                    let room = (1.0 - self.own_row_sums[offset + i]).max(0.0);
                    if f > room {
                        room / f
                    } else {
                        1.0
                    }
                })
                .collect()
        };
        let ca = allowance(ra, forward.row_sums(), &world.bodies[a].mesh.areas);
        let cb = allowance(
            rb,
            forward.transpose().row_sums(),
            &world.bodies[b].mesh.areas,
        );
        forward.scale_entries(|i, j| ca[i].min(cb[j]));
        let backward = forward.transpose();
        Cached {
            pose: b_to_a,
            sizes: PairSizes::new(world, &self.settings.albedo, &self.offsets, a, b),
            forward,
            backward,
        }
    }
}

/// A body's own block, capped, read from the cache when an intact file for its content
/// is there, built (and stored when there is a cache) otherwise; and its report.
fn own_form_factors(body: &Body, bvh: &Bvh, settings: &Settings) -> (Csr, FormFactorReport) {
    let t0 = Instant::now();
    let key = stored::content_key(&body.mesh, &settings.near_field);
    let file = settings
        .cache_dir
        .as_deref()
        .map(|d| crate::cache::file_for(d, &stored::KIND, &key));
    let mut source = "built".to_string();
    let mut read = None;
    if let Some(file) = &file {
        match stored::load(file, &key, body.mesh.len()) {
            Lookup::Hit(own) => read = Some(own),
            Lookup::Missing => {}
            Lookup::Rejected(why) => source = format!("built (cache file not used: {why})"),
        }
    }
    let from_cache = read.is_some();
    let own = read.unwrap_or_else(|| {
        let mut block = own_block(&body.mesh, bvh, &settings.near_field);
        let (max_row_sum, rows_capped) = cap_rows(&mut block, &body.mesh.areas);
        stored::OwnBlock {
            block,
            max_row_sum,
            rows_capped,
        }
    });
    let mut kept = file;
    if from_cache {
        source = "cache".into();
    } else if let Some(file) = &kept {
        if let Err(e) = stored::store(file, &key, &own) {
            source = format!("built (not cached: {e})");
            kept = None;
        }
    }
    let report = FormFactorReport {
        body: body.name.clone(),
        facets: body.mesh.len(),
        entries: own.block.nnz(),
        bytes: own.block.bytes(),
        build_s: t0.elapsed().as_secs_f64(),
        max_row_sum: own.max_row_sum,
        rows_capped: own.rows_capped,
        source,
        file: kept,
    };
    (own.block, report)
}

/// `S1 = F ρ D` for K steps side by side (lane k from `directs[k]`), in one pass over the
/// exchange areas.
fn lambertian_first_orders<const K: usize>(
    exchange: &Blocks,
    albedo: &[f64],
    directs: &[&[f64]],
    s1: &mut [[f64; K]],
) {
    let emitted: Vec<[f64; K]> = (0..albedo.len())
        .into_par_iter()
        .map(|i| std::array::from_fn(|k| directs[k][i] * albedo[i]))
        .collect();
    exchange.apply(&emitted, s1);
    s1.par_iter_mut()
        .zip(exchange.areas())
        .for_each(|(lanes, a)| {
            lanes
                .iter_mut()
                .for_each(|s| *s = if *a > 0.0 { *s / a } else { 0.0 });
        });
}

fn all_areas(world: &World) -> Vec<f64> {
    world
        .bodies
        .iter()
        .flat_map(|b| b.mesh.areas.iter().copied())
        .collect()
}

/// Caps the row sums of a symmetric block at the facet areas; returns the largest row
/// sum of F before capping and how many rows were above 1.
fn cap_rows(block: &mut Csr, areas: &[f64]) -> (f64, usize) {
    let f: Vec<f64> = block
        .row_sums()
        .par_iter()
        .zip(areas)
        .map(|(s, a)| if *a > 0.0 { s / a } else { 0.0 })
        .collect();
    let max = f.iter().copied().fold(0.0, f64::max);
    let capped = f.iter().filter(|&&s| s > 1.0).count();
    if capped > 0 {
        let c: Vec<f64> = f
            .iter()
            .map(|&s| if s > 1.0 { 1.0 / s } else { 1.0 })
            .collect();
        block.scale_entries(|i, j| c[i].min(c[j]));
    }
    (max, capped)
}
