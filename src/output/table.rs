//! Table files: Parquet and CSV written from one description, in batches.
//!
//! In: batches of named columns ([`super::columns::Table`]). Out: `NAME.parquet`
//! (Snappy-compressed, one row group per batch up to a size limit; see `parquet_file`)
//! and optionally `NAME.csv` with the same columns and values. A build without the
//! `parquet` feature writes the CSV alone, whatever the scene asks. Files are written as
//! `NAME.ext.partial` and renamed only by [`TableWriter::finish`], so an interrupted run
//! never leaves a file that looks complete.

use super::columns::{Table, Values};
#[cfg(feature = "parquet")]
use super::parquet_file::ParquetFile;
use crate::atomic::{commit, partial};
use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes one table as Parquet (and CSV if asked), batch by batch.
pub struct TableWriter {
    #[cfg(feature = "parquet")]
    parquet: ParquetFile,
    csv_path: Option<PathBuf>,
    csv: Option<BufWriter<File>>,
}

/// The files a [`TableWriter`] for table `name` writes: `NAME.parquet` with the `parquet`
/// feature, and `NAME.csv` when `csv` is asked for or Parquet is not built in.
pub fn file_names(name: &str, csv: bool) -> Vec<String> {
    let parquet = cfg!(feature = "parquet").then(|| format!("{name}.parquet"));
    let csv = (csv || !cfg!(feature = "parquet")).then(|| format!("{name}.csv"));
    parquet.into_iter().chain(csv).collect()
}

impl TableWriter {
    /// A writer for `DIR/NAME.parquet` and, if `csv` (or without Parquet support),
    /// `DIR/NAME.csv`.
    pub fn new(dir: &Path, name: &str, csv: bool) -> TableWriter {
        let csv = csv || !cfg!(feature = "parquet");
        TableWriter {
            #[cfg(feature = "parquet")]
            parquet: ParquetFile::new(dir.join(format!("{name}.parquet"))),
            csv_path: csv.then(|| dir.join(format!("{name}.csv"))),
            csv: None,
        }
    }

    /// Appends a batch (the first batch fixes the columns).
    pub fn write(&mut self, batch: &Table) -> Result<()> {
        #[cfg(feature = "parquet")]
        self.parquet.write(batch)?;
        if let Some(path) = &self.csv_path {
            if self.csv.is_none() {
                self.csv = Some(create_csv(path, batch)?);
            }
            let out = self.csv.as_mut().expect("created above");
            write_csv_rows(batch, out).map_err(|e| Error::io(&partial(path), e))?;
        }
        Ok(())
    }

    /// Closes the files and moves them into place. Returns the paths written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>> {
        let mut written = Vec::new();
        #[cfg(feature = "parquet")]
        written.extend(self.parquet.finish()?);
        if let (Some(mut out), Some(path)) = (self.csv.take(), self.csv_path.clone()) {
            let tmp = partial(&path);
            out.flush().map_err(|e| Error::io(&tmp, e))?;
            drop(out);
            commit(&tmp, &path)?;
            written.push(path);
        }
        Ok(written)
    }
}

/// `path` under its temporary name, with the header line of `first`'s columns.
fn create_csv(path: &Path, first: &Table) -> Result<BufWriter<File>> {
    let tmp = partial(path);
    let mut out = BufWriter::new(File::create(&tmp).map_err(|e| Error::io(&tmp, e))?);
    let header: Vec<&str> = first.columns.iter().map(|(n, _)| n.as_str()).collect();
    writeln!(out, "{}", header.join(",")).map_err(|e| Error::io(&tmp, e))?;
    Ok(out)
}

fn write_csv_rows(batch: &Table, out: &mut impl Write) -> std::io::Result<()> {
    for row in 0..batch.rows() {
        for (k, (_, values)) in batch.columns.iter().enumerate() {
            if k > 0 {
                out.write_all(b",")?;
            }
            write_csv_cell(values, row, out)?;
        }
        out.write_all(b"\n")?;
    }
    Ok(())
}

fn write_csv_cell(values: &Values, row: usize, out: &mut impl Write) -> std::io::Result<()> {
    match values {
        Values::F64(v) => write!(out, "{}", v[row]),
        Values::U32(v) => write!(out, "{}", v[row]),
        Values::U64(v) => write!(out, "{}", v[row]),
        Values::Str(v) => write_csv_text(&v[row], out),
    }
}

fn write_csv_text(s: &str, out: &mut impl Write) -> std::io::Result<()> {
    if s.contains([',', '"', '\n', '\r']) {
        write!(out, "\"{}\"", s.replace('"', "\"\""))
    } else {
        out.write_all(s.as_bytes())
    }
}
