//! PLY export of per-facet statistics, for ParaView and MeshLab.
//!
//! In: a body's mesh (metres) and its statistics. Out: a binary little-endian PLY with
//! float vertex coordinates (metres, body frame) and per-face float properties
//! `mean_w_m2`, `max_w_m2`, `min_w_m2`, `lit_fraction`, written atomically.

use crate::atomic::{commit, create_partial};
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::stats::FacetStats;
use std::io::Write;
use std::path::Path;

/// Writes `path` for the facets `offset .. offset + mesh.len()` of `stats`.
pub fn write_ply(path: &Path, mesh: &Mesh, stats: &FacetStats, offset: usize) -> Result<()> {
    let (tmp, mut out) = create_partial(path)?;
    write_body(&mut out, mesh, stats, offset)
        .and_then(|_| out.flush())
        .map_err(|e| Error::io(&tmp, e))?;
    drop(out);
    commit(&tmp, path)
}

fn write_body(
    out: &mut impl Write,
    mesh: &Mesh,
    stats: &FacetStats,
    offset: usize,
) -> std::io::Result<()> {
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\n\
         comment slim {}: direct solar irradiance statistics per face, W/m2; coordinates in metres\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\n\
         property float mean_w_m2\nproperty float max_w_m2\nproperty float min_w_m2\n\
         property float lit_fraction\nend_header\n",
        env!("CARGO_PKG_VERSION"),
        mesh.vertices.len(),
        mesh.len()
    )?;
    for v in &mesh.vertices {
        for c in v.to_array() {
            out.write_all(&(c as f32).to_le_bytes())?;
        }
    }
    for (i, t) in mesh.triangles.iter().enumerate() {
        out.write_all(&[3u8])?;
        for &v in t {
            out.write_all(&(v as i32).to_le_bytes())?;
        }
        let g = offset + i;
        for value in [
            stats.mean(g),
            stats.max(g),
            stats.min(g),
            stats.lit_fraction(g),
        ] {
            out.write_all(&(value as f32).to_le_bytes())?;
        }
    }
    Ok(())
}
