//! Build journals: the finished parts of a long build, kept on disk while it runs, so
//! that a build stopped part-way (a crash, a kill, a batch system's time limit, a
//! cancelled job) goes on from its last finished part the next time instead of from the
//! start.
//!
//! In: the path of the file the build leads to, the [`Kind`] of that file and its
//! content key; then the parts' bytes as they are finished. Out: on opening, the parts
//! a journal for exactly that key already holds, each checked, in order.
//!
//! The journal lives beside the file it leads to, as `<that file>.journal`. It is never
//! read as a result: only a build of the same key resumes from it, and the result is
//! still written whole and renamed into place ([`crate::atomic`]); the journal is
//! deleted after that.
//!
//! Layout (little-endian):
//!
//! | bytes | what |
//! |---|---|
//! | 8 | the kind's magic |
//! | 4 | the kind's format version |
//! | 32 | content key |
//! | per part: 8 | its length n |
//! | n | its bytes |
//! | 32 | SHA-256 of the key, the part's number (u64) and its bytes |
//!
//! A journal of another magic, version or key is started afresh. Parts are read up to
//! the first one that is cut short or fails its checksum (a write a crash interrupted);
//! the file is cut back to the end of the last good one, and the build appends after it.
//! While a process builds, it holds the journal under an exclusive lock: a second
//! process building the same file at the same time gets none and builds alone.

use crate::cache::Kind;
use crate::error::{Error, Result};
use sha2::{Digest, Sha256};
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

const HEADER: usize = 8 + 4 + 32;

/// An open journal, locked for this process.
#[derive(Debug)]
pub struct Journal {
    file: File,
    path: PathBuf,
    key: [u8; 32],
    /// Parts held so far.
    parts: u64,
}

/// What opening a journal gave.
#[derive(Debug)]
pub enum Opened {
    /// The journal, with `parts` good parts read back (each handed to the reader).
    Ready { journal: Journal, parts: u64 },
    /// Another process holds it: it is building the same file now.
    Busy,
}

/// The journal of the file at `path`.
pub fn path_for(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".journal");
    PathBuf::from(p)
}

/// About how many parts of `part_bytes` bytes each the journal of the file at `path`
/// holds, judged by its size alone (for news of a build another process is writing).
pub fn parts_held(path: &Path, part_bytes: u64) -> u64 {
    let held = std::fs::metadata(path_for(path)).map_or(0, |m| m.len());
    held.saturating_sub(HEADER as u64) / (8 + part_bytes + 32)
}

impl Journal {
    /// Opens (or creates) the journal of the file at `path` for `key`, and hands each
    /// good part it holds to `read(part number, bytes)` in order; reading stops at the
    /// first part `read` refuses (returns false) or that is damaged, and the journal is
    /// cut back to the parts before it.
    pub fn open(
        path: &Path,
        kind: &Kind,
        key: &[u8; 32],
        mut read: impl FnMut(u64, &[u8]) -> bool,
    ) -> Result<Opened> {
        let at = path_for(path);
        if let Some(dir) = at.parent() {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&at)
            .map_err(|e| Error::io(&at, e))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => return Ok(Opened::Busy),
            Err(TryLockError::Error(e)) => return Err(Error::io(&at, e)),
        }
        let header = header(kind, key);
        let (good_end, parts) = {
            let mut reader = BufReader::new(&mut file);
            let mut start = [0u8; HEADER];
            if reader.read_exact(&mut start).is_ok() && start[..] == header[..] {
                read_parts(&mut reader, key, &mut read)
            } else {
                (0, 0)
            }
        };
        let io = |e| Error::io(&at, e);
        if good_end == 0 {
            file.set_len(0).map_err(io)?;
            file.seek(SeekFrom::Start(0)).map_err(io)?;
            file.write_all(&header).map_err(io)?;
        } else {
            file.set_len(good_end).map_err(io)?;
            file.seek(SeekFrom::Start(good_end)).map_err(io)?;
        }
        let journal = Journal {
            file,
            path: at,
            key: *key,
            parts,
        };
        Ok(Opened::Ready { journal, parts })
    }

    /// Adds the next finished part.
    pub fn append(&mut self, part: &[u8]) -> Result<()> {
        let sum = part_sum(&self.key, self.parts, part);
        let mut write = |bytes: &[u8]| self.file.write_all(bytes);
        write(&(part.len() as u64).to_le_bytes())
            .and_then(|()| write(part))
            .and_then(|()| write(&sum))
            .map_err(|e| Error::io(&self.path, e))?;
        self.parts += 1;
        Ok(())
    }

    /// Deletes the journal: its build is finished and stored.
    pub fn finish(self) -> Result<()> {
        std::fs::remove_file(&self.path).map_err(|e| Error::io(&self.path, e))
    }
}

fn header(kind: &Kind, key: &[u8; 32]) -> [u8; HEADER] {
    let mut h = [0u8; HEADER];
    h[..8].copy_from_slice(kind.magic);
    h[8..12].copy_from_slice(&kind.version.to_le_bytes());
    h[12..].copy_from_slice(key);
    h
}

/// The checksum of part number `n`: it binds the part to its key and its place.
fn part_sum(key: &[u8; 32], n: u64, part: &[u8]) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(key);
    h.update(n.to_le_bytes());
    h.update(part);
    h.finalize().into()
}

/// Reads parts after the header while they are whole, check out and `read` takes them:
/// the end of the last such part (bytes from the file's start) and their number.
fn read_parts(
    reader: &mut impl Read,
    key: &[u8; 32],
    read: &mut impl FnMut(u64, &[u8]) -> bool,
) -> (u64, u64) {
    let (mut end, mut n) = (HEADER as u64, 0u64);
    loop {
        let mut len = [0u8; 8];
        if reader.read_exact(&mut len).is_err() {
            break;
        }
        let len = u64::from_le_bytes(len);
        // Read through `take`, so that a damaged length cannot ask for more memory than
        // the file holds.
        let mut part = Vec::new();
        match reader.by_ref().take(len).read_to_end(&mut part) {
            Ok(got) if got as u64 == len => {}
            _ => break,
        }
        let mut sum = [0u8; 32];
        if reader.read_exact(&mut sum).is_err() || sum != part_sum(key, n, &part) || !read(n, &part)
        {
            break;
        }
        end += 8 + len + 32;
        n += 1;
    }
    (end, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    const KIND: Kind = Kind {
        magic: b"SLIMTST\0",
        version: 1,
        prefix: "test",
    };

    /// Opens the journal and collects the parts it hands back.
    fn reopen(path: &Path, key: &[u8; 32]) -> (Journal, Vec<Vec<u8>>) {
        let mut got = Vec::new();
        match Journal::open(path, &KIND, key, |n, p| {
            assert_eq!(n as usize, got.len(), "parts come in order");
            got.push(p.to_vec());
            true
        })
        .expect("open")
        {
            Opened::Ready { journal, parts } => {
                assert_eq!(parts as usize, got.len());
                (journal, got)
            }
            Opened::Busy => panic!("busy"),
        }
    }

    fn parts(k: usize) -> Vec<Vec<u8>> {
        (0..k).map(|i| vec![i as u8 + 1; 10 * i + 3]).collect()
    }

    #[test]
    fn parts_written_come_back_in_order_after_the_writer_is_gone() {
        let dir = crate::TempDir::new("unit", "journal-order");
        let path = dir.join("result.bin");
        let key = [1u8; 32];
        let (mut journal, got) = reopen(&path, &key);
        assert!(got.is_empty());
        for p in parts(3) {
            journal.append(&p).expect("append");
        }
        drop(journal);
        let (mut journal, got) = reopen(&path, &key);
        assert_eq!(got, parts(3));
        // Appending goes on after them.
        journal.append(&parts(4)[3]).expect("append");
        drop(journal);
        let (journal, got) = reopen(&path, &key);
        assert_eq!(got, parts(4));
        journal.finish().expect("finish");
        assert!(!path_for(&path).exists());
        // Parts of one size are counted from the journal's size, half a part not.
        let (mut journal, _) = reopen(&path, &key);
        for _ in 0..5 {
            journal.append(&[9u8; 100]).expect("append");
        }
        assert_eq!(parts_held(&path, 100), 5);
        journal.append(&[9u8; 40]).expect("append");
        assert_eq!(parts_held(&path, 100), 5);
    }

    #[test]
    fn a_damaged_or_unfinished_part_and_all_after_it_are_dropped() {
        let dir = crate::TempDir::new("unit", "journal-damage");
        let path = dir.join("result.bin");
        let key = [2u8; 32];
        let (mut journal, _) = reopen(&path, &key);
        for p in parts(4) {
            journal.append(&p).expect("append");
        }
        drop(journal);
        let at = path_for(&path);
        let whole = std::fs::read(&at).expect("read");
        let part_end = |k: usize| HEADER + parts(k).iter().map(|p| 8 + p.len() + 32).sum::<usize>();

        // A write cut short inside the fourth part: three come back, and a part appended
        // then follows them cleanly.
        std::fs::write(&at, &whole[..part_end(3) + 20]).expect("write");
        let (mut journal, got) = reopen(&path, &key);
        assert_eq!(got, parts(3));
        journal.append(b"next").expect("append");
        drop(journal);
        let (_, got) = reopen(&path, &key);
        assert_eq!(got.len(), 4);
        assert_eq!(got[3], b"next");

        // A flipped byte inside the second part: only the first survives.
        let mut flipped = whole.clone();
        flipped[part_end(1) + 8 + 2] ^= 1;
        std::fs::write(&at, &flipped).expect("write");
        assert_eq!(reopen(&path, &key).1, parts(1));

        // A length that claims more than the file holds reads nothing past it.
        let mut huge = whole.clone();
        huge[HEADER..HEADER + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&at, &huge).expect("write");
        assert!(reopen(&path, &key).1.is_empty());

        // Parts swapped in place fail their checksums, which bind them to their number.
        let mut swapped = whole[..HEADER].to_vec();
        swapped.extend_from_slice(&whole[part_end(1)..part_end(2)]);
        swapped.extend_from_slice(&whole[part_end(0)..part_end(1)]);
        std::fs::write(&at, &swapped).expect("write");
        assert!(reopen(&path, &key).1.is_empty());
    }

    #[test]
    fn a_journal_of_other_content_or_a_refused_part_starts_over_there() {
        let dir = crate::TempDir::new("unit", "journal-other");
        let path = dir.join("result.bin");
        let (mut journal, _) = reopen(&path, &[3u8; 32]);
        for p in parts(2) {
            journal.append(&p).expect("append");
        }
        drop(journal);
        // Another key: nothing comes back, and the file is started afresh.
        let (journal, got) = reopen(&path, &[4u8; 32]);
        assert!(got.is_empty());
        drop(journal);
        assert_eq!(
            std::fs::metadata(path_for(&path)).expect("meta").len(),
            HEADER as u64
        );
        // Garbage where a header should be: started afresh too.
        std::fs::write(path_for(&path), b"not a journal").expect("write");
        assert!(reopen(&path, &[4u8; 32]).1.is_empty());
        // A part the reader refuses ends the reading there.
        let (mut journal, _) = reopen(&path, &[5u8; 32]);
        for p in parts(3) {
            journal.append(&p).expect("append");
        }
        drop(journal);
        let mut seen = 0;
        let opened = Journal::open(&path, &KIND, &[5u8; 32], |n, _| {
            seen += 1;
            n < 1
        })
        .expect("open");
        assert!(matches!(opened, Opened::Ready { parts: 1, .. }));
        assert_eq!(seen, 2);
    }

    #[test]
    fn a_journal_held_by_one_build_is_busy_for_another() {
        let dir = crate::TempDir::new("unit", "journal-busy");
        let path = dir.join("result.bin");
        let key = [6u8; 32];
        let (journal, _) = reopen(&path, &key);
        // File locks are per open file description: a second open in this process
        // stands for another process.
        assert!(matches!(
            Journal::open(&path, &KIND, &key, |_, _| true).expect("open"),
            Opened::Busy
        ));
        drop(journal);
        assert!(matches!(
            Journal::open(&path, &KIND, &key, |_, _| true).expect("open"),
            Opened::Ready { .. }
        ));
    }
}
