//! The files of a part folder besides `run.json`: the partial statistics and history.
//!
//! **`part.bin`**, layout version [`FORMAT_VERSION`], little-endian:
//!
//! | bytes | what |
//! |---|---|
//! | 8 | `SLIMPART` |
//! | 4 | layout version (u32) |
//! | 8 | header length H (u64) |
//! | H | header, JSON: `steps`, `facets`, `bins` (`width_w_m2`, `count`), `statistics` (names) |
//! | per statistic | [`FacetStats::write_to`]: facets × 76 bytes of moments, then per facet its CDF counts as LEB128 varints (a run of zeros as 0 and its length) |
//! | 32 | SHA-256 of every byte before it |
//!
//! **`part-history.bin`** (when the scene asks for history): for each of the part's steps
//! in order, `values` arrays of the part's facets as f64 (the total; with scattered light
//! then the direct and the scattered part), nothing else. Its size is checked against
//! `run.json` before it is read.
//!
//! Both are written under a temporary name and renamed when complete, before `run.json`.

use crate::atomic::{commit, create_partial};
use crate::error::{Error, Result};
use crate::simulate::StepIrradiance;
use crate::stats::{Bins, FacetStats};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// The layout version of `part.bin`.
pub const FORMAT_VERSION: u32 = 1;
const MAGIC: &[u8; 8] = b"SLIMPART";
/// The partial statistics' file name in a part folder.
pub const PART_FILE: &str = "part.bin";
/// The history's file name in a part folder.
pub const HISTORY_FILE: &str = "part-history.bin";
/// The largest header a part file may claim (it is a few hundred bytes).
const MAX_HEADER: u64 = 1 << 20;

/// What `part.bin` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub steps: u64,
    pub facets: usize,
    pub bins: Bins,
    pub statistics: Vec<String>,
}

/// A writer that hashes what goes through it.
struct Hashing<W> {
    inner: W,
    hash: Sha256,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Writes `DIR/part.bin` with `statistics` (the total first), all of the same facets,
/// steps and bins.
pub fn write_part(dir: &Path, statistics: &[(String, &FacetStats)]) -> Result<PathBuf> {
    let path = dir.join(PART_FILE);
    let first = statistics.first().expect("the total is always there").1;
    let header = Header {
        steps: first.steps(),
        facets: first.facets(),
        bins: first.bins(),
        statistics: statistics.iter().map(|(n, _)| n.clone()).collect(),
    };
    let json = serde_json::to_vec(&header).map_err(|e| Error::output(&path, e))?;
    let (tmp, file) = create_partial(&path)?;
    let mut out = Hashing {
        inner: file,
        hash: Sha256::new(),
    };
    let written: std::io::Result<()> = (|| {
        out.write_all(MAGIC)?;
        out.write_all(&FORMAT_VERSION.to_le_bytes())?;
        out.write_all(&(json.len() as u64).to_le_bytes())?;
        out.write_all(&json)?;
        for (_, stats) in statistics {
            stats.write_to(&mut out)?;
        }
        let digest = out.hash.clone().finalize();
        out.inner.write_all(&digest)?;
        out.inner.flush()
    })();
    written.map_err(|e| Error::io(&tmp, e))?;
    commit(&tmp, &path)?;
    Ok(path)
}

/// A `part.bin` read into memory and checked (checksum, magic, version, header) before
/// any of it is used: a damaged part is refused before its numbers reach a merge.
struct PartFile {
    path: PathBuf,
    bytes: Vec<u8>,
    /// Where the statistics start and end (the checksum follows).
    start: usize,
    end: usize,
    header: Header,
}

impl PartFile {
    /// Reads and checks `DIR/part.bin` into `bytes` (its capacity reused).
    fn open(dir: &Path, mut bytes: Vec<u8>) -> Result<PartFile> {
        let path = dir.join(PART_FILE);
        let bad = |what: String| Error::file(&path, what);
        bytes.clear();
        File::open(&path)
            .and_then(|mut f| f.read_to_end(&mut bytes))
            .map_err(|e| Error::io(&path, e))?;
        if !bytes.starts_with(MAGIC) {
            return Err(bad(
                "is not a slim part file (no SLIMPART at its start)".into()
            ));
        }
        if bytes.len() < 20 + 32 {
            return Err(bad(
                "is cut short (an interrupted copy?); run this part again".into(),
            ));
        }
        let end = bytes.len() - 32;
        if Sha256::digest(&bytes[..end])[..] != bytes[end..] {
            return Err(bad(
                "fails its checksum (cut short, or damaged on disk or in a copy); run this \
                 part again"
                    .into(),
            ));
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        if version != FORMAT_VERSION {
            return Err(bad(format!(
                "has layout version {version}; this slim reads version {FORMAT_VERSION}: \
                 run the part again with this slim"
            )));
        }
        let header_len = u64::from_le_bytes(bytes[12..20].try_into().expect("8 bytes"));
        if header_len > MAX_HEADER || header_len > (end - 20) as u64 {
            return Err(bad(format!(
                "claims a {header_len}-byte header; it is damaged"
            )));
        }
        let start = 20 + header_len as usize;
        let header: Header = serde_json::from_slice(&bytes[20..start])
            .map_err(|e| bad(format!("has a damaged header: {e}")))?;
        if header.bins.count == 0 {
            return Err(bad(
                "has no CDF thresholds in its header; it is damaged".into()
            ));
        }
        Ok(PartFile {
            path,
            bytes,
            start,
            end,
            header,
        })
    }

    /// The statistics' bytes.
    fn statistics(&self) -> &[u8] {
        &self.bytes[self.start..self.end]
    }

    /// The error for statistics that do not read as the header says (possible only for a
    /// file written wrongly with a valid checksum).
    fn read_error(&self, e: std::io::Error) -> Error {
        Error::file(
            &self.path,
            format!("does not hold what its header describes ({e}); run this part again"),
        )
    }

    /// Checks that the statistics were read to their end (`left` bytes were not).
    fn check_all_read(&self, left: usize) -> Result<()> {
        if left > 0 {
            return Err(Error::file(
                &self.path,
                "holds bytes its header does not account for; it is damaged",
            ));
        }
        Ok(())
    }
}

/// A `part.bin` read and checked, its statistics not yet decoded ([`open_part`]).
pub struct OpenPart(PartFile);

/// Reads `DIR/part.bin` into memory and checks its checksum, magic, version and header.
/// The file is read into `buffer`, whose memory is reused (a merge reads part after part
/// of the same size, and fresh memory of that size costs more than reading the file).
pub fn open_part(dir: &Path, buffer: Vec<u8>) -> Result<OpenPart> {
    PartFile::open(dir, buffer).map(OpenPart)
}

/// Reads `DIR/part.bin`: its header and statistics (the total first), after checking
/// the checksum, the magic and the version.
pub fn read_part(dir: &Path) -> Result<(Header, Vec<FacetStats>)> {
    let part = PartFile::open(dir, Vec::new())?;
    let h = &part.header;
    let mut input = part.statistics();
    let statistics = h
        .statistics
        .iter()
        .map(|_| FacetStats::read_from(&mut input, h.facets, h.steps, h.bins))
        .collect::<std::io::Result<Vec<_>>>()
        .map_err(|e| part.read_error(e))?;
    part.check_all_read(input.len())?;
    Ok((part.header, statistics))
}

/// Merges an opened part over the steps that follow those of `into` (the same facets
/// and statistics) straight into `into`. `check` sees the header before anything is
/// merged. Returns the part's memory, for the next part to be read into.
pub fn merge_part(
    part: OpenPart,
    into: &mut [FacetStats],
    check: impl FnOnce(&Header) -> Result<()>,
) -> Result<Vec<u8>> {
    let part = part.0;
    check(&part.header)?;
    let h = &part.header;
    let fits = h.statistics.len() == into.len()
        && into
            .iter()
            .all(|s| s.facets() == h.facets && s.bins() == h.bins);
    if !fits {
        return Err(Error::file(
            &part.path,
            "holds other facets, bins or statistics than the parts before it",
        ));
    }
    let mut input = part.statistics();
    for stats in into.iter_mut() {
        stats
            .merge_from(&mut input, h.steps)
            .map_err(|e| part.read_error(e))?;
    }
    part.check_all_read(input.len())?;
    Ok(part.bytes)
}

/// Streams a part's history into `part-history.bin`.
pub struct HistoryPart {
    path: PathBuf,
    tmp: PathBuf,
    out: BufWriter<File>,
}

impl HistoryPart {
    /// A writer for `DIR/part-history.bin`.
    pub fn create(dir: &Path) -> Result<HistoryPart> {
        let path = dir.join(HISTORY_FILE);
        let (tmp, out) = create_partial(&path)?;
        Ok(HistoryPart { path, tmp, out })
    }
}

impl crate::run::HistorySink for HistoryPart {
    /// Appends one step: the total, then the direct and scattered parts if any.
    fn write_step(&mut self, _: &crate::ephemeris::EpochState, step: StepIrradiance) -> Result<()> {
        let arrays =
            std::iter::once(step.total).chain(step.parts.into_iter().flat_map(|(d, s)| [d, s]));
        for values in arrays {
            for v in values {
                self.out
                    .write_all(&v.to_le_bytes())
                    .map_err(|e| Error::io(&self.tmp, e))?;
            }
        }
        Ok(())
    }

    /// Finishes the file (flushed and renamed into place).
    fn finish(mut self: Box<Self>) -> Result<Vec<PathBuf>> {
        self.out.flush().map_err(|e| Error::io(&self.tmp, e))?;
        commit(&self.tmp, &self.path)?;
        Ok(vec![self.path])
    }
}

/// Reads a part's history back, step by step.
pub struct HistoryReader {
    path: PathBuf,
    input: BufReader<File>,
    bytes: Vec<u8>,
    /// Arrays per step and values per array.
    arrays: usize,
    facets: usize,
}

impl HistoryReader {
    /// Opens `DIR/part-history.bin`, which must hold `steps` steps of `arrays` arrays of
    /// `facets` values.
    pub fn open(dir: &Path, steps: usize, arrays: usize, facets: usize) -> Result<HistoryReader> {
        let path = dir.join(HISTORY_FILE);
        let input = File::open(&path).map_err(|e| Error::io(&path, e))?;
        let size = input.metadata().map_err(|e| Error::io(&path, e))?.len();
        let expected = steps as u128 * arrays as u128 * facets as u128 * 8;
        if size as u128 != expected {
            return Err(Error::file(
                &path,
                format!(
                    "is {size} bytes, but {steps} steps of {arrays} × {facets} values are \
                     {expected}: it is cut short or damaged; run this part again"
                ),
            ));
        }
        Ok(HistoryReader {
            path,
            input: BufReader::new(input),
            bytes: vec![0; facets * 8],
            arrays,
            facets,
        })
    }

    /// Appends the next step's arrays to `into` (one vector per array).
    pub fn next_step(&mut self, into: &mut [Vec<f64>]) -> Result<()> {
        for array in into.iter_mut().take(self.arrays) {
            self.input
                .read_exact(&mut self.bytes)
                .map_err(|e| Error::io(&self.path, e))?;
            array.extend(
                self.bytes
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
            );
        }
        debug_assert!(into
            .iter()
            .take(self.arrays)
            .all(|a| a.len() >= self.facets));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_part_file_reads_back_and_damage_is_named() {
        let dir = crate::TempDir::new("unit", "part-roundtrip");
        let bins = Bins::covering(10.0, 50.0);
        let mut total = FacetStats::new(3, bins);
        let mut direct = FacetStats::new(3, bins);
        for t in 0..5 {
            total.add_step(&[t as f64, 2.0 * t as f64, 0.0]);
            direct.add_step(&[0.5 * t as f64, 0.0, 0.0]);
        }
        let sets = [
            ("total".to_string(), &total),
            ("direct".to_string(), &direct),
        ];
        let path = write_part(&dir, &sets).unwrap();
        let (header, back) = read_part(&dir).unwrap();
        assert_eq!(header.statistics, ["total", "direct"]);
        assert_eq!(back, vec![total, direct]);
        let bytes = std::fs::read(&path).unwrap();
        let mut flipped = bytes.clone();
        let in_the_statistics = bytes.len() - 40;
        flipped[in_the_statistics] ^= 1;
        std::fs::write(&path, &flipped).unwrap();
        let e = read_part(&dir).unwrap_err().to_string();
        assert!(e.contains("part.bin") && e.contains("checksum"), "{e}");
        std::fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
        let e = read_part(&dir).unwrap_err().to_string();
        assert!(e.contains("checksum"), "{e}");
        std::fs::write(&path, &bytes[..30]).unwrap();
        let e = read_part(&dir).unwrap_err().to_string();
        assert!(e.contains("cut short") || e.contains("checksum"), "{e}");
        std::fs::write(&path, b"PAR1 not ours").unwrap();
        let e = read_part(&dir).unwrap_err().to_string();
        assert!(e.contains("not a slim part file"), "{e}");
    }
}
