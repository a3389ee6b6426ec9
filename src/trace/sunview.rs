//! The fast tracer: a 2-D grid in the Sun's view.
//!
//! Every shadow ray of a step points at the Sun, so all rays are parallel. Projecting the
//! mesh once onto the plane perpendicular to the Sun turns each ray into a point: a facet
//! blocks the ray if the point lies inside the facet's projection and the facet is nearer
//! the Sun there. Facets are binned into a uniform 2-D grid over the projection (about two
//! per cell); a query looks at one cell. Building costs O(facets) per Sun direction, a
//! query O(facets in a cell), independent of how far the ray travels.
//!
//! Every facet with an area is binned, whichever way it faces: culling facets that face
//! the Sun would be valid only for embedded closed surfaces, and real shape models fold
//! (m1phobos has fins below its surface along a seam).
//!
//! In: a mesh (metres, body frame) and a unit Sun direction. Out: [`ShadowQuery`] answers
//! computed with the same predicate and projection as the reference grid.

use super::ray::{hit_distance, RayFrame};
use super::{caster_facets, ShadowQuery, Tracer};
use crate::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;

/// Target number of facet entries per cell, on average.
const FACETS_PER_CELL: f64 = 2.0;
/// Largest number of cells along one axis.
const MAX_CELLS_PER_AXIS: usize = 1 << 14;

/// The tracer: remembers the mesh and which facets cast shadows.
pub struct SunView<'m> {
    mesh: &'m Mesh,
    casters: Vec<u32>,
}

impl<'m> SunView<'m> {
    pub fn new(mesh: &'m Mesh) -> SunView<'m> {
        SunView {
            mesh,
            casters: caster_facets(mesh),
        }
    }
}

impl Tracer for SunView<'_> {
    fn toward(&self, dir: DVec3) -> Box<dyn ShadowQuery + '_> {
        Box::new(SunGrid::build(self.mesh, &self.casters, RayFrame::new(dir)))
    }
}

/// One projected caster: its corners in the ray frame and its nearest-to-Sun depth.
#[derive(Clone, Copy)]
struct Projected {
    facet: u32,
    corners: [DVec3; 3],
    max_depth: f64,
}

/// The 2-D grid for one Sun direction: compressed rows of indices into `projected`.
struct SunGrid {
    frame: RayFrame,
    lo: DVec2,
    inv_cell: f64,
    dims: [usize; 2],
    cell_start: Vec<u32>,
    /// Per entry, the facet's largest depth (so most candidates are rejected without
    /// touching the facet) and its index in `projected`.
    cell_items: Vec<(f64, u32)>,
    /// Per cell, the largest depth (nearest the Sun) of any facet listed there: a ray
    /// starting nearer the Sun than that is unblocked without looking at the facets.
    cell_max_depth: Vec<f64>,
    projected: Vec<Projected>,
}

impl SunGrid {
    fn build(mesh: &Mesh, casters: &[u32], frame: RayFrame) -> SunGrid {
        let vertices: Vec<DVec3> = mesh
            .vertices
            .par_iter()
            .map(|&v| frame.project(v))
            .collect();
        let projected: Vec<Projected> = casters
            .par_iter()
            .map(|&f| {
                let corners = mesh.triangles[f as usize].map(|v| vertices[v as usize]);
                let max_depth = corners[0].z.max(corners[1].z).max(corners[2].z);
                Projected {
                    facet: f,
                    corners,
                    max_depth,
                }
            })
            .collect();
        let (lo, hi) = bounds_2d(projected.iter().flat_map(|p| p.corners));
        let extent = (hi - lo).max(DVec2::splat(1e-9 * (hi - lo).max_element().max(1e-9)));
        let cells = (projected.len() as f64 / FACETS_PER_CELL).max(1.0);
        let side = (extent.x * extent.y / cells).sqrt();
        let dims = [
            ((extent.x / side).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS),
            ((extent.y / side).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS),
        ];
        let cell = (extent.x / dims[0] as f64).max(extent.y / dims[1] as f64);
        let mut grid = SunGrid {
            frame,
            lo,
            inv_cell: 1.0 / cell,
            dims,
            cell_start: Vec::new(),
            cell_items: Vec::new(),
            cell_max_depth: Vec::new(),
            projected,
        };
        grid.bin(cell);
        grid
    }

    /// Lists every projected facet in each cell its padded 2-D bounding box overlaps.
    fn bin(&mut self, cell: f64) {
        let ranges: Vec<[usize; 4]> = self
            .projected
            .par_iter()
            .map(|p| {
                let (lo, hi) = bounds_2d(p.corners);
                // Padding makes a facet whose edge lies on a cell boundary visible from
                // both cells; the exact predicate decides the rest.
                let pad = DVec2::splat(cell * 1e-9 + (hi - lo).max_element() * 1e-9);
                let (x0, y0) = self.cell_of(lo - pad);
                let (x1, y1) = self.cell_of(hi + pad);
                [x0, y0, x1, y1]
            })
            .collect();
        let width = self.dims[0];
        let cells_of = move |r: [usize; 4]| {
            (r[1]..=r[3]).flat_map(move |y| (r[0]..=r[2]).map(move |x| y * width + x))
        };
        let mut start = vec![0u32; self.dims[0] * self.dims[1] + 1];
        for r in &ranges {
            cells_of(*r).for_each(|c| start[c + 1] += 1);
        }
        for i in 1..start.len() {
            start[i] += start[i - 1];
        }
        let mut fill = start.clone();
        let mut items = vec![(0.0, 0u32); *start.last().unwrap_or(&0) as usize];
        let mut max_depth = vec![f64::NEG_INFINITY; self.dims[0] * self.dims[1]];
        for (k, r) in ranges.iter().enumerate() {
            let depth = self.projected[k].max_depth;
            for c in cells_of(*r) {
                items[fill[c] as usize] = (depth, k as u32);
                fill[c] += 1;
                max_depth[c] = max_depth[c].max(depth);
            }
        }
        self.cell_start = start;
        self.cell_items = items;
        self.cell_max_depth = max_depth;
    }

    fn cell_of(&self, p: DVec2) -> (usize, usize) {
        let c = (p - self.lo) * self.inv_cell;
        (
            (c.x.max(0.0) as usize).min(self.dims[0] - 1),
            (c.y.max(0.0) as usize).min(self.dims[1] - 1),
        )
    }

    fn contains(&self, q: DVec2) -> bool {
        let c = (q - self.lo) * self.inv_cell;
        c.x >= 0.0 && c.y >= 0.0 && c.x <= self.dims[0] as f64 && c.y <= self.dims[1] as f64
    }
}

fn bounds_2d(points: impl IntoIterator<Item = DVec3>) -> (DVec2, DVec2) {
    points.into_iter().fold(
        (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
        |(lo, hi), c| (lo.min(c.truncate()), hi.max(c.truncate())),
    )
}

impl ShadowQuery for SunGrid {
    fn blocked(&self, origin: DVec3, t_min: f64, skip: Option<u32>) -> bool {
        let q = self.frame.project(origin);
        if self.projected.is_empty() || !self.contains(q.truncate()) {
            return false;
        }
        let (x, y) = self.cell_of(q.truncate());
        let i = y * self.dims[0] + x;
        // Interpolated depths can exceed the largest corner depth by rounding only.
        let nearest_useful = q.z + t_min;
        let slack = 1e-12 * (q.z.abs() + t_min);
        if self.cell_max_depth[i] + slack <= nearest_useful {
            return false;
        }
        let items = &self.cell_items[self.cell_start[i] as usize..self.cell_start[i + 1] as usize];
        items.iter().any(|&(max_depth, k)| {
            max_depth + slack > nearest_useful && {
                let p = &self.projected[k as usize];
                Some(p.facet) != skip && hit_distance(&p.corners, q).is_some_and(|t| t > t_min)
            }
        })
    }
}
