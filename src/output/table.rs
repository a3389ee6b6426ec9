//! Tables written as Parquet and CSV from one description, in batches.
//!
//! In: batches of named columns ([`Table`]). Out: `NAME.parquet` (Snappy-compressed, one
//! row group per batch up to a size limit; see `parquet_file`) and optionally
//! `NAME.csv` with the same columns and values. A build without the `parquet` feature
//! writes the CSV alone, whatever the scene asks. Files are written as
//! `NAME.ext.partial` and renamed only by [`TableWriter::finish`], so an interrupted run
//! never leaves a file that looks complete.

#[cfg(feature = "parquet")]
use super::parquet_file::ParquetFile;
use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// One column of a batch.
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    F64(Vec<f64>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    Str(Vec<String>),
}

impl Values {
    pub(super) fn len(&self) -> usize {
        match self {
            Values::F64(v) => v.len(),
            Values::U32(v) => v.len(),
            Values::U64(v) => v.len(),
            Values::Str(v) => v.len(),
        }
    }

    fn write_csv_cell(&self, row: usize, out: &mut impl Write) -> std::io::Result<()> {
        match self {
            Values::F64(v) => write!(out, "{}", v[row]),
            Values::U32(v) => write!(out, "{}", v[row]),
            Values::U64(v) => write!(out, "{}", v[row]),
            Values::Str(v) => write_csv_text(&v[row], out),
        }
    }
}

fn write_csv_text(s: &str, out: &mut impl Write) -> std::io::Result<()> {
    if s.contains([',', '"', '\n', '\r']) {
        write!(out, "\"{}\"", s.replace('"', "\"\""))
    } else {
        out.write_all(s.as_bytes())
    }
}

/// A batch of rows: named columns of equal length. Names carry units (`mean_w_m2`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    pub columns: Vec<(String, Values)>,
}

impl Table {
    /// Adds a column.
    pub fn with(mut self, name: impl Into<String>, values: Values) -> Table {
        self.columns.push((name.into(), values));
        self
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, |(_, v)| v.len())
    }
}

/// Writes one table as Parquet (and CSV if asked), batch by batch.
pub struct TableWriter {
    #[cfg(feature = "parquet")]
    parquet: ParquetFile,
    csv_path: Option<PathBuf>,
    csv: Option<BufWriter<File>>,
}

pub(super) fn partial(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".partial");
    PathBuf::from(p)
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
            values.write_csv_cell(row, out)?;
        }
        out.write_all(b"\n")?;
    }
    Ok(())
}

/// Moves a finished temporary file to its final name.
pub fn commit(tmp: &Path, path: &Path) -> Result<()> {
    std::fs::rename(tmp, path).map_err(|e| Error::io(path, e))
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
    Ok((tmp, BufWriter::new(file)))
}
