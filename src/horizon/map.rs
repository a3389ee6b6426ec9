//! Horizon maps: per facet, the horizon as a function of azimuth, built once per mesh.
//!
//! In: a mesh (metres, body frame), its [`Bvh`] and a number of azimuth wedges `A`.
//! Out: a [`HorizonMap`] — for every facet centroid, in the facet's own frame (zenith the
//! facet normal, azimuth measured in its tangent plane from [`tangent_frame`]'s first
//! axis), two elevations per wedge `[2πk/A, 2π(k+1)/A)`, quantised to 16 bits over 0–90°
//! (0.0014°):
//!
//! - **upper**: an exact upper bound of the elevation of every point of every other facet
//!   that lies in the wedge (each triangle's highest point in the wedge found from its
//!   outline, `super::outline`, or by clipping it to the wedge where the outline would be
//!   ill conditioned: at a corner, on an arc or straight up; widened by the exact
//!   predicate's rounding and rounded up when quantised). A Sun above it in that wedge
//!   lights the facet for certain: the exact ray tracers would find nothing.
//! - **centre**: the horizon at the wedge's centre azimuth, the highest point of any
//!   facet in that vertical half-plane (exact, rounded to the nearest quantum). Linear
//!   interpolation between wedge centres is the approximate horizon.
//!
//! A map of [`MapKind::Centres`] keeps the centres alone (every upper bound at 90°): all
//! that a disk Sun's and the approximate mode's lookups read. Its search never clips a
//! triangle to a wedge, and prunes a box unless its span holds a wedge centre that it
//! can rise above; the centres come out the same, quantum for quantum.
//!
//! A map may be built for a [`SunBand`], the zone of directions a run's Sun takes: then
//! only the facets that meet the cone of those directions from the centroid count, and
//! the cells hold for Suns of the band alone (the band's module says why that is exact);
//! [`SunBand::WHOLE`] gives the map of every direction.
//!
//! Folded shapes: under an overhang the blocked elevations at one azimuth are not one
//! interval (sky below an arch, rock above it). The map keeps only the top of the
//! blocked set, so the approximate horizon calls a Sun seen under an overhang dark; the
//! exact mode never relies on it below the upper bound and traces a ray instead.
//!
//! Cost: one tree search per facet, parallel over facets, that prunes every box lower
//! than the upper bounds of the wedges it spans. Memory: `4·A` bytes per facet.
//!
//! The same search gives the horizon from any point off the surface ([`PointHorizon`]:
//! a panel or a mast at a height, around the local vertical), with elevations below the
//! horizontal kept (a point on a ridge sees down its flanks) and no facet left out.

use super::band::SunBand;
use super::geometry::{
    arc_max_sin, directions_max_sin, distance_to_triangle, polygon_max_sin, pseudo_angle,
    rounding_widening, signed_box_bound, tangent_frame, touches, ANGLE_ERROR,
};
use super::outline::{turned_outward, Outline};
use crate::mesh::Mesh;
use crate::trace::bvh::{Bvh, SearchBox};
use glam::DVec3;
use rayon::prelude::*;
use std::cell::RefCell;
use std::f64::consts::{FRAC_PI_2, TAU};

/// Quanta per radian of elevation: 0–90° onto 0–65535.
pub(super) const QUANTA_PER_RAD: f64 = 65535.0 / FRAC_PI_2;

/// Least and most wedges a map may have (a wedge must be narrower than half a turn).
pub const AZIMUTHS_MIN: u32 = 8;
pub const AZIMUTHS_MAX: u32 = 4096;

/// Bytes per facet of a map's ceilings (the whole horizon's, f64, and its octants', f32),
/// beside its `4 × azimuths` bytes of cells.
pub const CEILING_BYTES: usize = 8 + 8 * 4;

/// How far (radians) a Sun must stand above a wedge's upper bound to clear it: more than
/// the rounding of its elevation.
pub(super) const CLEAR_MARGIN: f64 = 1e-9;

/// Extra width (radians) given to each wedge on both sides when the upper bound is
/// built, so that the rounding of the Sun's azimuth at lookup never picks a wedge that
/// misses a blocker near its edge.
const WEDGE_OVERLAP: f64 = 1e-9;

/// What a map's cells hold beside each wedge's centre horizon.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MapKind {
    /// Each wedge's upper bound too: what the exact mode certifies a lit facet by.
    #[default]
    Bounded,
    /// The centre horizons alone, every upper bound left at 90°: all that a disk Sun's
    /// and the approximate mode's lookups read, built in 0.81–0.91× the time (the
    /// triangles are never clipped to a wedge). Its ceilings are the centres' alone, so
    /// the exact mode must never read it.
    Centres,
}

/// The horizon of every facet of one mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct HorizonMap {
    pub(super) azimuths: u32,
    kind: MapKind,
    /// Per wedge, per facet: [upper, centre] elevation in quanta, in blocks of
    /// [`CELL_BLOCK`] facets (each block's cells wedge by wedge; [`HorizonMap::cell`]).
    cells: Vec<[u16; 2]>,
    /// Per facet, a sine of elevation that no wedge's upper bound or centre reaches
    /// (derived from `cells`; for a map of [`MapKind::Centres`], from its centres alone):
    /// a Sun higher than it clears the facet's whole horizon, decided without its
    /// azimuth.
    pub(super) ceilings: Vec<f64>,
    /// Per facet, the same per octant of azimuth (f32 rounded up), over the wedges that
    /// meet the octant and one more on each side (the interpolation's neighbours).
    pub(super) octant_ceilings: Vec<[f32; 8]>,
}

/// Facets whose cells a map keeps together, wedge by wedge: neighbouring facets see the
/// Sun at nearly the same azimuth, so that the cells a step reads for them share cache
/// lines (a wedge's cells of 16 facets fill 64 bytes) where a row per facet would give
/// each facet a line of its own.
const CELL_BLOCK: usize = 16;

/// Facets in a part of a map's build ([`MapParts`]): a few seconds of work at most, and
/// a whole number of the seeded runs' 64 facets.
pub const MAP_PART: usize = 4096;

/// A map's build cut into parts of consecutive facets that can be built one by one, in
/// separate processes too (a build resumed from its journal): every part starts
/// the seeded runs afresh at the same facets, so the parts give the map of one
/// whole build, bit for bit.
pub struct MapParts<'a> {
    mesh: &'a Mesh,
    bvh: &'a Bvh<'a>,
    receivers: usize,
    part: usize,
    wedges: Wedges,
    widening: f64,
    band: SunBand,
    kind: MapKind,
}

impl<'a> MapParts<'a> {
    /// The parts of the map of the first `receivers` facets of `mesh` for Suns of `band`
    /// (as [`HorizonMap::build`]), `part` facets each (a multiple of 64, the seeded runs).
    pub fn new(
        mesh: &'a Mesh,
        receivers: usize,
        bvh: &'a Bvh<'a>,
        (azimuths, band): (u32, SunBand),
        part: usize,
    ) -> MapParts<'a> {
        assert!(
            part > 0 && part.is_multiple_of(SEEDED_RUN),
            "a part of {part} facets splits a seeded run"
        );
        let azimuths = azimuths.clamp(AZIMUTHS_MIN, AZIMUTHS_MAX);
        MapParts {
            mesh,
            bvh,
            receivers,
            part,
            wedges: Wedges::new(azimuths as usize),
            widening: rounding_widening(mesh),
            band,
            kind: MapKind::Bounded,
        }
    }

    /// The same parts for a map of `kind` ([`MapKind::Bounded`] unless told).
    pub fn of_kind(self, kind: MapKind) -> MapParts<'a> {
        MapParts { kind, ..self }
    }

    /// What the map's cells hold.
    pub fn kind(&self) -> MapKind {
        self.kind
    }

    /// Wedges per facet (the count asked for, clamped).
    pub fn azimuths(&self) -> u32 {
        self.wedges.count as u32
    }

    /// The Suns the map serves.
    pub fn band(&self) -> SunBand {
        self.band
    }

    /// Cells of the whole map: `azimuths` per facet.
    pub fn cell_count(&self) -> usize {
        self.receivers * self.wedges.count
    }

    /// How many parts.
    pub fn count(&self) -> usize {
        self.receivers.div_ceil(self.part)
    }

    /// The facets of part `p`.
    pub fn facets(&self, p: usize) -> std::ops::Range<usize> {
        p * self.part..((p + 1) * self.part).min(self.receivers)
    }

    /// The rows of part `p`'s facets, in facet order: `azimuths` cells each.
    pub fn rows(&self, p: usize) -> Vec<[u16; 2]> {
        // Each facet is seeded with the triangles that set its neighbour's horizon.
        let rows = in_seeded_runs(self.facets(p), |i, seeds: &Vec<u32>| {
            let sky = FacetSky::new(self.mesh.centroids[i], self.mesh.normals[i], &self.wedges)
                .widened_by(self.widening)
                .for_band(self.band)
                .of_kind(self.kind);
            facet_horizon(self.mesh, self.bvh, i, sky, seeds)
        });
        let mut cells = Vec::with_capacity(self.facets(p).len() * self.wedges.count);
        rows.into_iter().for_each(|row| cells.extend(row));
        cells
    }

    /// The whole map, every part built in turn in this process.
    pub fn whole(&self) -> HorizonMap {
        let mut cells = Vec::with_capacity(self.cell_count());
        for p in 0..self.count() {
            cells.extend(self.rows(p));
        }
        self.assemble(cells)
            .expect("the parts' rows make the whole map")
    }

    /// The map from every part's rows, in order; `None` when their number does not fit.
    pub fn assemble(&self, cells: Vec<[u16; 2]>) -> Option<HorizonMap> {
        HorizonMap::from_cells((self.azimuths(), self.kind), self.receivers, cells)
    }
}

impl HorizonMap {
    /// Builds the map of the first `receivers` facets of `mesh` with `azimuths` wedges
    /// (within [`AZIMUTHS_MIN`]..=[`AZIMUTHS_MAX`]) for Suns of `band`, searching `bvh`
    /// (built over the same mesh), in one go; runs build it part by part ([`MapParts`])
    /// with a journal.
    pub fn build(
        mesh: &Mesh,
        receivers: usize,
        bvh: &Bvh,
        (azimuths, band): (u32, SunBand),
    ) -> HorizonMap {
        MapParts::new(mesh, receivers, bvh, (azimuths, band), MAP_PART).whole()
    }

    /// A map of `kind` from stored cells (the cache); `None` when their number does not
    /// fit.
    pub(super) fn from_cells(
        (azimuths, kind): (u32, MapKind),
        facets: usize,
        cells: Vec<[u16; 2]>,
    ) -> Option<Self> {
        ((AZIMUTHS_MIN..=AZIMUTHS_MAX).contains(&azimuths)
            && cells.len() == facets * azimuths as usize)
            .then(|| HorizonMap::with_ceilings((azimuths, kind), cells))
    }

    /// The map of `cells` given facet by facet.
    fn with_ceilings((azimuths, kind): (u32, MapKind), mut cells: Vec<[u16; 2]>) -> HorizonMap {
        let a = azimuths as usize;
        // A map of centres alone has every upper bound at 90°: they would say nothing.
        let heights = |cell: &[u16; 2]| match kind {
            MapKind::Bounded => cell[0].max(cell[1]),
            MapKind::Centres => cell[1],
        };
        let ceilings = cells
            .chunks(a)
            .map(|row| ceiling(row.iter().map(heights)))
            .collect();
        let octants: Vec<Vec<usize>> = (0..8).map(|o| octant_wedges(a, o)).collect();
        let octant_ceilings = cells
            .chunks(a)
            .map(|row| {
                std::array::from_fn(|o| {
                    f32_at_least(ceiling(octants[o].iter().map(|&k| heights(&row[k]))))
                })
            })
            .collect();
        wedge_by_wedge(&mut cells, a);
        HorizonMap {
            azimuths,
            kind,
            cells,
            ceilings,
            octant_ceilings,
        }
    }

    /// What its cells hold.
    pub fn kind(&self) -> MapKind {
        self.kind
    }

    /// The cells of `facets`, facet by facet (as the cache stores them).
    pub(super) fn rows(
        &self,
        facets: std::ops::Range<usize>,
    ) -> impl Iterator<Item = [u16; 2]> + '_ {
        let a = self.azimuths as usize;
        facets.flat_map(move |i| (0..a).map(move |k| self.cell(i, k)))
    }

    /// Number of azimuth wedges.
    pub fn azimuths(&self) -> u32 {
        self.azimuths
    }

    /// Number of facets.
    pub fn facets(&self) -> usize {
        // One ceiling a facet: a length, where the cells' over the wedges would be a
        // division at every lookup of a cell.
        self.ceilings.len()
    }

    /// Memory held, bytes.
    pub fn bytes(&self) -> usize {
        self.cells.len() * 4 + self.ceilings.len() * CEILING_BYTES
    }

    /// The [upper, centre] elevations (radians) of facet `i` in wedge `k` (tests, reports).
    pub fn wedge(&self, i: usize, k: usize) -> [f64; 2] {
        self.cell(i, k).map(|q| q as f64 / QUANTA_PER_RAD)
    }

    /// Facet `i`'s cell of wedge `k`: in its block (the last may hold fewer facets),
    /// wedge `k`'s cells after those of the wedges before it.
    #[inline]
    pub(super) fn cell(&self, i: usize, k: usize) -> [u16; 2] {
        let first = i - i % CELL_BLOCK;
        let width = (self.facets() - first).min(CELL_BLOCK);
        self.cells[first * self.azimuths as usize + k * width + (i - first)]
    }
}

/// Reorders `cells`, given facet by facet (`a` wedges each), into the blocks of
/// [`HorizonMap::cell`], in place: a block's cells occupy the same places either way.
fn wedge_by_wedge(cells: &mut [[u16; 2]], a: usize) {
    let mut by_facet = Vec::with_capacity(CELL_BLOCK * a);
    for block in cells.chunks_mut(CELL_BLOCK * a) {
        let width = block.len() / a;
        by_facet.clear();
        by_facet.extend_from_slice(block);
        for (f, row) in by_facet.chunks(a).enumerate() {
            for (k, &cell) in row.iter().enumerate() {
                block[k * width + f] = cell;
            }
        }
    }
}

/// The wedges (of `a`) that meet octant `o`, with one more on each side.
pub(super) fn octant_wedges(a: usize, o: usize) -> Vec<usize> {
    let first = (o * a) / 8;
    let last = ((o + 1) * a).div_ceil(8);
    (first as isize - 1..=last as isize)
        .map(|k| k.rem_euclid(a as isize) as usize)
        .collect()
}

/// The sine of an elevation none of `heights` (quanta) reaches by [`CLEAR_MARGIN`]: a
/// Sun whose sine is above it stands more than the margin above every one of them
/// (1e-12 covers the rounding of sin); infinite when they reach straight up.
fn ceiling(heights: impl Iterator<Item = u16>) -> f64 {
    let top = heights.max().unwrap_or(0);
    let elevation = top as f64 / QUANTA_PER_RAD + CLEAR_MARGIN + 1e-12;
    if elevation >= FRAC_PI_2 {
        f64::INFINITY
    } else {
        elevation.sin()
    }
}

/// The least f32 at or above `v` (a sine in (0, 1], or infinite).
pub(super) fn f32_at_least(v: f64) -> f32 {
    let rounded = v as f32;
    if (rounded as f64) < v {
        // The next f32 up: positive floats order as their bits.
        f32::from_bits(rounded.to_bits() + 1)
    } else {
        rounded
    }
}

// The lookups' angles (`super::sky`), and the spans' turns, must err by less than the
// margins the build leaves.
const _: () = assert!(ANGLE_ERROR < WEDGE_OVERLAP && ANGLE_ERROR < CLEAR_MARGIN);
const _: () = assert!(TURN_ERROR < WEDGE_OVERLAP);

/// The wedges' boundary and centre azimuths, as in-plane unit vectors per facet frame
/// (cosine and sine pairs; the same for every facet), and as turns (the pseudo-angle of
/// [`Span`]) for finding the wedges a span meets without an angle.
struct Wedges {
    count: usize,
    /// cos, sin of the boundary azimuths 2πk/A, k = 0..=A.
    edges: Vec<(f64, f64)>,
    /// cos, sin of the centre azimuths 2π(k+½)/A.
    centres: Vec<(f64, f64)>,
    /// The centres as turns in `(0, 4)`.
    centre_turns: Vec<f64>,
    /// The wedges by turn, a bucket per `4/buckets` of turn ([`Wedges::wedge_at`]).
    buckets: Vec<Bucket>,
}

/// The wedges a bucket of turns meets: buckets are narrower than any wedge (a wedge of
/// 2π/A radians spans at least π/A of turn; a bucket, 2/A), so at most one boundary falls
/// inside each, and one read finds the wedge of any turn in it.
#[derive(Debug, Clone, Copy)]
struct Bucket {
    /// The wedge that the bucket's start lies in.
    wedge: usize,
    /// The turn at which the next wedge starts (4 after the last).
    next_edge: f64,
    /// The centre turns of that wedge and of the next.
    centres: [f64; 2],
}

/// Buckets of [`Wedges::buckets`] per wedge.
const BUCKETS_PER_WEDGE: usize = 2;

impl Wedges {
    fn new(count: usize) -> Wedges {
        let at = |x: f64| {
            let phi = TAU * x / count as f64;
            (phi.cos(), phi.sin())
        };
        let centres: Vec<(f64, f64)> = (0..count).map(|k| at(k as f64 + 0.5)).collect();
        let edges: Vec<(f64, f64)> = (0..=count).map(|k| at(k as f64)).collect();
        let mut edge_turns: Vec<f64> = edges.iter().map(|&e| turn_of(e)).collect();
        (edge_turns[0], edge_turns[count]) = (0.0, 4.0);
        let centre_turns: Vec<f64> = centres.iter().map(|&c| turn_of(c)).collect();
        let buckets = BUCKETS_PER_WEDGE * count;
        let per_turn = buckets as f64 / 4.0;
        let mut k = 0;
        let buckets = (0..buckets)
            .map(|b| {
                let start = b as f64 / per_turn;
                while edge_turns[k + 1] <= start {
                    k += 1;
                }
                let after = centre_turns
                    .get(k + 1)
                    .copied()
                    .unwrap_or(centre_turns[0] + 4.0);
                Bucket {
                    wedge: k,
                    next_edge: edge_turns[k + 1],
                    centres: [centre_turns[k], after],
                }
            })
            .collect();
        Wedges {
            count,
            edges,
            centres,
            centre_turns,
            buckets,
        }
    }

    fn width(&self) -> f64 {
        TAU / self.count as f64
    }

    /// Wedge `k`'s bounding azimuths as in-plane directions, each turned outward by an
    /// overlap given as its `(cos, sin)`.
    fn widened(&self, k: usize, overlap: (f64, f64)) -> ((f64, f64), (f64, f64)) {
        turned_outward(self.edges[k], self.edges[k + 1], overlap)
    }

    /// The wedges met by an azimuth span, each once, in order.
    fn covering(&self, span: Span) -> impl Iterator<Item = usize> + '_ {
        let Met { first, len, .. } = self.met(span);
        (first..first + len).map(|k| self.wrapped(k))
    }

    /// The wedge that turn `t` (in `[0, 8)`) lies in, counted on past the last wedge
    /// for a turn of 4 or more (`k + A`), and the turn of its centre, counted alike.
    #[inline]
    fn wedge_at(&self, t: f64) -> (usize, f64) {
        let (within, past, shift) = if t >= 4.0 {
            (t - 4.0, self.count, 4.0)
        } else {
            (t, 0, 0.0)
        };
        let per_turn = self.buckets.len() as f64 * 0.25;
        let b = ((within * per_turn) as usize).min(self.buckets.len() - 1);
        let bucket = &self.buckets[b];
        let next = usize::from(within >= bucket.next_edge);
        (past + bucket.wedge + next, bucket.centres[next] + shift)
    }

    /// The wedges a span meets: the first (as [`Wedges::wedge_at`] counts), how many,
    /// and whether the span holds the centres of the first and of the last (every wedge
    /// between them has its centre inside).
    #[inline]
    fn met(&self, span: Span) -> Met {
        match span {
            Span::All => Met {
                first: 0,
                len: self.count,
                ends_held: (true, true),
            },
            Span::Range(lo, hi) => {
                // Less than half a turn wide, from `[0, 4)` or, widened, a hair below.
                let (lo, hi) = if lo < 0.0 {
                    (lo + 4.0, hi + 4.0)
                } else {
                    (lo, hi)
                };
                let ((first, first_centre), (last, last_centre)) =
                    (self.wedge_at(lo), self.wedge_at(hi));
                Met {
                    first,
                    len: last - first + 1,
                    ends_held: (lo <= first_centre, last_centre <= hi),
                }
            }
        }
    }

    /// Wedge `k` of those [`Wedges::met`] counts (below twice the count): one
    /// subtraction, not a division, wraps it.
    #[inline]
    fn wrapped(&self, k: usize) -> usize {
        if k >= self.count {
            k - self.count
        } else {
            k
        }
    }
}

/// The wedges an azimuth span meets ([`Wedges::met`]).
struct Met {
    first: usize,
    len: usize,
    ends_held: (bool, bool),
}

/// The turn of the in-plane direction `(x, y)`: its pseudo-angle
/// ([`pseudo_angle`]) brought into `[0, 4)`, monotone in azimuth from 0 to 2π, a quarter
/// turn per unit, exact at every eighth of a turn.
#[inline]
fn turn_of(d: (f64, f64)) -> f64 {
    let p = pseudo_angle(d);
    if p < 0.0 {
        p + 4.0
    } else {
        p
    }
}

/// An azimuth span in a facet's frame: every azimuth, or `[lo, hi]` in turns with
/// `lo ≤ hi < lo + 2` (less than half a turn; not reduced to one turn).
///
/// A turn is the pseudo-angle of a direction in the tangent plane ([`turn_of`]): 0 to 4
/// over the circle, monotone in azimuth, so that a span of turns holds the same
/// directions as the span of azimuths between its ends, found without an angle. Its
/// slope is 1/(|cos φ| + |sin φ|)² per radian, between ½ and 1: a span widened by `δ`
/// turns is widened by at least `δ` radians, so that every widening the build asks for
/// in radians is met by the same number in turns.
#[derive(Debug, Clone, Copy)]
enum Span {
    All,
    Range(f64, f64),
}

/// Widening of a span's ends for the rounding of their turns (one division, a few
/// roundings of numbers below 4): far more than it.
const TURN_ERROR: f64 = 1e-13;

impl Span {
    /// The span of points `rel` (relative to the viewpoint) projected on the tangent
    /// plane `(t1, t2)`. Their hull must not hold the zenith axis (then every azimuth is
    /// spanned, which the caller knows from another test). The ends are widened by the
    /// rounding of their turns ([`TURN_ERROR`]), so that the span holds every point.
    ///
    /// A point on the zenith axis has no azimuth; the hull's points near it have those
    /// between the other points', which the span holds. As the first point, the one all
    /// turns are taken from, it gives every azimuth.
    fn of(rel: &[DVec3], t1: DVec3, t2: DVec3) -> Span {
        let in_plane = |p: &DVec3| (p.dot(t1), p.dot(t2));
        let first = in_plane(&rel[0]);
        if first == (0.0, 0.0) {
            return Span::All;
        }
        // Each point's turn from the first, as (cos, sin) up to a common factor, ordered
        // by its pseudo-angle: the extremes are the points with the least and the most.
        let turn = |(x, y): (f64, f64)| {
            // `+ 0.0` turns a −0 sine into +0, so that a turn of exactly π is π for the
            // pseudo-angle and for the cross product below alike.
            (first.0 * x + first.1 * y, first.0 * y - first.1 * x + 0.0)
        };
        let start = (0.0, (1.0, 0.0), first);
        let (mut lo, mut hi) = (start, start);
        for point in rel[1..].iter().map(in_plane) {
            let t = turn(point);
            let order = pseudo_angle(t);
            if order < lo.0 {
                lo = (order, t, point);
            }
            if order > hi.0 {
                hi = (order, t, point);
            }
        }
        // The turn from the lowest to the highest is half a turn or more when their
        // cross product is negative, or zero with the two pointing apart.
        let ((lx, ly), (hx, hy)) = (lo.1, hi.1);
        let cross = lx * hy - ly * hx;
        if cross < 0.0 || (cross == 0.0 && lx * hx + ly * hy < 0.0) {
            return Span::All;
        }
        let (lo, hi) = (turn_of(lo.2), turn_of(hi.2));
        // Less than half a turn apart: `hi` below `lo` by more than that has crossed
        // the first wedge's edge; by less, only rounding put it there.
        Span::Range(lo, if hi < lo - 2.0 { hi + 4.0 } else { hi.max(lo) }).widened(TURN_ERROR)
    }

    /// The span widened by `by` turns on both sides (at least `by` radians).
    fn widened(self, by: f64) -> Span {
        match self {
            Span::Range(lo, hi) if hi - lo + 2.0 * by < 2.0 => Span::Range(lo - by, hi + by),
            _ => Span::All,
        }
    }

    /// True when the span holds turn `t` (in `[0, 4)`, any number of whole turns off).
    fn holds(self, t: f64) -> bool {
        match self {
            Span::All => true,
            Span::Range(lo, hi) => {
                let t = lo + (t - lo).rem_euclid(4.0);
                t <= hi
            }
        }
    }
}

/// Facets in a run of [`in_seeded_runs`].
const SEEDED_RUN: usize = 64;

/// Neighbouring facets taken in turn, so that each search starts from what the last one
/// found: `each(i, seed)` for every facet `i` of `facets`, in parallel runs of 64
/// neighbours (in file order, which is spatially coherent in shape models and terrain).
/// Within a run, each facet's `seed` is what the facet before it handed on; the first
/// gets `S::default()`. The results come in facet order. A seed can only speed a search
/// up: it is one more candidate, taken first.
pub(super) fn in_seeded_runs<T: Send + Clone + Default, S: Default>(
    facets: std::ops::Range<usize>,
    each: impl Fn(usize, &S) -> (T, S) + Sync,
) -> Vec<T> {
    // Written in place, run by run: runs collected instead gather first in a list per
    // thread that grows by doubling, and glibc keeps the memory those lists free at the
    // top of each thread's arena resident (5.9 MB of a bound's build at 786k facets).
    let mut results = vec![T::default(); facets.len()];
    results
        .par_chunks_mut(SEEDED_RUN)
        .enumerate()
        .for_each(|(run, slots)| {
            let mut seed = S::default();
            let first = facets.start + run * SEEDED_RUN;
            for (k, slot) in slots.iter_mut().enumerate() {
                let (result, next) = each(first + k, &seed);
                *slot = result;
                seed = next;
            }
        });
    results
}

/// One facet's row of the map, and the triangles that set its horizon. Triangles in
/// `seeds` (a neighbour's horizon setters) are taken first: they are likely high here
/// too, and the higher the horizon found early, the more of the tree is pruned.
fn facet_horizon(
    mesh: &Mesh,
    bvh: &Bvh,
    i: usize,
    sky: FacetSky,
    seeds: &[u32],
) -> (Vec<[u16; 2]>, Vec<u32>) {
    if mesh.normals[i] == DVec3::ZERO || mesh.areas[i] <= 0.0 {
        // Never lit (n·s = 0): any horizon will do; the highest is the safe one.
        return (vec![[u16::MAX; 2]; sky.wedges.count], Vec::new());
    }
    let sky = search_sky(mesh, bvh, sky, Some(i as u32), seeds);
    let mut setters: Vec<u32> = sky
        .setter
        .iter()
        .copied()
        .filter(|&s| s != u32::MAX)
        .collect();
    setters.sort_unstable();
    setters.dedup();
    (sky.quantised(), setters)
}

/// Raises `sky` by every triangle of `mesh` but `skip` that can change it: the `seeds`
/// first, then a best-first search of `bvh` that prunes boxes no higher than the
/// horizons of the wedges they span.
fn search_sky<'a>(
    mesh: &Mesh,
    bvh: &Bvh,
    sky: FacetSky<'a>,
    skip: Option<u32>,
    seeds: &[u32],
) -> FacetSky<'a> {
    let sky = RefCell::new(sky);
    for &id in seeds.iter().filter(|&&id| Some(id) != skip) {
        sky.borrow_mut()
            .add_triangle(id, &mesh.corners(id as usize));
    }
    let view = {
        let sky = sky.borrow();
        let view = bvh.viewpoint(sky.c, sky.n, sky.widening);
        match sky.band.is_whole() {
            true => view,
            false => view.with_axial(),
        }
    };
    bvh.search(
        &view,
        (),
        |child, ()| sky.borrow().box_priority(child).map(|p| (p, ())),
        |id, tri, ()| {
            if Some(id) != skip {
                sky.borrow_mut().add_triangle(id, tri);
            }
        },
    );
    sky.into_inner()
}

/// The horizon seen from a point off the surface (a panel or a mast at some height), in
/// the frame of an `up` direction: per azimuth wedge (azimuth in the plane normal to
/// `up`, from [`tangent_frame`]'s first axis toward its second), an upper bound of the
/// elevation of every point of the mesh in the wedge and the horizon at the wedge's
/// centre, both in radians from −90° to 90° (a point on a ridge sees below the
/// horizontal). Built by the same search as a facet's row of a [`HorizonMap`], kept in
/// `f64`, not quantised; no facet is left out.
#[derive(Debug, Clone, PartialEq)]
pub struct PointHorizon {
    pub(super) up: DVec3,
    /// Per wedge: [upper, centre] elevation, radians.
    pub(super) cells: Vec<[f64; 2]>,
}

impl PointHorizon {
    /// The horizon from `point` (metres, the mesh's frame) around the unit vector `up`,
    /// with `azimuths` wedges (clamped to [`AZIMUTHS_MIN`]..=[`AZIMUTHS_MAX`]). `bvh` is
    /// built over `mesh`. A point on the mesh itself sees every wedge blocked.
    pub fn build(mesh: &Mesh, bvh: &Bvh, point: DVec3, up: DVec3, azimuths: u32) -> PointHorizon {
        let wedges = Wedges::new(azimuths.clamp(AZIMUTHS_MIN, AZIMUTHS_MAX) as usize);
        let sky = FacetSky::new(point, up, &wedges)
            .widened_by(rounding_widening(mesh))
            .above_floor(-1.0);
        let sky = search_sky(mesh, bvh, sky, None, &[]);
        let elevation = |sin: f64| sin.clamp(-1.0, 1.0).asin();
        PointHorizon {
            up,
            cells: sky
                .upper
                .iter()
                .zip(&sky.centre)
                .map(|(&up, &mid)| [elevation(up), elevation(mid.min(up))])
                .collect(),
        }
    }

    /// Number of azimuth wedges.
    pub fn azimuths(&self) -> u32 {
        self.cells.len() as u32
    }

    /// The [upper, centre] elevations (radians) of wedge `k`.
    pub fn wedge(&self, k: usize) -> [f64; 2] {
        self.cells[k]
    }
}

/// A facet's horizon while it is being built: sines of elevation per wedge.
struct FacetSky<'a> {
    c: DVec3,
    n: DVec3,
    t1: DVec3,
    t2: DVec3,
    zenith: ZenithLine,
    wedges: &'a Wedges,
    widening: f64,
    upper: Vec<f64>,
    centre: Vec<f64>,
    /// Per wedge, the triangle that set its centre horizon (`u32::MAX`: none).
    setter: Vec<u32>,
    /// The lowest centre horizon of all wedges.
    lowest_anywhere: f64,
    /// The highest centre horizon of all wedges.
    highest_anywhere: f64,
    /// The lowest elevation sine kept: 0 for a facet (its own plane hides what is below),
    /// −1 for a point above the surface.
    floor: f64,
    /// The Suns the horizon serves: boxes and triangles outside their cone are left out.
    band: SunBand,
}

impl<'a> FacetSky<'a> {
    /// The sky of a facet at `c` with unit normal `n`, before any triangle: nothing above
    /// its plane, for Suns from every direction, triangles taken as they are.
    fn new(c: DVec3, n: DVec3, wedges: &'a Wedges) -> FacetSky<'a> {
        let (t1, t2) = tangent_frame(n);
        FacetSky {
            c,
            n,
            t1,
            t2,
            zenith: ZenithLine::new(c, n),
            wedges,
            widening: 0.0,
            upper: vec![0.0; wedges.count],
            centre: vec![0.0; wedges.count],
            setter: vec![u32::MAX; wedges.count],
            lowest_anywhere: 0.0,
            highest_anywhere: 0.0,
            floor: 0.0,
            band: SunBand::WHOLE,
        }
    }

    /// Every triangle widened by `widening` (m), the exact predicate's rounding.
    fn widened_by(self, widening: f64) -> FacetSky<'a> {
        FacetSky { widening, ..self }
    }

    /// Elevations kept down to the sine `floor` (−1 for a point above the surface).
    fn above_floor(self, floor: f64) -> FacetSky<'a> {
        FacetSky {
            upper: vec![floor; self.wedges.count],
            centre: vec![floor; self.wedges.count],
            lowest_anywhere: floor,
            highest_anywhere: floor,
            floor,
            ..self
        }
    }

    /// Only what can stand in front of Suns of `band`.
    fn for_band(self, band: SunBand) -> FacetSky<'a> {
        FacetSky { band, ..self }
    }

    /// The horizon a map of `kind` keeps. For [`MapKind::Centres`] every wedge's upper
    /// bound starts (and stays) above any height: no triangle is clipped to a wedge, and
    /// a box or a triangle counts only where its span holds a wedge's centre.
    fn of_kind(self, kind: MapKind) -> FacetSky<'a> {
        match kind {
            MapKind::Bounded => self,
            MapKind::Centres => FacetSky {
                upper: vec![f64::INFINITY; self.wedges.count],
                ..self
            },
        }
    }

    /// The highest elevation sine of a box's points, never below the floor.
    fn box_bound(&self, lo: DVec3, hi: DVec3) -> f64 {
        signed_box_bound(self.c, self.n, lo, hi, self.widening).max(self.floor)
    }

    /// Whether to open the `child` box and with which priority: not when nothing in it
    /// can rise above the upper bounds of the wedges it spans.
    fn box_priority(&self, child: &SearchBox) -> Option<f64> {
        let bound = child.bound.max(self.floor);
        if bound <= self.lowest_anywhere || !self.band.meets_range(child.axial) {
            return None;
        }
        let (lo, hi) = child.corners();
        if bound > self.highest_anywhere {
            // Above every wedge's centre horizon: whatever azimuths the box spans.
            return Some(bound);
        }
        let (lo, hi) = (lo - self.widening, hi + self.widening);
        let corners: [DVec3; 8] = std::array::from_fn(|k| {
            DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            ) - self.c
        });
        let span = if self.zenith.meets_box(lo, hi) {
            Span::All
        } else {
            Span::of(&corners, self.t1, self.t2)
        };
        self.rises_above(span, bound).then_some(bound)
    }

    /// Whether a height `sin` in `span` can change the row: whether it rises above the
    /// centre horizon of a wedge whose centre azimuth the span holds, or above the upper
    /// bound of a wedge it meets beside its centre (at the span's ends). A NaN height is
    /// never ruled out.
    fn rises_above(&self, span: Span, sin: f64) -> bool {
        if sin.is_nan() {
            return true;
        }
        if let Span::All = span {
            return sin > self.lowest_anywhere;
        }
        let Met {
            first,
            len,
            ends_held: (first_held, last_held),
        } = self.wedges.met(span.widened(WEDGE_OVERLAP));
        let above = |k: usize, held: bool| {
            let k = self.wedges.wrapped(k);
            sin > if held { self.centre[k] } else { self.upper[k] }
        };
        if len == 1 {
            return above(first, first_held && last_held);
        }
        if above(first, first_held) || above(first + len - 1, last_held) {
            return true;
        }
        // Between the ends every centre is held: the least of them decides, a slice or
        // two (across the last wedge) at a time.
        let (start, inner) = (self.wedges.wrapped(first + 1), len - 2);
        let count = self.wedges.count;
        let (head, tail) = match (start + inner).checked_sub(count) {
            Some(past) => (start..count, 0..past),
            None => (start..start + inner, 0..0),
        };
        least(&self.centre[head]).min(least(&self.centre[tail])) < sin
    }

    /// Raises the wedges' upper bounds and centre horizons by triangle `tri`.
    fn add_triangle(&mut self, id: u32, tri: &[DVec3; 3]) {
        let rel = tri.map(|p| p - self.c);
        if self.floor >= 0.0 && rel.iter().all(|p| p.dot(self.n) < -self.widening) {
            return;
        }
        let gap = distance_to_triangle(self.c, tri);
        if touches(gap, self.widening) {
            // The triangle touches the viewpoint (a degenerate mesh): it may hide anything
            // (a map of centres alone keeps its bounds above any height).
            self.upper.iter_mut().for_each(|u| *u = u.max(1.0));
            return;
        }
        let margin = self.widening / (gap - self.widening);
        // Cheap first, over the wedges its corners span (or all of them when the zenith
        // might lie inside its box): no point rises more than its highest corner, nor
        // lies nearer than `gap`; below the plane, the box's bound.
        let (lo, hi) = (
            tri[0].min(tri[1]).min(tri[2]),
            tri[0].max(tri[1]).max(tri[2]),
        );
        if !self.band.meets_box(self.c, lo, hi, self.widening) {
            return;
        }
        let rise = rel
            .iter()
            .map(|p| p.dot(self.n))
            .fold(f64::NEG_INFINITY, f64::max);
        let boxed = if rise > 0.0 {
            (rise / gap).min(1.0)
        } else {
            self.box_bound(lo, hi)
        };
        if boxed + margin <= self.lowest_anywhere {
            return;
        }
        // The corners' span, once: the box test and the exact test differ only in how
        // they learn that the zenith may lie inside.
        let corners = Span::of(&rel, self.t1, self.t2);
        let rough = if self.zenith.meets_box(lo, hi) {
            Span::All
        } else {
            corners
        };
        if !self.rises_above(rough.widened(margin + WEDGE_OVERLAP), boxed + margin) {
            return;
        }
        // The triangle's outline gives its highest point, and each wedge's; where it
        // would be ill conditioned, the triangle is clipped to each wedge instead.
        let outline = Outline::new(&rel, self.n, self.t1, self.t2);
        let top = match &outline {
            Some(outline) => outline.highest(),
            None => directions_max_sin(self.n, rel.map(DVec3::normalize)),
        };
        let span = if top >= 1.0 { Span::All } else { corners };
        // Widening moves points by `margin` radians, which moves their azimuth by at
        // most `margin / cos e`: near the zenith the span is every azimuth.
        let cos_top = (1.0 - (top + margin).min(1.0).powi(2)).sqrt();
        let overlap = WEDGE_OVERLAP + margin / cos_top.max(1e-300);
        if !self.rises_above(span.widened(overlap), top + margin) {
            return;
        }
        let near_zenith = overlap >= 0.25 * self.wedges.width();
        let overlap_turn = (overlap.cos(), overlap.sin());
        let reach = span.widened(overlap);
        // A triangle whose widened span meets one wedge lies inside it with room to
        // spare, so the wedge's clip leaves it whole: its highest point is `top`.
        let in_one_wedge = self.wedges.covering(reach).nth(1).is_none();
        for k in self.wedges.covering(reach) {
            // Nothing of the triangle rises above `top`: a wedge whose bounds are already
            // that high needs no clipping and no cut.
            if top + margin > self.upper[k] {
                let sin = if near_zenith || in_one_wedge {
                    Some(top)
                } else if let Some(outline) = &outline {
                    let (lo, hi) = self.wedges.widened(k, overlap_turn);
                    outline.max_within(lo, hi)
                } else {
                    self.clipped_max_sin(&rel, k, overlap_turn)
                };
                let Some(sin) = sin else {
                    // None of it in the wedge, so none on its centre's half-plane either.
                    continue;
                };
                self.upper[k] = self.upper[k].max((sin + margin).min(1.0));
            }
            if top > self.centre[k] {
                let sin = match &outline {
                    Some(outline) => outline.top_at(self.wedges.centres[k]),
                    None => span
                        .holds(self.wedges.centre_turns[k])
                        .then(|| self.half_plane_max_sin(&rel, k)),
                };
                if let Some(sin) = sin.filter(|&sin| sin > self.centre[k]) {
                    let was_lowest = self.centre[k] == self.lowest_anywhere;
                    self.centre[k] = sin;
                    self.highest_anywhere = self.highest_anywhere.max(sin);
                    self.setter[k] = id;
                    if was_lowest {
                        self.lowest_anywhere = least(&self.centre);
                    }
                }
            }
        }
    }

    /// The highest elevation sine of the triangle `rel` (relative to the viewpoint) on
    /// the vertical half-plane at wedge `k`'s centre azimuth, never below the floor.
    fn half_plane_max_sin(&self, rel: &[DVec3; 3], k: usize) -> f64 {
        let (cos_c, sin_c) = self.wedges.centres[k];
        let u = self.t1 * cos_c + self.t2 * sin_c;
        let m = self.t2 * cos_c - self.t1 * sin_c;
        half_plane_max_sin(rel, self.n, u, m, self.floor)
    }

    /// The largest elevation sine of the part of the triangle `rel` (relative to the
    /// viewpoint) in wedge `k` widened by an overlap of `(cos, sin)` on both sides;
    /// `None` when none of it is.
    fn clipped_max_sin(&self, rel: &[DVec3; 3], k: usize, overlap: (f64, f64)) -> Option<f64> {
        let (t1, t2) = (self.t1, self.t2);
        let in_plane = |(cos, sin): (f64, f64)| (t1 * cos + t2 * sin, t2 * cos - t1 * sin);
        let (u_lo, m_lo) = in_plane(self.wedges.edges[k]);
        let (u_hi, m_hi) = in_plane(self.wedges.edges[k + 1]);
        let (co, so) = overlap;
        // Azimuth ≥ lower edge − overlap, and ≤ upper edge + overlap.
        let above_lo = m_lo * co + u_lo * so;
        let below_hi = -(m_hi * co - u_hi * so);
        let mut poly = Polygon::from(rel);
        poly.clip(above_lo);
        poly.clip(below_hi);
        poly.pts[..poly.len]
            .iter_mut()
            .for_each(|p| *p = p.normalize());
        let dirs = poly.points();
        match dirs.len() {
            0 => None,
            1 => Some(self.n.dot(dirs[0])),
            2 => Some(arc_max_sin(self.n, dirs[0], dirs[1])),
            _ => Some(polygon_max_sin(self.n, dirs)),
        }
    }

    /// The row in quanta: upper bounds rounded up, centre horizons to the nearest, each
    /// centre no higher than its wedge's upper bound.
    fn quantised(&self) -> Vec<[u16; 2]> {
        let quanta = |sin: f64| sin.clamp(0.0, 1.0).asin() * QUANTA_PER_RAD;
        self.upper
            .iter()
            .zip(&self.centre)
            .map(|(&up, &mid)| {
                let up = quanta(up).ceil().min(65535.0) as u16;
                let mid = quanta(mid).round().min(65535.0) as u16;
                [up, mid.min(up)]
            })
            .collect()
    }
}

/// The least of `values` (none NaN; infinite when empty), in four lanes: `f64::min`'s
/// care for NaN costs a blend per value, and this runs every time a row's lowest centre
/// horizon is raised (with `f64::min`, about 6 % of a map's build at 49k facets).
fn least(values: &[f64]) -> f64 {
    let mut lanes = [f64::INFINITY; 4];
    let quads = values.chunks_exact(4);
    let rest = quads.remainder();
    for quad in quads {
        for (lane, &v) in lanes.iter_mut().zip(quad) {
            *lane = if v < *lane { v } else { *lane };
        }
    }
    let [a, b, c, d] = lanes;
    (rest.iter().copied()).fold(a.min(b).min(c.min(d)), f64::min)
}

/// The line through a viewpoint `c` along its unit zenith `n` (both ways), for the slab
/// test of boxes: the reciprocals of `n`'s components are taken once per viewpoint, not
/// twice per box and axis (a test of every box and triangle the searches meet).
#[derive(Debug, Clone, Copy)]
pub(super) struct ZenithLine {
    c: DVec3,
    n: DVec3,
    inverse: DVec3,
}

impl ZenithLine {
    pub(super) fn new(c: DVec3, n: DVec3) -> ZenithLine {
        ZenithLine {
            c,
            n,
            inverse: n.recip(),
        }
    }

    /// The viewpoint and its zenith.
    pub(super) fn point_and_zenith(&self) -> (DVec3, DVec3) {
        (self.c, self.n)
    }

    /// Whether the line meets the box `lo..hi` (closed). Within the rounding of a product,
    /// a line grazing the box may be found either side of it: the callers' spans of
    /// azimuth then come out as (nearly) half a turn, which they take as every azimuth.
    pub(super) fn meets_box(&self, lo: DVec3, hi: DVec3) -> bool {
        let (c, n) = (self.c, self.n);
        let (mut enter, mut leave) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            if n[a] == 0.0 {
                if c[a] < lo[a] || c[a] > hi[a] {
                    return false;
                }
                continue;
            }
            let (t0, t1) = (
                (lo[a] - c[a]) * self.inverse[a],
                (hi[a] - c[a]) * self.inverse[a],
            );
            enter = enter.max(t0.min(t1));
            leave = leave.min(t0.max(t1));
        }
        enter <= leave
    }
}

/// The highest elevation sine of the triangle `rel` (relative to the viewpoint) in the
/// vertical half-plane spanned by the unit zenith `n` and the in-plane direction `u`
/// (`m` its normal): the triangle cut by the plane is a segment (or, lying in it, the
/// triangle itself), and the elevation along a line seen from a point off it changes
/// monotonically, so the highest point of the cut within the half-plane is one of its
/// ends, or straight up where it crosses the zenith.
fn half_plane_max_sin(rel: &[DVec3; 3], n: DVec3, u: DVec3, m: DVec3, floor: f64) -> f64 {
    let mut poly = Polygon::default();
    let g = rel.map(|p| p.dot(m));
    for j in 0..3 {
        let (a, b) = (rel[j], rel[(j + 1) % 3]);
        let (ga, gb) = (g[j], g[(j + 1) % 3]);
        if ga == 0.0 {
            poly.push(a);
        }
        if ga * gb < 0.0 {
            poly.push(a + (b - a) * (ga / (ga - gb)));
        }
    }
    poly.clip(u);
    poly.points()
        .iter()
        .map(|p| {
            let (x, y) = (p.dot(u), p.dot(n));
            let r = x.hypot(y);
            if r == 0.0 {
                1.0
            } else {
                y / r
            }
        })
        .fold(floor, f64::max)
}

/// A small convex polygon (at most a triangle clipped twice) for Sutherland–Hodgman
/// clipping by half-spaces through the origin.
#[derive(Debug, Default, Clone)]
struct Polygon {
    pts: [DVec3; 8],
    len: usize,
}

impl Polygon {
    fn from(tri: &[DVec3; 3]) -> Polygon {
        let mut p = Polygon::default();
        tri.iter().for_each(|&v| p.push(v));
        p
    }

    fn push(&mut self, v: DVec3) {
        if self.len < self.pts.len() {
            self.pts[self.len] = v;
            self.len += 1;
        }
    }

    fn points(&self) -> &[DVec3] {
        &self.pts[..self.len]
    }

    /// Keeps the part with `p·keep ≥ 0`.
    fn clip(&mut self, keep: DVec3) {
        let n = self.len;
        let mut heights = [0.0; 8];
        for (h, p) in heights.iter_mut().zip(self.points()) {
            *h = p.dot(keep);
        }
        if heights[..n].iter().all(|&h| h >= 0.0) {
            // Nothing to cut: the common case, which need not copy the corners.
            return;
        }
        let src = self.pts;
        self.len = 0;
        for j in 0..n {
            let k = (j + 1) % n;
            let (a, b) = (src[j], src[k]);
            let (da, db) = (heights[j], heights[k]);
            if da >= 0.0 {
                self.push(a);
            }
            if (da >= 0.0) != (db >= 0.0) && n > 1 {
                self.push(a + (b - a) * (da / (da - db)));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::{floor_and_wall, height_field};
    use crate::mesh::LengthUnit;
    use crate::trace::TracerKind;
    use crate::TestRng;
    use std::f64::consts::PI;

    fn build(mesh: &Mesh, azimuths: u32) -> HorizonMap {
        HorizonMap::build(
            mesh,
            mesh.len(),
            &Bvh::build(mesh),
            (azimuths, SunBand::WHOLE),
        )
    }

    #[test]
    fn cells_come_back_as_given_whatever_the_blocks() {
        // Facet counts below, at and past a block, and with a short last block.
        for facets in [1, 15, 16, 17, 37, 64] {
            let a = 8;
            let given: Vec<[u16; 2]> = (0..facets * a)
                .map(|c| [c as u16, (c as u16).wrapping_mul(7)])
                .collect();
            let map = HorizonMap::from_cells((a as u32, MapKind::Bounded), facets, given.clone())
                .unwrap();
            assert_eq!(map.facets(), facets);
            for i in 0..facets {
                for k in 0..a {
                    assert_eq!(
                        map.cell(i, k),
                        given[i * a + k],
                        "{facets} facets: {i}, {k}"
                    );
                }
            }
            assert_eq!(map.rows(0..facets).collect::<Vec<_>>(), given);
            assert_eq!(
                map.rows(3.min(facets)..facets).count(),
                (facets - 3.min(facets)) * a
            );
        }
    }

    /// A floor (two triangles facing +z) and a wall of height `h` along x = `d`: seen
    /// from a floor centroid, the wall's top at azimuth φ (from +x, which is the first
    /// tangent axis for the normal +z) stands at atan(h·cos φ / (d − x)).
    #[test]
    fn a_wall_matches_its_closed_form_in_every_wedge_that_sees_it() {
        let (h, d, half) = (3.0, 4.0, 1e4);
        let m = Mesh::from_raw(floor_and_wall(h, d, half), LengthUnit::M);
        assert_eq!(tangent_frame(DVec3::Z).0, DVec3::X);
        let a = 64;
        let map = build(&m, a);
        let width = TAU / a as f64;
        let quantum = 1.0 / QUANTA_PER_RAD;
        for i in 0..2 {
            let gap = d - m.centroids[i].x;
            let y = m.centroids[i].y;
            for k in 0..a as usize {
                let [upper, centre] = map.wedge(i, k);
                let phi = (k as f64 + 0.5) * width;
                if phi.cos() > 0.05 {
                    let expected = (h * phi.cos() / gap).atan();
                    assert!(
                        (centre - expected).abs() <= quantum,
                        "facet {i} wedge {k}: {centre} vs {expected}"
                    );
                } else if phi.cos() < -0.05 {
                    assert_eq!(centre, 0.0, "facet {i} wedge {k} looks away from the wall");
                }
                // The highest point of the wall within the wedge: at the edge nearer +x
                // (the floor's other triangle is coplanar: nothing of it rises).
                let nearest = [k as f64 * width, (k + 1) as f64 * width]
                    .map(|p| p.cos())
                    .into_iter()
                    .fold(f64::NEG_INFINITY, f64::max);
                let straight = (k as f64 * width..=(k + 1) as f64 * width).contains(&0.0)
                    || k == a as usize - 1;
                let cos_max = if straight { 1.0 } else { nearest };
                if cos_max > 0.05 {
                    let expected = (h * cos_max / gap).atan();
                    assert!(
                        upper >= expected && upper <= expected + 2.0 * quantum,
                        "facet {i} wedge {k}: upper {upper} vs {expected} (y {y})"
                    );
                }
            }
        }
    }

    /// A triangle with a corner exactly on the zenith axis below the viewpoint (it has no
    /// azimuth) and its top edge to the north (+y, azimuth 90°, elevation atan(2/5))
    /// bounds the wedges it rises in, whichever corner comes first. When that corner came
    /// first, it gave the triangle's corners a span of one azimuth, only the wedges at 0°
    /// heard of it, and a Sun 10° up in the north was cleared through it.
    #[test]
    fn a_corner_straight_below_the_viewpoint_leaves_no_wedge_unbounded() {
        let vertices = vec![
            DVec3::new(-0.1, -0.1, 0.0),
            DVec3::new(0.2, -0.1, 0.0),
            DVec3::new(-0.1, 0.2, 0.0),
            DVec3::new(0.0, 0.0, -1.0),
            DVec3::new(1.0, 5.0, 2.0),
            DVec3::new(-1.0, 5.0, 2.0),
        ];
        // The corner on the axis first, second and third.
        for blocker in [[3, 4, 5], [4, 5, 3], [5, 3, 4]] {
            let m = crate::mesh::in_metres(vertices.clone(), vec![[0, 1, 2], blocker]);
            assert_eq!((m.centroids[0], m.normals[0]), (DVec3::ZERO, DVec3::Z));
            let a = 64;
            let map = build(&m, a);
            let north = a as usize / 4;
            let expected = (2.0f64 / 5.0).atan();
            for k in [north - 1, north] {
                let [upper, centre] = map.wedge(0, k);
                assert!(upper >= expected, "{blocker:?} wedge {k}: upper {upper}");
                assert!(
                    (centre - expected).abs() < 0.01,
                    "wedge {k}: centre {centre}"
                );
            }
            // The Sun 10° up in the north is not cleared: the exact tracers call it blocked.
            let sun = DVec3::new(0.0, 10f64.to_radians().cos(), 10f64.to_radians().sin());
            let at = map.position(DVec3::Z, sun, sun.z);
            assert!(!map.clears(0, &at), "{blocker:?}");
            let tracer = crate::trace::build(TracerKind::Grid, &m);
            assert!(tracer.toward(sun).blocked(DVec3::ZERO, 0.0, Some(0)));
        }
    }

    /// A map of centres alone holds the bounded map's centre horizons quantum for
    /// quantum and every upper bound at 90°, its ceilings over the centres alone: never
    /// above the bounded map's, above every centre, and lower somewhere (the upper
    /// bounds were left out of them). For every direction and for a band of Suns.
    #[test]
    fn a_map_of_centres_alone_has_the_bounded_maps_centres() {
        let mut rng = TestRng::new(5);
        let raw = height_field((12, 12), (0.0, 60.0), (0.0, 60.0), |x, y| {
            3.0 * rng.unit() + 0.04 * (x * x + 2.0 * y)
        });
        let m = Mesh::from_raw(raw, LengthUnit::M);
        let bvh = Bvh::build(&m);
        let suns = (0..24).map(|k| {
            let phi = TAU * k as f64 / 24.0;
            DVec3::new(phi.cos(), phi.sin(), 0.5).normalize()
        });
        for band in [SunBand::WHOLE, SunBand::of_suns(suns, 0.0)] {
            let map = |kind| {
                MapParts::new(&m, m.len(), &bvh, (32, band), 64)
                    .of_kind(kind)
                    .whole()
            };
            let (bounded, centres) = (map(MapKind::Bounded), map(MapKind::Centres));
            assert_eq!(centres.kind(), MapKind::Centres);
            let mut lower = 0;
            for i in 0..m.len() {
                let mut top = 0;
                for k in 0..32 {
                    let ([up, mid], [_, expected]) = (centres.cell(i, k), bounded.cell(i, k));
                    assert_eq!(mid, expected, "facet {i} wedge {k}");
                    assert_eq!(up, u16::MAX, "facet {i} wedge {k}");
                    top = top.max(mid);
                }
                let ceiling = centres.ceilings[i];
                assert!(ceiling <= bounded.ceilings[i], "facet {i}");
                assert!(ceiling > (top as f64 / QUANTA_PER_RAD).sin(), "facet {i}");
                lower += usize::from(ceiling < bounded.ceilings[i]);
            }
            assert!(lower > 0, "no ceiling left the upper bounds out");
        }
    }

    /// A random rough height field: every ray the exact tracer calls blocked lies no
    /// higher than its wedge's upper bound; and the centre horizon is where the tracer
    /// changes its answer along the wedge's centre azimuth (a height field's blocked
    /// elevations at one azimuth form one interval, seen from above it).
    #[test]
    fn upper_bounds_hold_and_centres_match_ray_casts_on_a_rough_terrain() {
        let mut rng = TestRng::new(11);
        let raw = height_field((14, 14), (0.0, 70.0), (0.0, 70.0), |x, y| {
            let (i, j) = ((x / 5.0).round(), (y / 5.0).round());
            2.0 * rng.unit() + 0.05 * (i * i + j)
        });
        let m = Mesh::from_raw(raw, LengthUnit::M);
        let a = 32u32;
        let map = build(&m, a);
        let tracer = crate::trace::build(TracerKind::Grid, &m);
        let (mut blocked_rays, mut centres_checked) = (0, 0);
        for i in (0..m.len()).step_by(7) {
            let (c, nrm) = (m.centroids[i], m.normals[i]);
            let (t1, t2) = tangent_frame(nrm);
            let dir =
                |phi: f64, e: f64| (t1 * phi.cos() + t2 * phi.sin()) * e.cos() + nrm * e.sin();
            let blocked = |s: DVec3| tracer.toward(s).blocked(c, 1e-9, Some(i as u32));
            for _ in 0..200 {
                let (phi, e) = (rng.unit() * TAU, rng.unit() * 0.6);
                let s = dir(phi, e);
                if blocked(s) {
                    blocked_rays += 1;
                    let at = map.position(nrm, s, nrm.dot(s));
                    assert!(
                        !map.clears(i, &at),
                        "facet {i}: blocked ray at φ {phi} e {e} cleared"
                    );
                }
            }
            for k in 0..a as usize {
                let phi = (k as f64 + 0.5) * TAU / a as f64;
                let centre = map.wedge(i, k)[1];
                let (lo, hi) = (centre - 2e-3, centre + 2e-3);
                if centre > 3e-3 && centre < 1.2 {
                    centres_checked += 1;
                    assert!(
                        blocked(dir(phi, lo)),
                        "facet {i} wedge {k}: open below the horizon {centre}"
                    );
                    assert!(
                        !blocked(dir(phi, hi)),
                        "facet {i} wedge {k}: blocked above the horizon {centre}"
                    );
                }
            }
        }
        assert!(
            blocked_rays > 100 && centres_checked > 50,
            "{blocked_rays} {centres_checked}"
        );
    }

    #[test]
    fn the_least_of_a_row_is_its_smallest_value_wherever_it_stands() {
        // Every length from empty to three quads and a remainder, the least in each
        // place in turn (a lane's or the remainder's), among values of either sign; and
        // a row of equal values.
        let mut rng = TestRng::new(7);
        for len in 0..15 {
            let row: Vec<f64> = (0..len).map(|_| rng.unit() * 2.0 - 1.0).collect();
            assert_eq!(
                least(&row),
                row.iter().copied().fold(f64::INFINITY, f64::min)
            );
            for k in 0..len {
                let mut lowered = row.clone();
                lowered[k] = -1.5;
                assert_eq!(least(&lowered), -1.5, "length {len}, least at {k}");
            }
        }
        assert_eq!(least(&[0.25; 9]), 0.25);
    }

    #[test]
    fn a_span_holds_every_points_azimuth_and_no_more_and_half_a_turn_is_every_azimuth() {
        let mut rng = TestRng::new(12);
        let (t1, t2) = (DVec3::X, DVec3::Y);
        for case in 0..2000 {
            // Three to eight points within `width` of azimuth around a random start, at
            // random heights and distances; every fourth case across ±π.
            let width = PI * rng.unit() * if case % 2 == 0 { 0.99 } else { 1.6 };
            let start = if case % 4 == 0 {
                PI - 0.5 * width
            } else {
                TAU * rng.unit() - PI
            };
            let count = 3 + (rng.unit() * 6.0) as usize;
            let mut azimuths: Vec<f64> = (0..count).map(|_| start + width * rng.unit()).collect();
            azimuths.push(start + width);
            azimuths.swap(0, count);
            let points: Vec<DVec3> = azimuths
                .iter()
                .map(|&a| {
                    let r = 10f64.powf(3.0 * rng.unit() - 1.0);
                    DVec3::new(r * a.cos(), r * a.sin(), r * (rng.unit() - 0.5))
                })
                .collect();
            // The shortest arc holding them all: from the point after the widest gap
            // between neighbours around the circle to the point before it.
            let mut turns: Vec<f64> = azimuths.iter().map(|a| a.rem_euclid(TAU)).collect();
            turns.sort_by(f64::total_cmp);
            let gap_after = |k: usize| (turns[(k + 1) % turns.len()] - turns[k]).rem_euclid(TAU);
            let widest = (0..turns.len())
                .max_by(|&a, &b| gap_after(a).total_cmp(&gap_after(b)))
                .unwrap();
            let least = turns[(widest + 1) % turns.len()];
            let most = least + (TAU - gap_after(widest));
            match Span::of(&points, t1, t2) {
                Span::All => assert!(most - least > PI - 1e-9, "{width} spanned as all"),
                Span::Range(lo, hi) => {
                    assert!(most - least < PI + 1e-9, "{width} spanned as a range");
                    assert!(hi - lo >= 0.0 && hi - lo < 2.0);
                    // The same span, its ends as angles, up to whole turns.
                    let (lo_angle, hi_angle) = (azimuth_of_turn(lo), azimuth_of_turn(hi));
                    let shift = TAU * ((least - lo_angle) / TAU).round();
                    let widening = 1e-9;
                    assert!(
                        (lo_angle + shift - least).abs() < widening,
                        "{lo_angle} against {least}"
                    );
                    let most = most - shift;
                    assert!(
                        (hi_angle - most).abs() < widening,
                        "{hi_angle} against {most}"
                    );
                    for &a in &azimuths {
                        let turn = turn_of((a.cos(), a.sin()));
                        assert!(Span::Range(lo - 1e-12, hi + 1e-12).holds(turn));
                    }
                }
            }
        }
    }

    /// The azimuth (radians, unbounded) of a turn as the span's docs define it: in each
    /// quarter `q`, the turn `q + f` points along `(1 − f, f)` turned by `q` right angles.
    fn azimuth_of_turn(t: f64) -> f64 {
        let q = t.floor();
        let f = t - q;
        q * FRAC_PI_2 + f.atan2(1.0 - f)
    }

    #[test]
    fn every_azimuth_falls_in_its_wedge_and_a_span_meets_the_wedges_it_reaches() {
        // Against angles from libm: azimuths at random, on and a hair off every wedge's
        // edge and centre, for several wedge counts.
        let mut rng = TestRng::new(13);
        for count in [8usize, 9, 64, 128, 1000, 4096] {
            let wedges = Wedges::new(count);
            let width = TAU / count as f64;
            let mut azimuths: Vec<f64> = (0..2000).map(|_| TAU * rng.unit()).collect();
            for k in 0..count {
                for at in [0.0, 0.5] {
                    for off in [-1e-7, 1e-7] {
                        azimuths.push(width * (k as f64 + at) + off);
                    }
                }
            }
            for &a in azimuths.iter().filter(|a| (0.0..TAU).contains(*a)) {
                let (k, centre) = wedges.wedge_at(turn_of((a.cos(), a.sin())));
                assert_eq!(k, (a / width) as usize, "{a} of {count} wedges");
                let centre = azimuth_of_turn(centre);
                assert!(
                    (centre - width * (k as f64 + 0.5)).abs() < 1e-12,
                    "{centre}"
                );
            }
            // Spans from a random start, up to almost half a turn wide: the first and the
            // last wedge and their centres as the angles say.
            for _ in 0..500 {
                let (lo, hi) = (TAU * rng.unit(), 3.1 * rng.unit());
                let hi = lo + hi;
                let span = Span::Range(turn_of((lo.cos(), lo.sin())), {
                    let t = turn_of((hi.cos(), hi.sin()));
                    if hi >= TAU {
                        t + 4.0
                    } else {
                        t
                    }
                });
                let met = wedges.met(span);
                let (first, last) = ((lo / width) as usize, (hi / width) as usize);
                assert_eq!(
                    (met.first, met.len),
                    (first, last - first + 1),
                    "{lo}..{hi}"
                );
                let centre = |k: usize| width * (k as f64 + 0.5);
                assert_eq!(met.ends_held, (lo <= centre(first), centre(last) <= hi));
            }
        }
    }
}
