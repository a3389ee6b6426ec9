//! The horizon-map cache: maps built once per (mesh content, settings) and kept on disk.
//!
//! In: a mesh (its vertices in metres and its triangles), the number of azimuth wedges
//! and a cache folder. Out: a [`HorizonMap`] read back when a file for exactly that
//! content is there and intact, and a file written (to a temporary name, then renamed)
//! after a build.
//!
//! File layout (little-endian), named `horizon-<first 32 hex digits of the key>.bin`:
//!
//! | bytes | what |
//! |---|---|
//! | 8 | magic `SLIMHZN\0` |
//! | 4 | format version ([`FORMAT_VERSION`]) |
//! | 4 | azimuth wedges A |
//! | 8 | facets F |
//! | 32 | content key: SHA-256 of the format version, A, F, every vertex (f64 m) and every triangle |
//! | 4·A·F | per facet, per wedge: upper and centre elevation, u16 quanta of 90°/65535 |
//! | 32 | SHA-256 of everything above |
//!
//! A file whose size, header, key or checksum does not match is never trusted: it is
//! reported and the map is rebuilt (and the file replaced).

use super::map::HorizonMap;
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"SLIMHZN\0";

/// Bumped whenever the file layout or what a map holds changes.
pub const FORMAT_VERSION: u32 = 1;

const HEADER: usize = 8 + 4 + 4 + 8 + 32;

/// The content key of `mesh`'s map with `azimuths` wedges.
pub fn content_key(mesh: &Mesh, receivers: usize, azimuths: u32) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"slim horizon map");
    h.update(FORMAT_VERSION.to_le_bytes());
    h.update(azimuths.to_le_bytes());
    h.update((mesh.len() as u64).to_le_bytes());
    if receivers < mesh.len() {
        // Facets after the first `receivers` only cast shadows (surrounding terrain).
        h.update(b"receivers");
        h.update((receivers as u64).to_le_bytes());
    }
    for v in &mesh.vertices {
        for x in v.to_array() {
            h.update(x.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        for i in t {
            h.update(i.to_le_bytes());
        }
    }
    h.finalize().into()
}

/// The cache file for `key` in `dir`.
pub fn file_for(dir: &Path, key: &[u8; 32]) -> PathBuf {
    let hex: String = key[..16].iter().map(|b| format!("{b:02x}")).collect();
    dir.join(format!("horizon-{hex}.bin"))
}

/// What reading the cache gave.
#[derive(Debug)]
pub enum Lookup {
    /// An intact map for this content.
    Hit(HorizonMap),
    /// No file.
    Missing,
    /// A file that cannot be trusted, and why.
    Rejected(String),
}

/// Reads the map for `key` (a mesh of `facets` facets, `azimuths` wedges) from `path`.
pub fn load(path: &Path, key: &[u8; 32], facets: usize, azimuths: u32) -> Lookup {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Lookup::Missing,
        Err(e) => return Lookup::Rejected(format!("cannot be read: {e}")),
    };
    match decode(&bytes, key, facets, azimuths) {
        Ok(map) => Lookup::Hit(map),
        Err(why) => Lookup::Rejected(why),
    }
}

fn decode(
    bytes: &[u8],
    key: &[u8; 32],
    facets: usize,
    azimuths: u32,
) -> std::result::Result<HorizonMap, String> {
    let cells = facets.checked_mul(azimuths as usize).ok_or("absurd size")?;
    let expected = HEADER + 4 * cells + 32;
    if bytes.len() != expected {
        return Err(format!(
            "{} bytes, expected {expected} (truncated or another mesh)",
            bytes.len()
        ));
    }
    if &bytes[..8] != MAGIC {
        return Err("not a slim horizon map (bad magic)".into());
    }
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let version = u32_at(8);
    if version != FORMAT_VERSION {
        return Err(format!(
            "format version {version}, this slim writes {FORMAT_VERSION}"
        ));
    }
    let stored_azimuths = u32_at(12);
    let stored_facets = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes"));
    if stored_azimuths != azimuths || stored_facets != facets as u64 {
        return Err(format!(
            "holds {stored_facets} facets × {stored_azimuths} wedges, expected {facets} × {azimuths}"
        ));
    }
    if &bytes[24..56] != key {
        return Err("built from other mesh content or settings (content key differs)".into());
    }
    let body = expected - 32;
    let sum: [u8; 32] = Sha256::digest(&bytes[..body]).into();
    if sum[..] != bytes[body..] {
        return Err("checksum mismatch (corrupt)".into());
    }
    let cells: Vec<[u16; 2]> = bytes[HEADER..body]
        .chunks_exact(4)
        .map(|c| {
            [
                u16::from_le_bytes([c[0], c[1]]),
                u16::from_le_bytes([c[2], c[3]]),
            ]
        })
        .collect();
    HorizonMap::from_cells(azimuths, facets, cells).ok_or_else(|| "inconsistent sizes".into())
}

/// Writes `map` for `key` to `path` (temporary file, then rename).
pub fn store(path: &Path, key: &[u8; 32], map: &HorizonMap) -> Result<()> {
    let mut bytes = Vec::with_capacity(HEADER + map.bytes() + 32);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&map.azimuths().to_le_bytes());
    bytes.extend_from_slice(&(map.facets() as u64).to_le_bytes());
    bytes.extend_from_slice(key);
    for [up, mid] in map.cells() {
        bytes.extend_from_slice(&up.to_le_bytes());
        bytes.extend_from_slice(&mid.to_le_bytes());
    }
    let sum: [u8; 32] = Sha256::digest(&bytes).into();
    bytes.extend_from_slice(&sum);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    write_atomic(path, &bytes)
}

/// The cache folder when the scene names none: `$SLIM_CACHE_DIR`, else
/// `$XDG_CACHE_HOME/slim`, else `$HOME/.cache/slim`; `None` when none is set.
pub fn default_dir() -> Option<PathBuf> {
    let var = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    var("SLIM_CACHE_DIR")
        .or_else(|| var("XDG_CACHE_HOME").map(|d| d.join("slim")))
        .or_else(|| var("HOME").map(|d| d.join(".cache").join("slim")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::icosphere;
    use crate::mesh::LengthUnit;
    use crate::trace::bvh::Bvh;

    #[test]
    fn a_stored_map_reads_back_and_any_damage_or_other_content_is_refused() {
        let dir = std::env::temp_dir().join(format!("slim-horizon-cache-{}", std::process::id()));
        let mesh = Mesh::from_raw(icosphere(1, 1.0, glam::DVec3::ZERO), LengthUnit::Km);
        let map =
            HorizonMap::build(&mesh, mesh.len(), &Bvh::build(&mesh), 16, &|| false).expect("map");
        let key = content_key(&mesh, mesh.len(), 16);
        let file = file_for(&dir, &key);
        assert!(matches!(load(&file, &key, mesh.len(), 16), Lookup::Missing));
        store(&file, &key, &map).expect("store");
        match load(&file, &key, mesh.len(), 16) {
            Lookup::Hit(read) => assert_eq!(read, map),
            other => panic!("{other:?}"),
        }
        // Another wedge count or mesh gives another key; the same file under it is refused.
        let other = content_key(&mesh, mesh.len(), 32);
        assert_ne!(other, key);
        assert!(matches!(
            load(&file, &other, mesh.len(), 16),
            Lookup::Rejected(_)
        ));
        let bytes = std::fs::read(&file).expect("read");
        let mut flipped = bytes.clone();
        flipped[HEADER + 5] ^= 1;
        std::fs::write(&file, &flipped).expect("write");
        match load(&file, &key, mesh.len(), 16) {
            Lookup::Rejected(why) => assert!(why.contains("checksum"), "{why}"),
            other => panic!("{other:?}"),
        }
        std::fs::write(&file, &bytes[..bytes.len() - 7]).expect("write");
        assert!(matches!(
            load(&file, &key, mesh.len(), 16),
            Lookup::Rejected(_)
        ));
        std::fs::write(&file, b"").expect("write");
        assert!(matches!(
            load(&file, &key, mesh.len(), 16),
            Lookup::Rejected(_)
        ));
        std::fs::remove_dir_all(&dir).ok();
    }
}
