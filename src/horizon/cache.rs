//! The horizon cache: maps, and the BVH tracer's horizon bounds, built once per (mesh
//! content, settings) and kept on disk ([`crate::cache`]: the file's envelope, checksum
//! and folder).
//!
//! In: a mesh (its vertices in metres and its triangles), how many of its facets receive,
//! the number of azimuth wedges and a file. Out: a [`HorizonMap`] read back when the file
//! holds exactly that content intact, and a file written after a build. While a map is
//! built, its finished parts ([`MapParts`]) go to a build journal beside the file
//! (`horizon-<key>.bin.journal`, [`crate::journal`]), each part's cells laid out as in
//! the payload, so that a build stopped part-way resumes from them. Other processes that
//! need the same map meanwhile build parts the builder has not reached: each claimed
//! first ([`claim_part`]) and stored as a part file ([`store_part`], [`PART_KIND`]) that
//! the builder takes ([`load_part`]) instead of building the part.
//!
//! Payload (little-endian), in files named `horizon-<key>.bin`:
//!
//! | bytes | what |
//! |---|---|
//! | 4 | azimuth wedges A |
//! | 8 | facets F |
//! | 4·A·F | per facet, per wedge: upper and centre elevation, u16 quanta of 90°/65535 |
//!
//! The content key is the SHA-256 of the format version, the source of the code that
//! builds a map (the map, its triangles' outlines, its geometry, this file, the tree, the
//! ray predicate and the mesh's centroids and normals: `map_sources`, unit tests left
//! out, so that changed code never reads an old map), A, the receiving facets, every
//! vertex (f64 m) and every triangle.

use super::band::SunBand;
use super::bound::{BoundDetail, HorizonBound};
use super::map::{HorizonMap, MapKind, MapParts};
use crate::cache::{self, Kind, Lookup, Reader};
use crate::error::Result;
use crate::journal::{Journal, Opened};
use crate::mesh::Mesh;
use sha2::Digest;
use std::path::{Path, PathBuf};

/// Horizon-map files; version 2 moved to the shared envelope.
pub const KIND: Kind = Kind {
    magic: b"SLIMHZN\0",
    version: 2,
    prefix: "horizon",
};

/// Horizon-bound files ([`HorizonBound`]): payload the facet count F (u64), then per
/// facet its sine in 255ths (one byte), or [`super::bound::SECTORS`] of them for a bound
/// by sectors, in files named `horizon-bound-<key>.bin`. The key hashes the format
/// version, the code that builds a bound (the bound and the map's code, whose seeded runs
/// it shares), the receiving facets, the detail and the mesh's content.
pub const BOUND_KIND: Kind = Kind {
    magic: b"SLIMHZB\0",
    version: 2,
    prefix: "horizon-bound",
};

/// Parts of a map built by a helping process ([`part_file`]): payload the part's number
/// (u64), its first facet (u64) and the wedge count A (u32), then its facets' rows as in
/// the map's payload; the key is the map's.
pub const PART_KIND: Kind = Kind {
    magic: b"SLIMHZP\0",
    version: 1,
    prefix: "horizon-part",
};

/// The code that builds a map, path (from this folder) and text: every file of the
/// horizon and of the tree that the build imports, and those they import
/// (`the_keys_hash_every_file_their_builds_import` holds the list to the code), and the
/// mesh's own file, which derives the facets' centroids and normals from the vertices
/// the key hashes ([`cache::TREE_SOURCES`]). The sky lookups (`sky.rs`) are not among
/// them: they read a map, they do not make it.
fn map_sources() -> Vec<(&'static str, &'static str)> {
    let own = [
        ("map.rs", include_str!("map.rs")),
        ("band.rs", include_str!("band.rs")),
        ("outline.rs", include_str!("outline.rs")),
        ("geometry.rs", include_str!("geometry.rs")),
        ("cache.rs", include_str!("cache.rs")),
    ];
    own.into_iter().chain(cache::TREE_SOURCES).collect()
}

/// The code that builds a horizon bound: its own file, and the map's (whose seeded runs
/// it shares).
fn bound_sources() -> Vec<(&'static str, &'static str)> {
    let own = ("bound.rs", include_str!("bound.rs"));
    std::iter::once(own).chain(map_sources()).collect()
}

/// The texts of `sources`.
fn texts<'a>(sources: &[(&str, &'a str)]) -> Vec<&'a str> {
    sources.iter().map(|&(_, text)| text).collect()
}

/// The content key of the horizon bound of `mesh`'s first `receivers` facets, in `detail`.
pub fn bound_key(mesh: &Mesh, receivers: usize, detail: BoundDetail) -> [u8; 32] {
    let mut h = cache::key_hasher(b"slim horizon bound", &BOUND_KIND, &texts(&bound_sources()));
    h.update((receivers as u64).to_le_bytes());
    h.update([u8::from(detail == BoundDetail::Sectors)]);
    cache::mesh_content(&mut h, mesh);
    h.finalize().into()
}

/// Reads the bound for `key` of `mesh`'s first `receivers` facets, in `detail`, from `path`.
pub fn load_bound(
    path: &Path,
    key: &[u8; 32],
    mesh: &Mesh,
    (receivers, detail): (usize, BoundDetail),
) -> Lookup<HorizonBound> {
    cache::load(path, &BOUND_KIND, key).decode(|payload| {
        let mut r = Reader::new(&payload);
        let stored = r.u64("the facet count")?;
        if stored != receivers as u64 {
            return Err(format!("holds {stored} facets, expected {receivers}"));
        }
        let sines = r
            .items(receivers, detail.stride(), "the sines")?
            .flatten()
            .copied()
            .collect();
        r.finish()?;
        Ok(HorizonBound::from_sines(mesh, sines, detail))
    })
}

/// Writes `bound` for `key` to `path` (temporary file, then rename), without a second
/// copy of its sines.
pub fn store_bound(path: &Path, key: &[u8; 32], bound: &HorizonBound) -> Result<()> {
    let sines = bound.sines();
    let facets = sines.len() / bound.detail().stride();
    let head = (facets as u64).to_le_bytes().to_vec();
    store_streamed(path, &BOUND_KIND, key, head, sines, <[u8]>::to_vec)
}

/// The content key of `mesh`'s map of `kind` with `azimuths` wedges for Suns of `band`.
pub fn content_key(
    mesh: &Mesh,
    receivers: usize,
    (azimuths, band, kind): (u32, SunBand, MapKind),
) -> [u8; 32] {
    let mut h = cache::key_hasher(b"slim horizon map", &KIND, &texts(&map_sources()));
    h.update(azimuths.to_le_bytes());
    if kind == MapKind::Centres {
        h.update(b"centres");
    }
    if !band.is_whole() {
        h.update(b"band");
        h.update(band.key_bytes());
    }
    if receivers < mesh.len() {
        // Facets after the first `receivers` only cast shadows (surrounding terrain).
        h.update(b"receivers");
        h.update((receivers as u64).to_le_bytes());
    }
    cache::mesh_content(&mut h, mesh);
    h.finalize().into()
}

/// The cache file for `key` in `dir`.
pub fn file_for(dir: &Path, key: &[u8; 32]) -> PathBuf {
    cache::file_for(dir, &KIND, key)
}

/// Reads the map of `kind` for `key` (a mesh of `facets` facets, `azimuths` wedges) from
/// `path`.
pub fn load(
    path: &Path,
    key: &[u8; 32],
    facets: usize,
    (azimuths, kind): (u32, MapKind),
) -> Lookup<HorizonMap> {
    cache::load(path, &KIND, key).decode(|payload| decode(&payload, facets, (azimuths, kind)))
}

fn decode(
    payload: &[u8],
    facets: usize,
    (azimuths, kind): (u32, MapKind),
) -> std::result::Result<HorizonMap, String> {
    let mut r = Reader::new(payload);
    let stored_azimuths = r.u32("the wedge count")?;
    let stored_facets = r.u64("the facet count")?;
    if stored_azimuths != azimuths || stored_facets != facets as u64 {
        return Err(format!(
            "holds {stored_facets} facets × {stored_azimuths} wedges, expected {facets} × {azimuths}"
        ));
    }
    let cells = facets.checked_mul(azimuths as usize).ok_or("absurd size")?;
    let cells = cells_from(r.take(4 * cells, "the elevations")?);
    r.finish()?;
    HorizonMap::from_cells((azimuths, kind), facets, cells)
        .ok_or_else(|| "inconsistent sizes".into())
}

/// Values (map cells, bound sines) turned into payload bytes at a time when a file is
/// stored: 1 MiB of either, both being 4 bytes a value.
const VALUES_PER_PIECE: usize = 1 << 18;

/// Writes `map` for `key` to `path` (temporary file, then rename), its cells a piece at a
/// time, so that storing a map holds no second copy of it.
pub fn store(path: &Path, key: &[u8; 32], map: &HorizonMap) -> Result<()> {
    let facets = map.facets();
    let mut head = map.azimuths().to_le_bytes().to_vec();
    head.extend_from_slice(&(facets as u64).to_le_bytes());
    let per_piece = (VALUES_PER_PIECE / map.azimuths() as usize).max(1);
    let pieces = (0..facets)
        .step_by(per_piece)
        .map(|first| cell_bytes(map.rows(first..(first + per_piece).min(facets))).collect());
    cache::store_pieces(path, &KIND, key, std::iter::once(head).chain(pieces))
}

/// Stores `head` and then `values` as the payload of a `kind` file, the values turned
/// into bytes by `bytes` a piece of [`VALUES_PER_PIECE`] at a time.
fn store_streamed<T>(
    path: &Path,
    kind: &Kind,
    key: &[u8; 32],
    head: Vec<u8>,
    values: &[T],
    bytes: impl Fn(&[T]) -> Vec<u8>,
) -> Result<()> {
    let pieces = values.chunks(VALUES_PER_PIECE).map(bytes);
    cache::store_pieces(path, kind, key, std::iter::once(head).chain(pieces))
}

/// Cells as the payload holds them: upper, then centre, 2 bytes each.
fn cell_bytes(cells: impl IntoIterator<Item = [u16; 2]>) -> impl Iterator<Item = u8> {
    cells
        .into_iter()
        .flat_map(|[up, mid]| [up.to_le_bytes(), mid.to_le_bytes()])
        .flatten()
}

/// The cells of [`cell_bytes`]' bytes (a whole number of cells).
fn cells_from(bytes: &[u8]) -> Vec<[u16; 2]> {
    bytes
        .chunks_exact(4)
        .map(|c| {
            [
                u16::from_le_bytes([c[0], c[1]]),
                u16::from_le_bytes([c[2], c[3]]),
            ]
        })
        .collect()
}

/// A map's build journal, opened to go on with.
pub struct Resumable {
    pub journal: Journal,
    /// The rows of the parts it holds, in facet order.
    pub cells: Vec<[u16; 2]>,
    /// How many of `parts`' parts they are.
    pub parts: usize,
}

/// Opens the build journal ([`crate::journal`]) beside the map file `path` for `key`,
/// with the rows of the parts of `parts` it holds: each part must have exactly the rows
/// its facets ask for. `None` when another process is building the same map.
pub fn resume(path: &Path, key: &[u8; 32], parts: &MapParts) -> Result<Option<Resumable>> {
    let row_bytes = 4 * parts.azimuths() as usize;
    // Room for the whole map at once: the build fills it up, and a growing vector would
    // hold its old and new buffers together (800 MB at 786k facets).
    let mut cells = Vec::with_capacity(parts.cell_count());
    let opened = Journal::open(path, &KIND, key, |n, bytes| {
        let n = n as usize;
        let fits = n < parts.count() && bytes.len() == parts.facets(n).len() * row_bytes;
        if fits {
            cells.extend(cells_from(bytes));
        }
        fits
    })?;
    Ok(match opened {
        Opened::Ready { journal, parts } => Some(Resumable {
            journal,
            cells,
            parts: parts as usize,
        }),
        Opened::Busy => None,
    })
}

/// About how many facets' rows the build journal beside the map file `path` holds,
/// judged by its size (another process may be writing it).
pub fn facets_journaled(path: &Path, parts: &MapParts) -> usize {
    let whole = parts.facets(0).len();
    (parts_journaled(path, parts) * whole).min(parts.facets(parts.count().saturating_sub(1)).end)
}

/// About how many whole parts the build journal beside the map file `path` holds.
pub fn parts_journaled(path: &Path, parts: &MapParts) -> usize {
    let row_bytes = 4 * parts.azimuths() as u64;
    let whole = parts.facets(0).len() as u64;
    crate::journal::parts_held(path, whole * row_bytes) as usize
}

/// Adds a finished part's rows to its build's journal.
pub fn keep(journal: &mut Journal, rows: &[[u16; 2]]) -> Result<()> {
    let mut bytes = Vec::with_capacity(4 * rows.len());
    bytes.extend(cell_bytes(rows.iter().copied()));
    journal.append(&bytes)
}

/// A part of a map built by a process that helps another one's build (the journal's
/// holder), beside the map file `path`: `<map file>.part-<p>`.
pub fn part_file(path: &Path, p: usize) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(format!(".part-{p}"));
    PathBuf::from(name)
}

/// The claim on part `p` of the map at `path` by a helping process:
/// `<map file>.part-<p>.claim`, an empty file.
fn claim_file(path: &Path, p: usize) -> PathBuf {
    let mut name = part_file(path, p).into_os_string();
    name.push(".claim");
    PathBuf::from(name)
}

/// Claims part `p` of the map at `path` for this process: true when no one had (the
/// claim file is created only if it did not exist, so two helpers never both get it).
pub fn claim_part(path: &Path, p: usize) -> Result<bool> {
    let claim = claim_file(path, p);
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&claim)
    {
        Ok(_) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
        Err(e) => Err(crate::error::Error::io(&claim, e)),
    }
}

/// Whether part `p` of the map at `path` is claimed or done by a helper.
pub fn part_taken(path: &Path, p: usize) -> bool {
    part_file(path, p).exists() || claim_file(path, p).exists()
}

/// Writes part `p`'s rows (of `parts`, for the map of `key` at `path`) to its part file
/// (temporary file, then rename).
pub fn store_part(
    path: &Path,
    key: &[u8; 32],
    parts: &MapParts,
    p: usize,
    rows: &[[u16; 2]],
) -> Result<()> {
    let mut head = (p as u64).to_le_bytes().to_vec();
    head.extend_from_slice(&(parts.facets(p).start as u64).to_le_bytes());
    head.extend_from_slice(&parts.azimuths().to_le_bytes());
    store_streamed(&part_file(path, p), &PART_KIND, key, head, rows, |piece| {
        cell_bytes(piece.iter().copied()).collect()
    })
}

/// Part `p`'s rows from its part file beside the map at `path` for `key`, when one is
/// there, intact, and holds exactly that part's facets.
pub fn load_part(path: &Path, key: &[u8; 32], parts: &MapParts, p: usize) -> Lookup<Vec<[u16; 2]>> {
    cache::load(&part_file(path, p), &PART_KIND, key).decode(|payload| {
        let mut r = Reader::new(&payload);
        let (index, first) = (r.u64("the part's number")?, r.u64("its first facet")?);
        let azimuths = r.u32("the wedge count")?;
        let facets = parts.facets(p);
        if (index, first, azimuths) != (p as u64, facets.start as u64, parts.azimuths()) {
            return Err(format!(
                "holds part {index} from facet {first} × {azimuths} wedges, expected part \
                 {p} from facet {} × {}",
                facets.start,
                parts.azimuths()
            ));
        }
        let cells = cells_from(r.take(4 * facets.len() * azimuths as usize, "the elevations")?);
        r.finish()?;
        Ok(cells)
    })
}

/// Deletes the part and claim files of the map at `path` (its `count` parts), once the
/// map is stored; a file that cannot be deleted is left for `slim cache` to prune.
pub fn clear_parts(path: &Path, count: usize) {
    for p in 0..count {
        std::fs::remove_file(part_file(path, p)).ok();
        std::fs::remove_file(claim_file(path, p)).ok();
    }
}

/// How the tests read a file's imports, shared with the crate's structure test.
#[cfg(test)]
#[path = "../../tests/common/imports.rs"]
mod imports;

#[cfg(test)]
mod tests {
    use super::imports::names_after;
    use super::*;
    use crate::mesh::generate::icosphere;
    use crate::mesh::LengthUnit;
    use crate::trace::bvh::Bvh;

    /// The files (paths from this folder) that `text`, the file at `path`, imports by
    /// `super::`, `crate::horizon::` or `crate::trace::` in its code (comments and unit
    /// tests aside). Other imports (errors, the mesh type) are left out; the mesh's file
    /// is hashed as a whole.
    fn imported_files(path: &str, text: &str) -> Vec<String> {
        let modules = |folder: &str| -> Vec<String> {
            let list = match folder {
                "" => include_str!("mod.rs"),
                _ => include_str!("../trace/mod.rs"),
            };
            list.lines()
                .filter_map(|l| l.trim_start_matches("pub ").strip_prefix("mod "))
                .filter_map(|l| l.strip_suffix(';'))
                .map(str::to_string)
                .collect()
        };
        let file = |folder: &str, name: &str| {
            let name = if modules(folder).iter().any(|m| m == name) {
                name
            } else {
                "mod"
            };
            format!("{folder}{name}.rs")
        };
        let own = if path.starts_with("../trace/") {
            "../trace/"
        } else {
            ""
        };
        let mut found = Vec::new();
        for part in crate::cache::without_unit_tests(text) {
            for (prefix, folder) in [
                ("super::", own),
                ("crate::horizon::", ""),
                ("crate::trace::", "../trace/"),
            ] {
                found.extend(names_after(part, prefix).iter().map(|n| file(folder, n)));
            }
        }
        found.sort();
        found.dedup();
        found
    }

    /// Imports that feed no build: this file stores bounds beside maps, but a map's
    /// build never reads a bound.
    const NOT_BUILD_INPUTS: [(&str, &str); 1] = [("cache.rs", "bound.rs")];

    /// The files imported by `sources` that are not among them.
    fn unhashed(sources: &[(&str, &str)]) -> Vec<String> {
        let hashed: Vec<&str> = sources.iter().map(|&(path, _)| path).collect();
        let mut missing: Vec<String> = sources
            .iter()
            .flat_map(|&(path, text)| {
                imported_files(path, text)
                    .into_iter()
                    .filter(move |f| !NOT_BUILD_INPUTS.contains(&(path, f.as_str())))
            })
            .filter(|f| !hashed.contains(&f.as_str()))
            .collect();
        missing.sort();
        missing.dedup();
        missing
    }

    #[test]
    fn the_keys_hash_every_file_their_builds_import() {
        // A file the build imports but the key leaves out would let a changed build read
        // maps of the old one (the triangles' outlines were once left out so).
        assert_eq!(unhashed(&map_sources()), Vec::<String>::new());
        assert_eq!(unhashed(&bound_sources()), Vec::<String>::new());
        let without_outlines: Vec<_> = map_sources()
            .into_iter()
            .filter(|&(path, _)| path != "outline.rs")
            .collect();
        assert_eq!(unhashed(&without_outlines), ["outline.rs"]);
        let without_tree_interface: Vec<_> = map_sources()
            .into_iter()
            .filter(|&(path, _)| path != "../trace/mod.rs")
            .collect();
        assert_eq!(unhashed(&without_tree_interface), ["../trace/mod.rs"]);
        // The lookups stay out: changing them keeps every cached map.
        assert!(!map_sources().iter().any(|&(path, _)| path == "sky.rs"));
    }

    #[test]
    fn a_stored_map_reads_back_and_any_damage_or_other_content_is_refused() {
        let dir = crate::TempDir::new("unit", "horizon-cache");
        let mesh = Mesh::from_raw(icosphere(1, 1.0, glam::DVec3::ZERO), LengthUnit::Km);
        let map = HorizonMap::build(&mesh, mesh.len(), &Bvh::build(&mesh), (16, SunBand::WHOLE));
        let key = content_key(&mesh, mesh.len(), (16, SunBand::WHOLE, MapKind::Bounded));
        let file = file_for(&dir, &key);
        assert!(matches!(
            load(&file, &key, mesh.len(), (16, MapKind::Bounded)),
            Lookup::Missing
        ));
        store(&file, &key, &map).expect("store");
        match load(&file, &key, mesh.len(), (16, MapKind::Bounded)) {
            Lookup::Hit(read) => assert_eq!(read, map),
            other => panic!("{other:?}"),
        }
        // Another wedge count, band or mesh gives another key; the same file under it is
        // refused.
        let other = content_key(&mesh, mesh.len(), (32, SunBand::WHOLE, MapKind::Bounded));
        assert_ne!(other, key);
        let centres = content_key(&mesh, mesh.len(), (16, SunBand::WHOLE, MapKind::Centres));
        assert_ne!(centres, key);
        let band = SunBand::of_suns([glam::DVec3::X], 0.0);
        let banded = content_key(&mesh, mesh.len(), (16, band, MapKind::Bounded));
        assert_ne!(banded, key);
        assert_ne!(
            banded,
            content_key(
                &mesh,
                mesh.len(),
                (
                    16,
                    SunBand::of_suns([glam::DVec3::Z], 0.0),
                    MapKind::Bounded
                )
            )
        );
        assert!(matches!(
            load(&file, &other, mesh.len(), (16, MapKind::Bounded)),
            Lookup::Rejected(_)
        ));
        let bytes = std::fs::read(&file).expect("read");
        let mut flipped = bytes.clone();
        flipped[cache::PAYLOAD_OFFSET + 15] ^= 1;
        std::fs::write(&file, &flipped).expect("write");
        match load(&file, &key, mesh.len(), (16, MapKind::Bounded)) {
            Lookup::Rejected(why) => assert!(why.contains("checksum"), "{why}"),
            other => panic!("{other:?}"),
        }
        std::fs::write(&file, &bytes[..bytes.len() - 7]).expect("write");
        assert!(matches!(
            load(&file, &key, mesh.len(), (16, MapKind::Bounded)),
            Lookup::Rejected(_)
        ));
        std::fs::write(&file, b"").expect("write");
        assert!(matches!(
            load(&file, &key, mesh.len(), (16, MapKind::Bounded)),
            Lookup::Rejected(_)
        ));
    }

    #[test]
    fn a_helpers_part_reads_back_only_as_the_part_it_is_and_is_claimed_once() {
        let dir = crate::TempDir::new("unit", "horizon-part");
        let mesh = Mesh::from_raw(icosphere(2, 1.0, glam::DVec3::ZERO), LengthUnit::Km);
        let bvh = Bvh::build(&mesh);
        let parts = MapParts::new(&mesh, mesh.len(), &bvh, (16, SunBand::WHOLE), 128);
        let key = content_key(&mesh, mesh.len(), (16, SunBand::WHOLE, MapKind::Bounded));
        let file = file_for(&dir, &key);
        assert!(matches!(load_part(&file, &key, &parts, 1), Lookup::Missing));
        assert!(!part_taken(&file, 1));
        assert!(claim_part(&file, 1).expect("claim"));
        assert!(!claim_part(&file, 1).expect("claim"), "claimed once");
        assert!(part_taken(&file, 1));
        let rows = parts.rows(1);
        store_part(&file, &key, &parts, 1, &rows).expect("store");
        match load_part(&file, &key, &parts, 1) {
            Lookup::Hit(read) => assert_eq!(read, rows),
            other => panic!("{other:?}"),
        }
        // Read as another part, or for another map, it is refused.
        std::fs::copy(part_file(&file, 1), part_file(&file, 2)).expect("copy");
        match load_part(&file, &key, &parts, 2) {
            Lookup::Rejected(why) => assert!(why.contains("expected part 2"), "{why}"),
            other => panic!("{other:?}"),
        }
        let other = content_key(&mesh, mesh.len(), (32, SunBand::WHOLE, MapKind::Bounded));
        assert!(matches!(
            load_part(&file, &other, &parts, 1),
            Lookup::Rejected(_)
        ));
        // The last part is shorter: a whole part's rows do not pass for it.
        let last = parts.count() - 1;
        store_part(&file, &key, &parts, last, &rows).expect("store");
        assert!(matches!(
            load_part(&file, &key, &parts, last),
            Lookup::Rejected(_)
        ));
        clear_parts(&file, parts.count());
        assert_eq!(std::fs::read_dir(&dir).expect("dir").count(), 0);
    }
}
