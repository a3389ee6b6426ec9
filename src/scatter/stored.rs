//! Form factors kept between runs: a body's own block of exchange areas, cached per
//! (mesh content, near-field settings) in the scene's cache folder ([`crate::cache`]:
//! envelope, checksum, folder).
//!
//! In: a mesh, the near-field settings and a file. Out: the block (capped, as the stage
//! uses it) with its largest row sum and capped-row count, read back when the file holds
//! exactly that content intact; a file written after a build. Only a body's own block
//! is kept: blocks between bodies depend on their poses.
//!
//! Payload (little-endian), in files named `form-factors-<key>.bin`: the largest row sum
//! (f64), the capped rows (u64), then the matrix as [`Csr::encode`] writes it. The
//! content key is the SHA-256 of the format version, the source of the code that builds
//! a block (this stage, the form factors, visibility, storage, the tracers' interface
//! that picks the tree's facets, the tree, the ray predicate and the mesh's centroids,
//! normals and areas, unit tests left out: changed code never reads an old block), the
//! near-field settings, and the mesh's facet count, vertices (f64 m) and triangles.

use super::csr::Csr;
use super::form_factor::NearField;
use crate::cache::{self, Kind, Lookup, Reader};
use crate::error::Result;
use crate::mesh::Mesh;
use sha2::Digest;
use std::path::Path;

/// Form-factor files.
pub const KIND: Kind = Kind {
    magic: b"SLIMFFB\0",
    version: 1,
    prefix: "form-factors",
};

/// A body's own exchange areas as the stage keeps them.
#[derive(Debug, Clone, PartialEq)]
pub struct OwnBlock {
    pub block: Csr,
    /// Largest row sum Σ_j F_ij before capping.
    pub max_row_sum: f64,
    /// Rows whose sum exceeded 1 and were scaled down.
    pub rows_capped: usize,
}

/// The content key of `mesh`'s own block with these near-field settings.
pub fn content_key(mesh: &Mesh, near: &NearField) -> [u8; 32] {
    let own = [
        include_str!("mod.rs"),
        include_str!("form_factor.rs"),
        include_str!("visibility.rs"),
        include_str!("csr.rs"),
        include_str!("stored.rs"),
    ];
    let tree = cache::TREE_SOURCES.map(|(_, text)| text);
    let mut h = cache::key_hasher(b"slim form factors", &KIND, &[&own[..], &tree[..]].concat());
    h.update(near.far_ratio.to_le_bytes());
    h.update(near.tolerance.to_le_bytes());
    h.update(near.max_depth.to_le_bytes());
    cache::mesh_content(&mut h, mesh);
    h.finalize().into()
}

/// Reads the block for `key` (a mesh of `facets` facets) from `path`.
pub fn load(path: &Path, key: &[u8; 32], facets: usize) -> Lookup<OwnBlock> {
    cache::load(path, &KIND, key).decode(|payload| {
        let mut r = Reader::new(&payload);
        let max_row_sum = r.f64("the largest row sum")?;
        let rows_capped = r.u64("the capped rows")? as usize;
        let block = Csr::decode(&mut r, facets, facets)?;
        r.finish()?;
        if !block.symmetric {
            return Err("not a symmetric block".into());
        }
        Ok(OwnBlock {
            block,
            max_row_sum,
            rows_capped,
        })
    })
}

/// Writes `own` for `key` to `path` (temporary file, then rename).
pub fn store(path: &Path, key: &[u8; 32], own: &OwnBlock) -> Result<()> {
    let mut payload = Vec::with_capacity(16 + own.block.bytes() + 64);
    payload.extend_from_slice(&own.max_row_sum.to_le_bytes());
    payload.extend_from_slice(&(own.rows_capped as u64).to_le_bytes());
    own.block.encode(&mut payload);
    cache::store(path, &KIND, key, &payload)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::height_field;
    use crate::mesh::LengthUnit;
    use crate::scatter::visibility::own_block;
    use crate::trace::bvh::Bvh;

    #[test]
    fn a_stored_block_reads_back_bit_for_bit_and_other_content_is_refused() {
        let dir = crate::TempDir::new("unit", "ff-cache");
        // A rough field, so that facets see each other.
        let raw = height_field((6, 6), (0.0, 6.0), (0.0, 6.0), |x, y| {
            (x * 1.7).sin() + (y * 2.3).cos()
        });
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let near = NearField::default();
        let own = OwnBlock {
            block: own_block(&mesh, &Bvh::build(&mesh), &near),
            max_row_sum: 0.7,
            rows_capped: 2,
        };
        assert!(own.block.nnz() > 0);
        let key = content_key(&mesh, &near);
        let file = cache::file_for(&dir, &KIND, &key);
        assert!(matches!(load(&file, &key, mesh.len()), Lookup::Missing));
        store(&file, &key, &own).expect("store");
        match load(&file, &key, mesh.len()) {
            Lookup::Hit(read) => assert_eq!(read, own),
            other => panic!("{other:?}"),
        }
        // Other near-field settings or another facet count are refused.
        let finer = NearField {
            far_ratio: 32.0,
            ..near
        };
        assert_ne!(content_key(&mesh, &finer), key);
        assert!(matches!(
            load(&file, &key, mesh.len() + 1),
            Lookup::Rejected(_)
        ));
    }
}
