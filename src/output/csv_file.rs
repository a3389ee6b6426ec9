//! CSV files from [`super::columns::Table`] batches.
//!
//! In: batches of named columns, the first fixing the header line. Out: one CSV file,
//! numbers as Rust prints them (the shortest text that reads back to the same f64),
//! text quoted only when it holds a comma, a quote or a line break; written under its
//! `.partial` name and renamed when finished.
//!
//! Tables repeat numbers (CDF thresholds and steps, zeros), and formatting a float costs
//! more than copying its text, so each float column keeps the text of its recent values.

use super::columns::{Table, TableFile, Values};
use crate::atomic::{commit, create_partial, partial};
use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::Arc;

/// One CSV file being written.
pub(super) struct CsvFile {
    path: PathBuf,
    out: Option<BufWriter<File>>,
    /// Per column, the text of its recent floats.
    recent: Vec<RecentFloats>,
}

impl CsvFile {
    pub(super) fn new(path: PathBuf) -> CsvFile {
        CsvFile {
            path,
            out: None,
            recent: Vec::new(),
        }
    }

    fn write_rows(&mut self, batch: &Table) -> std::io::Result<()> {
        let out = self.out.as_mut().expect("created before the rows");
        for row in 0..batch.rows() {
            for (k, (_, values)) in batch.columns.iter().enumerate() {
                if k > 0 {
                    out.write_all(b",")?;
                }
                match values {
                    Values::F64(v) => self.recent[k].write(v[row], out)?,
                    Values::U32(v) => write_integer(u64::from(v[row]), out)?,
                    Values::U64(v) => write_integer(v[row], out)?,
                    Values::Str(v) => write_text(&v[row], out)?,
                    Values::Runs(runs) => write_text(run_text(runs, row), out)?,
                }
            }
            out.write_all(b"\n")?;
        }
        Ok(())
    }
}

impl TableFile for CsvFile {
    fn write(&mut self, batch: Arc<Table>) -> Result<()> {
        if self.out.is_none() {
            let (tmp, mut out) = create_partial(&self.path)?;
            let header: Vec<&str> = batch.columns.iter().map(|(n, _)| n.as_str()).collect();
            writeln!(out, "{}", header.join(",")).map_err(|e| Error::io(&tmp, e))?;
            self.out = Some(out);
            self.recent = batch.columns.iter().map(|_| RecentFloats::new()).collect();
        }
        self.write_rows(&batch)
            .map_err(|e| Error::io(&partial(&self.path), e))
    }

    fn finish(self: Box<Self>) -> Result<Option<PathBuf>> {
        let Some(mut out) = self.out else {
            return Ok(None);
        };
        let tmp = partial(&self.path);
        out.flush().map_err(|e| Error::io(&tmp, e))?;
        drop(out);
        commit(&tmp, &self.path)?;
        Ok(Some(self.path))
    }
}

/// The text of the floats a column held recently: a direct-mapped table by bit pattern.
struct RecentFloats {
    slots: Vec<(u64, Vec<u8>)>,
}

impl RecentFloats {
    const SLOTS: usize = 512;

    fn new() -> RecentFloats {
        RecentFloats {
            slots: vec![(0, Vec::new()); Self::SLOTS],
        }
    }

    /// Writes `v` as `{}` prints it.
    fn write(&mut self, v: f64, out: &mut impl Write) -> std::io::Result<()> {
        let bits = v.to_bits();
        // Fibonacci hashing: the top bits of the product mix every bit of the pattern.
        let slot = (bits.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 55) as usize % Self::SLOTS;
        let (key, text) = &mut self.slots[slot];
        // A printed number is never empty, so an empty text is a slot not yet used.
        if *key != bits || text.is_empty() {
            text.clear();
            write!(text, "{v}")?;
            *key = bits;
        }
        out.write_all(text)
    }
}

/// Writes `v` in decimal, as `{}` prints it.
fn write_integer(mut v: u64, out: &mut impl Write) -> std::io::Result<()> {
    let mut digits = [0u8; 20];
    let mut at = digits.len();
    loop {
        at -= 1;
        digits[at] = b'0' + (v % 10) as u8;
        v /= 10;
        if v == 0 {
            break;
        }
    }
    out.write_all(&digits[at..])
}

/// The text on `row` of a column in runs (few runs: one per body).
fn run_text(runs: &[(String, usize)], mut row: usize) -> &str {
    for (text, rows) in runs {
        if row < *rows {
            return text;
        }
        row -= rows;
    }
    panic!("row {row} past the end of a column in runs")
}

/// Writes `s`, quoted when it holds a comma, a quote or a line break.
fn write_text(s: &str, out: &mut impl Write) -> std::io::Result<()> {
    if s.contains([',', '"', '\n', '\r']) {
        write!(out, "\"{}\"", s.replace('"', "\"\""))
    } else {
        out.write_all(s.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_print_as_rust_prints_them() {
        let mut recent = RecentFloats::new();
        let floats = [
            0.0,
            -0.0,
            1.0,
            0.1,
            1e-7,
            1e21,
            1361.0 / 3.0,
            f64::NAN,
            f64::INFINITY,
            5e-324,
        ];
        let mut text = Vec::new();
        // Twice, so the second pass reads the recent text; then values that share slots.
        for v in floats
            .iter()
            .chain(&floats)
            .copied()
            .chain((0..5000).map(|k| k as f64 * 0.37))
        {
            text.clear();
            recent.write(v, &mut text).unwrap();
            assert_eq!(String::from_utf8(text.clone()).unwrap(), format!("{v}"));
        }
        for v in [0, 7, 10, 4_294_967_295, u64::MAX] {
            text.clear();
            write_integer(v, &mut text).unwrap();
            assert_eq!(String::from_utf8(text.clone()).unwrap(), v.to_string());
        }
    }
}
