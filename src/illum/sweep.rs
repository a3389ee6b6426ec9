//! The direct stage facet by facet: each chunk of a body's facets takes every step of
//! the run, in the order of the Sun's path across the body's sky, before the next chunk.
//!
//! In: the run's steps, a body that shadows itself with the BVH tracer and its horizon
//! bound, or whose horizon map decides alone (a disk Sun, the approximate mode); a point
//! Sun or a disk. Out: per facet and step the irradiance (W/m²), handed to the
//! statistics chunk by chunk in time order ([`FacetRun`]), and the run's counts.
//!
//! A map that decides alone needs nothing of the path: each chunk reads its facets'
//! cells step after step in time order, and the statistics take each facet's steps
//! while its counts are in cache, where the step loop passes every facet's counts (370
//! MB at 786k facets) through memory once a block of steps.
//!
//! Why: a shadow ray the bound cannot spare costs a walk through the tree (about 0.5 µs
//! at 786k facets), and a year of hourly steps leaves about a billion of them. Taken in
//! the order of the Sun's path (the steps sorted by the Sun's direction in the body's
//! frame, [`path_order`]), consecutive steps see the Sun a small angle apart (0.04° for
//! a year of hourly Suns at one latitude, where time order puts them 30° apart). So:
//! - a facet whose ray was lit looks at a cone of directions around the Sun
//!   ([`HorizonBound::reaching`]): the facets reaching into it are all a ray within it can
//!   cross, so they decide every such ray alone by the tracer's exact predicate
//!   ([`BvhRays::blocked_among`]; none: lit). The facet keeps that list while the Sun
//!   stays within the cone, a dozen steps or more; a cone that more than [`LIST_MAX`]
//!   facets reach into is dropped and the rays traced;
//! - a facet whose ray was blocked looks for the blocker around the last one
//!   ([`ShadowQuery::blocker_near`]), as the step loop's rays recall theirs, then traces;
//! - the rest go through the tree in packets ([`ShadowQuery::blockers`]).
//!
//! A disk Sun asks each facet the bound leaves in doubt what its centroid sees of the
//! disk's cone ([`HorizonBound::cone_view`]: clear, covered, or the facets reaching in,
//! which then answer the disk's samples), as the step loop does, with the same memory:
//! - the cones are wider by the disk's radius, so that one serving a Sun holds its
//!   whole disk; the view is then taken from the cone's list alone
//!   ([`HorizonBound::cone_view_among`]), and it is the tree's;
//! - a facet whose disk one facet covered tries that facet first;
//! - a facet all of whose samples were blocked keeps each sample's blocker, and while
//!   every sample above its plane is blocked still (by that blocker seen as a
//!   [`Screen`], or one found by a walk from it) its share is 0, as the step loop's
//!   tally gives it;
//! - such a facet also looks for a patch of facets joined across their edges to a
//!   blocker that covers a whole cone around the Sun ([`HorizonBound::patch_cover`]):
//!   while the disk stays within it, its share is 0 without a sample.
//!
//! Every answer is the tracer's, bit for bit, and so are the statistics
//! ([`FacetRun::add_steps`] adds each facet's steps in time order).
//!
//! Memory: per chunk being computed, its values for every step (8 bytes per facet and
//! step, chunks sized to keep this to a few MB) and its certificates; for a disk Sun,
//! each step's samples with their rays (120 bytes a sample, 34 MB for a year of hourly
//! steps at 32 samples).

use super::{disk_point, ChunkScratch, Direct, Facets, OwnHorizon, Sky, StepCounts};
use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::horizon::bound::{Cone, ConeView, HorizonBound, Screen};
use crate::horizon::SunShape;
use crate::mesh::inspect::edge_neighbours;
use crate::mesh::Mesh;
use crate::progress::Progress;
use crate::stats::FacetRun;
use crate::trace::bvh::{Bvh, BvhRays};
use crate::trace::{Blocker, ShadowQuery, ShadowRay};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};

/// Half-angle of the cones (radians) as a multiple of the median angle between the
/// Suns of consecutive steps in the path's order, within [`CONE_MIN`] and [`CONE_MAX`].
const CONE_STEPS: f64 = 12.0;

/// The narrowest cone (radians): about the Sun's own radius at 1 AU.
const CONE_MIN: f64 = 0.0047;

/// The widest cone (radians, 1.2°): wider, a cone costs several rays and is seldom
/// clear (on the 786k Itokawa a cone of 1.2° around a lit ray was clear 88 % of the
/// time for 1.8 µs, one of 2.5° 76 % for 6.4 µs).
const CONE_MAX: f64 = 0.021;

/// Most bytes of values a chunk holds at once (its facets over every step).
const CHUNK_VALUE_BYTES: usize = 4 << 20;

/// Facets per chunk of a sweep over `steps` steps of `facets` facets: values of at
/// most 4 MiB, at least 16 facets, and at least 48 chunks per thread
/// where the mesh allows, as the step-by-step passes take them.
pub fn chunk_facets(steps: usize, facets: usize) -> usize {
    let by_memory = CHUNK_VALUE_BYTES / (8 * steps.max(1));
    let by_threads = facets.div_ceil(48 * rayon::current_num_threads());
    by_memory.min(by_threads).clamp(16, 2048)
}

/// Bytes a sweep from a horizon map alone holds over `steps` steps of `facets` facets:
/// each thread's chunk of values.
pub fn look_up_sweep_bytes(steps: usize, facets: usize) -> f64 {
    let chunk = chunk_facets(steps, facets) as f64 * steps as f64 * 8.0;
    rayon::current_num_threads() as f64 * chunk
}

/// Buffers of values lent to the sweep's tasks in turn: a chunk's values (4 MB) made
/// and zeroed anew for each of a run's thousands of chunks were 3 % of the samples of a
/// year's run at 786k facets (55 GB of zeroes). As many are made as tasks run at once.
#[derive(Default)]
struct Lender(Mutex<Vec<Vec<f64>>>);

impl Lender {
    /// Runs `task` on `len` values that hold whatever an earlier task left in them.
    fn lend<R>(&self, len: usize, task: impl FnOnce(&mut [f64]) -> R) -> R {
        let mut values = self.shelf().pop().unwrap_or_default();
        values.resize(len, 0.0);
        let result = task(&mut values);
        self.shelf().push(values);
        result
    }

    /// The buffers not lent (a task that panicked leaves them as they were).
    fn shelf(&self) -> std::sync::MutexGuard<'_, Vec<Vec<f64>>> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// The most facets a cone may list: past that, its rays are traced ([`Last::Lit`]).
const LIST_MAX: usize = 8;

/// Bytes a sweep over `steps` steps of `facets` facets holds: each thread's chunk of
/// values and facts (for a disk Sun at most a blocker per sample and 16 screens per
/// facet), the facets' neighbours across their edges (12 bytes each), and for a disk
/// Sun of `disk_samples` samples each step's samples with their rays.
pub fn sweep_bytes(steps: usize, facets: usize, disk_samples: Option<u32>) -> f64 {
    let samples = f64::from(disk_samples.unwrap_or(0));
    let fact = size_of::<Fact>() as f64
        + match disk_samples {
            Some(_) => 4.0 * samples + (SCREENS_MAX * size_of::<(u32, Option<Screen>)>()) as f64,
            None => 0.0,
        };
    let facts = rayon::current_num_threads() as f64 * chunk_facets(steps, facets) as f64 * fact;
    let sample_bytes = size_of::<(DVec3, BvhRays)>() as f64;
    let shared = 12.0 * facets as f64 + sample_bytes * samples * steps as f64;
    look_up_sweep_bytes(steps, facets) + facts + shared
}

/// What one facet knows of its shadow for Suns near the one it was taken for: the path
/// position of the Sun its cone is centred on, and the facets reaching into the cone
/// (none: every ray within it is lit), which answer any ray within it alone.
struct Certificate {
    axis: usize,
    among: Vec<u32>,
}

/// What a facet learnt of its shadow ray at the last step it needed one.
#[derive(Clone, Copy, Default)]
enum Last {
    #[default]
    Unknown,
    /// Lit; a cone is taken from this path position on (a cone that listed too many
    /// facets waits until the Sun has moved on by its width).
    Lit(usize),
    Blocker(u32),
    /// Every sample of a disk Sun above the facet's plane was blocked, each by the facet
    /// kept for it in [`Fact::dark`].
    Dark,
}

/// How [`Direct::decide`] answers a facet's ray.
enum Answer {
    Lit,
    Shadowed,
    /// Through the tree, with the step's other rays.
    Trace,
}

/// What a chunk keeps of one facet between steps.
#[derive(Default)]
struct Fact {
    certificate: Option<Certificate>,
    last: Last,
    /// Under a disk Sun, per sample of the disk, the facet that blocked it at the last
    /// tally (`u32::MAX` for a sample clear or below the facet's plane); read only while
    /// [`Last::Dark`], when every sample above the plane had one. A wrong entry costs
    /// time, not bits: [`Direct::still_dark`] tests every sample again.
    dark: Vec<u32>,
    /// The blockers of [`Fact::dark`] as screens seen from the facet, set up once for
    /// the many steps and samples they serve (at most [`SCREENS_MAX`]).
    screens: Vec<(u32, Option<Screen>)>,
    /// Under a disk Sun, facets joined across their edges that cover a cone around it.
    cover: Option<Cover>,
    /// The path position from which a cover is looked for again after one was not found.
    cover_from: usize,
}

/// A patch of facets covering, seen from a facet, a cone centred on the Sun at path
/// position `axis` ([`HorizonBound::patch_cover`]), as wide as a certificate's: every
/// ray within it is blocked by a facet farther than `beyond` metres.
struct Cover {
    axis: usize,
    beyond: f64,
}

/// The most facets a patch covering a cone may hold ([`Fact::cover`]): on the 786k
/// Itokawa, a cone of 0.7° was covered by about 17 facets on average.
const PATCH_MAX: usize = 128;

/// The most blockers a facet keeps as screens ([`Fact::screens`]).
const SCREENS_MAX: usize = 16;

/// The run's Suns in the order of their path, with what every chunk shares.
struct Path<'a> {
    /// Step index at each position.
    steps: Vec<usize>,
    /// Per position, the Sun (body frame) and its shadow queries.
    suns: Vec<DVec3>,
    queries: Vec<BvhRays<'a>>,
    /// For a disk Sun, per position its cone and its samples (directions with their
    /// rays; [`Direct::disk_samples`]'s count per position, as the step loop takes them).
    disks: Vec<Cone>,
    samples: Vec<(DVec3, BvhRays<'a>)>,
    /// Per facet of the tree, its neighbour across each edge (the walks from a last
    /// blocker, [`ShadowQuery::blocker_near`]).
    neighbours: Vec<[u32; 3]>,
    /// Per position, the farthest position ahead whose Sun stands within the cone's
    /// reach of this one's, where a cone made here is centred.
    ahead: Vec<usize>,
    /// The cosine of how far a Sun may stand from a cone's axis for the cone to serve
    /// it; no cones where the Suns stand too far apart for one to serve many steps.
    cos_inside: f64,
    cones: bool,
    /// The cones' half-angle: how far a Sun may stand from a cone's axis (12 times the
    /// Suns' median spacing, within [`CONE_MIN`] and [`CONE_MAX`]) and the widest disk of
    /// the run (0 for a point Sun), so that a cone serving a Sun holds its whole disk.
    listed: f64,
}

/// What a chunk of facets shares with the sweep: the run's skies and path, the body's
/// tree, bound and mesh.
struct Chunk<'a> {
    facets: Facets,
    skies: &'a [Sky],
    path: &'a Path<'a>,
    bound: &'a HorizonBound,
    bvh: &'a Bvh<'a>,
    mesh: &'a Mesh,
}

impl Direct<'_> {
    /// Whether body `b` can be computed facet by facet ([`Direct::sweep`]): it traces
    /// its own shadows through the BVH and its bound, or its horizon map decides alone.
    pub fn sweeps(&self, b: usize) -> bool {
        match &self.horizons[b] {
            OwnHorizon::Bound { .. } => self.traces_own(b),
            OwnHorizon::Map { .. } => self.map_decides_alone(b),
            OwnHorizon::None => false,
        }
    }

    /// The direct irradiance of body `b` (its facets only) over `states`, facet by
    /// facet, added to `runs` (the body's statistics in runs of consecutive facets,
    /// [`crate::stats::FacetStats::facet_runs`]); the counts of every step.
    pub fn sweep(
        &self,
        b: usize,
        states: &[EpochState],
        runs: Vec<FacetRun<'_>>,
        progress: &dyn Progress,
    ) -> Result<StepCounts> {
        let skies = (states.iter())
            .map(|state| self.sky(b, state))
            .collect::<Result<Vec<_>>>()?;
        match &self.horizons[b] {
            OwnHorizon::Bound { bound, bvh } => {
                let mesh = self.world.bodies[b].shadow_mesh();
                let path = Path::new(&skies, bvh, mesh, &self.disk_samples);
                let chunk = |facets| Chunk {
                    facets,
                    skies: &skies,
                    path: &path,
                    bound,
                    bvh,
                    mesh,
                };
                self.sweep_runs((b, skies.len()), runs, progress, |facets, run, values| {
                    let counts = self.sweep_chunk(&chunk(facets), values);
                    run.add_steps(values);
                    counts
                })
            }
            OwnHorizon::Map { .. } if self.map_decides_alone(b) => {
                self.sweep_runs((b, skies.len()), runs, progress, |facets, run, values| {
                    self.look_up_chunk(facets, &skies, run, values)
                })
            }
            _ => unreachable!("sweeps() is checked first"),
        }
    }

    /// Runs `chunk` on each run of body `b`'s facets (in parallel, one run a task), which
    /// computes the run's facets over every one of `steps` into the values it is lent
    /// (one per facet and step, every one of them written before it is read) and adds
    /// them to its statistics.
    fn sweep_runs(
        &self,
        (b, steps): (usize, usize),
        runs: Vec<FacetRun<'_>>,
        progress: &dyn Progress,
        chunk: impl Fn(Facets, &mut FacetRun<'_>, &mut [f64]) -> StepCounts + Sync,
    ) -> Result<StepCounts> {
        let size = runs.first().map_or(1, FacetRun::len);
        let done = AtomicUsize::new(0);
        let chunks = runs.len();
        let lender = Lender::default();
        let counts = (runs.into_par_iter().with_max_len(1).enumerate())
            .map(|(c, mut run)| {
                if progress.cancelled() {
                    return Err(Error::Cancelled);
                }
                let facets = Facets {
                    body: b,
                    first: c * size,
                };
                let counts =
                    lender.lend(steps * run.len(), |values| chunk(facets, &mut run, values));
                // Steps done, in proportion to the chunks done.
                let before = done.fetch_add(1, Ordering::Relaxed);
                let steps = |k: usize| k * steps / chunks;
                (steps(before)..steps(before + 1)).for_each(|_| progress.step_done());
                Ok(counts)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(counts.into_iter().fold(StepCounts::default(), |mut a, c| {
            a += c;
            a
        }))
    }

    /// One run of facets over every step in time order, from the body's horizon map
    /// alone (no ray), added to `run`. Each step is computed into a row of the run's
    /// facets and written facet by facet, so that the statistics read each facet's
    /// steps in a line: read a step apart, they missed the cache on every value.
    fn look_up_chunk(
        &self,
        facets: Facets,
        skies: &[Sky],
        run: &mut FacetRun<'_>,
        series: &mut [f64],
    ) -> StepCounts {
        let (len, steps) = (run.len(), skies.len());
        let mut row = vec![0.0; len];
        let mut scratch = ChunkScratch::default();
        let mut counts = StepCounts::default();
        for (k, sky) in skies.iter().enumerate() {
            let (lit, rays) = self.light_chunk(facets, sky, &mut row, &mut scratch);
            debug_assert!(rays.is_empty(), "a map that decides alone asks for no ray");
            counts += lit;
            for (j, &e) in row.iter().enumerate() {
                series[j * steps + k] = e;
            }
        }
        run.add_series(series);
        counts
    }

    /// One chunk of facets over every step, in the path's order; `values` takes them
    /// step by step in time order.
    fn sweep_chunk(&self, chunk: &Chunk<'_>, values: &mut [f64]) -> StepCounts {
        let skies = chunk.skies;
        let len = values.len() / skies.len().max(1);
        let mut facts: Vec<Fact> = (0..len).map(|_| Fact::default()).collect();
        let mut scratch = ChunkScratch::default();
        let mut counts = StepCounts::default();
        for (p, &k) in chunk.path.steps.iter().enumerate() {
            let out = &mut values[k * len..(k + 1) * len];
            let (lit, rays) = self.light_chunk(chunk.facets, &skies[k], out, &mut scratch);
            counts += lit;
            counts += match self.sun {
                SunShape::Point => self.shade_point(chunk, p, &rays, &mut facts, out),
                SunShape::Disk => self.shade_disk_by_facts(chunk, p, &rays, &mut facts, out),
            };
        }
        counts
    }

    /// Darkens the facets of a chunk whose `rays` toward a point Sun at path position
    /// `p` are blocked: those their facts decide ([`Direct::decide`]), then the rest
    /// through the tree together, whose answers become the facts of the next step.
    fn shade_point(
        &self,
        chunk: &Chunk<'_>,
        p: usize,
        rays: &[ShadowRay],
        facts: &mut [Fact],
        out: &mut [f64],
    ) -> StepCounts {
        let mut counts = StepCounts {
            rays: rays.len() as u64,
            ..StepCounts::default()
        };
        let mut traced = Vec::new();
        for ray in rays {
            let j = ray.facet as usize - chunk.facets.first;
            match self.decide(chunk, &mut facts[j], ray, p, &mut counts) {
                Answer::Lit => {}
                Answer::Shadowed => {
                    counts.shadowed += 1;
                    out[j] = 0.0;
                }
                Answer::Trace => traced.push(*ray),
            }
        }
        for (ray, blocker) in traced.iter().zip(chunk.path.queries[p].blockers(&traced)) {
            let j = ray.facet as usize - chunk.facets.first;
            let fact = &mut facts[j];
            fact.last = match (blocker, fact.last) {
                (Blocker::Clear, Last::Lit(from)) => Last::Lit(from),
                (Blocker::Clear, _) => Last::Lit(p),
                (Blocker::Facet(id), _) => Last::Blocker(id),
                (Blocker::Unnamed, _) => Last::Unknown,
            };
            if blocker != Blocker::Clear {
                counts.shadowed += 1;
                out[j] = 0.0;
            }
        }
        counts
    }

    /// What facet `fact` learnt last decides `ray` at path position `p` where it can: a
    /// cone that still holds the Sun decides by its list; a facet lit last time gets a
    /// cone, which most often stays clear for the steps to come; a blocker is looked for
    /// around the last one. The rest are traced.
    fn decide(
        &self,
        chunk: &Chunk<'_>,
        fact: &mut Fact,
        ray: &ShadowRay,
        p: usize,
        counts: &mut StepCounts,
    ) -> Answer {
        let path = chunk.path;
        if !fact.holds(path, p) {
            match fact.last {
                Last::Lit(from) if from <= p && path.cones => {
                    if !self.certify(chunk, fact, ray, p, counts) {
                        return Answer::Trace;
                    }
                }
                Last::Blocker(id) => {
                    let query = &path.queries[p];
                    let near =
                        query.blocker_near(ray.origin, ray.t_min, ray.facet, id, &path.neighbours);
                    let Some(id) = near else {
                        return Answer::Trace;
                    };
                    fact.last = Last::Blocker(id);
                    counts.remembered += 1;
                    return Answer::Shadowed;
                }
                Last::Lit(_) | Last::Unknown | Last::Dark => return Answer::Trace,
            }
        }
        let among = &fact.certificate.as_ref().expect("held or made above").among;
        match !among.is_empty()
            && path.queries[p].blocked_among(ray.origin, ray.t_min, ray.facet, among)
        {
            true => Answer::Shadowed,
            false => Answer::Lit,
        }
    }

    /// Scales the facets of a chunk whose `rays` need their own body's share of a disk
    /// Sun at path position `p` by that share ([`Direct::disk_view`]), as the step loop
    /// does ([`Direct::shade_disk`]).
    fn shade_disk_by_facts(
        &self,
        chunk: &Chunk<'_>,
        p: usize,
        rays: &[ShadowRay],
        facts: &mut [Fact],
        out: &mut [f64],
    ) -> StepCounts {
        let samples = || self.disk_samples_at(chunk, p);
        let mut counts = StepCounts::default();
        for ray in rays {
            let j = ray.facet as usize - chunk.facets.first;
            let fact = &mut facts[j];
            let remembered = (self.still_covered(chunk, fact, ray, p))
                .or_else(|| self.still_dark(chunk, fact, ray, p));
            let (share, answered) = match remembered {
                Some(answered) => {
                    counts.remembered += 1;
                    (0.0, answered)
                }
                None => {
                    let view = self.disk_view(chunk, fact, ray, p, &mut counts);
                    match &view {
                        ConeView::Partial(among) => {
                            self.tally_and_learn(chunk, fact, ray, p, among)
                        }
                        _ => self.share_in_view(chunk.facets.body, ray, &view, samples()),
                    }
                }
            };
            if fact.cover.is_none() {
                self.find_cover(chunk, fact, ray, p);
            }
            counts.rays += answered;
            out[j] *= share;
            counts.shadowed += (out[j] == 0.0) as u64;
        }
        counts
    }

    /// The samples of the disk Sun at path position `p` (directions, with their rays),
    /// as the step loop takes them.
    fn disk_samples_at<'c>(
        &self,
        chunk: &Chunk<'c>,
        p: usize,
    ) -> impl Iterator<Item = (DVec3, BvhRays<'c>)> + 'c {
        let n = self.disk_samples.len();
        chunk.path.samples[p * n..(p + 1) * n].iter().copied()
    }

    /// The share of the disk Sun at path position `p` that the facets `among` (reaching
    /// into its cone) leave in view of facet `ray.facet`, and the samples answered, as
    /// the step loop's tally gives them; where every sample above the facet's plane is
    /// blocked, each sample's blocker is kept ([`Last::Dark`]) for the steps after.
    fn tally_and_learn(
        &self,
        chunk: &Chunk<'_>,
        fact: &mut Fact,
        ray: &ShadowRay,
        p: usize,
        among: &[u32],
    ) -> (f64, u64) {
        // `fact.dark` serves only a facet kept dark, which this one is not (its samples
        // were not all answered as blocked): its room takes this tally's blockers, one
        // per sample, whether or not they are kept.
        let mut blockers = std::mem::take(&mut fact.dark);
        blockers.clear();
        let samples = self.disk_samples_at(chunk, p);
        let (share, answered) = self.share_among(chunk.facets.body, ray, among, samples, |id| {
            blockers.push(id)
        });
        // A share of 0 says every sample above the plane was blocked (and one was there).
        if share == 0.0 {
            fact.last = Last::Dark;
        }
        fact.dark = blockers;
        (share, answered)
    }

    /// For a facet with a cover ([`Fact::cover`]): whether it holds the disk Sun at path
    /// position `p`, wholly above the facet's plane and its samples' rays reaching past
    /// the cover's distance; then every sample is blocked, the share is 0, as the step
    /// loop's tally gives it, and the samples (all answered) are returned. A cover that
    /// no longer holds is dropped.
    fn still_covered(
        &self,
        chunk: &Chunk<'_>,
        fact: &mut Fact,
        ray: &ShadowRay,
        p: usize,
    ) -> Option<u64> {
        let cover = fact.cover.as_ref()?;
        let path = chunk.path;
        let sky = &chunk.skies[path.steps[p]];
        let beyond = self.disk_beyond(chunk.facets.body, ray.facet as usize, (sky.sun, sky.radius));
        let held =
            path.suns[cover.axis].dot(path.suns[p]) >= path.cos_inside && beyond < cover.beyond;
        if !held {
            fact.cover = None;
            return None;
        }
        Some(self.disk_samples.len() as u64)
    }

    /// Looks for a cover ([`Fact::cover`]) of a cone centred a little ahead of path
    /// position `p` for a facet whose samples were all blocked there ([`Last::Dark`]:
    /// kept dark, or found so by the tally; nothing for any other facet),
    /// by the facets joined to a blocker of theirs; where none is found, not again
    /// until the Sun has moved on by the cone's width.
    fn find_cover(&self, chunk: &Chunk<'_>, fact: &mut Fact, ray: &ShadowRay, p: usize) {
        let path = chunk.path;
        if !path.cones || p < fact.cover_from || !matches!(fact.last, Last::Dark) {
            return;
        }
        let Some(&seed) = fact.dark.iter().find(|&&id| id != u32::MAX) else {
            return;
        };
        let axis = path.ahead[p];
        let cone = Cone::new(path.suns[axis], path.listed);
        let i = ray.facet as usize;
        let found =
            (chunk.bound).patch_cover(chunk.mesh, &path.neighbours, (i, &cone), seed, PATCH_MAX);
        fact.cover = found.map(|beyond| Cover { axis, beyond });
        if fact.cover.is_none() {
            fact.cover_from = path.ahead[path.ahead[p]];
        }
    }

    /// For a facet all of whose disk samples were blocked last time ([`Last::Dark`]):
    /// whether every sample above its plane at path position `p` is blocked still, each
    /// found by a walk from its last blocker ([`ShadowQuery::blocker_near`]); then its
    /// share is 0, as the step loop's tally gives it, and the samples answered are
    /// returned. `None` when a walk fails or no sample stands above the plane (a disk
    /// that only grazes the plane is taken as whole by the tally).
    fn still_dark(
        &self,
        chunk: &Chunk<'_>,
        fact: &mut Fact,
        ray: &ShadowRay,
        p: usize,
    ) -> Option<u64> {
        if !matches!(fact.last, Last::Dark) {
            return None;
        }
        let (b, i) = (chunk.facets.body, ray.facet as usize);
        let n = self.world.bodies[b].mesh.normals[i];
        let neighbours = &chunk.path.neighbours;
        let screens = &mut fact.screens;
        let mut answered = 0;
        for ((s, query), last) in self.disk_samples_at(chunk, p).zip(&mut fact.dark) {
            let cos = n.dot(s);
            if cos <= 0.0 {
                continue;
            }
            let t_min = self.t_min(b, i, cos);
            let screen = match screens.iter().find(|(id, _)| id == last) {
                Some(&(_, screen)) => screen,
                None if *last == u32::MAX => None,
                None => {
                    if screens.len() == SCREENS_MAX {
                        screens.clear();
                    }
                    let screen = chunk.bound.screen(chunk.mesh, i, *last);
                    screens.push((*last, screen));
                    screen
                }
            };
            let start = match *last {
                _ if screen.is_some_and(|screen| screen.blocks(s, t_min)) => Some(*last),
                u32::MAX => None,
                id => query.blocker_near(ray.origin, t_min, ray.facet, id, neighbours),
            };
            let Some(id) = start else {
                fact.last = Last::Unknown;
                return None;
            };
            *last = id;
            answered += 1;
        }
        if answered == 0 {
            fact.last = Last::Unknown;
        }
        (answered > 0).then_some(answered)
    }

    /// What facet `fact`'s centroid sees of the cone of the disk Sun at path position
    /// `p` (the view the step loop takes through the tree, [`HorizonBound::cone_view`]),
    /// from what it learnt before where it can: a cone that still holds the disk, or
    /// the facet that covered it last; else through the tree.
    fn disk_view(
        &self,
        chunk: &Chunk<'_>,
        fact: &mut Fact,
        ray: &ShadowRay,
        p: usize,
        counts: &mut StepCounts,
    ) -> ConeView {
        let (path, i) = (chunk.path, ray.facet as usize);
        let sky = &chunk.skies[path.steps[p]];
        let cone = &path.disks[p];
        let at = || {
            (
                i,
                cone,
                self.disk_beyond(chunk.facets.body, i, (sky.sun, sky.radius)),
            )
        };
        if !fact.holds(path, p) {
            match fact.last {
                Last::Lit(from) if from <= p && path.cones => {
                    self.certify(chunk, fact, ray, p, counts);
                }
                Last::Blocker(id) => {
                    let view = chunk.bound.cone_view_among(chunk.mesh, at(), &[id]);
                    if matches!(view, ConeView::Covered(_)) {
                        counts.remembered += 1;
                        return view;
                    }
                }
                Last::Lit(_) | Last::Unknown | Last::Dark => {}
            }
        }
        let view = match &fact.certificate {
            // Most often: nothing reaches in, and the disk's depth is not needed.
            Some(certificate) if certificate.among.is_empty() => ConeView::Clear,
            Some(certificate) => {
                (chunk.bound).cone_view_among(chunk.mesh, at(), &certificate.among)
            }
            None => (chunk.bound).cone_view(chunk.mesh, chunk.bvh, i, cone, at().2),
        };
        fact.last = match (&view, fact.last) {
            (ConeView::Covered(Some(id)), _) => Last::Blocker(*id),
            (ConeView::Covered(None), _) => Last::Unknown,
            (_, Last::Lit(from)) => Last::Lit(from),
            _ => Last::Lit(p),
        };
        view
    }

    /// Gives `fact` the facets reaching into the cone centred on the Sun a little ahead
    /// on the path of position `p`'s, which holds that Sun (and its disk), seen from
    /// facet `ray.facet`; false when more than [`LIST_MAX`] do: the facet then waits
    /// until the Sun has moved on by the cone's width.
    fn certify(
        &self,
        chunk: &Chunk<'_>,
        fact: &mut Fact,
        ray: &ShadowRay,
        p: usize,
        counts: &mut StepCounts,
    ) -> bool {
        counts.cones += 1;
        let path = chunk.path;
        let axis = path.ahead[p];
        let cone = Cone::new(path.suns[axis], path.listed);
        let i = ray.facet as usize;
        let among = (chunk.bound).reaching(chunk.mesh, chunk.bvh, i, &cone, LIST_MAX);
        fact.certificate = among.map(|among| Certificate { axis, among });
        if fact.certificate.is_none() {
            fact.last = Last::Lit(path.ahead[path.ahead[p]]);
        }
        fact.certificate.is_some()
    }
}

impl Fact {
    /// Whether the facet's cone still holds the Sun at path position `p`; drops it if not.
    fn holds(&mut self, path: &Path<'_>, p: usize) -> bool {
        let held = |c: &Certificate| path.suns[c.axis].dot(path.suns[p]) >= path.cos_inside;
        if !self.certificate.as_ref().is_some_and(held) {
            self.certificate = None;
        }
        self.certificate.is_some()
    }
}

impl<'a> Path<'a> {
    /// The Suns of `skies` in the order of their path, with their queries through `bvh`
    /// and for a disk Sun its cones and its samples at `offsets` ([`disk_point`]).
    fn new(skies: &[Sky], bvh: &'a Bvh<'a>, mesh: &Mesh, offsets: &[(f64, f64)]) -> Path<'a> {
        let steps = path_order(&skies.iter().map(|s| s.sun).collect::<Vec<_>>());
        let suns: Vec<DVec3> = steps.iter().map(|&k| skies[k].sun).collect();
        let queries = suns.iter().map(|&s| BvhRays::new(bvh, s)).collect();
        let disks = match offsets.is_empty() {
            true => Vec::new(),
            false => (steps.iter())
                .map(|&k| Cone::new(skies[k].sun, skies[k].radius))
                .collect(),
        };
        let samples = (steps.iter())
            .flat_map(|&k| offsets.iter().map(move |&offset| (&skies[k], offset)))
            .map(|(sky, offset)| {
                let s = disk_point(sky.sun, sky.radius, offset);
                (s, BvhRays::new(bvh, s))
            })
            .collect();
        let turn = median_turn(&suns);
        let cone = (CONE_STEPS * turn).clamp(CONE_MIN, CONE_MAX);
        // A Sun counts as inside a little within the cone: its test is widened by far
        // more than this (`Bvh::near_cone`).
        let cos_inside = (cone * (1.0 - 1e-3)).cos();
        let ahead = cone_centres(&suns, cone);
        let widest = skies.iter().map(|s| s.radius).fold(0.0, f64::max);
        Path {
            steps,
            suns,
            queries,
            disks,
            samples,
            neighbours: edge_neighbours(mesh),
            ahead,
            cos_inside,
            cones: cone_pays(turn),
            listed: cone + widest,
        }
    }
}

/// Per position of the path `suns`, the farthest position ahead whose Sun stands within
/// 0.9 of the half-angle `cone` of this one's, where a cone made here is centred: it
/// then holds this Sun and the Suns up to about twice as far on.
fn cone_centres(suns: &[DVec3], cone: f64) -> Vec<usize> {
    let reach = (0.9 * cone).cos();
    let mut ahead = Vec::with_capacity(suns.len());
    let mut q = 0;
    for p in 0..suns.len() {
        q = q.max(p);
        while q + 1 < suns.len() && suns[p].dot(suns[q + 1]) >= reach {
            q += 1;
        }
        // The cone decides this Sun's ray at once, so it must hold it: where the path
        // turned back (a band's end), the farthest found for the position before may
        // stand beyond this one's reach.
        ahead.push(match suns[p].dot(suns[q]) >= reach {
            true => q,
            false => p,
        });
    }
    ahead
}

/// Whether cones pay where consecutive Suns on the path stand `turn` radians apart
/// (median): where the widest cone spans six of them or more. Measured on the 786k
/// Itokawa (true hours of its spin, one latitude): 0.16° apart, cones took the run
/// from 39 s to 26 s; 0.41° apart (the widest cone spanning six), 18.3–19.6 s against
/// 19.8–20.0 s.
fn cone_pays(turn: f64) -> bool {
    3.0 * turn <= CONE_MAX
}

/// The median angle (radians) between consecutive Suns.
fn median_turn(suns: &[DVec3]) -> f64 {
    let mut turns: Vec<f64> = (suns.windows(2))
        .map(|w| w[0].angle_between(w[1]))
        .collect();
    if turns.is_empty() {
        return 0.0;
    }
    let mid = turns.len() / 2;
    *turns.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The step indices of `suns` (unit vectors) in the order of their path: bands of
/// latitude, each swept in longitude, the next band back the other way, so that
/// consecutive Suns stand close. A run whose Sun keeps one latitude (a spin, a season's
/// days at a pole) is one band, sorted by longitude.
fn path_order(suns: &[DVec3]) -> Vec<usize> {
    let lat = |s: &DVec3| s.z.clamp(-1.0, 1.0).asin();
    let lon = |s: &DVec3| s.y.atan2(s.x);
    let (lo, hi) = (suns.iter().map(lat)).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), l| {
        (a.min(l), b.max(l))
    });
    // Bands about as tall as the Suns are apart in a band, when they fill the band.
    let spread = (hi - lo).max(0.0);
    let band = (spread * std::f64::consts::TAU / suns.len().max(1) as f64)
        .sqrt()
        .max(1e-6);
    let mut keyed: Vec<(i64, f64, usize)> = (suns.iter().enumerate())
        .map(|(k, s)| {
            let row = ((lat(s) - lo) / band) as i64;
            let along = match row % 2 {
                0 => lon(s),
                _ => -lon(s),
            };
            (row, along, k)
        })
        .collect();
    keyed.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    keyed.into_iter().map(|(_, _, k)| k).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestRng;

    fn sun(lat_deg: f64, lon_deg: f64) -> DVec3 {
        let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
        DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin())
    }

    /// Suns of one latitude, given 30° apart in time, come out in order of longitude,
    /// each a 360th of the turn from the next (but at the seam).
    #[test]
    fn suns_of_one_latitude_follow_their_longitude() {
        let suns: Vec<DVec3> = (0..360)
            .map(|k| sun(15.0, (k * 30 + k / 12) as f64))
            .collect();
        let order = path_order(&suns);
        let mut path: Vec<DVec3> = order.iter().map(|&k| suns[k]).collect();
        let turns: Vec<f64> = path.windows(2).map(|w| w[0].angle_between(w[1])).collect();
        let step = 15f64.to_radians().cos() * 1f64.to_radians();
        assert!(
            turns.iter().all(|&t| (t - step).abs() < 1e-6 * step),
            "{turns:?}"
        );
        path.dedup();
        assert_eq!(path.len(), 360);
    }

    /// Over Suns scattered across a band of latitude (several bands of the path, turns
    /// at their ends), every position's cone centre holds its own Sun within the reach,
    /// lies ahead of it, and the path visits every step once.
    #[test]
    fn every_cone_holds_the_sun_it_is_made_for() {
        let mut rng = TestRng::new(7);
        let suns: Vec<DVec3> = (0..3000)
            .map(|_| sun(-20.0 + 40.0 * rng.unit(), 360.0 * rng.unit()))
            .collect();
        let mut order = path_order(&suns);
        let path: Vec<DVec3> = order.iter().map(|&k| suns[k]).collect();
        for cone in [0.005, 0.02, 0.2] {
            let ahead = cone_centres(&path, cone);
            let reach = (0.9 * cone).cos();
            for (p, &a) in ahead.iter().enumerate() {
                assert!(
                    a >= p && path[p].dot(path[a]) >= reach,
                    "{cone}: {p} -> {a}"
                );
            }
            // The widest cone holds many Suns (they stand about 2° apart here).
            let far = ahead.iter().enumerate().filter(|(p, &a)| a > p + 2).count();
            assert!(cone < 0.1 || far > 1000, "{cone}: {far}");
        }
        order.sort_unstable();
        assert!(order.iter().enumerate().all(|(k, &o)| k == o));
    }
}
