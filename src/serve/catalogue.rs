//! Catalogue: what the data folder offers, and the one gate every request path passes.
//!
//! In: the canonical data folder `DIR` and paths named by requests (relative, `/`
//! separated). Out: the listing of `DIR/shapes`, `DIR/kernels` and `DIR/scenes` (path
//! relative to `DIR`, size in bytes), and resolved paths that are guaranteed to name an
//! existing file inside `DIR`: absolute paths, `..` components and symbolic links that
//! lead out of `DIR` are refused with 403, missing files with 404.

use super::reply::{ApiError, ApiResult};
use serde::Serialize;
use std::path::{Component, Path, PathBuf};

/// The catalogue folders under `DIR`, by kind.
pub const KINDS: [&str; 3] = ["shapes", "kernels", "scenes"];

/// One file of the catalogue.
#[derive(Debug, Clone, Serialize, PartialEq, Eq)]
pub struct Entry {
    /// Path relative to the data folder, `/`-separated (as requests name it).
    pub path: String,
    pub bytes: u64,
}

/// The catalogue: every file under each kind's folder.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Catalogue {
    pub shapes: Vec<Entry>,
    pub kernels: Vec<Entry>,
    pub scenes: Vec<Entry>,
}

/// Lists the catalogue of `dir` (canonical). Links leading out of `dir` are left out.
pub fn list(dir: &Path) -> Catalogue {
    let mut lists = KINDS.map(|kind| {
        let mut entries = Vec::new();
        walk(dir, &dir.join(kind), &mut entries);
        entries.sort_by(|a, b| a.path.cmp(&b.path));
        entries
    });
    Catalogue {
        shapes: std::mem::take(&mut lists[0]),
        kernels: std::mem::take(&mut lists[1]),
        scenes: std::mem::take(&mut lists[2]),
    }
}

/// Lists the files below `folder`. Linked folders are not entered (no loops); linked
/// files are listed when their target lies inside `root`.
fn walk(root: &Path, folder: &Path, out: &mut Vec<Entry>) {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        if kind.is_dir() {
            walk(root, &path, out);
            continue;
        }
        let Ok(real) = path.canonicalize() else {
            continue;
        };
        if !real.starts_with(root) || !real.is_file() {
            continue;
        }
        if let (Ok(rel), Ok(meta)) = (path.strip_prefix(root), real.metadata()) {
            out.push(Entry {
                path: slash_path(rel),
                bytes: meta.len(),
            });
        }
    }
}

/// A relative path written with `/` separators.
pub fn slash_path(rel: &Path) -> String {
    rel.components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}

/// The file `name` (relative to `dir`) as a canonical path inside `dir`.
pub fn resolve(dir: &Path, name: &str) -> ApiResult<PathBuf> {
    if Path::new(name).has_root() {
        return Err(escape(name, "absolute paths are not allowed"));
    }
    check_joined(dir, name, &dir.join(name))
}

/// Checks a path the scene parser has already joined to its folder: written out without
/// `.` and `..`, it must stay below `dir`, and its target (links followed) must be a
/// file inside `dir`. `name` says which key or request field it came from.
pub fn check_joined(dir: &Path, name: &str, joined: &Path) -> ApiResult<PathBuf> {
    let lexical = lexically_normal(joined);
    let shown = format!(
        "{name} '{}'",
        joined.strip_prefix(dir).unwrap_or(joined).display()
    );
    if !lexical.starts_with(dir) {
        return Err(escape(
            &shown,
            "leads outside the data folder ('..' or an absolute path); name files relative to \
             the data folder",
        ));
    }
    inside(dir, &shown, &lexical)
}

/// `path` with `.` dropped and each `..` removing the component before it.
fn lexically_normal(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

fn escape(name: &str, why: &str) -> ApiError {
    ApiError::new(
        axum::http::StatusCode::FORBIDDEN,
        "path_outside_data",
        format!("{name}: {why}"),
    )
}

/// The canonical form of `path`, which must exist and lie inside `dir`.
fn inside(dir: &Path, name: &str, path: &Path) -> ApiResult<PathBuf> {
    let real = path.canonicalize().map_err(|_| {
        ApiError::not_found(
            "unknown_catalogue_entry",
            format!("{name}: no such file in the data folder (GET /v1/catalogue lists them)"),
        )
    })?;
    if !real.starts_with(dir) {
        return Err(escape(name, "a link that leads outside the data folder"));
    }
    if !real.is_file() {
        return Err(ApiError::not_found(
            "unknown_catalogue_entry",
            format!("{name}: not a file"),
        ));
    }
    Ok(real)
}
