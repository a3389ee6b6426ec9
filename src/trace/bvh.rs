//! A bounding-volume hierarchy for rays in any direction: the segment any-hit query that
//! facet-to-facet visibility needs.
//!
//! In: a mesh (metres, body frame). Out: [`Bvh::segment_blocked`] — whether the open
//! segment from `a` to `b` crosses a facet other than the (up to two) facets it joins.
//! The hit decision is the shared exact predicate of [`super::ray`] evaluated in the frame
//! of the segment's direction, so a segment is classified exactly as a shadow ray of the
//! other tracers would be. The tree is split at the median centroid along the longest
//! axis of each node's box; leaves hold at most [`LEAF_SIZE`] facets.

use super::caster_facets;
use super::ray::{inside, DepthPlane, RayFrame};
use crate::mesh::Mesh;
use glam::DVec3;

/// Most facets in a leaf.
const LEAF_SIZE: usize = 4;

/// One node: a box and either two children (`count == 0`, children at `first` and
/// `first + 1`) or a run of `count` facets starting at `first` in the facet order.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    first: u32,
    count: u32,
}

/// A BVH over one mesh's facets of non-zero area.
pub struct Bvh<'m> {
    mesh: &'m Mesh,
    nodes: Vec<Node>,
    facets: Vec<u32>,
}

impl<'m> Bvh<'m> {
    /// Builds the tree.
    pub fn build(mesh: &'m Mesh) -> Bvh<'m> {
        let mut facets = caster_facets(mesh);
        let mut nodes = Vec::with_capacity(2 * facets.len() / LEAF_SIZE + 1);
        if !facets.is_empty() {
            nodes.push(leaf(mesh, &facets, 0));
            split(mesh, &mut nodes, &mut facets, 0);
        }
        Bvh {
            mesh,
            nodes,
            facets,
        }
    }

    /// True if a facet other than those in `skip` crosses the segment `a → b` (mesh frame,
    /// metres) farther than `margin` from both ends.
    pub fn segment_blocked(&self, a: DVec3, b: DVec3, skip: [u32; 2], margin: f64) -> bool {
        let length = (b - a).length();
        if self.nodes.is_empty() || length <= 2.0 * margin {
            return false;
        }
        let dir = (b - a) / length;
        let frame = RayFrame::new(dir);
        let q = frame.project(a);
        let inv = dir.recip();
        let (t0, t1) = (margin, length - margin);
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = self.nodes[stack[top] as usize];
            if !slab_hit(&node, a, inv, t0, t1) {
                continue;
            }
            if node.count == 0 {
                stack[top] = node.first;
                stack[top + 1] = node.first + 1;
                top += 2;
                continue;
            }
            let run = &self.facets[node.first as usize..(node.first + node.count) as usize];
            if run
                .iter()
                .any(|&f| !skip.contains(&f) && self.crosses(&frame, q, f, t0, t1))
            {
                return true;
            }
        }
        false
    }

    /// The exact predicate, with the hit distance bounded on both sides.
    fn crosses(&self, frame: &RayFrame, q: DVec3, f: u32, t0: f64, t1: f64) -> bool {
        let tri = self.mesh.corners(f as usize).map(|p| frame.project(p));
        let plane = DepthPlane::new(frame.project(self.mesh.normals[f as usize]), tri[0]);
        let t = plane.distance(q);
        t > t0 && t < t1 && inside(&tri, q)
    }
}

/// Ray–box slab test over the parameter range [t0, t1].
#[inline]
fn slab_hit(node: &Node, o: DVec3, inv: DVec3, t0: f64, t1: f64) -> bool {
    let a = (node.lo - o) * inv;
    let b = (node.hi - o) * inv;
    // NaN (0·∞ on a box face) compares false and so never narrows the range.
    let near = a.min(b).max_element().max(t0);
    let far = a.max(b).min_element().min(t1);
    near <= far
}

fn leaf(mesh: &Mesh, facets: &[u32], first: u32) -> Node {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for &f in facets {
        for p in mesh.corners(f as usize) {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    // Padding so that facets lying in a box face are never clipped away by rounding.
    let pad = DVec3::splat((hi - lo).max_element() * 1e-9 + 1e-300);
    Node {
        lo: lo - pad,
        hi: hi + pad,
        first,
        count: facets.len() as u32,
    }
}

/// Splits node `n` (a leaf over `facets[first..first+count]`) until leaves are small.
fn split(mesh: &Mesh, nodes: &mut Vec<Node>, facets: &mut [u32], n: usize) {
    let Node { first, count, .. } = nodes[n];
    if count as usize <= LEAF_SIZE {
        return;
    }
    let run = &mut facets[first as usize..(first + count) as usize];
    let (clo, chi) = run.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &f| {
            let c = mesh.centroids[f as usize];
            (lo.min(c), hi.max(c))
        },
    );
    let extent = chi - clo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let half = run.len() / 2;
    run.select_nth_unstable_by(half, |&x, &y| {
        mesh.centroids[x as usize][axis].total_cmp(&mesh.centroids[y as usize][axis])
    });
    let left = nodes.len();
    nodes.push(leaf(mesh, &run[..half], first));
    nodes.push(leaf(mesh, &run[half..], first + half as u32));
    nodes[n].first = left as u32;
    nodes[n].count = 0;
    split(mesh, nodes, facets, left);
    split(mesh, nodes, facets, left + 1);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::icosphere;
    use crate::mesh::LengthUnit;

    #[test]
    fn chords_of_a_sphere_seen_from_outside_and_inside() {
        let mesh = Mesh::from_raw(icosphere(3, 1.0, DVec3::ZERO), LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let none = [u32::MAX; 2];
        // A segment through the sphere crosses its surface; one outside it does not.
        assert!(bvh.segment_blocked(
            DVec3::new(-2.0, 0.1, 0.0),
            DVec3::new(2.0, 0.1, 0.0),
            none,
            1e-9
        ));
        assert!(!bvh.segment_blocked(
            DVec3::new(-2.0, 1.5, 0.0),
            DVec3::new(2.0, 1.5, 0.0),
            none,
            1e-9
        ));
        // A chord between two facet centroids crosses nothing but its end facets.
        let (i, j) = (0usize, mesh.len() / 2 + 7);
        let (a, b) = (mesh.centroids[i], mesh.centroids[j]);
        assert!(!bvh.segment_blocked(a, b, [i as u32, j as u32], 1e-9));
        // Hits at the very ends fall within the margin; carried on past b, the segment
        // crosses facet j.
        assert!(!bvh.segment_blocked(a, b, [i as u32, u32::MAX], 1e-9));
        let beyond = a + (b - a) * 1.5;
        assert!(bvh.segment_blocked(a, beyond, [i as u32, u32::MAX], 1e-9));
        assert!(!bvh.segment_blocked(a, beyond, [i as u32, j as u32], 1e-9));
    }
}
