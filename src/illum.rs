//! Illum: direct solar irradiance on every facet at one epoch, or at each of a block of
//! epochs (SLIM paper, section 6.1).
//!
//! In: the [`World`], one [`EpochState`] or a block of them (Sun direction and flux per
//! body, poses) and a tracer per body (with horizon maps where the run uses them).
//! Out: `E_i = S · max(0, n_i · s)` in W/m² for every facet (global ids), or 0 when the
//! ray from the facet centroid toward the Sun is blocked by any facet of any body. With
//! the Sun as a disk, `E_i = S · f · sin ē` ([`crate::horizon::disk`]) times the share
//! of the disk no other body hides: a generated ellipsoid's in closed form ([`crate::horizon::eclipse`]), a
//! mesh's by `sun_samples` rays through the disk. Bodies whose light nothing reads
//! ([`Direct::only_for`]) get 0 and still cast shadows. A run that keeps statistics
//! only may instead take every step of a chunk of facets at once, in the order of the
//! Sun's path (from a map that decides alone, in time order; [`Direct::sweep`], module
//! `sweep`): the same values, handed to the statistics facet by facet.
//!
//! Self-shadowing guard: the facet itself is excluded by id, and a blocking hit must lie
//! higher above the facet's plane than `h_min = 1e-9·L + 256·ε·R` (L the facet's longest
//! edge, R the body's size, ε machine epsilon): the first term is the geometry's scale,
//! the second the rounding of coordinates of that size. A shadow missed because of it
//! costs at most `S · h_min / t` W/m² for a blocker at distance t — nothing measurable.

use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::horizon::bound::{Cone, ConeView, HorizonBound};
use crate::horizon::disk::SolarDisk;
use crate::horizon::eclipse::Ellipsoid;
use crate::horizon::map::{HorizonMap, MapKind};
use crate::horizon::shadows::BoundRecord;
use crate::horizon::sky::{LocalHorizon, SkyPosition};
use crate::horizon::{HorizonMode, Shadows, SunShape};
use crate::mesh::inspect::edge_neighbours;
use crate::trace::bvh::{round_up, Bvh, BvhRays};
use crate::trace::{self, Blocker, ShadowQuery, ShadowRay, Tracer, TracerKind};
use crate::world::{Body, FrameTransform, World};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;

mod sweep;
pub use sweep::{chunk_facets as sweep_chunk_facets, look_up_sweep_bytes, sweep_bytes};

/// Counts of what one step did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct StepCounts {
    /// Facets facing away from the Sun (no ray needed).
    pub night: u64,
    /// Shadow rays traced (facet-to-body queries).
    pub rays: u64,
    /// Facets facing the Sun but shadowed.
    pub shadowed: u64,
    /// Facets facing the Sun whose own body's shadow ray was not traced: the Sun stood
    /// above their horizon bound ([`crate::horizon::bound`]).
    #[serde(default)]
    pub above_horizon: u64,
    /// Facet–steps decided by a horizon map alone (approximate mode, or the Sun as a
    /// disk), without a ray.
    #[serde(default)]
    pub horizon_lookups: u64,
    /// Shadow rays (counted in `rays`) answered on the surface around the facet that
    /// blocked the same facet's ray at the step before ([`ShadowQuery::blocker_near`]),
    /// without a walk through the tracer. A measure of
    /// work, like a timing: it depends on the steps the same process computed before (a
    /// part of a sharded run starts afresh), never on the result.
    #[serde(default)]
    pub remembered: u64,
    /// Shadow rays that walked the surface from a remembered blocker, finding one
    /// (counted in `remembered`) or not: how often walks pay, where a group of facets
    /// walks only while they do. Like `remembered`, a measure of work.
    #[serde(default)]
    pub walks: u64,
    /// Cones of directions looked at around the Sun when steps are taken facet by facet
    /// ([`Direct::sweep`]): each decides the facet's shadow rays (counted in `rays`) while
    /// the Sun stays within it, without a walk through the tracer.
    #[serde(default)]
    pub cones: u64,
}

impl std::ops::AddAssign for StepCounts {
    fn add_assign(&mut self, o: StepCounts) {
        self.night += o.night;
        self.rays += o.rays;
        self.shadowed += o.shadowed;
        self.above_horizon += o.above_horizon;
        self.horizon_lookups += o.horizon_lookups;
        self.remembered += o.remembered;
        self.walks += o.walks;
        self.cones += o.cones;
    }
}

/// The direct-irradiance stage: one tracer per body, built once.
pub struct Direct<'w> {
    world: &'w World,
    tracers: Vec<Box<dyn Tracer + 'w>>,
    /// Per body, what spares or replaces its own shadow rays.
    horizons: Vec<OwnHorizon<'w>>,
    sun: SunShape,
    disk: SolarDisk,
    /// Equal-flux points of the disk (units of its radius) that sample the share a mesh
    /// hides: another body's, or the body's own where no horizon map decides.
    disk_samples: Vec<(f64, f64)>,
    /// Per body and facet, `h_min` (module doc) in metres, held as an `f32` not below it
    /// (within two `f32` steps): half the memory, and a guard higher by a few parts in
    /// 10⁷ at most.
    min_height_m: Vec<Vec<f32>>,
    offsets: Vec<usize>,
    /// Per body, whether its own irradiance is needed (false: it only casts shadows and
    /// nothing reads its facets' light; they stay at 0).
    lit: Vec<bool>,
    /// Where each horizon bound came from, for the bodies that have one.
    bound_records: Vec<BoundRecord>,
    /// Per body whose rays remember their blockers ([`Shadows::remembers_blockers`]),
    /// the blockers met at earlier steps ([`Direct::trace_own`]); `None` for other bodies.
    last_blockers: Vec<Option<LastBlockers>>,
}

/// What a body's shadow rays remember of earlier steps: the blockers of each of the last
/// `lag` steps (the run's [`crate::ephemeris::SunReturn`]), so that a step's rays start
/// from those of the step `lag` before, where the Sun stood nearest.
struct LastBlockers {
    lag: usize,
    /// Row `k % lag`, facet by facet, holds the facet that blocked the ray of step `k`
    /// (`NO_BLOCKER`: none, or lit since); the ray of step `k + lag` walks the surface
    /// from it ([`ShadowQuery::blocker_near`]) and leaves its own.
    facets: Vec<AtomicU32>,
    /// Per facet, its neighbour across each edge, the walk's paths
    /// ([`edge_neighbours`]).
    neighbours: Vec<[u32; 3]>,
    /// Per run of [`WALK_GROUP`] facets, whether walks pay there ([`WalkYield`], packed).
    walks: Vec<AtomicU64>,
}

/// The blockers one step's rays read and leave: a row of [`LastBlockers`].
#[derive(Clone, Copy)]
struct Row<'a> {
    facets: &'a [AtomicU32],
    neighbours: &'a [[u32; 3]],
    walks: &'a [AtomicU64],
}

impl LastBlockers {
    /// The row of step `step` (its index in the run).
    fn row(&self, step: usize) -> Row<'_> {
        let n = self.facets.len() / self.lag;
        let r = step % self.lag;
        Row {
            facets: &self.facets[r * n..(r + 1) * n],
            neighbours: &self.neighbours,
            walks: &self.walks,
        }
    }

    fn new(body: &Body, lag: usize) -> LastBlockers {
        LastBlockers {
            lag,
            facets: (0..body.mesh.len() * lag)
                .map(|_| AtomicU32::new(NO_BLOCKER))
                .collect(),
            // The blockers are facets of everything that casts shadows.
            neighbours: edge_neighbours(body.shadow_mesh()),
            walks: (0..body.mesh.len().div_ceil(WALK_GROUP))
                .map(|_| AtomicU64::new(WalkYield::FIRST.packed()))
                .collect(),
        }
    }
}

/// No blocker remembered.
const NO_BLOCKER: u32 = u32::MAX;

/// What a body knows of its horizon.
enum OwnHorizon<'w> {
    /// Nothing: a ray per facet facing the Sun.
    None,
    /// The horizon bound of the BVH tracer: no ray for a Sun above it; with the tree
    /// (shared with the tracer), what a facet sees of a disk Sun's cone.
    Bound {
        bound: HorizonBound,
        bvh: Arc<Bvh<'w>>,
    },
    /// A horizon map: no ray where it is certain (`exact`), or none at all.
    Map { map: HorizonMap, exact: bool },
}

impl OwnHorizon<'_> {
    /// Whether it decides every facet-step without a ray under a Sun shaped `sun`: a
    /// map in the approximate mode, and any map for a disk Sun.
    fn decides_alone(&self, sun: SunShape) -> bool {
        matches!(self, OwnHorizon::Map { exact, .. } if !exact || sun == SunShape::Disk)
    }
}

/// Another body that may shadow a receiver at this step, with the transform taking
/// receiver-frame points into its frame.
struct ForeignCaster<'q> {
    to_caster: FrameTransform,
    /// The Sun's centre, caster frame.
    sun: DVec3,
    /// Radius of a sphere about the caster's origin that holds it, metres.
    reach_m: f64,
    shadow: CasterShadow<'q>,
}

/// How another body's shadow is found.
enum CasterShadow<'q> {
    /// Rays through its mesh: toward the Sun's centre, and for a disk Sun toward each of
    /// the disk's equal-flux samples.
    Rays {
        centre: Box<dyn ShadowQuery + 'q>,
        disk: Vec<Box<dyn ShadowQuery + 'q>>,
    },
    /// A generated ellipsoid under a disk Sun: the hidden share in closed form.
    Ellipsoid(Ellipsoid),
}

impl<'w> Direct<'w> {
    /// Builds the tracers of every body, for a point Sun and shadow rays. With the BVH
    /// tracer, a body that can shadow itself also gets its horizon bound, built with the
    /// same tree.
    pub fn new(world: &'w World, kind: TracerKind) -> Direct<'w> {
        let none = world.bodies.iter().map(|_| None).collect();
        Direct::with_maps(world, kind, none, &Shadows::default())
    }

    /// As [`Direct::new`], with a horizon map for the bodies that have one in `maps`
    /// (scene order), used as `shadows` says, and the Sun shaped as it says.
    pub fn with_maps(
        world: &'w World,
        kind: TracerKind,
        maps: Vec<Option<HorizonMap>>,
        shadows: &Shadows,
    ) -> Direct<'w> {
        let exact = shadows.mode == HorizonMode::Exact;
        // The last blockers (their edge neighbours) are found before the body's tree is
        // built: the hash maps that find them are freed first, and the tree and the
        // bound reuse their memory instead of adding to it.
        let lag = shadows.recall.lag;
        let remember = |b: &Body, remembers: bool| remembers.then(|| LastBlockers::new(b, lag));
        let mut bound_records = Vec::new();
        let mut last_blockers = Vec::new();
        let (tracers, horizons) = world
            .bodies
            .iter()
            .zip(maps)
            .map(|(b, map)| match (map, kind) {
                // The few rays a map leaves are traced by the BVH, which costs nothing per
                // step (every tracer classifies each ray identically). A lone body whose
                // map decides alone casts no ray at all: the tracer without setup stands
                // in for a tree (786k facets: 1.3 s and its memory) that nothing reads.
                (Some(map), _) => {
                    last_blockers.push(remember(b, shadows.remembers_blockers(true)));
                    let bounded = map.kind() == MapKind::Bounded;
                    let horizon = OwnHorizon::Map { map, exact };
                    let alone = horizon.decides_alone(shadows.sun);
                    // A map of centres alone certifies nothing: the exact mode's lit facets
                    // would go unchecked.
                    assert!(
                        bounded || alone,
                        "a map of centres alone where the exact mode reads its upper bounds"
                    );
                    let tracer = match world.bodies.len() == 1 && alone {
                        true => trace::build(TracerKind::Sunview, b.shadow_mesh()),
                        false => Box::new(Bvh::build(b.shadow_mesh())) as Box<dyn Tracer + 'w>,
                    };
                    (tracer, horizon)
                }
                (None, TracerKind::Bvh) if !b.convex => {
                    last_blockers.push(remember(b, shadows.remembers_blockers(false)));
                    let bvh = Arc::new(Bvh::build(b.shadow_mesh()));
                    let (bound, record) = shadows.bound(b, &bvh);
                    bound_records.push(record);
                    let tracer = Box::new(Arc::clone(&bvh)) as Box<dyn Tracer + 'w>;
                    (tracer, OwnHorizon::Bound { bound, bvh })
                }
                (None, _) => {
                    last_blockers.push(None);
                    (trace::build(kind, b.shadow_mesh()), OwnHorizon::None)
                }
            })
            .unzip();
        Direct {
            bound_records,
            last_blockers,
            ..Direct::assemble(world, tracers, horizons, shadows)
        }
    }

    /// For shadow rays through the given tracers, one per body (scene order): built by
    /// the caller, who may share them (the point queries' trees); the Sun shaped as
    /// `shadows` says (horizon maps are not used).
    pub fn with_tracers(
        world: &'w World,
        tracers: Vec<Box<dyn Tracer + 'w>>,
        shadows: &Shadows,
    ) -> Direct<'w> {
        let horizons = tracers.iter().map(|_| OwnHorizon::None).collect();
        Direct::assemble(world, tracers, horizons, shadows)
    }

    fn assemble(
        world: &'w World,
        tracers: Vec<Box<dyn Tracer + 'w>>,
        horizons: Vec<OwnHorizon<'w>>,
        shadows: &Shadows,
    ) -> Direct<'w> {
        Direct {
            world,
            tracers,
            horizons,
            sun: shadows.sun,
            disk: shadows.disk,
            disk_samples: match shadows.sun {
                SunShape::Point => Vec::new(),
                SunShape::Disk => shadows.disk.samples(shadows.sun_samples as usize),
            },
            min_height_m: world.bodies.iter().map(min_blocker_heights).collect(),
            offsets: world.offsets(),
            lit: vec![true; world.bodies.len()],
            bound_records: Vec::new(),
            last_blockers: world.bodies.iter().map(|_| None).collect(),
        }
    }

    /// Where each body's horizon bound came from (the bodies whose rays use one).
    pub fn bound_records(&self) -> &[BoundRecord] {
        &self.bound_records
    }

    /// Leaves out the irradiance of the bodies not `needed` (scene order): their facets
    /// get 0, and they still cast shadows on the others.
    pub fn only_for(mut self, needed: Vec<bool>) -> Self {
        self.lit = needed;
        self
    }

    /// Irradiance (W/m²) of every facet at `state`, written to `out` (global facet ids).
    pub fn compute(&self, state: &EpochState, out: &mut [f64]) -> Result<StepCounts> {
        self.compute_steps(std::slice::from_ref(state), &mut [out])
    }

    /// Irradiance (W/m²) of every facet at each of `states`, written to the matching
    /// `outs` (global facet ids); the same values as [`Direct::compute`] step by step.
    /// Facets are lit for all the steps in one pass, so a horizon map's data and the
    /// normals are read once per block of steps instead of once per step; each step's
    /// shadow queries are then set up and traced one step at a time, as before.
    pub fn compute_steps(
        &self,
        states: &[EpochState],
        outs: &mut [&mut [f64]],
    ) -> Result<StepCounts> {
        let each = self.compute_steps_each(states, outs)?;
        Ok(each.into_iter().fold(StepCounts::default(), |mut all, c| {
            all += c;
            all
        }))
    }

    /// [`Direct::compute_steps`] with the counts of each step apart.
    pub fn compute_steps_each(
        &self,
        states: &[EpochState],
        outs: &mut [&mut [f64]],
    ) -> Result<Vec<StepCounts>> {
        assert_eq!(states.len(), outs.len(), "one output per step");
        let mut counts = vec![StepCounts::default(); states.len()];
        for (b, body) in self.world.bodies.iter().enumerate() {
            let range = self.offsets[b]..self.offsets[b] + body.mesh.len();
            let mut views: Vec<&mut [f64]> =
                outs.iter_mut().map(|o| &mut o[range.clone()]).collect();
            if !self.lit[b] {
                views.iter_mut().for_each(|v| v.fill(0.0));
                continue;
            }
            let skies = states
                .iter()
                .map(|state| self.sky(b, state))
                .collect::<Result<Vec<_>>>()?;
            let block = match self.steps_one_by_one(b) {
                true => 1,
                false => states.len().max(1),
            };
            for (((states, skies), views), counts) in states
                .chunks(block)
                .zip(skies.chunks(block))
                .zip(views.chunks_mut(block))
                .zip(counts.chunks_mut(block))
            {
                let own: Vec<_> = skies.iter().map(|sky| self.point_query(b, sky)).collect();
                let facing = self.light_facing(b, skies, &own, views);
                for ((((state, sky), (lit, rays)), out), counts) in
                    states.iter().zip(skies).zip(facing).zip(views).zip(counts)
                {
                    *counts += lit;
                    *counts += self.shade(b, &self.others_light(b, state, sky), &rays, out);
                }
            }
        }
        Ok(counts)
    }

    /// Whether body `b` takes a block's steps one at a time. A body that traces most of
    /// its lit facets (it shadows itself and has no horizon map) would hold a block's
    /// rays at once for a disk Sun's samples (hundreds of MB at a million facets), and
    /// the Sun-view grid builds a grid per direction. Toward a point Sun through the BVH
    /// (the tracer with a horizon bound) the rays are traced where they arise and the
    /// queries cost nothing to hold, so a chunk of facets takes every step of the block
    /// in turn, as with a map: one parallel pass per block instead of one per step.
    fn steps_one_by_one(&self, b: usize) -> bool {
        let traces_most = self.traces_own(b) && !matches!(self.horizons[b], OwnHorizon::Map { .. });
        let queries_are_free =
            self.sun == SunShape::Point && matches!(self.horizons[b], OwnHorizon::Bound { .. });
        traces_most && !queries_are_free
    }

    /// Irradiance (W/m²) at `state` of a few facets, each given as (body index, local
    /// facet id); only those facets are traced. Meant for the grid tracer, whose Sun
    /// queries cost nothing to set up.
    pub fn compute_facets(
        &self,
        state: &EpochState,
        facets: &[(usize, usize)],
    ) -> Result<Vec<f64>> {
        let mut counts = StepCounts::default();
        // Each body's Sun and shadow queries, set up once for all its facets asked for.
        let mut lights: Vec<Option<Sunlight<'_>>> =
            self.world.bodies.iter().map(|_| None).collect();
        let mut values = Vec::with_capacity(facets.len());
        for &(b, i) in facets {
            let light = match &mut lights[b] {
                Some(light) => light,
                empty => empty.insert(self.sunlight(b, state)?),
            };
            values.push(self.facet_irradiance(b, i, light, &mut counts));
        }
        Ok(values)
    }

    /// The share of the Sun's flux that no other body hides from `point` (body `b`'s
    /// frame, metres; a point off the surface such as a panel): 0 or 1 for a point Sun
    /// (the ray toward its centre), the visible share of the disk for a disk Sun (closed
    /// form behind an ellipsoid, the disk's samples behind a mesh).
    pub fn share_past_others(&self, b: usize, state: &EpochState, point: DVec3) -> Result<f64> {
        let light = self.sunlight(b, state)?;
        let mut counts = StepCounts::default();
        Ok(match self.sun {
            SunShape::Point => {
                let blocked = light.blocked_by_others(point, 0.0, &mut counts);
                if blocked {
                    0.0
                } else {
                    1.0
                }
            }
            SunShape::Disk => light.visible_past_others(point, 0.0, &mut counts),
        })
    }

    /// Where body `b`'s Sun stands at this step.
    fn sky(&self, b: usize, state: &EpochState) -> Result<Sky> {
        let body = &self.world.bodies[b];
        let radius = match self.sun {
            SunShape::Point => 0.0,
            SunShape::Disk => SolarDisk::angular_radius(state.bodies[b].sun_distance_m),
        };
        Ok(Sky {
            step: state.step,
            sun: checked_sun(body, state, b)?,
            flux: state.bodies[b].flux_w_m2,
            radius,
            sin_radius: radius.sin(),
        })
    }

    /// Body `b`'s Sun, flux and shadow queries at this step (also used by the renderer
    /// for points that are not centroids).
    pub(crate) fn sunlight(&self, b: usize, state: &EpochState) -> Result<Sunlight<'_>> {
        let mut light = self.others_light(b, state, &self.sky(b, state)?);
        light.own = self
            .traces_own(b)
            .then(|| self.tracers[b].toward(light.sun));
        Ok(light)
    }

    /// [`Direct::sunlight`] in `sky` (the step's, [`Direct::sky`]) with the shadow queries
    /// of the other bodies alone: the step loop traces a point Sun's rays through the body
    /// itself with the facets ([`Direct::light_facing`]), and a disk Sun's by samples
    /// ([`Direct::shade_disk`]).
    fn others_light(&self, b: usize, state: &EpochState, sky: &Sky) -> Sunlight<'_> {
        let Sky {
            sun, flux, radius, ..
        } = *sky;
        Sunlight {
            sun,
            flux,
            radius,
            disk: self.disk,
            own: None,
            foreign: self.foreign_casters(b, state, sun, radius),
        }
    }

    /// The shadow queries through body `b` itself toward a point Sun in `sky`, when its
    /// own shadows need rays; `None` for a disk Sun, whose samples are traced apart.
    fn point_query(&self, b: usize, sky: &Sky) -> Option<Box<dyn ShadowQuery + '_>> {
        (self.sun == SunShape::Point && self.traces_own(b)).then(|| self.tracers[b].toward(sky.sun))
    }

    /// Whether body `b`'s own shadows need rays: it can shadow itself, and no horizon
    /// map decides alone (approximate mode, or the Sun as a disk).
    fn traces_own(&self, b: usize) -> bool {
        !self.world.bodies[b].convex && !self.map_decides_alone(b)
    }

    /// Whether body `b`'s horizon map decides every facet-step without a ray: in the
    /// approximate mode, and for a disk Sun.
    fn map_decides_alone(&self, b: usize) -> bool {
        self.horizons[b].decides_alone(self.sun)
    }

    /// Bodies whose bounding spheres can reach into the receiver's shadow: the cylinder
    /// toward the Sun's centre, widened by the cone of a disk Sun of angular `radius`.
    fn foreign_casters(
        &self,
        receiver: usize,
        state: &EpochState,
        sun: DVec3,
        radius: f64,
    ) -> Vec<ForeignCaster<'_>> {
        let bodies = &self.world.bodies;
        let rx = &state.bodies[receiver];
        (0..bodies.len())
            .filter(|&c| c != receiver)
            .filter_map(|c| {
                let to_caster = rx.pose.relative_to(&state.bodies[c].pose);
                let centre = to_caster.rotation.transpose() * -to_caster.offset_m;
                let along = centre.dot(sun);
                let across = (centre - along * sun).length();
                let reach = bodies[receiver].bounding_radius_m + bodies[c].bounding_radius_m;
                let penumbra = (along + reach).max(0.0) * radius.tan();
                (along > -reach && across <= reach + penumbra)
                    .then(|| self.foreign_caster(c, to_caster, to_caster.vector(sun), radius))
            })
            .collect()
    }

    /// Body `c` as a caster of shadows, for the Sun along `sun` (its frame).
    fn foreign_caster(
        &self,
        c: usize,
        to_caster: FrameTransform,
        sun: DVec3,
        radius: f64,
    ) -> ForeignCaster<'_> {
        let body = &self.world.bodies[c];
        let shadow = match (self.sun, body.ellipsoid_radii_m) {
            (SunShape::Disk, Some(radii_m)) => CasterShadow::Ellipsoid(Ellipsoid { radii_m }),
            _ => CasterShadow::Rays {
                centre: self.tracers[c].toward(sun),
                disk: self
                    .disk_samples
                    .iter()
                    .map(|&offset| self.tracers[c].toward(disk_point(sun, radius, offset)))
                    .collect(),
            },
        };
        ForeignCaster {
            to_caster,
            sun,
            reach_m: body.bounding_radius_m,
            shadow,
        }
    }

    /// Scales the facets of body `b` in `out` by the share of a disk Sun their own body
    /// leaves in view (their sample `rays`; a point Sun's rays were traced with the
    /// facets), then darkens those other bodies shadow.
    fn shade(
        &self,
        b: usize,
        light: &Sunlight<'_>,
        rays: &[ShadowRay],
        out: &mut [f64],
    ) -> StepCounts {
        let mut counts = StepCounts::default();
        if self.sun == SunShape::Disk && self.traces_own(b) {
            counts += self.shade_disk(b, light, rays, out);
        }
        if !light.foreign.is_empty() {
            counts += self.shade_by_others(b, light, out);
        }
        counts
    }

    /// Darkens the facets of a chunk (numbered from `first`, values in `values`) whose
    /// shadow `rays` through their own body `own` (toward a point Sun) are blocked. Traced
    /// in the chunk's own task: one parallel pass per step, not one for the facets and
    /// one for the rays. Rays the surface around their remembered blocker answers are
    /// taken first, where such walks pay ([`WalkYield`]); the rest go through the tracer
    /// together ([`ShadowQuery::blockers`]).
    fn trace_own(
        &self,
        facets: Facets,
        step: usize,
        own: &dyn ShadowQuery,
        rays: &[ShadowRay],
        values: &mut [f64],
    ) -> StepCounts {
        let last = self.last_blockers[facets.body]
            .as_ref()
            .map(|l| l.row(step));
        let mut counts = StepCounts {
            rays: rays.len() as u64,
            ..StepCounts::default()
        };
        // Without remembered blockers every ray goes to the tracer as it came.
        let left;
        let to_trace = match last {
            Some(row) => {
                let walked;
                (left, walked) = walk_from_remembered(own, rays, row, values, facets);
                counts += walked;
                counts.shadowed += walked.remembered;
                &left[..]
            }
            None => rays,
        };
        for (r, blocker) in to_trace.iter().zip(own.blockers(to_trace)) {
            if let Some(row) = last {
                remember(row, r, blocker);
            }
            if blocker != Blocker::Clear {
                counts.shadowed += 1;
                values[r.facet as usize - facets.first] = 0.0;
            }
        }
        counts
    }

    /// Scales the facets of `rays` in `out`, which hold the share of a disk Sun above
    /// their planes, by the share their own body leaves in view ([`Direct::own_disk_shares`]).
    fn shade_disk(
        &self,
        b: usize,
        light: &Sunlight<'_>,
        rays: &[ShadowRay],
        out: &mut [f64],
    ) -> StepCounts {
        let (shares, mut counts) = self.own_disk_shares(b, light, rays);
        for (r, share) in rays.iter().zip(shares) {
            let e = &mut out[r.facet as usize];
            *e *= share;
            counts.shadowed += (*e == 0.0) as u64;
        }
        counts
    }

    /// Per ray of `rays`, the share of a disk Sun above its facet's plane that the
    /// facet's own body leaves in view: the share of the disk's samples above the plane
    /// whose rays are clear, each weighted by its `n·s` (the flux it brings; [`DiskTally`]).
    /// With the BVH tracer's bound and tree, the disk's cone decides first
    /// ([`Direct::disk_shares_by_cones`]); without, every sample is traced
    /// ([`Direct::disk_shares_traced`]).
    fn own_disk_shares(
        &self,
        b: usize,
        light: &Sunlight<'_>,
        rays: &[ShadowRay],
    ) -> (Vec<f64>, StepCounts) {
        if rays.is_empty() {
            // Nothing to build: a Sun-view grid per sample is dear.
            return (Vec::new(), StepCounts::default());
        }
        let (shares, traced) = match &self.horizons[b] {
            OwnHorizon::Bound { bound, bvh } => {
                self.disk_shares_by_cones(b, light, rays, (bound, bvh))
            }
            _ => self.disk_shares_traced(b, light, rays),
        };
        let counts = StepCounts {
            rays: traced,
            ..StepCounts::default()
        };
        (shares, counts)
    }

    /// [`Direct::own_disk_shares`] through the cones: a facet whose cone is clear gets 1,
    /// one covered (by one facet or a pair sharing an edge) 0, and one partly covered its
    /// samples, answered by the few facets reaching into the cone alone, without walks
    /// through the tree. Also the count of samples answered.
    fn disk_shares_by_cones(
        &self,
        b: usize,
        light: &Sunlight<'_>,
        rays: &[ShadowRay],
        (bound, bvh): (&HorizonBound, &Bvh),
    ) -> (Vec<f64>, u64) {
        let body = &self.world.bodies[b];
        let samples: Vec<(DVec3, BvhRays)> = (self.disk_samples.iter())
            .map(|&offset| {
                let s = disk_point(light.sun, light.radius, offset);
                (s, BvhRays::new(bvh, s))
            })
            .collect();
        let cone = Cone::new(light.sun, light.radius);
        let (shares, answered): (Vec<f64>, Vec<u64>) = rays
            .par_iter()
            .map(|r| {
                let beyond = self.disk_beyond(b, r.facet as usize, (light.sun, light.radius));
                let view =
                    bound.cone_view(body.shadow_mesh(), bvh, r.facet as usize, &cone, beyond);
                self.share_in_view(b, r, &view, samples.iter().copied())
            })
            .unzip();
        (shares, answered.iter().sum())
    }

    /// How far (metres) from facet `i`'s centroid a facet must stand to cover a disk Sun
    /// (unit vector toward its centre, angular radius) for it: the disk's samples count
    /// hits beyond their `t_min`, the farthest for the disk's lowest point; a disk
    /// reaching below the plane is never covered.
    fn disk_beyond(&self, b: usize, i: usize, (sun, radius): (DVec3, f64)) -> f64 {
        let n = self.world.bodies[b].mesh.normals[i];
        let lowest = lowest_sin(n.dot(sun), radius);
        match lowest > 0.0 {
            true => self.t_min(b, i, lowest),
            false => f64::INFINITY,
        }
    }

    /// The share of a disk Sun above the plane of the facet of `r` that its own body
    /// leaves in view, from what its centroid sees of the disk's cone (`view`), and the
    /// samples answered: a clear cone 1, a covered one 0, a partial one the share of its
    /// `samples` (directions with their rays) that the facets reaching in leave clear.
    fn share_in_view<'q>(
        &self,
        b: usize,
        r: &ShadowRay,
        view: &ConeView,
        samples: impl Iterator<Item = (DVec3, BvhRays<'q>)>,
    ) -> (f64, u64) {
        match view {
            ConeView::Clear => (1.0, 0),
            ConeView::Covered(_) => (0.0, 0),
            ConeView::Partial(among) => self.share_among(b, r, among, samples, |_| {}),
        }
    }

    /// The share of the disk's `samples` above the plane of the facet of `r` that the
    /// facets `among` leave clear, and the samples answered; each sample's blocker (the
    /// first of `among` that blocks it; `u32::MAX` for one clear or below the plane) goes
    /// to `blocker`, in the samples' order.
    fn share_among<'q>(
        &self,
        b: usize,
        r: &ShadowRay,
        among: &[u32],
        samples: impl Iterator<Item = (DVec3, BvhRays<'q>)>,
        mut blocker: impl FnMut(u32),
    ) -> (f64, u64) {
        let i = r.facet as usize;
        let n = self.world.bodies[b].mesh.normals[i];
        let mut tally = DiskTally::default();
        for (s, query) in samples {
            let mut found = None;
            tally.add(n.dot(s), |cos| {
                found = query.blocker_among(r.origin, self.t_min(b, i, cos), r.facet, among);
                found.is_none()
            });
            blocker(found.unwrap_or(u32::MAX));
        }
        (tally.share(), tally.rays)
    }

    /// [`Direct::own_disk_shares`] with every sample traced by the body's tracer, one
    /// direction at a time, so that one direction's shadow queries (a Sun-view grid) are
    /// held at once, as for a point Sun. Also the count of rays traced.
    fn disk_shares_traced(
        &self,
        b: usize,
        light: &Sunlight<'_>,
        rays: &[ShadowRay],
    ) -> (Vec<f64>, u64) {
        let normals = &self.world.bodies[b].mesh.normals;
        let mut tallies = vec![DiskTally::default(); rays.len()];
        for &offset in &self.disk_samples {
            let s = disk_point(light.sun, light.radius, offset);
            let query = self.tracers[b].toward(s);
            (rays.par_iter().zip(&mut tallies)).for_each(|(r, tally)| {
                let i = r.facet as usize;
                tally.add(normals[i].dot(s), |cos| {
                    !query.blocked(r.origin, self.t_min(b, i, cos), Some(r.facet))
                });
            });
        }
        let traced = tallies.iter().map(|t| t.rays).sum();
        (tallies.iter().map(DiskTally::share).collect(), traced)
    }

    /// Lights every facet of body `b` facing the Sun at each step (`skies[k]` into
    /// `outs[k]`) as if nothing of its own body blocked it, except where a horizon map
    /// decides; traces the own body's shadow rays toward a point Sun through `own[k]`
    /// ([`Direct::point_query`]) and lists per step those left to trace by disk samples:
    /// none when the body cannot shadow itself, none where the Sun stands above the
    /// facet's horizon bound or the map is certain or decides alone. A chunk of facets
    /// takes every step in turn while its normals and map data are in cache.
    fn light_facing(
        &self,
        b: usize,
        skies: &[Sky],
        own: &[Option<Box<dyn ShadowQuery + '_>>],
        outs: &mut [&mut [f64]],
    ) -> Vec<(StepCounts, Vec<ShadowRay>)> {
        // Chunks of 256 to 2048 facets, at least 48 per thread where the mesh allows, each
        // taken alone by whichever thread is free: the rays gather where the shadows are,
        // so chunks cost unevenly, and a thread left with the last few (rayon's default
        // runs of several) idled its partner for a chunk's time or more per pass. Whole
        // groups of walk records, so that each is one task's.
        let count = outs.first().map_or(0, |o| o.len());
        let chunk = count
            .div_ceil(48 * rayon::current_num_threads())
            .clamp(256, 2048)
            .next_multiple_of(WALK_GROUP);
        let mut chunks: Vec<Vec<&mut [f64]>> = Vec::new();
        for out in outs.iter_mut() {
            for (c, part) in out.chunks_mut(chunk).enumerate() {
                if chunks.len() == c {
                    chunks.push(Vec::with_capacity(skies.len()));
                }
                chunks[c].push(part);
            }
        }
        let nothing = || {
            skies
                .iter()
                .map(|_| (StepCounts::default(), Vec::new()))
                .collect()
        };
        chunks
            .into_par_iter()
            .with_max_len(1)
            .enumerate()
            .map(|(c, steps)| {
                let facets = Facets {
                    body: b,
                    first: c * chunk,
                };
                let mut scratch = ChunkScratch::default();
                (steps.into_iter().zip(skies).zip(own))
                    .map(|((values, sky), own)| {
                        let (mut counts, rays) =
                            self.light_chunk(facets, sky, values, &mut scratch);
                        match own {
                            Some(own) => {
                                counts +=
                                    self.trace_own(facets, sky.step, own.as_ref(), &rays, values);
                                (counts, Vec::new())
                            }
                            None => (counts, rays),
                        }
                    })
                    .collect::<Vec<_>>()
            })
            .reduce(nothing, |mut a, b| {
                for ((ca, ra), (cb, rb)) in a.iter_mut().zip(b) {
                    *ca += cb;
                    ra.extend(rb);
                }
                a
            })
    }

    /// [`Direct::light_facing`] for one step and one chunk of facets, numbered from
    /// `facets.first`, whose values are `values`; `scratch` is the task's, kept between
    /// its calls.
    fn light_chunk(
        &self,
        facets: Facets,
        sky: &Sky,
        values: &mut [f64],
        scratch: &mut ChunkScratch,
    ) -> (StepCounts, Vec<ShadowRay>) {
        let Facets { body: b, first } = facets;
        let mesh = &self.world.bodies[b].mesh;
        let horizon = &self.horizons[b];
        let traces_own = self.traces_own(b);
        // A disk starts to rise above a facet's plane when its centre is ρ below it, and
        // stands wholly above it when its centre is ρ above.
        let sin_radius = sky.sin_radius;
        let facing = -sin_radius;
        let mut counts = StepCounts::default();
        let mut rays = Vec::new();
        let ChunkScratch { day, pending } = scratch;
        pending.clear();
        let normals = &mesh.normals[first..first + values.len()];
        let sun = self.sun;
        // The cosines first, in a loop of their own: most facets need nothing else.
        for (e, normal) in values.iter_mut().zip(normals) {
            *e = normal.dot(sky.sun);
        }
        facets_facing(values, facing, day);
        counts.night = (values.len() - day.len()) as u64;
        for &k in day.iter() {
            let k = k as usize;
            let i = first + k;
            let e = &mut values[k];
            let cos = *e;
            let cleared = match horizon {
                OwnHorizon::Map { map, exact } => {
                    // A point Sun above the facet's whole horizon, or above the octant of
                    // azimuth it stands in, needs no lookup; nor does a disk wholly above
                    // every horizon its map gives, at any azimuth or in its octant.
                    let at = match sun {
                        SunShape::Point if map.above_all(i, cos) => None,
                        SunShape::Point => map.locate(i, normals[k], sky.sun, cos),
                        SunShape::Disk if map.disk_above_all(i, cos, sky.radius) => None,
                        SunShape::Disk => {
                            map.locate_disk(i, normals[k], (sky.sun, sky.radius), cos)
                        }
                    };
                    match at {
                        // Its value holds the cosine until the lookup.
                        Some(at) => {
                            pending.push((k, at));
                            continue;
                        }
                        None if *exact && sun == SunShape::Point => counts.above_horizon += 1,
                        None => counts.horizon_lookups += 1,
                    }
                    *e = sky.flux * cos;
                    continue;
                }
                // The facet's own plane; then, unless nothing else can rise into the
                // disk, its samples' rays (`shade`).
                _ if sun == SunShape::Disk => {
                    *e = sky.flux * self.plane_disk_share(cos, (sky.radius, sin_radius));
                    let cleared = self.disk_clears_own(b, i, cos, sky.radius);
                    if *e == 0.0 {
                        counts.shadowed += 1;
                    } else if !cleared {
                        rays.push(self.own_ray(b, i, cos.max(f64::MIN_POSITIVE)));
                    } else if traces_own {
                        counts.above_horizon += 1;
                    }
                    continue;
                }
                OwnHorizon::Bound { bound, .. } => bound.clears(i, normals[k], sky.sun, cos),
                OwnHorizon::None if traces_own => false,
                OwnHorizon::None => {
                    *e = sky.flux * cos;
                    continue;
                }
            };
            *e = sky.flux * cos;
            if cleared {
                counts.above_horizon += 1;
            } else {
                rays.push(self.own_ray(b, i, cos));
            }
        }
        if let OwnHorizon::Map { map, exact } = horizon {
            let lookups = Lookups {
                map,
                exact: *exact,
                sky,
            };
            self.read_cells(facets, lookups, pending, values, &mut counts, &mut rays);
        }
        (counts, rays)
    }

    /// Decides the `pending` facets of a chunk from their map cells: lit, dark, the
    /// disk's visible share, or (exact mode) a ray. The cells are read in a loop of their
    /// own: the reads do not wait on one another, so the memory serves several at once.
    fn read_cells(
        &self,
        facets: Facets,
        lookups: Lookups<'_>,
        pending: &[(usize, SkyPosition)],
        values: &mut [f64],
        counts: &mut StepCounts,
        rays: &mut Vec<ShadowRay>,
    ) {
        let Lookups { map, exact, sky } = lookups;
        for &(k, at) in pending {
            let i = facets.first + k;
            let e = &mut values[k];
            let cos = *e;
            *e = sky.flux * cos;
            if self.sun == SunShape::Disk {
                counts.horizon_lookups += 1;
                let h = map.horizon(i, &at);
                *e = sky.flux * self.disk_share(cos, h, sky.radius);
                counts.shadowed += (*e == 0.0) as u64;
            } else if !exact {
                counts.horizon_lookups += 1;
                if map.hides(i, &at) {
                    *e = 0.0;
                    counts.shadowed += 1;
                }
            } else if map.clears(i, &at) {
                counts.above_horizon += 1;
            } else {
                rays.push(self.own_ray(facets.body, i, cos));
            }
        }
    }

    /// Darkens the facets of body `b` still lit in `out` that other bodies shadow: a
    /// point Sun when the ray from the centroid toward it is blocked; a disk Sun by the
    /// share of it they hide (taken as independent of the share the facet's own horizon
    /// hides, which is exact whenever only one of them cuts the disk).
    fn shade_by_others(&self, b: usize, light: &Sunlight<'_>, out: &mut [f64]) -> StepCounts {
        out.par_iter_mut()
            .enumerate()
            .filter(|(_, e)| **e > 0.0)
            .map(|(i, e)| {
                let mut counts = StepCounts::default();
                self.dim_by_others(b, i, light, e, &mut counts);
                counts.shadowed += (*e == 0.0) as u64;
                counts
            })
            .reduce(StepCounts::default, |mut a, b| {
                a += b;
                a
            })
    }

    /// Dims `e`, the irradiance of facet `i` of body `b`, by what other bodies hide of
    /// the Sun: all of it for a point Sun whose ray they block, their share of a disk.
    fn dim_by_others(
        &self,
        b: usize,
        i: usize,
        light: &Sunlight<'_>,
        e: &mut f64,
        counts: &mut StepCounts,
    ) {
        let mesh = &self.world.bodies[b].mesh;
        // A disk can light a facet whose plane hides the Sun's centre.
        let cos = mesh.normals[i].dot(light.sun).max(1e-6);
        let t_min = self.t_min(b, i, cos);
        let point = mesh.centroids[i];
        match self.sun {
            SunShape::Point if light.blocked_by_others(point, t_min, counts) => *e = 0.0,
            SunShape::Point => {}
            SunShape::Disk => *e *= light.visible_past_others(point, t_min, counts),
        }
    }

    /// Irradiance of facet `i` of body `b` under a disk Sun, as the step loop gives it:
    /// the share above its plane or its map's horizon, then the share its own body's
    /// rays leave, then other bodies'.
    fn facet_disk_irradiance(
        &self,
        b: usize,
        i: usize,
        light: &Sunlight<'_>,
        counts: &mut StepCounts,
    ) -> f64 {
        let normal = self.world.bodies[b].mesh.normals[i];
        let cos = normal.dot(light.sun);
        if cos <= -light.radius.sin() {
            counts.night += 1;
            return 0.0;
        }
        let mut e = match &self.horizons[b] {
            OwnHorizon::Map { map, .. } => {
                let horizon = map.horizon(i, &map.position(normal, light.sun, cos));
                light.flux * self.disk_share(cos, horizon, light.radius)
            }
            _ => light.flux * self.plane_disk_share(cos, (light.radius, light.radius.sin())),
        };
        let own_rays = !matches!(self.horizons[b], OwnHorizon::Map { .. })
            && !self.disk_clears_own(b, i, cos, light.radius);
        if e > 0.0 && own_rays {
            let ray = self.own_ray(b, i, cos.max(f64::MIN_POSITIVE));
            let (shares, traced) = self.own_disk_shares(b, light, &[ray]);
            e *= shares[0];
            *counts += traced;
        }
        if e > 0.0 && !light.foreign.is_empty() {
            self.dim_by_others(b, i, light, &mut e, counts);
        }
        counts.shadowed += (e == 0.0) as u64;
        e
    }

    /// Irradiance of facet `i` of body `b`: zero when it faces away from the Sun or the
    /// ray from its centroid is blocked by its own body or another; a disk Sun's share
    /// ([`Direct::facet_disk_irradiance`]).
    fn facet_irradiance(
        &self,
        b: usize,
        i: usize,
        light: &Sunlight<'_>,
        counts: &mut StepCounts,
    ) -> f64 {
        if self.sun == SunShape::Disk {
            return self.facet_disk_irradiance(b, i, light, counts);
        }
        let mesh = &self.world.bodies[b].mesh;
        let cos = mesh.normals[i].dot(light.sun);
        if cos <= 0.0 {
            counts.night += 1;
            return 0.0;
        }
        let blocked = light.blocked(mesh.centroids[i], self.t_min(b, i, cos), i, counts);
        counts.shadowed += blocked as u64;
        if blocked {
            0.0
        } else {
            light.flux * cos
        }
    }

    /// Whether nothing of body `b` but facet `i`'s own plane can hide part of a disk Sun
    /// of angular `radius` whose centre stands at `sin_elevation` (`n·s`) above it: the
    /// body cannot shadow itself, or the BVH tracer's bound lies below the disk.
    fn disk_clears_own(&self, b: usize, i: usize, sin_elevation: f64, radius: f64) -> bool {
        match &self.horizons[b] {
            OwnHorizon::Bound { bound, .. } => {
                bound.clears_all_around(i, lowest_sin(sin_elevation, radius))
            }
            _ => !self.traces_own(b),
        }
    }

    /// The share of the flux a facet receives from a disk Sun of angular radius
    /// `radius` whose centre stands at `sin_elevation` above its plane, with `horizon`
    /// (approximated by a straight line across the disk; [`crate::horizon::disk`]).
    /// A whole disk gives its centre's `sin_elevation` itself (the flux centroid of a
    /// symmetric disk), whichever way its horizon was found.
    fn disk_share(&self, sin_elevation: f64, horizon: LocalHorizon, radius: f64) -> f64 {
        let e = sin_elevation.clamp(-1.0, 1.0).asin();
        match self.disk.cut_by(e, horizon, radius) {
            None => sin_elevation.max(0.0),
            Some((fraction, centroid)) => fraction * centroid.sin().max(0.0),
        }
    }

    /// [`Direct::disk_share`] over the facet's own plane alone, the disk's angular radius
    /// given with its sine: a disk wholly above the plane gives its centre's cosine (the
    /// flux centroid of a symmetric disk), with no angle taken.
    fn plane_disk_share(&self, sin_elevation: f64, (radius, sin_radius): (f64, f64)) -> f64 {
        match sin_elevation >= sin_radius {
            true => sin_elevation,
            false => self.disk_share(sin_elevation, PLANE, radius),
        }
    }

    /// The shadow ray of facet `i` of body `b` through its own body, the Sun at `cos_i`
    /// from its normal.
    fn own_ray(&self, b: usize, i: usize, cos_i: f64) -> ShadowRay {
        ShadowRay {
            facet: i as u32,
            origin: self.world.bodies[b].mesh.centroids[i],
            t_min: self.t_min(b, i, cos_i),
        }
    }

    /// The least distance along the Sun ray at which a hit on facet `i` of body `b` counts
    /// as a shadow, for the Sun at `cos_i` from its normal (the module doc's `h_min`).
    pub fn t_min(&self, b: usize, i: usize, cos_i: f64) -> f64 {
        f64::from(self.min_height_m[b][i]) / cos_i
    }
}

/// The samples of a disk Sun above one facet's plane, each weighted by its `n·s` (the
/// flux it brings), and those of them in view.
#[derive(Debug, Clone, Copy, Default)]
struct DiskTally {
    seen: f64,
    clear: f64,
    /// Samples above the plane (rays answered).
    rays: u64,
}

impl DiskTally {
    /// Takes a sample at `cos = n·s` above the plane (nothing below it), in view when
    /// `clear(cos)` says so.
    fn add(&mut self, cos: f64, clear: impl FnOnce(f64) -> bool) {
        if cos <= 0.0 {
            return;
        }
        self.seen += cos;
        self.rays += 1;
        if clear(cos) {
            self.clear += cos;
        }
    }

    /// The share of the samples' flux in view: 1 for a facet the disk only grazes,
    /// with no sample above its plane.
    fn share(&self) -> f64 {
        if self.seen > 0.0 {
            self.clear / self.seen
        } else {
            1.0
        }
    }
}

/// Where one body's Sun stands at one step: all that lighting its facets as if nothing
/// blocked the Sun needs.
#[derive(Debug, Clone, Copy)]
struct Sky {
    /// The step's index in the run.
    step: usize,
    /// Unit vector toward the Sun's centre, body frame.
    sun: DVec3,
    /// Flux at the body, W/m².
    flux: f64,
    /// The Sun's angular radius, radians (0 for a point Sun).
    radius: f64,
    /// Its sine, taken once a step (not once for each chunk of facets).
    sin_radius: f64,
}

/// What [`Direct::light_chunk`] lists of a chunk's facets at one step, kept by a task
/// between its calls so that the lists are not allocated anew each step.
#[derive(Default)]
struct ChunkScratch {
    /// The facets facing the Sun (chunk-local).
    day: Vec<u32>,
    /// Those whose map cells decide, with where the Sun stands in their sky.
    pending: Vec<(usize, SkyPosition)>,
}

/// A chunk of body `body`'s facets, numbered from `first` (body-local ids).
#[derive(Debug, Clone, Copy)]
struct Facets {
    body: usize,
    first: usize,
}

/// What the cell reads of a chunk's facets need: the map, its mode, and the Sun.
#[derive(Clone, Copy)]
struct Lookups<'a> {
    map: &'a HorizonMap,
    exact: bool,
    sky: &'a Sky,
}

/// One body's Sun at one step with the shadow queries that serve it.
pub(crate) struct Sunlight<'q> {
    sun: DVec3,
    flux: f64,
    /// The Sun's angular radius, radians (0 for a point Sun).
    radius: f64,
    disk: SolarDisk,
    own: Option<Box<dyn ShadowQuery + 'q>>,
    foreign: Vec<ForeignCaster<'q>>,
}

impl Sunlight<'_> {
    /// True when a facet of any body blocks the Sun from `point` (receiver frame, on
    /// facet `facet` of the receiver) farther than `t_min`; counts the rays traced.
    pub(crate) fn blocked(
        &self,
        point: DVec3,
        t_min: f64,
        facet: usize,
        counts: &mut StepCounts,
    ) -> bool {
        let blocked_by_self = self.own.as_deref().is_some_and(|q| {
            counts.rays += 1;
            q.blocked(point, t_min, Some(facet as u32))
        });
        blocked_by_self || self.blocked_by_others(point, t_min, counts)
    }

    /// True when another body blocks the Sun's centre from `point` farther than `t_min`.
    fn blocked_by_others(&self, point: DVec3, t_min: f64, counts: &mut StepCounts) -> bool {
        self.foreign.iter().any(|f| {
            let at = f.to_caster.point(point);
            match &f.shadow {
                CasterShadow::Rays { centre, .. } => {
                    counts.rays += 1;
                    centre.blocked(at, t_min, None)
                }
                CasterShadow::Ellipsoid(e) => e.blocks(at, f.sun),
            }
        })
    }

    /// The share of the disk Sun's flux that no other body hides from `point`.
    fn visible_past_others(&self, point: DVec3, t_min: f64, counts: &mut StepCounts) -> f64 {
        self.foreign
            .iter()
            .map(|f| {
                let at = f.to_caster.point(point);
                if !f.may_cover(at, self.radius) {
                    return 1.0;
                }
                match &f.shadow {
                    CasterShadow::Ellipsoid(e) => {
                        1.0 - e.hidden_share(at, f.sun, self.radius, &self.disk)
                    }
                    CasterShadow::Rays { disk, .. } => {
                        counts.rays += disk.len() as u64;
                        let clear = disk.iter().filter(|q| !q.blocked(at, t_min, None)).count();
                        clear as f64 / disk.len() as f64
                    }
                }
            })
            .product()
    }
}

impl ForeignCaster<'_> {
    /// Whether the caster's bounding sphere reaches into the cone of a disk Sun of
    /// angular `radius` seen from `at` (caster frame).
    fn may_cover(&self, at: DVec3, radius: f64) -> bool {
        let distance = at.length();
        if distance <= self.reach_m {
            return true;
        }
        let apart = self.sun.dot(-at / distance).clamp(-1.0, 1.0).acos();
        apart <= (self.reach_m / distance).asin() + radius
    }
}

/// The direction toward a point of the solar disk: `offset` (units of the angular
/// `radius`) from the centre `sun`, on the plane tangent to the sky there.
fn disk_point(sun: DVec3, radius: f64, offset: (f64, f64)) -> DVec3 {
    let e1 = sun.any_orthonormal_vector();
    let e2 = sun.cross(e1);
    (sun + radius.tan() * (offset.0 * e1 + offset.1 * e2)).normalize()
}

/// A facet's own plane as its horizon: elevation 0 at every azimuth.
const PLANE: LocalHorizon = LocalHorizon {
    elevation: 0.0,
    slope: 0.0,
};

/// Whether `ray` is blocked by a facet found on the surface around the one that
/// blocked it `lag` steps before (the row `last`): a Sun that moved a little is often
/// still behind it or a neighbour, and a few exact tests cost far less than a walk
/// through the tree. The answer is the tracer's own predicate's; the facet found is
/// remembered in its place, and the walk is counted in `walked` (`walks`, and
/// `remembered` when it found one).
fn blocked_as_remembered(
    own: &dyn ShadowQuery,
    ray: &ShadowRay,
    last: Row<'_>,
    walked: &mut StepCounts,
) -> bool {
    let memo = &last.facets[ray.facet as usize];
    let before = memo.load(Ordering::Relaxed);
    if before == NO_BLOCKER {
        return false;
    }
    let near = own.blocker_near(ray.origin, ray.t_min, ray.facet, before, last.neighbours);
    if let Some(id) = near.filter(|&id| id != before) {
        memo.store(id, Ordering::Relaxed);
    }
    walked.walks += 1;
    walked.remembered += u64::from(near.is_some());
    near.is_some()
}

/// Darkens the facets (of a chunk numbered from `first`, values in `values`) whose
/// `rays` a walk from their remembered blocker ([`blocked_as_remembered`]) finds blocked,
/// where walks pay: each run of [`WALK_GROUP`] facets keeps its own [`WalkYield`] in
/// `row`, learnt from its rays' walks step after step. Returns the rays left to trace
/// and the walks (`walks`, and `remembered` for those that found a blocker).
fn walk_from_remembered(
    own: &dyn ShadowQuery,
    rays: &[ShadowRay],
    row: Row<'_>,
    values: &mut [f64],
    Facets { first, .. }: Facets,
) -> (Vec<ShadowRay>, StepCounts) {
    let mut to_trace = Vec::with_capacity(rays.len());
    let mut walked = StepCounts::default();
    let group_of = |r: &ShadowRay| r.facet as usize / WALK_GROUP;
    for group in rays.chunk_by(|a, b| group_of(a) == group_of(b)) {
        let record = &row.walks[group_of(&group[0])];
        let mut walks = WalkYield::unpacked(record.load(Ordering::Relaxed));
        let mut here = StepCounts::default();
        for r in group {
            if walks.walks(r.facet) && blocked_as_remembered(own, r, row, &mut here) {
                values[r.facet as usize - first] = 0.0;
            } else {
                to_trace.push(*r);
            }
        }
        walks.learn(&here);
        record.store(walks.packed(), Ordering::Relaxed);
        walked += here;
    }
    (to_trace, walked)
}

/// Facets whose rays share one record of how walks pay ([`WalkYield`]): neighbours in
/// the mesh's order, which mostly lie near each other, see their shadows move alike.
/// Chunks of facets taken in parallel hold whole groups, so each record is one task's
/// and evolves step by step alike on any number of threads and in blocks of any size.
const WALK_GROUP: usize = 256;

/// Whether the rays of a group of facets walk from their remembered blockers
/// ([`blocked_as_remembered`]), judged by how often their recent walks found one.
///
/// A walk that finds a blocker spares the ray its trip through the tree; one that does
/// not costs its exact tests on top of that trip. How often walks find one falls as the
/// Sun moves farther between the steps they recall, and faster on finer meshes (the
/// shadow crosses more facets per degree). Measured with `bench_peer --tracer
/// bvh-sectors --threads 1` (2026-11-29, walks always against never, steps 1° to 10°
/// apart), walks paid on Itokawa 49k, 786k and the folded shape alike while more than
/// about 0.65 of the shadowed rays were found by one; below that they cost (at 786k with
/// 10° steps, where 0.13 were, 25 % of the step). So walks go on while at least
/// [`WalkYield::PAYING`] of those a group tried found a blocker, and otherwise the rays
/// of one facet in [`WalkYield::PROBE`] still walk, to notice when they pay again. Of
/// the shares tried for it (0.3, 0.45, 0.6; same benchmark, records per group), 0.45
/// stepped 2–5 % faster than 0.6 with steps 1° apart on all three meshes and within 3 %
/// of it with steps 10° apart.
#[derive(Debug, Clone, Copy)]
struct WalkYield {
    walking: bool,
    /// Walks on record, and how many of them found a blocker (each below
    /// `WINDOW + WALK_GROUP`).
    tried: u32,
    found: u32,
}

impl WalkYield {
    /// Before any walk: walking, nothing on record.
    const FIRST: WalkYield = WalkYield {
        walking: true,
        tried: 0,
        found: 0,
    };

    /// The least share of walks finding a blocker for walks to go on.
    const PAYING: f64 = 0.45;

    /// While walks do not pay, the rays of one facet in this many still walk.
    const PROBE: u32 = 32;

    /// Walks on record before they decide anything.
    const ENOUGH: u32 = 16;

    /// Walks on record beyond which the older ones count half, so that the record
    /// follows the Sun's pace.
    const WINDOW: u32 = 64;

    /// Whether the ray of `facet` walks.
    fn walks(&self, facet: u32) -> bool {
        self.walking || facet.is_multiple_of(Self::PROBE)
    }

    /// Adds the walks of `counts` (`walks`, and `remembered`, those that found a
    /// blocker) to the record and decides whether the next rays walk; with too few on
    /// record, as before.
    fn learn(&mut self, counts: &StepCounts) {
        self.tried += counts.walks as u32;
        self.found += counts.remembered as u32;
        if self.tried >= Self::ENOUGH {
            self.walking = f64::from(self.found) >= Self::PAYING * f64::from(self.tried);
        }
        while self.tried > Self::WINDOW {
            self.tried /= 2;
            self.found /= 2;
        }
    }

    /// The record in one word, as [`LastBlockers`] keeps it.
    fn packed(self) -> u64 {
        u64::from(self.walking) << 63 | u64::from(self.found) << 32 | u64::from(self.tried)
    }

    fn unpacked(word: u64) -> WalkYield {
        WalkYield {
            walking: word >> 63 != 0,
            found: (word >> 32) as u32 & (u32::MAX >> 1),
            tried: word as u32,
        }
    }
}

/// Keeps in `last` what the tracer found on `ray`: the facet that blocks it, or none
/// when it came out clear (no exact test wasted on that facet at the next recall).
fn remember(last: Row<'_>, ray: &ShadowRay, blocker: Blocker) {
    let memo = &last.facets[ray.facet as usize];
    let id = match blocker {
        Blocker::Facet(id) => id,
        Blocker::Clear => NO_BLOCKER,
        Blocker::Unnamed => return,
    };
    if memo.load(Ordering::Relaxed) != id {
        memo.store(id, Ordering::Relaxed);
    }
}

/// The sine of the elevation above a facet's plane of the lowest point of a disk of
/// angular `radius` whose centre stands at `sin_elevation` (`n·s`).
fn lowest_sin(sin_elevation: f64, radius: f64) -> f64 {
    let e = sin_elevation.clamp(-1.0, 1.0).asin();
    (e - radius).sin()
}

/// Lists in `day` the offsets of the facets in `values` whose cosine of the Sun stands
/// above `facing`, in order; the others' values become 0 (night). Without a branch per
/// facet: on a rough shape day and night alternate from facet to facet, and the
/// mispredicted branch took a tenth of a step of map lookups.
fn facets_facing(values: &mut [f64], facing: f64, day: &mut Vec<u32>) {
    day.clear();
    day.resize(values.len(), 0);
    let mut count = 0;
    for (k, e) in values.iter_mut().enumerate() {
        let lit = *e > facing;
        day[count] = k as u32;
        count += usize::from(lit);
        *e = if lit { *e } else { 0.0 };
    }
    day.truncate(count);
}

/// The body's Sun direction at this step, checked to be a finite unit vector.
fn checked_sun(body: &Body, state: &EpochState, b: usize) -> Result<DVec3> {
    let s = state.bodies[b].sun_dir;
    let flux = state.bodies[b].flux_w_m2;
    if !s.is_finite() || (s.length() - 1.0).abs() > 1e-9 || !flux.is_finite() || flux < 0.0 {
        return Err(Error::Geometry {
            body: body.name.clone(),
            step: state.step,
            msg: format!("invalid Sun direction {s} or flux {flux} W/m²"),
        });
    }
    Ok(s)
}

/// Per facet, the least height above its plane at which a hit counts as a shadow, as an
/// `f32` not below it.
fn min_blocker_heights(body: &Body) -> Vec<f32> {
    let rounding = 256.0 * f64::EPSILON * body.bounding_radius_m;
    (0..body.mesh.len())
        .map(|i| {
            let [a, b, c] = body.mesh.corners(i);
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            round_up(1e-9 * longest + rounding)
        })
        .collect()
}
