//! Files kept between runs: results that take seconds to minutes to build and depend only
//! on a mesh's content and a few settings (horizon maps, form factors).
//!
//! In: a folder, the [`Kind`] of file, a content key (SHA-256 of everything the result
//! depends on: [`mesh_content`], the settings, and the [`code`] that builds it) and the
//! payload's bytes. Out: the payload read
//! back when the file for exactly that key is there and intact; files written to a
//! temporary name, then renamed.
//!
//! File layout (little-endian), named `<prefix>-<first 32 hex digits of the key>.bin`:
//!
//! | bytes | what |
//! |---|---|
//! | 8 | the kind's magic |
//! | 4 | the kind's format version |
//! | 32 | content key |
//! | n | payload (its layout is in the kind's module) |
//! | 32 | SHA-256 of everything above |
//!
//! A file whose magic, version, key or checksum does not match is never trusted: the
//! caller is told why, rebuilds the result and replaces the file.
//!
//! Keys change with the code, so a folder gathers files no later run will read (a
//! 786k-facet horizon map is 400 MB). Each read marks its file used (its modification
//! time); [`entries`] lists a folder's files and [`prune`] deletes those unused since a
//! given time (`slim cache`).

use crate::atomic::{commit, create_partial};
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use sha2::{Digest, Sha256};
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// One kind of cached file.
#[derive(Debug, Clone, Copy)]
pub struct Kind {
    pub magic: &'static [u8; 8],
    /// Bumped whenever the payload's layout or what it holds changes.
    pub version: u32,
    /// File names start with this.
    pub prefix: &'static str,
}

const HEADER: usize = 8 + 4 + 32;

/// Where the payload starts in a file (for tests that damage it).
pub const PAYLOAD_OFFSET: usize = HEADER;

/// What reading the cache gave.
#[derive(Debug)]
pub enum Lookup<T> {
    /// An intact file for this content.
    Hit(T),
    /// No file.
    Missing,
    /// A file that cannot be trusted, and why.
    Rejected(String),
}

impl<T> Lookup<T> {
    /// Decodes a hit; a payload that does not decode is rejected with the reason.
    pub fn decode<U>(self, f: impl FnOnce(T) -> std::result::Result<U, String>) -> Lookup<U> {
        match self {
            Lookup::Hit(t) => match f(t) {
                Ok(u) => Lookup::Hit(u),
                Err(why) => Lookup::Rejected(why),
            },
            Lookup::Missing => Lookup::Missing,
            Lookup::Rejected(why) => Lookup::Rejected(why),
        }
    }
}

/// The code of the tree and of the mesh, path (as seen from a stage's folder, `src/horizon/`
/// or `src/scatter/`) and text: every cached product built through a mesh's BVH (horizon
/// maps and bounds, form factors) depends on it, and hashes it into its key beside its
/// own stage's files.
pub const TREE_SOURCES: [(&str, &str); 4] = [
    ("../trace/mod.rs", include_str!("trace/mod.rs")),
    ("../trace/bvh.rs", include_str!("trace/bvh.rs")),
    ("../trace/ray.rs", include_str!("trace/ray.rs")),
    ("../mesh/mod.rs", include_str!("mesh/mod.rs")),
];

/// A content key's hash begun with what every key holds: what the file is for (`label`),
/// its kind's format version and the source of the code that builds it ([`code`]).
pub fn key_hasher(label: &[u8], kind: &Kind, sources: &[&str]) -> Sha256 {
    let mut h = Sha256::new();
    h.update(label);
    h.update(kind.version.to_le_bytes());
    code(&mut h, sources);
    h
}

/// Adds a mesh's content to a key: facet count, every vertex (f64 m) and every triangle.
pub fn mesh_content(h: &mut Sha256, mesh: &Mesh) {
    h.update((mesh.len() as u64).to_le_bytes());
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
}

/// Adds to a key the source text of the code that builds a kind of file, so that any
/// change to that code (a developer's as well as a release's) builds the file again
/// instead of reading one the old code wrote. A file's unit-test module is left out: a
/// test changes what is checked, not what is built, and should not cost every cached
/// file a rebuild (about 25 minutes for a 786k-facet horizon map).
pub fn code(h: &mut Sha256, sources: &[&str]) {
    for text in sources {
        for part in without_unit_tests(text) {
            h.update((part.len() as u64).to_le_bytes());
            h.update(part.as_bytes());
        }
    }
}

/// Source `text` without its `#[cfg(test)] mod tests { … }` block: the parts before and
/// after it. The block ends at the first line after its opening that is a lone `}`, as
/// rustfmt lays it out; a text without such a block is kept whole.
pub(crate) fn without_unit_tests(text: &str) -> [&str; 2] {
    const OPEN: &str = "\n#[cfg(test)]\nmod tests {\n";
    let Some(start) = text.find(OPEN) else {
        return [text, ""];
    };
    let body = &text[start + OPEN.len()..];
    let end = match body.find("\n}\n") {
        Some(at) => at + 3,
        None if body.ends_with("\n}") => body.len(),
        None => return [text, ""],
    };
    [&text[..start], &body[end..]]
}

/// The file for `key` of this kind in `dir`.
pub fn file_for(dir: &Path, kind: &Kind, key: &[u8; 32]) -> PathBuf {
    let hex: String = key[..16].iter().map(|b| format!("{b:02x}")).collect();
    dir.join(format!("{}-{hex}.bin", kind.prefix))
}

/// Reads the payload for `key` from `path`, and marks the file used now (its
/// modification time, which [`prune`] goes by).
pub fn load(path: &Path, kind: &Kind, key: &[u8; 32]) -> Lookup<Vec<u8>> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Lookup::Missing,
        Err(e) => return Lookup::Rejected(format!("cannot be read: {e}")),
    };
    match open(bytes, kind, key) {
        Ok(payload) => {
            // A folder we may read but not write keeps its old times: only pruning
            // comes sooner.
            File::open(path)
                .and_then(|f| f.set_modified(SystemTime::now()))
                .ok();
            Lookup::Hit(payload)
        }
        Err(why) => Lookup::Rejected(why),
    }
}

/// One file of a cache folder that slim wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    pub path: PathBuf,
    /// What it holds: the kind's prefix ("horizon", "horizon-bound", "form-factors"),
    /// with " journal" for a build's journal, " unfinished" for a write a run did not
    /// finish, " part" and " claim" for the parts of a map that a run helped build.
    pub what: String,
    pub bytes: u64,
    /// When a run last wrote or read it.
    pub last_used: SystemTime,
}

/// The files of `dir` that slim wrote (`<prefix>-<32 hex digits>.bin`, their journals
/// and unfinished writes), least recently used first; nothing else in the folder is
/// listed. An absent folder has none.
pub fn entries(dir: &Path) -> Result<Vec<Entry>> {
    let listing = match std::fs::read_dir(dir) {
        Ok(l) => l,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut found = Vec::new();
    for item in listing {
        let item = item.map_err(|e| Error::io(dir, e))?;
        let Some(what) = item.file_name().to_str().and_then(kind_of_name) else {
            continue;
        };
        let path = item.path();
        let meta = item.metadata().map_err(|e| Error::io(&path, e))?;
        if meta.is_file() {
            found.push(Entry {
                what,
                bytes: meta.len(),
                last_used: meta.modified().map_err(|e| Error::io(&path, e))?,
                path,
            });
        }
    }
    found.sort_by(|a, b| (a.last_used, &a.path).cmp(&(b.last_used, &b.path)));
    Ok(found)
}

/// What a file named `name` holds, when slim wrote it ([`file_for`]'s names, and their
/// `.journal` and `.partial` companions, and the `.part-<n>` files and claims of a
/// build that others helped).
fn kind_of_name(name: &str) -> Option<String> {
    let (stem, suffix) = name.rsplit_once(".bin")?;
    let suffix = match suffix {
        "" => "",
        ".journal" => " journal",
        ".partial" => " unfinished",
        _ => {
            let helped = suffix.strip_prefix(".part-")?;
            let (number, what) = match helped.split_once('.') {
                None => (helped, " part"),
                Some((number, "claim")) => (number, " claim"),
                Some((number, "partial")) => (number, " unfinished"),
                Some(_) => return None,
            };
            if number.is_empty() || !number.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            what
        }
    };
    let (prefix, hex) = stem.rsplit_once('-')?;
    let named = !prefix.is_empty()
        && prefix.bytes().all(|b| b.is_ascii_lowercase() || b == b'-')
        && hex.len() == 32
        && hex
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b));
    named.then(|| format!("{prefix}{suffix}"))
}

/// Deletes the files of `dir` that slim wrote and no run has used since `before`, but
/// not a build's journal that a running build holds; gives what it deleted.
pub fn prune(dir: &Path, before: SystemTime) -> Result<Vec<Entry>> {
    let mut deleted = Vec::new();
    for entry in entries(dir)? {
        if entry.last_used >= before || held(&entry) {
            continue;
        }
        std::fs::remove_file(&entry.path).map_err(|e| Error::io(&entry.path, e))?;
        deleted.push(entry);
    }
    Ok(deleted)
}

/// Whether `entry` is a journal a running build holds locked.
fn held(entry: &Entry) -> bool {
    entry.what.ends_with(" journal")
        && File::open(&entry.path)
            .is_ok_and(|f| matches!(f.try_lock(), Err(std::fs::TryLockError::WouldBlock)))
}

fn open(mut bytes: Vec<u8>, kind: &Kind, key: &[u8; 32]) -> std::result::Result<Vec<u8>, String> {
    if bytes.len() < HEADER + 32 {
        return Err(format!("{} bytes: truncated", bytes.len()));
    }
    if &bytes[..8] != kind.magic {
        return Err(format!("not a slim {} file (bad magic)", kind.prefix));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
    if version != kind.version {
        return Err(format!(
            "format version {version}, this slim writes {}",
            kind.version
        ));
    }
    if &bytes[12..HEADER] != key {
        return Err("built from other mesh content or settings (content key differs)".into());
    }
    let body = bytes.len() - 32;
    let sum: [u8; 32] = Sha256::digest(&bytes[..body]).into();
    if sum[..] != bytes[body..] {
        return Err("checksum mismatch (corrupt or truncated)".into());
    }
    bytes.truncate(body);
    bytes.drain(..HEADER);
    Ok(bytes)
}

/// Writes `payload` for `key` to `path` (temporary file, then rename), creating the
/// folder.
pub fn store(path: &Path, kind: &Kind, key: &[u8; 32], payload: &[u8]) -> Result<()> {
    store_pieces(path, kind, key, [payload])
}

/// As [`store`], the payload handed over in consecutive pieces, each written and added to
/// the checksum as it comes: a payload made from a larger structure (a 786k-facet map is
/// 400 MB) is never held whole in a second buffer.
pub fn store_pieces<P: AsRef<[u8]>>(
    path: &Path,
    kind: &Kind,
    key: &[u8; 32],
    payload: impl IntoIterator<Item = P>,
) -> Result<()> {
    let mut header = Vec::with_capacity(HEADER);
    header.extend_from_slice(kind.magic);
    header.extend_from_slice(&kind.version.to_le_bytes());
    header.extend_from_slice(key);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let (tmp, mut out) = create_partial(path)?;
    let mut sum = Sha256::new();
    let mut write = |bytes: &[u8]| {
        sum.update(bytes);
        out.write_all(bytes)
    };
    write(&header)
        .and_then(|()| {
            payload
                .into_iter()
                .try_for_each(|piece| write(piece.as_ref()))
        })
        .and_then(|()| out.write_all(&sum.finalize()))
        .and_then(|()| out.flush())
        .map_err(|e| Error::io(&tmp, e))?;
    drop(out);
    commit(&tmp, path)
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

/// The folder a scene's cached files go to: its `run.cache_dir` (relative to the scene
/// file), else [`default_dir`].
pub fn dir_for(scene_dir: &Path, key: Option<&Path>) -> Option<PathBuf> {
    match key {
        Some(p) => Some(scene_dir.join(p)),
        None => default_dir(),
    }
}

/// Little-endian readers over a payload, each failing with what was short.
pub struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    pub fn new(bytes: &'a [u8]) -> Reader<'a> {
        Reader { bytes }
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize, what: &str) -> std::result::Result<&'a [u8], String> {
        if self.bytes.len() < n {
            return Err(format!("payload ends inside {what}"));
        }
        let (head, rest) = self.bytes.split_at(n);
        self.bytes = rest;
        Ok(head)
    }

    /// The next `n` items of `width` bytes each.
    pub fn items(
        &mut self,
        n: usize,
        width: usize,
        what: &str,
    ) -> std::result::Result<std::slice::ChunksExact<'a, u8>, String> {
        let bytes = n.checked_mul(width).ok_or("absurd size")?;
        Ok(self.take(bytes, what)?.chunks_exact(width))
    }

    pub fn u64(&mut self, what: &str) -> std::result::Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8, what)?.try_into().expect("8 bytes"),
        ))
    }

    pub fn u32(&mut self, what: &str) -> std::result::Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }

    pub fn f64(&mut self, what: &str) -> std::result::Result<f64, String> {
        Ok(f64::from_bits(self.u64(what)?))
    }

    /// Fails unless every byte was read.
    pub fn finish(&self) -> std::result::Result<(), String> {
        if self.bytes.is_empty() {
            Ok(())
        } else {
            Err(format!("{} bytes left over", self.bytes.len()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key_of(source: &str) -> [u8; 32] {
        let mut h = Sha256::new();
        code(&mut h, &[source]);
        h.finalize().into()
    }

    #[test]
    fn the_code_key_ignores_unit_tests_but_not_the_code_around_them() {
        let with = |code: &str, test: &str, after: &str| {
            format!("{code}\n#[cfg(test)]\nmod tests {{\n    fn t() {{ {test} }}\n}}\n{after}")
        };
        let base = key_of(&with("fn a() {}", "x", ""));
        assert_eq!(key_of(&with("fn a() {}", "y", "")), base, "a test edit");
        assert_ne!(
            key_of(&with("fn b() {}", "x", "")),
            base,
            "code before the tests"
        );
        assert_ne!(
            key_of(&with("fn a() {}", "x", "fn c() {}")),
            base,
            "code after them"
        );
        // Without a tests module (or an unclosed one) every byte counts.
        assert_ne!(key_of("fn a() {}"), key_of("fn a() { }"));
        let unclosed = "fn a() {}\n#[cfg(test)]\nmod tests {\n    fn t() {}";
        assert_ne!(key_of(unclosed), key_of(&unclosed.replace("t()", "u()")));
        // Each file's parts are delimited, so text cannot move between them unnoticed.
        let mut h = Sha256::new();
        code(&mut h, &["fn a() {}", "fn b() {}"]);
        let mut moved = Sha256::new();
        code(&mut moved, &["fn a() {}fn b", "() {}"]);
        assert_ne!(h.finalize(), moved.finalize());
        // On this very file the tests module is found and nothing follows it.
        let [code, after] = without_unit_tests(include_str!("cache.rs"));
        assert!(code.trim_end().ends_with("\n}") && !code.contains("fn the_code_key_ignores"));
        assert_eq!(after, "");
    }

    const KIND: Kind = Kind {
        magic: b"SLIMTST\0",
        version: 3,
        prefix: "test",
    };

    #[test]
    fn only_the_names_slim_writes_are_cache_files() {
        let hex = "0123456789abcdef0123456789abcdef";
        let kind = |name: String| kind_of_name(&name);
        for (name, what) in [
            (format!("horizon-{hex}.bin"), "horizon"),
            (format!("horizon-bound-{hex}.bin"), "horizon-bound"),
            (format!("horizon-{hex}.bin.journal"), "horizon journal"),
            (
                format!("form-factors-{hex}.bin.partial"),
                "form-factors unfinished",
            ),
            (format!("horizon-{hex}.bin.part-12"), "horizon part"),
            (format!("horizon-{hex}.bin.part-0.claim"), "horizon claim"),
            (
                format!("horizon-{hex}.bin.part-3.partial"),
                "horizon unfinished",
            ),
        ] {
            assert_eq!(kind(name).as_deref(), Some(what));
        }
        for other in [
            format!("horizon-{}.bin", &hex[1..]),
            format!("horizon-{}.bin", hex.to_uppercase()),
            format!("horizon-{hex}.bin.bak"),
            format!("horizon-{hex}.bin.part-"),
            format!("horizon-{hex}.bin.part-1x"),
            format!("horizon-{hex}.bin.part-1.bak"),
            format!("-{hex}.bin"),
            format!("Notes-{hex}.bin"),
            "results.csv".to_string(),
        ] {
            assert_eq!(kind(other.clone()), None, "{other}");
        }
    }

    #[test]
    fn pruning_deletes_only_slims_files_unused_since_then_and_no_held_journal() {
        let dir = crate::TempDir::new("unit", "cache-prune");
        let day = std::time::Duration::from_secs(86_400);
        let now = SystemTime::now();
        let (old_key, new_key, held_key) = ([1u8; 32], [2u8; 32], [3u8; 32]);
        let (old, new) = (
            file_for(&dir, &KIND, &old_key),
            file_for(&dir, &KIND, &new_key),
        );
        store(&old, &KIND, &old_key, b"old").expect("store");
        store(&new, &KIND, &new_key, b"new").expect("store");
        let mut journal = file_for(&dir, &KIND, &held_key).into_os_string();
        journal.push(".journal");
        let journal = PathBuf::from(journal);
        std::fs::write(&journal, b"parts").expect("write");
        // A running build holds its journal locked.
        let held = File::open(&journal).expect("open");
        held.try_lock().expect("lock");
        let stranger = dir.join("notes.txt");
        std::fs::write(&stranger, b"mine").expect("write");
        let age = |path: &Path, days: u32| {
            File::open(path)
                .and_then(|f| f.set_modified(now - day * days))
                .expect("age");
        };
        for path in [&old, &journal, &stranger] {
            age(path, 40);
        }
        age(&new, 40);
        // Reading a file marks it used.
        assert!(matches!(load(&new, &KIND, &new_key), Lookup::Hit(_)));
        let listed = entries(&dir).expect("list");
        assert_eq!(listed.len(), 3, "{listed:?}");
        assert_eq!(listed[2].path, new, "the one just read is the most recent");
        let deleted = prune(&dir, now - day * 30).expect("prune");
        assert_eq!(
            deleted.iter().map(|e| &e.path).collect::<Vec<_>>(),
            vec![&old]
        );
        assert!(new.exists() && journal.exists() && stranger.exists());
        // Once no build holds it, an old journal goes too.
        drop(held);
        assert_eq!(prune(&dir, now - day * 30).expect("prune").len(), 1);
        assert!(!journal.exists() && new.exists());
        assert!(entries(&dir.join("absent")).expect("absent").is_empty());
    }

    #[test]
    fn a_stored_payload_reads_back_and_any_damage_or_other_key_is_refused() {
        let dir = crate::TempDir::new("unit", "cache");
        let key = [7u8; 32];
        let file = file_for(&dir, &KIND, &key);
        assert!(matches!(load(&file, &KIND, &key), Lookup::Missing));
        store(&file, &KIND, &key, b"payload").expect("store");
        match load(&file, &KIND, &key) {
            Lookup::Hit(p) => assert_eq!(p, b"payload"),
            other => panic!("{other:?}"),
        }
        let refused = |why: &str| match load(&file, &KIND, &key) {
            Lookup::Rejected(r) => assert!(r.contains(why), "{r}"),
            other => panic!("{other:?}"),
        };
        assert!(matches!(
            load(&file, &KIND, &[8u8; 32]),
            Lookup::Rejected(_)
        ));
        let other_version = Kind { version: 4, ..KIND };
        assert!(matches!(
            load(&file, &other_version, &key),
            Lookup::Rejected(_)
        ));
        let bytes = std::fs::read(&file).expect("read");
        let mut flipped = bytes.clone();
        flipped[PAYLOAD_OFFSET + 2] ^= 1;
        std::fs::write(&file, &flipped).expect("write");
        refused("checksum");
        std::fs::write(&file, &bytes[..bytes.len() - 3]).expect("write");
        refused("checksum");
        std::fs::write(&file, b"").expect("write");
        refused("truncated");
    }
}
