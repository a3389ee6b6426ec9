//! The direct stage facet by facet: each chunk of a body's facets takes every step of
//! the run, in the order of the Sun's path across the body's sky, before the next chunk.
//!
//! In: the run's steps, a body that shadows itself with the BVH tracer and its horizon
//! bound, a point Sun. Out: per facet and step the irradiance (W/m²), handed to the
//! statistics chunk by chunk in time order ([`FacetRun`]), and the run's counts.
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
//! Every answer is the tracer's, bit for bit, and so are the statistics
//! ([`FacetRun::add_steps`] adds each facet's steps in time order).
//!
//! Memory: per chunk being computed, its values for every step (8 bytes per facet and
//! step, chunks sized to keep this to a few MB) and its certificates.

use super::{Direct, Facets, OwnHorizon, Sky, StepCounts};
use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::horizon::bound::{Cone, HorizonBound};
use crate::mesh::inspect::edge_neighbours;
use crate::progress::Progress;
use crate::stats::FacetRun;
use crate::trace::bvh::{Bvh, BvhRays};
use crate::trace::{Blocker, ShadowQuery, ShadowRay};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

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

/// The most facets a cone may list: past that, its rays are traced ([`Last::Lit`]).
const LIST_MAX: usize = 8;

/// Bytes a sweep over `steps` steps of `facets` facets holds: each thread's chunk of
/// values, and the facets' neighbours across their edges (12 bytes each).
pub fn sweep_bytes(steps: usize, facets: usize) -> f64 {
    let chunk = chunk_facets(steps, facets) as f64 * steps as f64 * 8.0;
    rayon::current_num_threads() as f64 * chunk + 12.0 * facets as f64
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
}

/// The run's Suns in the order of their path, with what every chunk shares.
struct Path<'a> {
    /// Step index at each position.
    steps: Vec<usize>,
    /// Per position, the Sun (body frame) and its shadow queries.
    suns: Vec<DVec3>,
    queries: Vec<BvhRays<'a>>,
    /// Per facet of the tree, its neighbour across each edge (the walks from a last
    /// blocker, [`ShadowQuery::blocker_near`]).
    neighbours: Vec<[u32; 3]>,
    /// Per position, the farthest position ahead whose Sun stands within the cone's
    /// reach of this one's, where a cone made here is centred.
    ahead: Vec<usize>,
    /// The cones' half-angle, and the cosine within which a Sun is taken as inside;
    /// no cones where the Suns stand too far apart for one to serve many steps.
    cone: f64,
    cos_inside: f64,
    cones: bool,
}

impl Direct<'_> {
    /// Whether body `b` can be computed facet by facet ([`Direct::sweep`]).
    pub fn sweeps(&self, b: usize) -> bool {
        self.sun == crate::horizon::SunShape::Point
            && self.traces_own(b)
            && matches!(self.horizons[b], OwnHorizon::Bound { .. })
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
        let OwnHorizon::Bound { bound, bvh } = &self.horizons[b] else {
            unreachable!("sweeps() is checked first");
        };
        let skies = (states.iter())
            .map(|state| self.sky(b, state))
            .collect::<Result<Vec<_>>>()?;
        let path = Path::new(&skies, bvh, self.world.bodies[b].shadow_mesh());
        let size = runs.first().map_or(1, FacetRun::len);
        let done = AtomicUsize::new(0);
        let chunks = runs.len();
        let counts = (runs.into_par_iter().with_max_len(1).enumerate())
            .map(|(c, mut run)| {
                if progress.cancelled() {
                    return Err(Error::Cancelled);
                }
                let facets = Facets {
                    body: b,
                    first: c * size,
                };
                let mut values = vec![0.0; skies.len() * run.len()];
                let counts = self.sweep_chunk(facets, (&skies, &path), (bound, bvh), &mut values);
                run.add_steps(&values);
                // Steps done, in proportion to the chunks done.
                let before = done.fetch_add(1, Ordering::Relaxed);
                let steps = |k: usize| k * states.len() / chunks;
                (steps(before)..steps(before + 1)).for_each(|_| progress.step_done());
                Ok(counts)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(counts.into_iter().fold(StepCounts::default(), |mut a, c| {
            a += c;
            a
        }))
    }

    /// One chunk of facets over every step, in the path's order; `values` takes them
    /// step by step in time order.
    fn sweep_chunk(
        &self,
        facets: Facets,
        (skies, path): (&[Sky], &Path<'_>),
        (bound, bvh): (&HorizonBound, &Bvh),
        values: &mut [f64],
    ) -> StepCounts {
        let len = values.len() / skies.len().max(1);
        let mesh = self.world.bodies[facets.body].shadow_mesh();
        let mut facts: Vec<Fact> = (0..len).map(|_| Fact::default()).collect();
        let mut counts = StepCounts::default();
        let mut traced = Vec::new();
        for (p, &k) in path.steps.iter().enumerate() {
            let out = &mut values[k * len..(k + 1) * len];
            let (lit, rays) = self.light_chunk(facets, &skies[k], out);
            counts += lit;
            counts.rays += rays.len() as u64;
            let query = &path.queries[p];
            traced.clear();
            for ray in &rays {
                let j = ray.facet as usize - facets.first;
                match self.decide(&mut facts[j], ray, path, p, (bound, bvh, mesh), &mut counts) {
                    Answer::Lit => {}
                    Answer::Shadowed => {
                        counts.shadowed += 1;
                        out[j] = 0.0;
                    }
                    Answer::Trace => traced.push(*ray),
                }
            }
            for (ray, blocker) in traced.iter().zip(query.blockers(&traced)) {
                let j = ray.facet as usize - facets.first;
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
        }
        counts
    }

    /// What facet `fact` learnt last decides `ray` at path position `p` where it can: a
    /// cone that still holds the Sun decides by its list; a facet lit last time gets a
    /// cone, which most often stays clear for the steps to come; a blocker is looked for
    /// around the last one. The rest are traced.
    fn decide(
        &self,
        fact: &mut Fact,
        ray: &ShadowRay,
        path: &Path<'_>,
        p: usize,
        tree: (&HorizonBound, &Bvh, &crate::mesh::Mesh),
        counts: &mut StepCounts,
    ) -> Answer {
        let held = |c: &Certificate| path.suns[c.axis].dot(path.suns[p]) >= path.cos_inside;
        if !fact.certificate.as_ref().is_some_and(held) {
            fact.certificate = None;
            match fact.last {
                Last::Lit(from) if from <= p && path.cones => {
                    counts.cones += 1;
                    fact.certificate = self.certify(ray, path, p, tree);
                    if fact.certificate.is_none() {
                        // Too many facets reach in: wait until the Sun has moved on by
                        // the cone's width.
                        fact.last = Last::Lit(path.ahead[path.ahead[p]]);
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
                Last::Lit(_) | Last::Unknown => return Answer::Trace,
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

    /// The facets reaching into the cone centred on the Sun a little ahead on the path
    /// of position `p`'s, which holds that Sun, seen from facet `ray.facet`; `None` when
    /// more than [`LIST_MAX`] do.
    fn certify(
        &self,
        ray: &ShadowRay,
        path: &Path<'_>,
        p: usize,
        (bound, bvh, mesh): (&HorizonBound, &Bvh, &crate::mesh::Mesh),
    ) -> Option<Certificate> {
        let axis = path.ahead[p];
        let cone = Cone::new(path.suns[axis], path.cone);
        let among = bound.reaching(mesh, bvh, ray.facet as usize, &cone, LIST_MAX)?;
        Some(Certificate { axis, among })
    }
}

impl<'a> Path<'a> {
    /// The Suns of `skies` in the order of their path, with their queries through `bvh`.
    fn new(skies: &[Sky], bvh: &'a Bvh<'a>, mesh: &crate::mesh::Mesh) -> Path<'a> {
        let steps = path_order(&skies.iter().map(|s| s.sun).collect::<Vec<_>>());
        let suns: Vec<DVec3> = steps.iter().map(|&k| skies[k].sun).collect();
        let queries = suns.iter().map(|&s| BvhRays::new(bvh, s)).collect();
        let turn = median_turn(&suns);
        let cone = (CONE_STEPS * turn).clamp(CONE_MIN, CONE_MAX);
        // A Sun counts as inside a little within the cone: its test is widened by far
        // more than this (`Bvh::near_cone`).
        let cos_inside = (cone * (1.0 - 1e-3)).cos();
        let ahead = cone_centres(&suns, cone);
        Path {
            steps,
            suns,
            queries,
            neighbours: edge_neighbours(mesh),
            ahead,
            cone,
            cos_inside,
            cones: cone_pays(turn),
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
