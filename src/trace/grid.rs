//! The SLIM paper's reference tracer: a 3-D uniform grid over the body's bounding box,
//! traversed with the Amanatides–Woo algorithm ("A fast voxel traversal algorithm for ray
//! tracing", Eurographics 1987).
//!
//! In: a mesh (metres, body frame). Built once and reused for every Sun direction. Each
//! facet is listed in every cell its (slightly padded) bounding box overlaps, so a facet
//! touching a cell face is found from both sides. A query walks the cells the ray crosses,
//! from the cell holding the origin (or the ray's entry into the box) until it leaves the
//! box, and tests the facets listed there with the shared exact predicate.
//!
//! The cells are coarsened only if the facets would fill more entries than `u32` offsets
//! address (see `trace::cells`); no real mesh comes near.

use super::cells::{CellLists, Cover, TooManyEntries};
use super::ray::{blocks, DepthPlane, RayFrame};
use super::{caster_facets, ShadowQuery, Tracer};
use crate::mesh::Mesh;
use glam::{DVec3, IVec3};

/// Target number of facet entries per cell, on average.
const FACETS_PER_CELL: f64 = 2.0;
/// Largest number of cells along one axis.
const MAX_CELLS_PER_AXIS: i32 = 1024;

/// A uniform 3-D grid of facet lists.
pub struct UniformGrid<'m> {
    mesh: &'m Mesh,
    lo: DVec3,
    cell: DVec3,
    dims: IVec3,
    facets: CellLists<u32>,
}

impl<'m> UniformGrid<'m> {
    /// Bins every facet with non-zero area.
    pub fn build(mesh: &'m Mesh) -> UniformGrid<'m> {
        let casters = caster_facets(mesh);
        let (lo, hi) = mesh.bounds();
        let extent = (hi - lo).max(DVec3::splat(1e-9 * (hi - lo).max_element().max(1e-9)));
        let pad = extent * 1e-9;
        let (lo, extent) = (lo - pad, extent + 2.0 * pad);
        let mut dims = grid_dims(extent, casters.len());
        loop {
            let mut grid = UniformGrid {
                mesh,
                lo,
                cell: extent / dims.as_dvec3(),
                dims,
                facets: CellLists::default(),
            };
            // With one cell every facet is one entry, which always fits.
            if grid.bin(&casters).is_ok() || dims == IVec3::ONE {
                return grid;
            }
            dims = (dims + 1) / 2;
        }
    }

    /// Lists every caster in each cell its padded bounding box overlaps.
    fn bin(&mut self, casters: &[u32]) -> Result<(), TooManyEntries> {
        let boxes: Vec<CellBox> = casters
            .iter()
            .map(|&f| {
                let [a, b, c] = self.mesh.corners(f as usize);
                let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
                let pad = (hi - lo).max_element() * 1e-9 + self.cell.min_element() * 1e-9;
                CellBox {
                    lo: self.cell_of(lo - DVec3::splat(pad)),
                    hi: self.cell_of(hi + DVec3::splat(pad)),
                    dims: self.dims,
                }
            })
            .collect();
        let n_cells = (self.dims.x * self.dims.y * self.dims.z) as usize;
        self.facets
            .build(n_cells, casters.len(), |k| boxes[k], |k| casters[k])
    }

    fn cell_of(&self, p: DVec3) -> IVec3 {
        let c = ((p - self.lo) / self.cell).floor();
        IVec3::new(c.x as i32, c.y as i32, c.z as i32).clamp(IVec3::ZERO, self.dims - 1)
    }

    fn facets_in(&self, c: IVec3) -> &[u32] {
        self.facets.cell(cell_index(self.dims, c))
    }

    /// Parameter range `[t_enter, t_exit]` of the ray inside the grid box, if it meets it.
    fn clip(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let hi = self.lo + self.cell * self.dims.as_dvec3();
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if d[k] == 0.0 {
                if o[k] < self.lo[k] || o[k] > hi[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((self.lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        (t0 <= t1).then_some((t0, t1))
    }
}

/// Cells per axis so that the grid holds about `FACETS_PER_CELL` facets per cell.
fn grid_dims(extent: DVec3, facets: usize) -> IVec3 {
    let cells = (facets.max(1) as f64 / FACETS_PER_CELL).max(1.0);
    let side = (extent.x * extent.y * extent.z / cells).cbrt();
    let n = (extent / side).ceil();
    IVec3::new(n.x as i32, n.y as i32, n.z as i32)
        .clamp(IVec3::ONE, IVec3::splat(MAX_CELLS_PER_AXIS))
}

/// Index of cell `c` in a grid of `dims` cells, x fastest.
fn cell_index(dims: IVec3, c: IVec3) -> usize {
    ((c.z * dims.y + c.y) * dims.x + c.x) as usize
}

/// The cells `lo..=hi` (inclusive on every axis) of a grid of `dims` cells.
#[derive(Clone, Copy)]
struct CellBox {
    lo: IVec3,
    hi: IVec3,
    dims: IVec3,
}

impl Cover for CellBox {
    fn cell_count(&self) -> u64 {
        let n = (self.hi - self.lo + 1).max(IVec3::ZERO).to_array();
        n.iter().map(|&side| side as u64).product()
    }

    fn cells(&self) -> impl Iterator<Item = usize> {
        let CellBox { lo, hi, dims } = *self;
        (lo.z..=hi.z).flat_map(move |z| {
            (lo.y..=hi.y).flat_map(move |y| {
                (lo.x..=hi.x).map(move |x| cell_index(dims, IVec3::new(x, y, z)))
            })
        })
    }
}

impl Tracer for UniformGrid<'_> {
    fn toward(&self, dir: DVec3) -> Box<dyn ShadowQuery + '_> {
        Box::new(GridQuery {
            grid: self,
            frame: RayFrame::new(dir),
        })
    }
}

struct GridQuery<'g, 'm> {
    grid: &'g UniformGrid<'m>,
    frame: RayFrame,
}

impl GridQuery<'_, '_> {
    fn cell_blocks(&self, cell: IVec3, q: DVec3, t_min: f64, skip: Option<u32>) -> bool {
        let mesh = self.grid.mesh;
        self.grid.facets_in(cell).iter().any(|&f| {
            let tri = mesh.corners(f as usize).map(|p| self.frame.project(p));
            let plane = DepthPlane::new(self.frame.project(mesh.normals[f as usize]), tri[0]);
            Some(f) != skip && blocks(&tri, &plane, q, t_min)
        })
    }
}

impl ShadowQuery for GridQuery<'_, '_> {
    fn blocked(&self, origin: DVec3, t_min: f64, skip: Option<u32>) -> bool {
        let g = self.grid;
        let d = self.frame.dir();
        let Some((t_enter, t_exit)) = g.clip(origin, d) else {
            return false;
        };
        let q = self.frame.project(origin);
        let mut cell = g.cell_of(origin + d * t_enter);
        let step = IVec3::new(sign(d.x), sign(d.y), sign(d.z));
        let mut t_next = DVec3::ZERO;
        let mut t_delta = DVec3::ZERO;
        for k in 0..3 {
            if step[k] == 0 {
                t_next[k] = f64::INFINITY;
                t_delta[k] = f64::INFINITY;
                continue;
            }
            let boundary = g.lo[k] + g.cell[k] * (cell[k] + (step[k] > 0) as i32) as f64;
            t_next[k] = (boundary - origin[k]) / d[k];
            t_delta[k] = g.cell[k] / d[k].abs();
        }
        loop {
            if self.cell_blocks(cell, q, t_min, skip) {
                return true;
            }
            let k = if t_next.x <= t_next.y && t_next.x <= t_next.z {
                0
            } else if t_next.y <= t_next.z {
                1
            } else {
                2
            };
            if t_next[k] > t_exit {
                return false;
            }
            cell[k] += step[k];
            if cell[k] < 0 || cell[k] >= g.dims[k] {
                return false;
            }
            t_next[k] += t_delta[k];
        }
    }
}

fn sign(x: f64) -> i32 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}
