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
//! The per-step buffers (tens of MB for large meshes) are kept between steps: allocating
//! them afresh made the kernel zero new pages every step.
//!
//! The cells are coarsened only if the casters would fill more entries than `u32` offsets
//! address (see `trace::cells`); no real mesh comes near.
//!
//! In: a mesh (metres, body frame) and a unit Sun direction. Out: [`ShadowQuery`] answers
//! computed with the same predicate and projection as the reference grid.

use super::cells::{CellLists, Cover, TooManyEntries};
use super::ray::{blocks, DepthPlane, RayFrame};
use super::{caster_facets, ShadowQuery, Tracer};
use crate::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::sync::Mutex;

/// Target number of facet entries per cell, on average.
const FACETS_PER_CELL: f64 = 2.0;
/// Largest number of cells along one axis.
const MAX_CELLS_PER_AXIS: usize = 1 << 14;

/// The tracer: the mesh, the facets that cast shadows, and buffers kept between steps.
pub struct SunView<'m> {
    mesh: &'m Mesh,
    casters: Vec<u32>,
    spare: Mutex<Option<Buffers>>,
}

impl<'m> SunView<'m> {
    pub fn new(mesh: &'m Mesh) -> SunView<'m> {
        SunView {
            mesh,
            casters: caster_facets(mesh),
            spare: Mutex::new(None),
        }
    }
}

impl Tracer for SunView<'_> {
    fn toward(&self, dir: DVec3) -> Box<dyn ShadowQuery + '_> {
        let buffers = self
            .spare
            .lock()
            .ok()
            .and_then(|mut s| s.take())
            .unwrap_or_default();
        Box::new(SunGrid::build(self, buffers, RayFrame::new(dir)))
    }
}

/// Storage of one Sun-view grid, reused from step to step.
#[derive(Default)]
struct Buffers {
    /// Every vertex in the ray frame.
    vertices: Vec<DVec3>,
    /// Per caster: its cell range [x0, y0, x1, y1] and its largest depth.
    ranges: Vec<([u32; 4], f64)>,
    /// Per caster: its projected corners and depth plane, in one record so a candidate
    /// costs one memory access.
    projected: Vec<Projected>,
    /// Per cell, per caster listed there: the facet's largest depth (candidates behind
    /// the ray's origin are rejected on it alone) and the caster's index.
    items: CellLists<(f64, u32)>,
    /// Per cell, the largest depth of any facet listed there: a ray starting nearer the
    /// Sun than that is unblocked without looking at the facets.
    cell_max_depth: Vec<f64>,
}

/// A caster in the ray frame.
#[derive(Clone, Copy)]
struct Projected {
    corners: [DVec3; 3],
    plane: DepthPlane,
}

/// The 2-D grid for one Sun direction.
struct SunGrid<'v, 'm> {
    view: &'v SunView<'m>,
    frame: RayFrame,
    lo: DVec2,
    inv_cell: f64,
    dims: [usize; 2],
    buf: Buffers,
}

impl<'v, 'm> SunGrid<'v, 'm> {
    fn build(view: &'v SunView<'m>, mut buf: Buffers, frame: RayFrame) -> SunGrid<'v, 'm> {
        let mesh = view.mesh;
        buf.vertices.clear();
        mesh.vertices
            .par_iter()
            .map(|&v| frame.project(v))
            .collect_into_vec(&mut buf.vertices);
        let (lo, hi) = view
            .casters
            .par_iter()
            .map(|&f| bounds_2d(corners(mesh, &buf.vertices, f)))
            .reduce(empty_bounds, |a, b| (a.0.min(b.0), a.1.max(b.1)));
        let extent = (hi - lo).max(DVec2::splat(1e-9 * (hi - lo).max_element().max(1e-9)));
        let cells = (view.casters.len() as f64 / FACETS_PER_CELL).max(1.0);
        let side = (extent.x * extent.y / cells).sqrt();
        let dims = [
            ((extent.x / side).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS),
            ((extent.y / side).ceil() as usize).clamp(1, MAX_CELLS_PER_AXIS),
        ];
        let mut grid = SunGrid {
            view,
            frame,
            lo,
            inv_cell: 0.0,
            dims,
            buf,
        };
        grid.project_casters();
        loop {
            let cell = (extent.x / grid.dims[0] as f64).max(extent.y / grid.dims[1] as f64);
            grid.inv_cell = 1.0 / cell;
            // With one cell every caster is one entry, which always fits.
            if grid.bin(cell).is_ok() || grid.dims == [1, 1] {
                return grid;
            }
            grid.dims = grid.dims.map(|n| n.div_ceil(2));
        }
    }

    /// Every caster's corners and depth plane in the ray frame.
    fn project_casters(&mut self) {
        let (mesh, frame, vertices) = (self.view.mesh, self.frame, &self.buf.vertices);
        self.view
            .casters
            .par_iter()
            .map(|&f| {
                let corners = corners(mesh, vertices, f);
                let normal = frame.project(mesh.normals[f as usize]);
                Projected {
                    corners,
                    plane: DepthPlane::new(normal, corners[0]),
                }
            })
            .collect_into_vec(&mut self.buf.projected);
    }

    /// Lists every caster in each cell its padded 2-D bounding box overlaps.
    fn bin(&mut self, cell: f64) -> Result<(), TooManyEntries> {
        let mesh = self.view.mesh;
        let mut buf = std::mem::take(&mut self.buf);
        let vertices = &buf.vertices;
        self.view
            .casters
            .par_iter()
            .map(|&f| {
                let c = corners(mesh, vertices, f);
                let (lo, hi) = bounds_2d(c);
                // Padding makes a facet whose edge lies on a cell boundary visible from
                // both cells; the exact predicate decides the rest.
                let pad = DVec2::splat(cell * 1e-9 + (hi - lo).max_element() * 1e-9);
                let (x0, y0) = self.cell_of(lo - pad);
                let (x1, y1) = self.cell_of(hi + pad);
                (
                    [x0, y0, x1, y1].map(|i| i as u32),
                    c[0].z.max(c[1].z).max(c[2].z),
                )
            })
            .collect_into_vec(&mut buf.ranges);
        let width = self.dims[0];
        let n_cells = self.dims[0] * self.dims[1];
        let ranges = &buf.ranges;
        let built = buf.items.build(
            n_cells,
            ranges.len(),
            |k| CellRect {
                range: ranges[k].0,
                width,
            },
            |k| (ranges[k].1, k as u32),
        );
        let items = &buf.items;
        buf.cell_max_depth.clear();
        buf.cell_max_depth.extend((0..n_cells).map(|c| {
            items
                .cell(c)
                .iter()
                .fold(f64::NEG_INFINITY, |max, &(depth, _)| max.max(depth))
        }));
        self.buf = buf;
        built
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

impl Drop for SunGrid<'_, '_> {
    fn drop(&mut self) {
        if let Ok(mut spare) = self.view.spare.lock() {
            *spare = Some(std::mem::take(&mut self.buf));
        }
    }
}

/// Facet `f`'s corners in the ray frame.
#[inline]
fn corners(mesh: &Mesh, projected: &[DVec3], f: u32) -> [DVec3; 3] {
    mesh.triangles[f as usize].map(|v| projected[v as usize])
}

fn empty_bounds() -> (DVec2, DVec2) {
    (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY))
}

fn bounds_2d(points: [DVec3; 3]) -> (DVec2, DVec2) {
    points.iter().fold(empty_bounds(), |(lo, hi), c| {
        (lo.min(c.truncate()), hi.max(c.truncate()))
    })
}

/// The cells `[x0, y0, x1, y1]` (inclusive) of a grid `width` cells wide, x fastest.
#[derive(Clone, Copy)]
struct CellRect {
    range: [u32; 4],
    width: usize,
}

impl Cover for CellRect {
    fn cell_count(&self) -> u64 {
        let [x0, y0, x1, y1] = self.range.map(u64::from);
        (x1 + 1).saturating_sub(x0) * (y1 + 1).saturating_sub(y0)
    }

    fn cells(&self) -> impl Iterator<Item = usize> {
        let [x0, y0, x1, y1] = self.range.map(|i| i as usize);
        let width = self.width;
        (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| y * width + x))
    }
}

impl ShadowQuery for SunGrid<'_, '_> {
    fn blocked(&self, origin: DVec3, t_min: f64, skip: Option<u32>) -> bool {
        let q = self.frame.project(origin);
        if self.view.casters.is_empty() || !self.contains(q.truncate()) {
            return false;
        }
        let (x, y) = self.cell_of(q.truncate());
        let i = y * self.dims[0] + x;
        // Interpolated depths can exceed the largest corner depth by rounding only.
        let nearest_useful = q.z + t_min;
        let slack = 1e-12 * (q.z.abs() + t_min);
        if self.buf.cell_max_depth[i] + slack <= nearest_useful {
            return false;
        }
        self.buf.items.cell(i).iter().any(|&(max_depth, k)| {
            max_depth + slack > nearest_useful && {
                let p = &self.buf.projected[k as usize];
                Some(self.view.casters[k as usize]) != skip
                    && blocks(&p.corners, &p.plane, q, t_min)
            }
        })
    }
}
