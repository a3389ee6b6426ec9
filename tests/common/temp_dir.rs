//! Folders for the tests, the integration tests' and (through `src/lib.rs`) the crate's
//! unit tests': one per test, removed when it is dropped, and one per process for a run
//! that several tests share from a static (which is never dropped), removed by a later
//! test process once the process that made it has ended.
//!
//! In: the suite's name (its test file's) and the test's. Out: a fresh, empty folder
//! `slim-test-{suite}-{process id}-{test}` in the system's temporary folder.
//!
//! Each test crate includes this with `#[path]` and uses its part of it, so the parts
//! another uses would read as dead code here.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// A fresh folder for one test, removed on drop; it reads as the [`Path`] it is.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// The folder for test `test` of suite `suite`, emptied first.
    pub fn new(suite: &str, test: &str) -> TempDir {
        TempDir(fresh(suite, test))
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The folder for a run that the tests of suite `suite` share for the process's life
/// (`shared-{name}`), after removing the shared folders of the suite's earlier
/// processes that have ended.
pub fn shared_dir(suite: &str, name: &str) -> PathBuf {
    remove_ended_processes_folders(suite);
    fresh(suite, &format!("shared-{name}"))
}

fn fresh(suite: &str, test: &str) -> PathBuf {
    let name = format!("slim-test-{suite}-{}-{test}", std::process::id());
    let dir = std::env::temp_dir().join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

/// Removes the suite's folders whose process has ended (read from `/proc`; where there
/// is none, nothing is removed).
fn remove_ended_processes_folders(suite: &str) {
    let (Ok(entries), true) = (
        std::fs::read_dir(std::env::temp_dir()),
        Path::new("/proc/self").exists(),
    ) else {
        return;
    };
    let prefix = format!("slim-test-{suite}-");
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some((pid, _)) = name.strip_prefix(&prefix).and_then(|r| r.split_once('-')) else {
            continue;
        };
        if pid.parse::<u32>().is_ok() && !Path::new("/proc").join(pid).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}
