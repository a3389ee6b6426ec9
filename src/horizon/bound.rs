//! Horizon bound: per facet (and, in detail, per sector of azimuth), the highest
//! elevation at which its centroid sees any other facet of its body, so that a Sun above
//! it needs no shadow ray.
//!
//! In: a mesh (metres, body frame), its [`Bvh`] and a [`BoundDetail`]. Out:
//! [`HorizonBound`]: per facet, the sine of the largest elevation above the facet's plane
//! of any point of any other facet with an area, seen from the facet's centroid (0 when
//! nothing rises above the plane); by sectors, one such sine per each of [`SECTORS`]
//! sectors of azimuth (in the facet's tangent frame, [`tangent_frame`]) over the points
//! whose azimuth lies in it. A shadow ray leaves the centroid at the Sun's azimuth and
//! elevation (`sin e = n·s`); when that is above the bound of its sector, every point
//! the ray passes lies higher than anything of the body in that direction, so no facet
//! can block it, and [`HorizonBound::clears`] answers without tracing. The answer is then
//! the exact tracers' answer, not an approximation: on a convex patch of a surface
//! nothing rises above the facet's plane, and by sectors a crater wall to the east says
//! nothing of a Sun in the west.
//!
//! The bound is computed exactly (`super::geometry`) for every triangle the tree cannot
//! rule out, each triangle widened by the rounding of the exact predicate (a few units
//! in the last place of the mesh's coordinates, `ROUNDING_ULPS · ε · |v|max`), so that
//! a ray the tracers call blocked through rounding is never cleared. By sectors, a
//! triangle counts in the sectors its widened box reaches (widened again past the
//! rounding of the turns), in each with the highest point of its part there, found from
//! its outline (`super::outline`, the maps' own) over the sector widened by the turn the
//! widening can give a point; where the outline is ill conditioned (a corner near the
//! zenith line), with its highest point anywhere. An upper bound in each sector either
//! way; the first keeps a neighbouring facet, which spans half the sectors but rises in
//! few, from holding them all to its top (17 % fewer rays at 49k facets). The
//! branch and bound stops refining within a slack (0.02 in sine, about 1°, for a whole
//! bound; 0.01 by sectors, whose rays are worth more to spare) of each sector's highest
//! horizon, which it adds to the bound: a Sun less than that above the horizon is
//! simply traced.
//!
//! Cost: a tree search per facet, parallel over facets, each seeded with the triangles
//! that set its neighbour's sectors; by sectors 5–8× a whole bound's (every sector's
//! horizon proved, not only the highest; docs/performance.md), most of it finding the
//! sectors that boxes and triangles reach, which each box hands on to the boxes below
//! it (theirs lie within its own), so that they are asked only where that decides
//! something. Kept on disk beside the horizon maps and read back by later runs
//! (`super::cache`). Memory: a byte per facet, [`SECTORS`] bytes by sectors (each sine
//! rounded up to a 255th).

use super::geometry::{
    distance_to_triangle, may_rise_above, pseudo_angle, rounding_widening, tangent_frame,
    triangle_bound,
};
use super::map::{in_seeded_runs, ZenithLine};
use super::outline::{turned_outward, Outline};
use crate::mesh::inspect::NO_NEIGHBOUR;
use crate::mesh::Mesh;
use crate::trace::bvh::Bvh;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;

/// How far above the highest horizon found a whole bound may lie (sine): the search
/// skips whatever cannot rise more than this above it, which keeps it to the few hundred
/// triangles near each facet and the far ones that form its horizon.
const WHOLE_SLACK: f64 = 0.02;

/// The same for each sector of a bound by sectors: half the whole one's, for a build
/// about a third dearer (its rays, mostly below a real horizon, are worth sparing).
const SECTOR_SLACK: f64 = 0.01;

/// Least gap between the Sun's `sin e` and the bound for a ray to be cleared, over and
/// above the widened triangles: the rounding of `n·s` itself.
const SIN_MARGIN: f64 = 1e-9;

/// How finely a bound follows the horizon around a facet (in `run.json`: "whole" or
/// "sectors").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BoundDetail {
    /// One bound for the whole horizon (every sector holds the highest): cheap to build,
    /// about a tenth of [`BoundDetail::Sectors`].
    #[default]
    Whole,
    /// A bound per sector of azimuth: spares the rays of a Sun low in a sector whose
    /// horizon is lower than the facet's highest, for a search that proves each
    /// sector's horizon.
    Sectors,
}

impl BoundDetail {
    /// How far above each horizon found the bound may lie (sine).
    fn slack(self) -> f64 {
        match self {
            BoundDetail::Whole => WHOLE_SLACK,
            BoundDetail::Sectors => SECTOR_SLACK,
        }
    }

    /// Sines kept per facet.
    pub fn stride(self) -> usize {
        match self {
            BoundDetail::Whole => 1,
            BoundDetail::Sectors => SECTORS,
        }
    }
}

/// Sectors of azimuth a bound keeps apart. A direction's azimuth in the facet's tangent
/// frame is taken as its turn: a pseudo-angle (`geometry::pseudo_angle`, without
/// `atan2`) from 0 to 4, a quarter turn per unit, monotone in azimuth and exact at every
/// eighth of a turn. Sector `k` holds the turns `[k, k+1) · 4/SECTORS`: with 16, sectors
/// 18.4° to 26.6° wide, so that a Sun low in one sector is not held to the horizon of
/// another.
pub const SECTORS: usize = 16;

/// Sectors per unit of turn.
const SECTORS_PER_TURN: f64 = SECTORS as f64 / 4.0;

/// Every sector, as bits.
const ALL_SECTORS: u32 = u32::MAX >> (32 - SECTORS);

/// How far (units of turn) the sectors a box reaches are widened on both sides: far more
/// than the rounding of a turn of a direction at least `ZENITH_CLEARANCE` off the zenith.
const TURN_OVERLAP: f64 = 1e-9;

/// Least sine of the angle from the zenith line at which a direction's azimuth is taken:
/// nearer, a box reaches every sector and a Sun is held to the highest (the azimuth of a
/// direction `ε` off the zenith errs by about `1e-16/ε`).
const ZENITH_CLEARANCE: f64 = 1e-6;

/// Steps of a stored sine: each sector's sine is rounded up to a multiple of 1/255.
const SINE_STEPS: f64 = 255.0;

/// The sine each stored byte stands for, `q / 255`: divided once here, where the
/// lighting pass would divide at every facet facing the Sun (a quarter of
/// [`HorizonBound::clears`]' time in a profile).
const STEP_SINES: [f64; 256] = {
    let mut sines = [0.0; 256];
    let mut q = 0;
    while q < 256 {
        sines[q] = q as f64 / SINE_STEPS;
        q += 1;
    }
    sines
};

/// Per facet (and sector, in [`BoundDetail::Sectors`]), the sine of the highest elevation
/// of any other facet seen from its centroid.
#[derive(Debug, Clone)]
pub struct HorizonBound {
    /// Per facet, one sine ([`BoundDetail::Whole`]) or one per sector, each rounded up to
    /// a multiple of 1/255: a byte, and the bound stays a bound (the search leaves it up
    /// to its slack high anyway).
    sines: Vec<u8>,
    /// How far triangles are widened against the exact predicate's rounding (m).
    widening: f64,
    detail: BoundDetail,
}

/// A cone of directions (a disk Sun's): its unit axis and its half-angle's cosine, sine
/// and tangent, taken once for every facet that looks at it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cone {
    axis: DVec3,
    cos_half: f64,
    sin_half: f64,
    tan_half: f64,
}

impl Cone {
    /// The directions within `half_angle` (radians) of the unit `axis`.
    pub fn new(axis: DVec3, half_angle: f64) -> Cone {
        Cone {
            axis,
            cos_half: half_angle.cos(),
            sin_half: half_angle.sin(),
            tan_half: half_angle.tan(),
        }
    }
}

/// A triangle seen from a point as a screen for rays: the planes through the point and
/// each edge, the triangle's distance, and the margin past the rounding of the ray
/// predicate. [`HorizonBound::cone_view`]'s test of a cover, for a cone of no width,
/// set up once for the many directions it is then asked about ([`Screen::blocks`]).
#[derive(Debug, Clone, Copy)]
pub struct Screen {
    /// Unit directions from the point toward the corners.
    corners: [DVec3; 3],
    /// Unit normals of the planes through the point and each edge, toward the inside.
    inward: [DVec3; 3],
    /// The nearest distance (metres) past which the triangle blocks, and the sine by
    /// which a direction must lie inside every edge's plane.
    beyond: f64,
    spare: f64,
}

impl Screen {
    /// Whether the ray along the unit `dir` from the point, counting hits farther than
    /// `t_min` metres, is blocked by the triangle for the tracers' exact predicate: it
    /// passes inside every edge by more than the rounding can move it, and the triangle
    /// lies wholly beyond `t_min`. (False says nothing: the ray is then traced.)
    #[inline]
    pub fn blocks(&self, dir: DVec3, t_min: f64) -> bool {
        self.beyond > t_min
            && self.corners.iter().all(|u| dir.dot(*u) > 0.0)
            && self.inward.iter().all(|m| dir.dot(*m) > self.spare)
    }
}

/// What a facet's centroid sees of a narrow cone of directions (a disk Sun).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConeView {
    /// No other facet reaches into the cone: every ray within it is clear.
    Clear,
    /// One facet (`Some`, its mesh id) or a pair sharing an edge (`None`) covers the
    /// whole cone beyond the distance asked for: every ray within it is blocked.
    Covered(Option<u32>),
    /// Anything else: facets reach in without one covering it all. They are every facet
    /// a ray within the cone can cross (as the tracers' predicate decides, rounding
    /// included), which can then answer it alone (`BvhRays::blocked_among`).
    Partial(Vec<u32>),
}

impl HorizonBound {
    /// The bound of facets `0..receivers` of `mesh`, using `bvh` (built over all of
    /// `mesh`, whose other facets only cast shadows), in the given `detail`.
    pub fn new(mesh: &Mesh, receivers: usize, bvh: &Bvh, detail: BoundDetail) -> HorizonBound {
        // Each facet is seeded with the triangles that set its neighbour's sectors: they
        // are likely high here too, and the higher the first values, the more of the
        // tree the search prunes.
        let widening = rounding_widening(mesh);
        let search = |i, seeds: &Setters| facet_bound(mesh, bvh, (i, detail), widening, seeds);
        let sines = match detail {
            // Every sector holds the same: one byte per facet.
            BoundDetail::Whole => in_seeded_runs(0..receivers, |i, seeds: &Setters| {
                let (sines, setters) = search(i, seeds);
                (sine_step_up(sines[0]), setters)
            }),
            BoundDetail::Sectors => in_seeded_runs(0..receivers, |i, seeds: &Setters| {
                let (sines, setters) = search(i, seeds);
                (sines.map(sine_step_up), setters)
            })
            .into_flattened(),
        };
        HorizonBound {
            sines,
            widening,
            detail,
        }
    }

    /// The bound of `mesh`'s first facets from their stored sines (the cache: a byte per
    /// facet and sector of `detail`), as [`HorizonBound::new`] built them over the same
    /// mesh.
    pub(super) fn from_sines(mesh: &Mesh, sines: Vec<u8>, detail: BoundDetail) -> HorizonBound {
        HorizonBound {
            sines,
            widening: rounding_widening(mesh),
            detail,
        }
    }

    /// The sines kept, in 255ths (for the cache): per facet, [`BoundDetail::stride`] bytes.
    pub(super) fn sines(&self) -> &[u8] {
        &self.sines
    }

    /// How finely the bound follows the horizon.
    pub fn detail(&self) -> BoundDetail {
        self.detail
    }

    /// The facets of `mesh` other than `i` reaching into the `cone` of directions from
    /// facet `i`'s centroid (every facet a ray within it can cross, as the tracers'
    /// predicate decides, rounding included), or `None` when more than `most` do: then
    /// the rays within it are better traced. Empty: every ray within it is clear.
    pub fn reaching(
        &self,
        mesh: &Mesh,
        bvh: &Bvh,
        i: usize,
        cone: &Cone,
        most: usize,
    ) -> Option<Vec<u32>> {
        let mut reaching = Vec::new();
        self.each_reaching(mesh, bvh, i, cone, |id, _| {
            reaching.push(id);
            reaching.len() > most
        });
        (reaching.len() <= most).then_some(reaching)
    }

    /// Each facet of `mesh` but `i` that reaches into `cone` from facet `i`'s centroid,
    /// with its corners, to `visit`, until it returns `true`.
    fn each_reaching(
        &self,
        mesh: &Mesh,
        bvh: &Bvh,
        i: usize,
        cone: &Cone,
        mut visit: impl FnMut(u32, &[DVec3; 3]) -> bool,
    ) {
        let reaches = self.reaches(mesh, i, cone);
        // The tree's boxes are padded far beyond the widening (`Bvh`'s box margin).
        bvh.near_cone(mesh.centroids[i], cone.axis, cone.tan_half, |id, tri| {
            reaches(id, tri) && visit(id, tri)
        });
    }

    /// Whether a facet (its id and corners) other than `i` reaches into `cone` from facet
    /// `i`'s centroid, widened by the rounding of the ray predicate.
    fn reaches(&self, mesh: &Mesh, i: usize, cone: &Cone) -> impl Fn(u32, &[DVec3; 3]) -> bool {
        let Cone {
            axis,
            cos_half,
            tan_half,
            ..
        } = *cone;
        let c = mesh.centroids[i];
        // Across the axis, toward the facet's plane: where its neighbours lie.
        let n = mesh.normals[i];
        let down = -(n - axis * n.dot(axis)).normalize_or_zero();
        let widening = self.widening;
        // A triangle's elevation sine above the plane across `axis` is the cosine of its
        // least angle from `axis`: what the bound's geometry computes exactly.
        move |id, tri| {
            id as usize != i
                && may_reach_cone(c, (axis, tan_half), down, tri, widening)
                && triangle_bound(c, axis, tri, widening, cos_half) > cos_half
        }
    }

    /// What facet `i`'s centroid sees of the `cone` of directions, through the other
    /// facets of `mesh` (the one `bvh` and the bound were built over):
    /// [`ConeView::Covered`] only by a facet farther than `beyond` metres. Exact up to the
    /// rounding of the ray predicate, which every triangle is widened by (so a clear cone
    /// is clear, a covered one covered, for the tracers' rays).
    pub fn cone_view(
        &self,
        mesh: &Mesh,
        bvh: &Bvh,
        i: usize,
        cone: &Cone,
        beyond: f64,
    ) -> ConeView {
        self.view_of(mesh, (i, cone, beyond), |visit| {
            self.each_reaching(mesh, bvh, i, cone, visit)
        })
    }

    /// [`HorizonBound::cone_view`] from the facets `among` alone, without the tree: the
    /// same view when `among` holds every facet reaching into `cone` (as the facets
    /// [`HorizonBound::reaching`] finds for a wider cone holding it do). Fewer can still
    /// show the cone covered (the facet that covered it a step before).
    pub fn cone_view_among(
        &self,
        mesh: &Mesh,
        (i, cone, beyond): (usize, &Cone, f64),
        among: &[u32],
    ) -> ConeView {
        let reaches = self.reaches(mesh, i, cone);
        self.view_of(mesh, (i, cone, beyond), |visit| {
            for &id in among {
                let tri = mesh.corners(id as usize);
                if reaches(id, &tri) && visit(id, &tri) {
                    break;
                }
            }
        })
    }

    /// [`HorizonBound::cone_view`] over the facets reaching into the cone that
    /// `each_reaching` hands to its visitor (until the visitor returns `true`).
    fn view_of(
        &self,
        mesh: &Mesh,
        (i, cone, beyond): (usize, &Cone, f64),
        each_reaching: impl FnOnce(&mut dyn FnMut(u32, &[DVec3; 3]) -> bool),
    ) -> ConeView {
        let Cone { axis, sin_half, .. } = *cone;
        let c = mesh.centroids[i];
        // The plane tests first, with no spare (a cover with one is a cover without), so
        // that the distance is taken only for the few outlines that pass them.
        let cover = |pieces: &[&[DVec3; 3]], outline: &[DVec3]| {
            covers(c, (axis, sin_half), outline, 0.0) && {
                let gap = pieces
                    .iter()
                    .map(|t| distance_to_triangle(c, t))
                    .fold(f64::INFINITY, f64::min);
                gap - self.widening > beyond
                    && covers(
                        c,
                        (axis, sin_half),
                        outline,
                        self.widening / (gap - self.widening),
                    )
            }
        };
        // The mesh ids of the triangles reaching into the cone, and the one covering it.
        let mut reaching = Vec::new();
        let mut covered_by = None;
        each_reaching(&mut |id, tri| {
            reaching.push(id);
            covered_by = cover(&[tri], tri).then_some(id);
            covered_by.is_some()
        });
        if covered_by.is_some() {
            return ConeView::Covered(covered_by);
        }
        if reaching.is_empty() {
            return ConeView::Clear;
        }
        // Two triangles sharing an edge that crosses the cone cover it together when,
        // seen from the centroid, they make a convex quadrilateral around it.
        let corners = |id: &u32| mesh.corners(*id as usize);
        let paired = reaching.len() <= PAIRED_MAX
            && reaching.iter().enumerate().any(|(k, a)| {
                let a = corners(a);
                reaching[k + 1..].iter().map(corners).any(|b| {
                    quadrilateral(&a, &b).is_some_and(|outline| cover(&[&a, &b], &outline))
                })
            });
        match paired {
            true => ConeView::Covered(None),
            false => ConeView::Partial(reaching),
        }
    }

    /// Facet `id` of `mesh` as a screen seen from facet `i`'s centroid ([`Screen`]);
    /// `None` where it is seen edge-on, or nearer than the rounding.
    pub fn screen(&self, mesh: &Mesh, i: usize, id: u32) -> Option<Screen> {
        let c = mesh.centroids[i];
        let tri = mesh.corners(id as usize);
        let gap = distance_to_triangle(c, &tri) - self.widening;
        let (directions, orientation) = seen_outline(c, &tri).filter(|_| gap > 0.0)?;
        let u = &directions[..3];
        Some(Screen {
            corners: [u[0], u[1], u[2]],
            inward: [0, 1, 2].map(|j| inward(u, j, orientation)),
            beyond: gap,
            spare: self.widening / gap,
        })
    }

    /// The distance (metres, less the rounding) past which a patch of facets joined
    /// across their edges to facet `seed` covers the whole `cone` seen from facet `i`'s
    /// centroid (`neighbours`: each facet's neighbour across each edge,
    /// [`crate::mesh::inspect::edge_neighbours`]); `None` when that is not shown with at
    /// most `most` facets.
    ///
    /// The patch grows from `seed` across every edge that comes into the cone (rounding
    /// included), so that every edge where it ends lies outside the cone. Seen from the
    /// centroid, the patch's outline can then cross the cone only at a fold: an edge
    /// whose two facets lie on one side of the plane through the centroid and the edge.
    /// Where no fold comes into the cone either, the patch covers all of the cone or
    /// none of it, and all of it when the axis lies inside one of its facets. A ray
    /// within the cone then crosses a facet of the patch by the tracers' predicate too,
    /// which gives two facets sharing an edge exactly opposite edge values
    /// (`crate::trace::ray`), so that no ray slips between them. An edge into the cone
    /// on the mesh's rim, or on facet `i` (whose rays leave it out), ends the search.
    pub fn patch_cover(
        &self,
        mesh: &Mesh,
        neighbours: &[[u32; 3]],
        (i, cone): (usize, &Cone),
        seed: u32,
        most: usize,
    ) -> Option<f64> {
        let c = mesh.centroids[i];
        // The facet's own edges lie in its plane.
        if mesh.normals[i].dot(cone.axis) <= cone.sin_half + SIN_MARGIN {
            return None;
        }
        let mut patch = Vec::with_capacity(most);
        let mut gap = f64::INFINITY;
        let mut join = |id: u32, patch: &mut Vec<(u32, f64)>| {
            let beyond = distance_to_triangle(c, &mesh.corners(id as usize)) - self.widening;
            // A facet of no area is left out by the tracers: it would leave a gap.
            let joins = patch.len() < most && beyond > 0.0 && mesh.areas[id as usize] > 0.0;
            gap = gap.min(beyond);
            patch.push((id, beyond));
            joins
        };
        if !join(seed, &mut patch) {
            return None;
        }
        let mut next = 0;
        while let Some(&(m, beyond)) = patch.get(next) {
            next += 1;
            let tri = mesh.corners(m as usize);
            // The rounding, as an angle seen from the centroid (a sine).
            let spare = self.widening / beyond;
            for (k, &across) in neighbours[m as usize].iter().enumerate() {
                let edge = (tri[k], tri[(k + 1) % 3]);
                let member = patch.iter().find(|(id, _)| *id == across).copied();
                let holds = match member {
                    // Two facets of the patch: an edge, unless they fold over it.
                    Some((_, other)) => {
                        let far = |p: &&DVec3| **p != edge.0 && **p != edge.1;
                        let x = mesh.corners(across as usize).iter().find(far).copied();
                        x.is_some_and(|x| opposite_sides(c, edge, tri[(k + 2) % 3], x))
                            || edge_clear_of_cone(c, edge, cone, spare.max(self.widening / other))
                    }
                    None if edge_clear_of_cone(c, edge, cone, spare) => true,
                    // The edge comes into the cone: the facet across must join.
                    None => {
                        across != NO_NEIGHBOUR && across as usize != i && join(across, &mut patch)
                    }
                };
                if !holds {
                    return None;
                }
            }
        }
        let covered = (patch.iter()).any(|&(m, beyond)| {
            covers(
                c,
                (cone.axis, 0.0),
                &mesh.corners(m as usize),
                self.widening / beyond,
            )
        });
        covered.then_some(gap)
    }

    /// True when a Sun along the unit vector `sun`, at `sin_elevation` (n·s) above the
    /// plane of facet `i` (unit normal `normal`, the mesh's), is higher than everything
    /// else of the body seen from its centroid at the Sun's azimuth: its shadow ray is
    /// unblocked.
    #[inline]
    pub fn clears(&self, i: usize, normal: DVec3, sun: DVec3, sin_elevation: f64) -> bool {
        let sector = match self.detail {
            BoundDetail::Whole => Some(0),
            BoundDetail::Sectors => sector_of(normal, sun),
        };
        match sector {
            Some(k) => sin_elevation > self.sector_sin(i, k) + SIN_MARGIN,
            None => self.clears_all_around(i, sin_elevation),
        }
    }

    /// True when a Sun at `sin_elevation` above facet `i`'s plane is higher than
    /// everything else of the body seen from its centroid, whatever its azimuth (for a
    /// disk, whose points lie in several sectors).
    #[inline]
    pub fn clears_all_around(&self, i: usize, sin_elevation: f64) -> bool {
        sin_elevation > self.sin_max(i) + SIN_MARGIN
    }

    /// Facet `i`'s bound around the whole horizon: the sine of the highest elevation
    /// (for tests and reports).
    pub fn sin_max(&self, i: usize) -> f64 {
        let stride = self.detail.stride();
        let row = &self.sines[i * stride..(i + 1) * stride];
        STEP_SINES[usize::from(row.iter().copied().max().unwrap_or(u8::MAX))]
    }

    /// Facet `i`'s bound in `sector` (0..[`SECTORS`]), a sine.
    #[inline]
    pub fn sector_sin(&self, i: usize, sector: usize) -> f64 {
        let at = match self.detail {
            BoundDetail::Whole => i,
            BoundDetail::Sectors => i * SECTORS + sector,
        };
        STEP_SINES[usize::from(self.sines[at])]
    }
}

/// The sector of azimuth that the unit vector `toward` lies in, in the tangent frame of
/// the unit `normal`; `None` within `ZENITH_CLEARANCE` (1e-6) of the zenith or the nadir,
/// where its azimuth is not known well enough.
#[inline]
pub fn sector_of(normal: DVec3, toward: DVec3) -> Option<usize> {
    let (t1, t2) = tangent_frame(normal);
    let (x, y) = (toward.dot(t1), toward.dot(t2));
    if x * x + y * y < ZENITH_CLEARANCE * ZENITH_CLEARANCE {
        return None;
    }
    Some(sector_in_plane(x, y))
}

/// The sector of the in-plane direction `(x, y)` (not zero): that of its turn, found by
/// comparisons instead of the turn's division (the lighting pass asks it of every facet
/// facing the Sun at every step). Within a quadrant the sectors' boundaries are the
/// directions a quarter of a turn's unit apart: `y = x/3`, `y = x`, `y = 3x` in the first
/// (pseudo-angle `y/(x+y)` of 1/4, 1/2, 3/4), alike in the others; a direction on a
/// boundary belongs to the sector above it, as by its turn. Rounding may put a direction
/// within a few units in the last place of a boundary on its other side: far inside the
/// overlap by which the build widens each sector (`TURN_OVERLAP`).
#[inline]
fn sector_in_plane(x: f64, y: f64) -> usize {
    const _: () = assert!(SECTORS == 16, "four sectors per quadrant");
    let (a, b) = (x.abs(), y.abs());
    let count = |tests: [bool; 4]| tests.into_iter().map(usize::from).sum::<usize>();
    match (x >= 0.0, y >= 0.0) {
        // Turns 0 to 1 (1 on the axis x = 0).
        (true, true) => count([3.0 * y >= x, y >= x, y >= 3.0 * x, x == 0.0]),
        // Turns 1 to 2, falling as y rises (2 on the axis y = 0).
        (false, true) => 8 - count([y > 0.0, 3.0 * y > a, y > a, y > 3.0 * a]),
        // Turns 2 to 3.
        (false, false) => 8 + count([3.0 * b >= a, b >= a, b >= 3.0 * a, false]),
        // Turns 3 to 4 (3 on the axis x = 0).
        (true, false) => 12 + count([b <= 3.0 * x, b <= x, 3.0 * b <= x, false]),
    }
}

/// The turn of the in-plane direction `(x, y)`: its pseudo-angle from 0 to 4.
#[inline]
fn turn(xy: (f64, f64)) -> f64 {
    let p = pseudo_angle(xy);
    if p < 0.0 {
        p + 4.0
    } else {
        p
    }
}

/// The sectors (as bits) reached by the points of the box `lo..hi` widened by `widening`,
/// seen from the viewpoint of `zenith` in the frame of its zenith `n` and the tangent
/// axes `(t1, t2)`: every sector when the zenith line meets the box or passes near a
/// corner; otherwise those between the corners' least and greatest turns (a box off the
/// zenith line spans less than half a turn, and every point of it lies between its
/// corners).
fn sectors_reached(
    zenith: &ZenithLine,
    (t1, t2): (DVec3, DVec3),
    (lo, hi): (DVec3, DVec3),
    widening: f64,
) -> u32 {
    let (lo, hi) = (lo - widening, hi + widening);
    if zenith.meets_box(lo, hi) {
        return ALL_SECTORS;
    }
    let (c, n) = zenith.point_and_zenith();
    // A corner's coordinates in the frame are the lowest corner's plus, per axis, the
    // box's extent along the axis seen in the frame: additions, not products. (Written
    // out: an array's `map` here was left a call of its own in some builds, 13 % of a
    // bound's build.)
    let v = lo - c;
    let base = DVec3::new(v.dot(t1), v.dot(t2), v.dot(n));
    let size = hi - lo;
    let steps = [
        DVec3::new(t1.x, t2.x, n.x) * size.x,
        DVec3::new(t1.y, t2.y, n.y) * size.y,
        DVec3::new(t1.z, t2.z, n.z) * size.z,
    ];
    let mut turns = [0.0; 8];
    for (k, t) in turns.iter_mut().enumerate() {
        let mut p = base;
        for (a, step) in steps.iter().enumerate() {
            if k >> a & 1 == 1 {
                p += *step;
            }
        }
        let across = p.x * p.x + p.y * p.y;
        // The sums' rounding is a few units in the last place of the box's size and
        // distance, far below the clearance asked of the corners.
        if across <= ZENITH_CLEARANCE * ZENITH_CLEARANCE * (across + p.z * p.z) {
            return ALL_SECTORS;
        }
        *t = turn((p.x, p.y));
    }
    let extremes = |turns: &[f64; 8]| {
        turns
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| {
                (lo.min(t), hi.max(t))
            })
    };
    let (mut first, mut last) = extremes(&turns);
    if last - first >= 2.0 {
        // Across turn 0: the low turns one turn on.
        (first, last) = extremes(&turns.map(|t| if t < 2.0 { t + 4.0 } else { t }));
    }
    if last - first >= 2.0 - 2.0 * TURN_OVERLAP {
        return ALL_SECTORS;
    }
    // A turn on, so that the widened turns stay positive and truncation floors them.
    let sector = |t: f64| ((t + 4.0) * SECTORS_PER_TURN) as usize;
    let (from, to) = (sector(first - TURN_OVERLAP), sector(last + TURN_OVERLAP));
    (from..=to).fold(0, |bits, k| bits | 1 << (k % SECTORS))
}

/// A sine rounded up to the next 255th (1 when NaN: never cleared).
fn sine_step_up(sin: f64) -> u8 {
    if sin.is_nan() {
        return u8::MAX;
    }
    let q = (sin.clamp(0.0, 1.0) * SINE_STEPS).ceil();
    // The product's rounding may leave `q` one step short.
    let q = if q / SINE_STEPS < sin { q + 1.0 } else { q };
    q.min(SINE_STEPS) as u8
}

/// Facet `i`'s bound per sector (sines; in `detail`: a whole bound in sector 0 alone),
/// and the triangle that set each sector (none where nothing rose above the plane). The
/// `seeds` (a neighbour's setters) are taken first.
fn facet_bound(
    mesh: &Mesh,
    bvh: &Bvh,
    (i, detail): (usize, BoundDetail),
    widening: f64,
    seeds: &Setters,
) -> ([f64; SECTORS], Setters) {
    let (c, n) = (mesh.centroids[i], mesh.normals[i]);
    if n == DVec3::ZERO || mesh.areas[i] <= 0.0 {
        return ([1.0; SECTORS], Setters::default());
    }
    let tangents = tangent_frame(n);
    let zenith = ZenithLine::new(c, n);
    let slack = detail.slack();
    let found = RefCell::new(SectorSines::new(detail.stride()));
    let reached = |lo: DVec3, hi: DVec3| match detail {
        // A whole bound keeps its horizon in sector 0 alone, which every box reaches.
        BoundDetail::Whole => 1,
        BoundDetail::Sectors => sectors_reached(&zenith, tangents, (lo, hi), widening),
    };
    // The search hands each box's sectors on to its children, whose sectors lie within
    // them: from the root, every sector, until a box's own are asked.
    let take = |id: u32, tri: &[DVec3; 3], around: u32| {
        // Below every sector's sine (and its slack) by its cheap bound, the triangle
        // raises none: the sectors it reaches, which cost more, are not asked.
        let lowest = found.borrow().lowest();
        if id as usize == i || !may_rise_above(c, n, tri, widening, lowest + slack) {
            return;
        }
        // The sectors first (additions and a division per corner): the lowest of those
        // the triangle reaches rules most triangles out before their exact bound. Under a
        // box that reaches one sector, the triangle lies in it.
        let sectors = match around.count_ones() {
            1 => around,
            _ => reached(
                tri[0].min(tri[1]).min(tri[2]),
                tri[0].max(tri[1]).max(tri[2]),
            ),
        };
        let lowest = found.borrow().lowest_of(sectors);
        let value = triangle_bound(c, n, tri, widening, lowest + slack);
        if value > lowest {
            let mut found = found.borrow_mut();
            if sectors.count_ones() == 1 {
                found.raise(sectors, value, id);
            } else {
                let view = FacetFrame { c, n, tangents };
                raise_by_sector(&mut found, &view, (id, tri), (sectors, value), widening);
            }
        }
    };
    for id in seeds.distinct() {
        take(id, &mesh.corners(id as usize), ALL_SECTORS);
    }
    bvh.search(
        &bvh.viewpoint(c, n, widening),
        ALL_SECTORS,
        |child, around| {
            let found = found.borrow();
            let bound = child.bound;
            if bound > found.highest + slack {
                return Some((bound, around));
            }
            // Where the parent's sectors are all below the bound, or none is (the bound
            // is no higher than every sector's sine and slack), the box's own (a part of
            // them) need not be asked.
            let below = found.below(bound - slack);
            if around & below == 0 {
                return None;
            }
            if around & !below == 0 {
                return Some((bound, around));
            }
            let (lo, hi) = child.corners();
            let sectors = reached(lo, hi);
            (sectors & below != 0).then_some((bound, sectors))
        },
        take,
    );
    let found = found.into_inner();
    (found.sines.map(|s| (s + slack).min(1.0)), found.setters)
}

/// A facet's centroid with its zenith and tangent axes.
struct FacetFrame {
    c: DVec3,
    n: DVec3,
    tangents: (DVec3, DVec3),
}

/// How far (radians) each sector's bounding azimuths are turned outward when a
/// triangle's part in it is found: far more than the rounding of the Sun's sector
/// (`sector_in_plane`) and of the outline's turns.
const SECTOR_EDGE_OVERLAP: f64 = 1e-8;

/// Raises each of `sectors` whose sine is below `value` (triangle `tri`'s bound over
/// all of them, widened) to the bound of the triangle's part in that sector alone: a
/// triangle beside the facet spans many sectors but rises high in few. Where its
/// outline is ill conditioned, or the widening may turn azimuths by more than 1e-3 rad
/// (near the zenith, or a triangle touching the centroid), every sector takes `value`.
fn raise_by_sector(
    found: &mut SectorSines,
    view: &FacetFrame,
    (id, tri): (u32, &[DVec3; 3]),
    (sectors, value): (u32, f64),
    widening: f64,
) {
    let (t1, t2) = view.tangents;
    let rel = tri.map(|p| p - view.c);
    // Below 1, `value` came from a triangle farther than `triangle_bound`'s touching
    // distance: the gap below leaves the widening's margin finite.
    let gap = distance_to_triangle(view.c, tri);
    let outline = (value < 1.0)
        .then(|| Outline::new(&rel, view.n, t1, t2))
        .flatten();
    let Some(outline) = outline else {
        found.raise(sectors, value, id);
        return;
    };
    // Widening moves points by `asin(margin)` radians, their azimuth by up to
    // `asin(margin / cos e)`: `margin / cos e` within 2e-10 while that stays below
    // 1e-3, which the edges' overlap covers. Beyond (a triangle all but touching the
    // centroid, or near its zenith), every sector takes the top.
    let margin = widening / (gap - widening);
    let turn = margin / (1.0 - value * value).sqrt();
    let overlap = SECTOR_EDGE_OVERLAP + turn;
    if turn > 1e-3 {
        found.raise(sectors, value, id);
        return;
    }
    let turn_out = (overlap.cos(), overlap.sin());
    for k in bits(sectors) {
        if value <= found.sines[k] {
            continue;
        }
        let (lo, hi) = sector_edges(k, turn_out);
        if let Some(sin) = outline.max_within(lo, hi) {
            found.raise(1 << k, (sin + margin).min(value), id);
        }
    }
}

/// Sector `k`'s bounding azimuths as in-plane directions `(x, y)`, each turned outward
/// by an angle given as its `(cos, sin)`. The sectors' edges are the turns `k/4`: in
/// the first quadrant the directions `(4 − j, j)`, `j = 0..4`, and alike a quarter turn
/// on in each other quadrant.
fn sector_edges(k: usize, turn_out: (f64, f64)) -> ((f64, f64), (f64, f64)) {
    let edge = |k: usize| {
        let j = (k % 4) as f64;
        let (x, y) = (4.0 - j, j);
        let r = (x * x + y * y).sqrt();
        match (k / 4) % 4 {
            0 => (x / r, y / r),
            1 => (-y / r, x / r),
            2 => (-x / r, -y / r),
            _ => (y / r, -x / r),
        }
    };
    turned_outward(edge(k), edge(k + 1), turn_out)
}

/// The triangles that set each sector's sine (`u32::MAX`: none).
#[derive(Clone, Copy)]
struct Setters([u32; SECTORS]);

impl Default for Setters {
    fn default() -> Setters {
        Setters([u32::MAX; SECTORS])
    }
}

impl Setters {
    /// Each triangle once.
    fn distinct(&self) -> impl Iterator<Item = u32> + '_ {
        let ids = &self.0;
        (0..SECTORS)
            .filter(move |&k| ids[k] != u32::MAX && !ids[..k].contains(&ids[k]))
            .map(move |k| ids[k])
    }
}

/// The highest elevation sines found so far in each sector of a facet's horizon.
struct SectorSines {
    sines: [f64; SECTORS],
    /// How many sectors are kept, from sector 0: all of them, or one for a whole bound.
    kept: usize,
    /// The highest of them.
    highest: f64,
    setters: Setters,
}

impl SectorSines {
    fn new(kept: usize) -> SectorSines {
        SectorSines {
            sines: [0.0; SECTORS],
            kept,
            highest: 0.0,
            setters: Setters::default(),
        }
    }

    /// The lowest sine of the sectors kept.
    fn lowest(&self) -> f64 {
        self.sines[..self.kept]
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }

    /// The lowest sine of the `sectors` (bits).
    fn lowest_of(&self, sectors: u32) -> f64 {
        bits(sectors).fold(f64::INFINITY, |low, k| low.min(self.sines[k]))
    }

    /// The sectors kept (as bits) whose sine stands below `sin`.
    fn below(&self, sin: f64) -> u32 {
        (0..self.kept).fold(0, |bits, k| bits | u32::from(self.sines[k] < sin) << k)
    }

    /// Raises the `sectors` (bits) to the elevation sine `value` of triangle `id`.
    fn raise(&mut self, sectors: u32, value: f64, id: u32) {
        for k in bits(sectors) {
            if value > self.sines[k] {
                self.sines[k] = value;
                self.setters.0[k] = id;
            }
        }
        self.highest = self.highest.max(value);
    }
}

/// The numbers of the bits set in `set`, lowest first.
fn bits(mut set: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (set != 0).then(|| {
            let k = set.trailing_zeros() as usize;
            set &= set - 1;
            k
        })
    })
}

/// False when no point within `widening` of triangle `tri` lies in the cone from `c`
/// along the unit `axis` whose half-angle has the tangent `tan_half`: a plane through
/// `c` has the cone on one side and the triangle's corners on the other, farther than
/// the widening. The planes tried: the one across the axis (a triangle behind `c`), and
/// those touching the cone's side toward the corners' mean and toward `down` (a unit
/// vector across the axis, or zero). A cheap screen before the exact bound: the tree
/// hands a narrow cone mostly triangles beside it, and the facet's neighbours below it.
fn may_reach_cone(
    c: DVec3,
    cone: (DVec3, f64),
    down: DVec3,
    tri: &[DVec3; 3],
    widening: f64,
) -> bool {
    let (axis, tan_half) = cone;
    let v = tri.map(|p| p - c);
    let along = v.map(|x| x.dot(axis));
    // The widening, scaled by the planes' tilt, and these few operations' own rounding:
    // a few units in the last place of the coordinates (`widening` is a thousand) and of
    // the corners' distances (bounded by twice their largest coordinate).
    let reach = v.iter().fold(0.0f64, |m, x| m.max(x.abs().max_element()));
    let slack = 2.0 * widening * (1.0 + tan_half) + 2e-12 * reach;
    if along.iter().all(|&a| a < -slack) {
        return false;
    }
    // The cone lies within `x·e ≤ |e| tan_half · x·axis` for every `e` across the axis.
    let beyond = |e: DVec3, length: f64| {
        (0..3).all(|k| v[k].dot(e) - length * (tan_half * along[k] + slack) > 0.0)
    };
    let mid = v[0] + v[1] + v[2];
    let aside = mid - axis * mid.dot(axis);
    !(beyond(aside, aside.length()) || beyond(down, down.length()))
}

/// Most triangles reaching into a cone whose pairs are tried as a cover.
const PAIRED_MAX: usize = 8;

/// True if the convex polygon `outline` (corners in order around it), seen from `c`,
/// covers every direction within the angle of sine `sin_half` of the unit `axis`, with
/// `spare` (a sine) more to each edge: the axis lies inside each plane through `c` and
/// an edge by more than both. The corners must lie less than 90° from the axis, so that
/// their directions keep their order on the plane tangent there, where turning the same
/// way at every corner makes the polygon convex. At most four corners.
fn covers(c: DVec3, cone: (DVec3, f64), outline: &[DVec3], spare: f64) -> bool {
    let (axis, sin_half) = cone;
    let Some((directions, orientation)) = seen_outline(c, outline) else {
        return false;
    };
    let u = &directions[..outline.len()];
    u.iter().all(|d| axis.dot(*d) > 0.0)
        && (0..u.len()).all(|j| axis.dot(inward(u, j, orientation)) > sin_half + spare)
}

/// The unit directions from `c` toward the corners of `outline` (3 or 4, in order
/// around it; the first `outline.len()` of the array) and the sign of their turn, when
/// they turn the same way at every corner; `None` when they do not, or the outline is
/// seen edge-on.
fn seen_outline(c: DVec3, outline: &[DVec3]) -> Option<([DVec3; 4], f64)> {
    // A triangle or a quadrilateral: the directions kept on the stack.
    assert!(outline.len() <= 4, "an outline has 3 or 4 corners");
    let mut directions = [DVec3::ZERO; 4];
    let k = outline.len();
    for (d, &p) in directions.iter_mut().zip(outline) {
        *d = (p - c).normalize();
    }
    let u = &directions[..k];
    let turn = |j: usize| u[j].dot(u[(j + 1) % k].cross(u[(j + 2) % k]));
    let orientation = turn(0);
    let convex = orientation != 0.0
        && orientation.is_finite()
        && (1..k).all(|j| turn(j) * orientation > 0.0);
    convex.then_some((directions, orientation.signum()))
}

/// The unit normal, toward the inside, of the plane through the point and edge `j` of
/// an outline seen from it as the unit directions `u`, turning with sign `orientation`
/// ([`seen_outline`]).
fn inward(u: &[DVec3], j: usize, orientation: f64) -> DVec3 {
    u[j].cross(u[(j + 1) % u.len()]).normalize_or_zero() * orientation
}

/// Whether `x` and `y` lie on opposite sides of the plane through `c` and the edge `a`–`b`,
/// each farther from it than the rounding: seen from `c`, the two triangles sharing the
/// edge then lie on either side of it.
fn opposite_sides(c: DVec3, (a, b): (DVec3, DVec3), x: DVec3, y: DVec3) -> bool {
    let plane = (a - c).cross(b - c);
    let side = |p: DVec3| {
        let s = plane.dot(p - c);
        // Far beyond the few units in the last place these products can be off by.
        let noise = 1e-9 * plane.length() * (p - c).length();
        match s.abs() > noise {
            true => s.signum(),
            false => 0.0,
        }
    };
    side(x) * side(y) < 0.0
}

/// Whether the segment `a`–`b`, seen from `c`, stays farther from `cone`'s axis than its
/// half-angle, by more than `spare` (a sine, the rounding) and a little more.
fn edge_clear_of_cone(c: DVec3, (a, b): (DVec3, DVec3), cone: &Cone, spare: f64) -> bool {
    let (ua, ub) = ((a - c).normalize(), (b - c).normalize());
    let Some(pole) = ua.cross(ub).try_normalize() else {
        return false;
    };
    let axis = cone.axis;
    // The point of the segment's great circle nearest the axis, when it lies between
    // the ends (the shorter arc from `ua` to `ub` turns positively about `pole`).
    let foot = axis - pole * axis.dot(pole);
    let between = ua.cross(foot).dot(pole) >= 0.0 && foot.cross(ub).dot(pole) >= 0.0;
    let nearest_cos = match between {
        true => foot.length(),
        false => axis.dot(ua).max(axis.dot(ub)),
    };
    // The cosine of the half-angle widened by `spare` twice and a margin, from below:
    // cos(h + d) >= cos h (1 - d²/2) - sin h d.
    let d = 2.0 * spare + SIN_MARGIN;
    nearest_cos < cone.cos_half * (1.0 - 0.5 * d * d) - cone.sin_half * d
}

/// The outline of triangles `a` and `b` when they share exactly one edge: its ends and
/// the two other corners, in order around the quadrilateral.
fn quadrilateral(a: &[DVec3; 3], b: &[DVec3; 3]) -> Option<[DVec3; 4]> {
    let shared = |p: &DVec3| b.contains(p);
    let apex = (0..3).filter(|&k| !shared(&a[k])).collect::<Vec<_>>();
    let [k] = apex[..] else {
        return None;
    };
    let (p, q) = (a[(k + 1) % 3], a[(k + 2) % 3]);
    let other = b.iter().find(|v| **v != p && **v != q)?;
    Some([a[k], p, *other, q])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::{floor_and_wall, icosphere};
    use crate::mesh::LengthUnit;
    use crate::trace::bvh::BvhRays;
    use crate::trace::{ShadowQuery, Tracer};

    /// A floor (two triangles, z = 0) and a vertical wall of height `h` along x = `wall_x`,
    /// wide enough that the top edge's nearest point is straight across from the floor
    /// facets' centroids: seen from a centroid `c`, the wall's top rises to
    /// sin e = h / √(h² + (wall_x − c.x)²).
    #[test]
    fn a_wall_beside_a_floor_is_the_floors_horizon() {
        let (h, wall_x, half) = (3.0, 4.0, 50.0);
        let mesh = Mesh::from_raw(floor_and_wall(h, wall_x, half), LengthUnit::M);
        let bound = HorizonBound::new(&mesh, mesh.len(), &Bvh::build(&mesh), BoundDetail::Sectors);
        for i in 0..2 {
            let c = mesh.centroids[i];
            let expected = h / (h * h + (wall_x - c.x).powi(2)).sqrt();
            let got = bound.sin_max(i);
            // Stored rounded up to a 255th: up to one above.
            let most = expected + SECTOR_SLACK + 1e-9 + 1.0 / SINE_STEPS;
            assert!(
                got >= expected && got <= most,
                "facet {i}: bound {got}, closed form {expected}"
            );
            // A Sun straight toward the wall just above its top is cleared, one just below
            // it is not.
            let n = mesh.normals[i];
            let toward_x = |sin: f64| DVec3::new((1.0 - sin * sin).sqrt(), 0.0, sin);
            let wall_sector = sector_of(n, toward_x(0.5)).expect("off the zenith");
            let above = bound.sector_sin(i, wall_sector) + 2.0 * SIN_MARGIN;
            assert!(bound.clears(i, n, toward_x(above), above));
            assert!(!bound.clears(i, n, toward_x(expected - 1e-6), expected - 1e-6));
            // Away from the wall (it spans ±85° of azimuth around +x) nothing rises: a
            // Sun 3° up toward −x is cleared by its sector, not by the whole horizon.
            let away = DVec3::new(-(1.0 - 0.05f64 * 0.05).sqrt(), 0.0, 0.05);
            let away_sector = sector_of(n, away).expect("off the zenith");
            assert!(bound.sector_sin(i, away_sector) <= SECTOR_SLACK + 1.0 / SINE_STEPS);
            assert!(bound.clears(i, n, away, 0.05));
            assert!(!bound.clears_all_around(i, 0.05));
        }
    }

    /// Each sector's bound follows the triangle's part in that sector, not its highest
    /// point: a slanted triangle beside a floor facet spans ±72° of azimuth but rises to
    /// 34° only straight ahead (a dense sampling of its points per sector is the
    /// reference; before the sectors were refined, all eight it reaches held 34°).
    #[test]
    fn a_slanted_triangle_raises_each_sector_to_its_own_part() {
        let corners = [
            DVec3::new(1.0, -3.0, 0.0),
            DVec3::new(1.0, 3.0, 0.0),
            DVec3::new(3.0, 0.0, 2.0),
        ];
        let mut vertices = vec![
            DVec3::new(-0.1, -0.1, 0.0),
            DVec3::new(0.1, -0.1, 0.0),
            DVec3::new(0.0, 0.1, 0.0),
        ];
        vertices.extend(corners);
        let raw = crate::mesh::RawMesh {
            vertices,
            triangles: vec![[0, 1, 2], [3, 4, 5]],
        };
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let bound = HorizonBound::new(&mesh, 1, &Bvh::build(&mesh), BoundDetail::Sectors);
        // The floor's tangent frame is x, y.
        let c = mesh.centroids[0];
        let mut sampled = [0.0f64; SECTORS];
        let steps = 1500;
        for i in 0..=steps {
            for j in 0..=steps - i {
                let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                let p = corners[0] + (corners[1] - corners[0]) * u + (corners[2] - corners[0]) * v;
                let rel = p - c;
                let k = (turn((rel.x, rel.y)) * SECTORS_PER_TURN) as usize % SECTORS;
                sampled[k] = sampled[k].max(rel.z / rel.length());
            }
        }
        // The stored sine: up to the slack and a 255th above; the sampling's spacing
        // (4 mm at 1–3 m) misses the highest point by less than 0.005.
        let most_above = SECTOR_SLACK + 1.0 / SINE_STEPS + 0.005;
        for (k, &expected) in sampled.iter().enumerate() {
            let got = bound.sector_sin(0, k);
            assert!(
                got >= expected && got <= expected + most_above,
                "sector {k}: bound {got}, sampled {expected}"
            );
        }
        // The case holds what it is meant to: the top (sin 34° = 0.555) in one sector,
        // barely anything in another the triangle reaches.
        let top = 2.0 / (2.0f64 * 2.0 + 3.0 * 3.0).sqrt();
        assert!(sampled[0] > top - 0.005 && sampled[3] > 0.0 && sampled[3] < 0.01);
    }

    /// From the floor, cones toward the wall: above its top (clear), inside its upper
    /// triangle (covered), across the diagonal between its two triangles (covered by the
    /// pair), across its top edge (partial), and inside it but nearer than asked
    /// (partial).
    #[test]
    fn a_wall_covers_cones_inside_it_but_not_across_its_top() {
        let (h, wall_x, half) = (3.0, 4.0, 50.0);
        let mesh = Mesh::from_raw(floor_and_wall(h, wall_x, half), LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let bound = HorizonBound::new(&mesh, mesh.len(), &bvh, BoundDetail::Sectors);
        let c = mesh.centroids[0];
        let d = wall_x - c.x;
        // Toward the wall at height z above the floor, straight across.
        let toward = |z: f64| DVec3::new(d, 0.0, z).normalize();
        let rho = 0.005;
        let view = |z: f64, beyond: f64| {
            bound.cone_view(&mesh, &bvh, 0, &Cone::new(toward(z), rho), beyond)
        };
        assert_eq!(view(h + 0.1, 0.0), ConeView::Clear);
        assert!(matches!(view(h - 0.2, 0.0), ConeView::Covered(Some(_))));
        assert!(matches!(view(h, 0.0), ConeView::Partial(_)));
        // The diagonal from (x, −half, 0) to (x, half, h) crosses y = c.y here.
        let diagonal = h * (c.y + half) / (2.0 * half);
        assert_eq!(view(diagonal, 0.0), ConeView::Covered(None));
        assert!(matches!(view(diagonal + 0.2, 0.0), ConeView::Covered(_)));
        assert!(matches!(view(h - 0.2, d + 0.5), ConeView::Partial(_)));
    }

    /// On rough terrain, a cone said clear has every ray within it unblocked, one said
    /// covered every ray blocked, and one said partial has its rays answered by the facets
    /// it lists as by the whole tree: by the BVH's rays (the disk Sun's samples' tracer),
    /// on a polar grid of the cone out to 0.999 of its half-angle.
    #[test]
    fn cone_views_agree_with_rays_through_the_cone() {
        let mesh = rough_terrain();
        let bvh = Bvh::build(&mesh);
        let bound = HorizonBound::new(&mesh, mesh.len(), &bvh, BoundDetail::Sectors);
        let mut rng = crate::TestRng::new(11);
        let mut seen = [0usize; 3];
        let mut partial_rays = [0usize; 2];
        for _ in 0..600 {
            let i = 60 + (rng.unit() * 270.0) as usize;
            let n = mesh.normals[i];
            let half = 0.002 + 0.05 * rng.unit();
            let axis = (n * 0.1 + DVec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() * 0.6))
                .normalize();
            let view = bound.cone_view(&mesh, &bvh, i, &Cone::new(axis, half), 1e-6);
            seen[match view {
                ConeView::Clear => 0,
                ConeView::Covered(_) => 1,
                ConeView::Partial(_) => 2,
            }] += 1;
            let (e1, e2) = (
                axis.any_orthonormal_vector(),
                axis.cross(axis.any_orthonormal_vector()),
            );
            for ring in [0.0, 0.3, 0.6, 0.9, 0.999] {
                for k in 0..16 {
                    let a = k as f64 * std::f64::consts::TAU / 16.0;
                    let off = half.tan() * ring;
                    let dir = (axis + off * (a.cos() * e1 + a.sin() * e2)).normalize();
                    if n.dot(dir) <= 0.0 {
                        continue;
                    }
                    let c = mesh.centroids[i];
                    let blocked = bvh.toward(dir).blocked(c, 1e-6, Some(i as u32));
                    let told = match &view {
                        ConeView::Partial(among) => {
                            partial_rays[blocked as usize] += 1;
                            BvhRays::new(&bvh, dir).blocked_among(c, 1e-6, i as u32, among)
                        }
                        view => matches!(view, ConeView::Covered(_)),
                    };
                    assert_eq!(told, blocked, "facet {i}, {view:?}, ring {ring}, k {k}");
                }
            }
        }
        assert!(
            seen.iter().all(|&k| k >= 20),
            "clear, covered, partial: {seen:?}"
        );
        // The partial cones' facets answered both ways, many times each.
        assert!(
            partial_rays.iter().all(|&k| k >= 200),
            "rays of partial cones clear, blocked: {partial_rays:?}"
        );
    }

    /// On rough terrain, a direction a [`Screen`] says blocked is blocked for the exact
    /// ray predicate, with the triangle alone (`BvhRays::blocked_among`): directions
    /// inside triangles, on their edges and corners, and a hair outside or inside the
    /// edges (1e-13 to 1e-9 of the distance), with `t_min` short of the triangle or
    /// reaching into it. Most interior directions must be screened.
    #[test]
    fn a_direction_a_screen_blocks_is_blocked_by_the_ray_predicate() {
        let mesh = rough_terrain();
        let bvh = Bvh::build(&mesh);
        let bound = HorizonBound::new(&mesh, mesh.len(), &bvh, BoundDetail::Whole);
        let mut rng = crate::TestRng::new(5);
        let (mut interior, mut screened, mut near_edges) = (0, 0, 0);
        for _ in 0..3000 {
            let i = (rng.unit() * mesh.len() as f64) as usize;
            let id = (rng.unit() * mesh.len() as f64) as u32;
            let Some(screen) = bound.screen(&mesh, i, id) else {
                continue;
            };
            let c = mesh.centroids[i];
            let [a, b, d] = mesh.corners(id as usize);
            let (u, v) = in_triangle(&mut rng);
            let inside = a + u * (b - a) + v * (d - a);
            let on_edge = a + u * (b - a);
            // Across the edge a→b within the triangle's plane, outward.
            let normal = (b - a).cross(d - a);
            let outward =
                (b - a).cross(normal).normalize() * (b - a).cross(normal).dot(a - d).signum();
            let reach = (inside - c).length();
            let mut targets = vec![(inside, true), (on_edge, false), (a, false)];
            for hair in [1e-13, 1e-11, 1e-9] {
                targets.push((on_edge + outward * hair * reach, false));
                targets.push((on_edge - outward * hair * reach, false));
            }
            for (target, counted) in targets {
                let dir = (target - c).normalize();
                let query = BvhRays::new(&bvh, dir);
                for t_min in [1e-6, 0.5 * reach, (target - c).length() * (1.0 - 1e-12)] {
                    let blocked = query.blocked_among(c, t_min, i as u32, &[id]);
                    let said = screen.blocks(dir, t_min);
                    assert!(!said || blocked, "facet {i}, triangle {id}, t_min {t_min}");
                    near_edges += (!counted && said) as usize;
                    if counted && t_min == 1e-6 {
                        interior += 1;
                        screened += said as usize;
                    }
                }
            }
        }
        assert!(
            interior > 300 && screened * 10 > interior * 9,
            "{screened} of {interior}"
        );
        // Directions a hair inside an edge are screened too, not only deep ones.
        assert!(near_edges > 100, "{near_edges}");
    }

    /// Rough terrain (folds of ±2.5 m over 20 m): for every facet and Suns at several
    /// elevations, around the horizon and exactly on every sector's boundary, a ray
    /// either bound clears is unblocked for the BVH's rays; and the sectors clear many
    /// rays the whole horizon's bound traces.
    #[test]
    fn a_ray_the_bound_clears_is_never_blocked() {
        let mesh = rough_terrain();
        let bvh = Bvh::build(&mesh);
        // In-plane directions: 64 around the turn, and one on each sector boundary
        // (turns k·4/SECTORS, exact in the pseudo-angle: y/(x+y) = f in the first
        // quadrant, turned by quarter turns).
        let mut in_plane: Vec<(f64, f64)> = (0..64)
            .map(|k| {
                let a = (k as f64 + 0.37) * std::f64::consts::TAU / 64.0;
                (a.cos(), a.sin())
            })
            .collect();
        for k in 0..SECTORS {
            let t = k as f64 * 4.0 / SECTORS as f64;
            let (q, f) = (t.floor() as usize, t.fract());
            let (x, y) = (1.0 - f, f);
            in_plane.push([(x, y), (-y, x), (-x, -y), (y, -x)][q]);
        }
        let mut cleared = [0usize; 2];
        let mut blocked = 0;
        let bounds = [BoundDetail::Whole, BoundDetail::Sectors]
            .map(|detail| HorizonBound::new(&mesh, mesh.len(), &bvh, detail));
        for i in 0..mesh.len() {
            let (c, n) = (mesh.centroids[i], mesh.normals[i]);
            let (t1, t2) = tangent_frame(n);
            for sin_e in [0.02f64, 0.06, 0.15, 0.3, 0.6] {
                let cos_e = (1.0 - sin_e * sin_e).sqrt();
                for &(x, y) in &in_plane {
                    let across = (t1 * x + t2 * y).normalize();
                    let sun = (across * cos_e + n * sin_e).normalize();
                    let sin = n.dot(sun);
                    let is_blocked = bvh.toward(sun).blocked(c, 1e-9, Some(i as u32));
                    blocked += usize::from(is_blocked);
                    for (bound, count) in bounds.iter().zip(&mut cleared) {
                        if bound.clears(i, n, sun, sin) {
                            assert!(!is_blocked, "facet {i}: {:?} cleared {sun}", bound.detail);
                            *count += 1;
                        }
                    }
                }
            }
        }
        let [whole, by_sector] = cleared;
        assert!(blocked > 1000, "blocked {blocked}");
        assert!(whole > 5000, "cleared by the whole bound {whole}");
        assert!(
            by_sector > whole + 1000,
            "by sectors {by_sector}, whole {whole}"
        );
    }

    /// Random boxes around a tilted facet's centroid, some across its zenith line: every
    /// point of a box lies in a sector the box is said to reach.
    #[test]
    fn a_box_reaches_the_sector_of_each_of_its_points() {
        let mut rng = crate::TestRng::new(5);
        let mut u = || rng.unit() - 0.5;
        let c = DVec3::new(3.0, -2.0, 1.0);
        let n = DVec3::new(0.3, -0.5, 0.8).normalize();
        let (t1, t2) = tangent_frame(n);
        let mut partial = 0;
        for _ in 0..2000 {
            let centre = c + DVec3::new(u(), u(), u()) * 8.0;
            let half = DVec3::new(u().abs(), u().abs(), u().abs()) * 2.0;
            let (lo, hi) = (centre - half, centre + half);
            let reached = sectors_reached(&ZenithLine::new(c, n), (t1, t2), (lo, hi), 0.0);
            if reached != ALL_SECTORS {
                partial += 1;
                assert_eq!(reached, corners_run(c, n, lo, hi), "{lo} {hi}");
            }
            for _ in 0..40 {
                let q = lo + (hi - lo) * DVec3::new(u() + 0.5, u() + 0.5, u() + 0.5);
                if let Some(k) = sector_of(n, (q - c).normalize()) {
                    assert!(
                        reached >> k & 1 == 1,
                        "{q} in sector {k}, box reaches {reached:b}"
                    );
                }
            }
        }
        assert!(
            partial > 1000,
            "boxes reaching some sectors only: {partial}"
        );
    }

    /// The shortest run of sectors (as bits, around the turn) holding the sectors of the
    /// box's eight corners: what a box off the zenith line reaches, no more.
    fn corners_run(c: DVec3, n: DVec3, lo: DVec3, hi: DVec3) -> u32 {
        let corners = (0..8).map(|k| {
            let pick = |bit: usize, a: f64, b: f64| if k >> bit & 1 == 1 { b } else { a };
            DVec3::new(
                pick(0, lo.x, hi.x),
                pick(1, lo.y, hi.y),
                pick(2, lo.z, hi.z),
            )
        });
        let held = corners.fold(0u32, |bits, q| {
            bits | sector_of(n, (q - c).normalize()).map_or(ALL_SECTORS, |k| 1 << k)
        });
        // Start after the longest run of empty sectors; end at the last held one.
        let empty_run_from = |k: usize| {
            (0..SECTORS)
                .take_while(|j| held >> ((k + j) % SECTORS) & 1 == 0)
                .count()
        };
        let start = (0..SECTORS)
            .max_by_key(|&k| (empty_run_from(k), SECTORS - k))
            .unwrap();
        let gap = empty_run_from(start);
        (gap..SECTORS).fold(0, |bits, j| bits | 1 << ((start + j) % SECTORS))
    }

    /// Sectors by comparisons are the sectors of the turns: on every boundary (the axes,
    /// the diagonals, y = ±x/3 and ±3x, which the pseudo-angle gives exactly) and for
    /// random directions of every size away from the boundaries.
    #[test]
    fn sectors_by_comparisons_are_the_turns_sectors() {
        let by_turn =
            |x: f64, y: f64| ((turn((x, y)) * SECTORS_PER_TURN) as usize).min(SECTORS - 1);
        let mut directions = Vec::new();
        for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)] {
            for (x, y) in [
                (1.0, 0.0),
                (0.0, 1.0),
                (1.0, 1.0),
                (3.0, 1.0),
                (1.0, 3.0),
                (0.0, 0.0),
            ] {
                directions.push((sx * x, sy * y));
            }
        }
        directions.extend([(-0.0, 1.0), (-0.0, -1.0), (-1.0, -0.0), (1.0, -0.0)]);
        directions.retain(|&(x, y)| x != 0.0 || y != 0.0);
        for &(x, y) in &directions {
            assert_eq!(sector_in_plane(x, y), by_turn(x, y), "({x}, {y})");
        }
        let mut rng = crate::TestRng::new(9);
        for _ in 0..100_000 {
            let angle = std::f64::consts::TAU * rng.unit();
            let size = 10f64.powf(8.0 * rng.unit() - 4.0);
            let (x, y) = (size * angle.cos(), size * angle.sin());
            let t = turn((x, y)) * SECTORS_PER_TURN;
            if (t - t.round()).abs() > 1e-9 {
                assert_eq!(sector_in_plane(x, y), by_turn(x, y), "({x}, {y})");
            }
        }
    }

    /// Sectors by turn: a boundary belongs to the sector above it; the zenith has none.
    #[test]
    fn sectors_follow_the_turn_and_the_zenith_has_none() {
        let n = DVec3::Z;
        let sector = |x: f64, y: f64| sector_of(n, DVec3::new(x, y, 0.5).normalize());
        assert_eq!(sector(1.0, 0.0), Some(0));
        assert_eq!(sector(1.0, 1.0), Some(SECTORS / 8));
        assert_eq!(sector(-1.0, 0.0), Some(SECTORS / 2));
        assert_eq!(sector(1.0, -1e-12), Some(SECTORS - 1));
        assert_eq!(sector_of(n, DVec3::new(1e-9, 0.0, 1.0).normalize()), None);
    }

    /// Rough terrain, from random facets toward random points of other facets, cones of
    /// 0.1° to 12°: wherever a patch is said to cover a cone, every ray within it (inside,
    /// and on its rim) is blocked past the distance given, for the BVH's exact rays
    /// through the whole mesh; the seed is the facet the axis points at, or any. Many
    /// covers are shown, among them cones that neither one facet nor a pair covers (the
    /// tree's view is partial), and many are refused.
    #[test]
    fn a_cone_a_patch_covers_is_blocked_for_every_ray() {
        let mesh = Mesh::from_raw(
            crate::mesh::generate::height_field((28, 28), (-10.0, 10.0), (-10.0, 10.0), |x, y| {
                2.5 * (x / 2.3).sin() * (y / 3.1).cos() + 0.3 * x
            }),
            LengthUnit::M,
        );
        let bvh = Bvh::build(&mesh);
        let bound = HorizonBound::new(&mesh, mesh.len(), &bvh, BoundDetail::Whole);
        let neighbours = crate::mesh::inspect::edge_neighbours(&mesh);
        let mut rng = crate::TestRng::new(11);
        let (mut covered, mut beyond_pairs, mut refused) = (0, 0, 0);
        for _ in 0..8000 {
            let i = (rng.unit() * mesh.len() as f64) as usize;
            let id = (rng.unit() * mesh.len() as f64) as u32;
            let [a, b, d] = mesh.corners(id as usize);
            let (u, v) = in_triangle(&mut rng);
            let c = mesh.centroids[i];
            let axis = (a + u * (b - a) + v * (d - a) - c).normalize();
            let half = (0.1 + 11.9 * rng.unit() * rng.unit()).to_radians();
            let cone = Cone::new(axis, half);
            // Every other seed anywhere: most often its patch lies wholly outside the cone.
            let seed = match rng.unit() < 0.5 {
                true => id,
                false => (rng.unit() * mesh.len() as f64) as u32,
            };
            let Some(gap) = bound.patch_cover(&mesh, &neighbours, (i, &cone), seed, 128) else {
                refused += 1;
                continue;
            };
            covered += 1;
            let view = bound.cone_view(&mesh, &bvh, i, &cone, 0.0);
            beyond_pairs += matches!(view, ConeView::Partial(_)) as usize;
            let across = axis.any_orthonormal_pair();
            for k in 0..64 {
                // Half the rays on the cone's rim, a hair inside it.
                let r = match k % 2 {
                    0 => half * (1.0 - 1e-9),
                    _ => half * rng.unit().sqrt(),
                };
                let turn = std::f64::consts::TAU * rng.unit();
                let side = across.0 * turn.cos() + across.1 * turn.sin();
                let dir = (axis * r.cos() + side * r.sin()).normalize();
                let t_min = gap * rng.unit();
                let blocked = BvhRays::new(&bvh, dir).blocked(c, t_min, Some(i as u32));
                assert!(blocked, "facet {i}, seed {seed}, half {half}, ray {k}");
            }
        }
        assert!(
            covered > 500 && refused > 500,
            "{covered} covered, {refused} refused"
        );
        assert!(
            beyond_pairs > 50,
            "{beyond_pairs} covers beyond one facet or a pair"
        );
    }

    /// Random coordinates (u, v) along two edges of a triangle from one corner, uniform
    /// over the triangle.
    fn in_triangle(rng: &mut crate::TestRng) -> (f64, f64) {
        let (u, v) = (rng.unit(), rng.unit());
        match u + v > 1.0 {
            true => (1.0 - u, 1.0 - v),
            false => (u, v),
        }
    }

    fn rough_terrain() -> Mesh {
        let raw =
            crate::mesh::generate::height_field((14, 14), (-10.0, 10.0), (-10.0, 10.0), |x, y| {
                2.5 * (x / 2.3).sin() * (y / 3.1).cos() + 0.3 * x
            });
        Mesh::from_raw(raw, LengthUnit::M)
    }

    #[test]
    fn a_convex_body_hides_nothing_above_any_facets_plane() {
        let mesh = Mesh::from_raw(icosphere(3, 1.0, DVec3::new(5e3, 0.0, 0.0)), LengthUnit::Km);
        let bound = HorizonBound::new(&mesh, mesh.len(), &Bvh::build(&mesh), BoundDetail::Sectors);
        let worst = (0..mesh.len()).fold(0.0f64, |m, i| m.max(bound.sin_max(i)));
        // Nothing rises above a face of a convex solid: only the search's slack remains,
        // rounded up to a 255th.
        assert!(worst <= SECTOR_SLACK + 1.0 / SINE_STEPS, "{worst}");
    }
}
