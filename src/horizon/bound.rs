//! Horizon bound: per facet, the highest elevation at which its centroid sees any other
//! facet of its body, so that a Sun above it needs no shadow ray.
//!
//! In: a mesh (metres, body frame) and its [`Bvh`]. Out: [`HorizonBound`], per facet the
//! sine of the largest elevation above the facet's plane of any point of any other facet
//! with an area, seen from the facet's centroid (0 when nothing rises above the plane).
//! A shadow ray leaves the centroid at the Sun's elevation (`sin e = n·s`); when that is
//! above the bound, every point the ray passes lies higher than anything of the body in
//! that direction, so no facet can block it, and [`HorizonBound::clears`] answers
//! without tracing. The answer is then the exact tracers' answer, not an approximation:
//! on a convex patch of a surface nothing rises above the facet's plane, and on a real
//! shape model most Sun-facing facets see the Sun above their highest horizon at most
//! steps.
//!
//! The bound is computed exactly (`super::geometry`) for every triangle the tree cannot
//! rule out, each triangle widened by the rounding of the exact predicate (a few units in
//! the last place of the mesh's coordinates, `ROUNDING_ULPS · ε · |v|max`), so that a ray
//! the tracers call blocked through rounding is never cleared. The branch and bound stops
//! refining within `SEARCH_SLACK` (0.02 in sine, about 1°) of the highest horizon, which
//! it adds to the bound: a Sun less than that above the horizon is simply traced.
//!
//! Cost: a tree search per facet, parallel over facets, each seeded with the triangle
//! that set its neighbour's bound; about 0.6 s per 49k facets on one core, growing a
//! little faster than the facet count; kept on disk beside the horizon maps and read
//! back by later runs (`super::cache`). Memory: 4 bytes per facet (the sine rounded up
//! to `f32`).

use super::geometry::{distance_to_triangle, rounding_widening, triangle_bound};
use super::map::{f32_at_least, in_seeded_runs};
use crate::mesh::Mesh;
use crate::trace::bvh::Bvh;
use glam::DVec3;
use std::cell::{Cell, RefCell};

/// How far above the highest horizon found the bound may lie (sine): the search skips
/// whatever cannot rise more than this above it, which keeps it to the few hundred
/// triangles near each facet and the far ones that form its horizon.
const SEARCH_SLACK: f64 = 0.02;

/// Least gap between the Sun's `sin e` and the bound for a ray to be cleared, over and
/// above the widened triangles: the rounding of `n·s` itself.
const SIN_MARGIN: f64 = 1e-9;

/// Per facet, the sine of the highest elevation of any other facet seen from its centroid.
#[derive(Debug, Clone)]
pub struct HorizonBound {
    /// Rounded up to `f32`: half the memory, and the bound stays a bound (the search
    /// leaves it up to `SEARCH_SLACK` high anyway).
    sin_max: Vec<f32>,
    /// How far triangles are widened against the exact predicate's rounding (m).
    widening: f64,
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

/// What a facet's centroid sees of a narrow cone of directions (a disk Sun).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConeView {
    /// No other facet reaches into the cone: every ray within it is clear.
    Clear,
    /// One facet covers the whole cone beyond the distance asked for: every ray within
    /// it is blocked.
    Covered,
    /// Anything else: facets reach in without one covering it all. They are every facet
    /// a ray within the cone can cross (as the tracers' predicate decides, rounding
    /// included), which can then answer it alone (`BvhRays::blocked_among`).
    Partial(Vec<u32>),
}

impl HorizonBound {
    /// The bound of facets `0..receivers` of `mesh`, using `bvh` (built over all of
    /// `mesh`, whose other facets only cast shadows).
    pub fn new(mesh: &Mesh, receivers: usize, bvh: &Bvh) -> HorizonBound {
        // Each facet is seeded with the triangle that set its neighbour's bound: it is
        // likely high here too, and the higher the first value, the more of the tree the
        // search prunes.
        let widening = rounding_widening(mesh);
        let sin_max = in_seeded_runs(0..receivers, |i, &seed| {
            let (sin, setter) = facet_bound(mesh, bvh, i, widening, seed);
            (f32_at_least(sin), setter)
        });
        HorizonBound { sin_max, widening }
    }

    /// The bound of `mesh`'s first facets from their stored sines (the cache), as
    /// [`HorizonBound::new`] built them over the same mesh.
    pub(super) fn from_sines(mesh: &Mesh, sin_max: Vec<f32>) -> HorizonBound {
        HorizonBound {
            sin_max,
            widening: rounding_widening(mesh),
        }
    }

    /// Per facet, the sine kept (for the cache).
    pub(super) fn sines(&self) -> &[f32] {
        &self.sin_max
    }

    /// What facet `i`'s centroid sees of the `cone` of directions, through the other
    /// facets of `mesh` (the one `bvh` and the bound were built over):
    /// [`ConeView::Covered`] only by a facet farther than `beyond` metres. Exact up to the rounding of the ray predicate, which every
    /// triangle is widened by (so a clear cone is clear, a covered one covered, for the
    /// tracers' rays).
    pub fn cone_view(
        &self,
        mesh: &Mesh,
        bvh: &Bvh,
        i: usize,
        cone: &Cone,
        beyond: f64,
    ) -> ConeView {
        let Cone {
            axis,
            cos_half,
            sin_half,
            tan_half,
        } = *cone;
        let c = mesh.centroids[i];
        let covered = Cell::new(false);
        // The mesh ids of the triangles reaching into the cone.
        let reaching = RefCell::new(Vec::new());
        // Across the axis, toward the facet's plane: where its neighbours lie.
        let n = mesh.normals[i];
        let down = -(n - axis * n.dot(axis)).normalize_or_zero();
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
        // The tree's boxes are padded far beyond the widening (`Bvh`'s box margin). A
        // triangle's elevation sine above the plane across `axis` is the cosine of its
        // least angle from `axis`: what the bound's geometry computes exactly.
        bvh.near_cone(c, axis, tan_half, |id, tri| {
            if id as usize != i
                && may_reach_cone(c, (axis, tan_half), down, tri, self.widening)
                && triangle_bound(c, axis, tri, self.widening, cos_half) > cos_half
            {
                covered.set(cover(&[tri], tri));
                reaching.borrow_mut().push(id);
            }
            covered.get()
        });
        let reaching = reaching.into_inner();
        if reaching.is_empty() {
            return ConeView::Clear;
        }
        // Two triangles sharing an edge that crosses the cone cover it together when,
        // seen from the centroid, they make a convex quadrilateral around it.
        let corners = |id: &u32| mesh.corners(*id as usize);
        let paired = covered.get()
            || (reaching.len() <= PAIRED_MAX
                && reaching.iter().enumerate().any(|(k, a)| {
                    let a = corners(a);
                    reaching[k + 1..].iter().map(corners).any(|b| {
                        quadrilateral(&a, &b).is_some_and(|outline| cover(&[&a, &b], &outline))
                    })
                }));
        if paired {
            ConeView::Covered
        } else {
            ConeView::Partial(reaching)
        }
    }

    /// True when a Sun at `sin_elevation` (n·s) above facet `i`'s plane is higher than
    /// everything else of the body seen from its centroid: its shadow ray is unblocked.
    #[inline]
    pub fn clears(&self, i: usize, sin_elevation: f64) -> bool {
        sin_elevation > self.sin_max[i] as f64 + SIN_MARGIN
    }

    /// Facet `i`'s bound: the sine of the highest elevation (for tests and reports).
    pub fn sin_max(&self, i: usize) -> f64 {
        self.sin_max[i] as f64
    }
}

/// Facet `i`'s bound, and the triangle that set it (`None`: nothing rose above the
/// plane). The `seed` triangle is taken first.
fn facet_bound(
    mesh: &Mesh,
    bvh: &Bvh,
    i: usize,
    widening: f64,
    seed: Option<u32>,
) -> (f64, Option<u32>) {
    let (c, n) = (mesh.centroids[i], mesh.normals[i]);
    if n == DVec3::ZERO || mesh.areas[i] <= 0.0 {
        return (1.0, None);
    }
    let best = Cell::new((0.0f64, None));
    let take = |id: u32, tri: &[DVec3; 3]| {
        if id as usize != i {
            let (high, _) = best.get();
            let value = triangle_bound(c, n, tri, widening, high + SEARCH_SLACK);
            if value > high {
                best.set((value, Some(id)));
            }
        }
    };
    if let Some(id) = seed {
        take(id, &mesh.corners(id as usize));
    }
    bvh.search(
        &bvh.viewpoint(c, n, widening),
        |child| (child.bound > best.get().0 + SEARCH_SLACK).then_some(child.bound),
        take,
    );
    let (found, setter) = best.get();
    ((found + SEARCH_SLACK).min(1.0), setter)
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
    // A triangle or a quadrilateral: the directions kept on the stack.
    assert!(outline.len() <= 4, "covers takes 3 or 4 corners");
    let mut directions = [DVec3::ZERO; 4];
    let k = outline.len();
    for (d, &p) in directions.iter_mut().zip(outline) {
        *d = (p - c).normalize();
    }
    let u = &directions[..k];
    let turn = |j: usize| u[j].dot(u[(j + 1) % k].cross(u[(j + 2) % k]));
    let orientation = turn(0);
    if orientation == 0.0 || !orientation.is_finite() || u.iter().any(|d| axis.dot(*d) <= 0.0) {
        return false;
    }
    (1..k).all(|j| turn(j) * orientation > 0.0)
        && (0..k).all(|j| {
            let inward = u[j].cross(u[(j + 1) % k]).normalize_or_zero() * orientation.signum();
            axis.dot(inward) > sin_half + spare
        })
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
    use crate::trace::Tracer;

    /// A floor (two triangles, z = 0) and a vertical wall of height `h` along x = `wall_x`,
    /// wide enough that the top edge's nearest point is straight across from the floor
    /// facets' centroids: seen from a centroid `c`, the wall's top rises to
    /// sin e = h / √(h² + (wall_x − c.x)²).
    #[test]
    fn a_wall_beside_a_floor_is_the_floors_horizon() {
        let (h, wall_x, half) = (3.0, 4.0, 50.0);
        let mesh = Mesh::from_raw(floor_and_wall(h, wall_x, half), LengthUnit::M);
        let bound = HorizonBound::new(&mesh, mesh.len(), &Bvh::build(&mesh));
        for i in 0..2 {
            let c = mesh.centroids[i];
            let expected = h / (h * h + (wall_x - c.x).powi(2)).sqrt();
            let got = bound.sin_max(i);
            // Stored rounded up to `f32`: up to one unit in its last place above.
            let most = (expected + SEARCH_SLACK + 1e-9) * (1.0 + f32::EPSILON as f64);
            assert!(
                got >= expected && got <= most,
                "facet {i}: bound {got}, closed form {expected}"
            );
            // A Sun just above the wall's top is cleared, one just below it is not.
            assert!(bound.clears(i, got + 2.0 * SIN_MARGIN));
            assert!(!bound.clears(i, expected - 1e-6));
        }
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
        let bound = HorizonBound::new(&mesh, mesh.len(), &bvh);
        let c = mesh.centroids[0];
        let d = wall_x - c.x;
        // Toward the wall at height z above the floor, straight across.
        let toward = |z: f64| DVec3::new(d, 0.0, z).normalize();
        let rho = 0.005;
        let view = |z: f64, beyond: f64| {
            bound.cone_view(&mesh, &bvh, 0, &Cone::new(toward(z), rho), beyond)
        };
        assert_eq!(view(h + 0.1, 0.0), ConeView::Clear);
        assert_eq!(view(h - 0.2, 0.0), ConeView::Covered);
        assert!(matches!(view(h, 0.0), ConeView::Partial(_)));
        // The diagonal from (x, −half, 0) to (x, half, h) crosses y = c.y here.
        let diagonal = h * (c.y + half) / (2.0 * half);
        assert_eq!(view(diagonal, 0.0), ConeView::Covered);
        assert_eq!(view(diagonal + 0.2, 0.0), ConeView::Covered);
        assert!(matches!(view(h - 0.2, d + 0.5), ConeView::Partial(_)));
    }

    /// On rough terrain, a cone said clear has every ray within it unblocked, one said
    /// covered every ray blocked, and one said partial has its rays answered by the facets
    /// it lists as by the whole tree: by the BVH's rays (the disk Sun's samples' tracer),
    /// on a polar grid of the cone out to 0.999 of its half-angle.
    #[test]
    fn cone_views_agree_with_rays_through_the_cone() {
        let raw =
            crate::mesh::generate::height_field((14, 14), (-10.0, 10.0), (-10.0, 10.0), |x, y| {
                2.5 * (x / 2.3).sin() * (y / 3.1).cos() + 0.3 * x
            });
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let bound = HorizonBound::new(&mesh, mesh.len(), &bvh);
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
                ConeView::Covered => 1,
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
                        view => *view == ConeView::Covered,
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

    #[test]
    fn a_convex_body_hides_nothing_above_any_facets_plane() {
        let mesh = Mesh::from_raw(icosphere(3, 1.0, DVec3::new(5e3, 0.0, 0.0)), LengthUnit::Km);
        let bound = HorizonBound::new(&mesh, mesh.len(), &Bvh::build(&mesh));
        let worst = (0..mesh.len()).fold(0.0f64, |m, i| m.max(bound.sin_max(i)));
        // Nothing rises above a face of a convex solid: only the search's slack remains.
        assert!(worst <= SEARCH_SLACK + 1e-6, "{worst}");
    }
}
