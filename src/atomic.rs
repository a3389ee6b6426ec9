//! Atomic files: every result is written under a `.partial` name and renamed into place
//! only when complete, so an interrupted run never leaves a file that looks complete.
//!
//! In: a final path and the bytes (or a stream) for it. Out: the file at that path, or
//! nothing there but a `NAME.partial` that the next run clears.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// The temporary name a file is written under: `NAME.partial`.
pub fn partial(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".partial");
    PathBuf::from(p)
}

/// Moves a finished temporary file to its final name, durably: the file's content is
/// flushed to disk before the rename and the folder's entry after it, so that a machine
/// crash leaves either the old state or the complete file, never a renamed empty one.
pub fn commit(tmp: &Path, path: &Path) -> Result<()> {
    File::open(tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| Error::io(tmp, e))?;
    std::fs::rename(tmp, path).map_err(|e| Error::io(path, e))?;
    sync_folder(path)
}

/// Flushes the folder holding `path` (its entries, after a rename). Only Unix can open a
/// folder to sync it; elsewhere the rename is left to the file system.
fn sync_folder(path: &Path) -> Result<()> {
    if cfg!(unix) {
        let folder = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        File::open(folder)
            .and_then(|f| f.sync_all())
            .map_err(|e| Error::io(folder, e))?;
    }
    Ok(())
}

/// Writes `bytes` to `path` atomically (temporary file, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = partial(path);
    std::fs::write(&tmp, bytes).map_err(|e| Error::io(&tmp, e))?;
    commit(&tmp, path)
}

/// Creates an output file for streaming writes under its temporary name.
pub fn create_partial(path: &Path) -> Result<(PathBuf, BufWriter<File>)> {
    let tmp = partial(path);
    let file = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
    Ok((tmp, BufWriter::with_capacity(WRITE_BUFFER, file)))
}

/// Bytes buffered before a streamed file is written to: large writes of whole pages
/// cost the kernel less than many small ones (GB-sized CSV tables).
const WRITE_BUFFER: usize = 1 << 20;
