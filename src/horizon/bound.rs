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
//! rule out,
//! each triangle widened by the rounding of the exact predicate (a few units in the last
//! place of the mesh's coordinates, `ROUNDING_ULPS · ε · |v|max`), so that a ray the
//! tracers call blocked through rounding is never cleared. The branch and bound stops
//! refining within `SEARCH_SLACK` (0.02 in sine, about 1°) of the highest horizon, which
//! it adds to the bound: a Sun less than that above the horizon is simply traced.
//!
//! Cost: a tree search per facet, parallel over facets, each seeded with the triangle
//! that set its neighbour's bound; about 1.5 s per 49k facets on one core, growing a
//! little faster than the facet count. Memory: 8 bytes per facet.

use super::geometry::{box_bound, rounding_widening, triangle_bound};
use super::map::in_seeded_runs;
use crate::mesh::Mesh;
use crate::trace::bvh::Bvh;
use glam::DVec3;
use std::cell::Cell;

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
    sin_max: Vec<f64>,
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
            facet_bound(mesh, bvh, i, widening, seed)
        });
        HorizonBound { sin_max }
    }

    /// True when a Sun at `sin_elevation` (n·s) above facet `i`'s plane is higher than
    /// everything else of the body seen from its centroid: its shadow ray is unblocked.
    #[inline]
    pub fn clears(&self, i: usize, sin_elevation: f64) -> bool {
        sin_elevation > self.sin_max[i] + SIN_MARGIN
    }

    /// Per facet, the sine of the highest elevation (for tests and reports).
    pub fn sin_max(&self) -> &[f64] {
        &self.sin_max
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
        |lo, hi| {
            let bound = box_bound(c, n, lo, hi, widening);
            (bound > best.get().0 + SEARCH_SLACK).then_some(bound)
        },
        take,
    );
    let (found, setter) = best.get();
    ((found + SEARCH_SLACK).min(1.0), setter)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::{floor_and_wall, icosphere};
    use crate::mesh::LengthUnit;

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
            let got = bound.sin_max()[i];
            assert!(
                got >= expected && got <= expected + SEARCH_SLACK + 1e-9,
                "facet {i}: bound {got}, closed form {expected}"
            );
            // A Sun just above the wall's top is cleared, one just below it is not.
            assert!(bound.clears(i, got + 2.0 * SIN_MARGIN));
            assert!(!bound.clears(i, expected - 1e-6));
        }
    }

    #[test]
    fn a_convex_body_hides_nothing_above_any_facets_plane() {
        let mesh = Mesh::from_raw(icosphere(3, 1.0, DVec3::new(5e3, 0.0, 0.0)), LengthUnit::Km);
        let bound = HorizonBound::new(&mesh, mesh.len(), &Bvh::build(&mesh));
        let worst = bound.sin_max().iter().fold(0.0f64, |m, &s| m.max(s));
        // Nothing rises above a face of a convex solid: only the search's slack remains.
        assert!(worst <= SEARCH_SLACK + 1e-6, "{worst}");
    }
}
