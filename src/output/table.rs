//! Tables written as Parquet and CSV from one description, in batches.
//!
//! In: batches of named columns ([`Table`]). Out: `NAME.parquet` (Snappy-compressed, one
//! row group per batch up to a size limit) and optionally `NAME.csv` with the same columns
//! and values. Files are written as `NAME.ext.partial` and renamed only by
//! [`TableWriter::finish`], so an interrupted run never leaves a file that looks complete.

use crate::error::{Error, Result};
use arrow::array::{ArrayRef, Float64Array, StringArray, UInt32Array, UInt64Array};
use arrow::datatypes::{DataType, Field, Schema, SchemaRef};
use arrow::record_batch::RecordBatch;
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::WriterProperties;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One column of a batch.
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    F64(Vec<f64>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    Str(Vec<String>),
}

impl Values {
    fn len(&self) -> usize {
        match self {
            Values::F64(v) => v.len(),
            Values::U32(v) => v.len(),
            Values::U64(v) => v.len(),
            Values::Str(v) => v.len(),
        }
    }

    fn data_type(&self) -> DataType {
        match self {
            Values::F64(_) => DataType::Float64,
            Values::U32(_) => DataType::UInt32,
            Values::U64(_) => DataType::UInt64,
            Values::Str(_) => DataType::Utf8,
        }
    }

    fn to_arrow(&self) -> ArrayRef {
        match self {
            Values::F64(v) => Arc::new(Float64Array::from(v.clone())),
            Values::U32(v) => Arc::new(UInt32Array::from(v.clone())),
            Values::U64(v) => Arc::new(UInt64Array::from(v.clone())),
            Values::Str(v) => Arc::new(StringArray::from(v.clone())),
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

    fn schema(&self) -> SchemaRef {
        Arc::new(Schema::new(
            self.columns
                .iter()
                .map(|(n, v)| Field::new(n.as_str(), v.data_type(), false))
                .collect::<Vec<_>>(),
        ))
    }

    fn to_record_batch(&self, schema: SchemaRef) -> std::result::Result<RecordBatch, String> {
        RecordBatch::try_new(
            schema,
            self.columns.iter().map(|(_, v)| v.to_arrow()).collect(),
        )
        .map_err(|e| e.to_string())
    }
}

/// Largest row group written, rows.
const ROW_GROUP_ROWS: usize = 1 << 20;

/// Writes one table as Parquet (and CSV if asked), batch by batch.
pub struct TableWriter {
    parquet_path: PathBuf,
    parquet: Option<ArrowWriter<File>>,
    schema: Option<SchemaRef>,
    csv_path: Option<PathBuf>,
    csv: Option<BufWriter<File>>,
}

fn partial(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".partial");
    PathBuf::from(p)
}

impl TableWriter {
    /// A writer for `DIR/NAME.parquet` and, if `csv`, `DIR/NAME.csv`.
    pub fn new(dir: &Path, name: &str, csv: bool) -> TableWriter {
        TableWriter {
            parquet_path: dir.join(format!("{name}.parquet")),
            parquet: None,
            schema: None,
            csv_path: csv.then(|| dir.join(format!("{name}.csv"))),
            csv: None,
        }
    }

    /// Appends a batch (the first batch fixes the columns).
    pub fn write(&mut self, batch: &Table) -> Result<()> {
        if self.schema.is_none() {
            self.open(batch)?;
        }
        let schema = self.schema.clone().expect("opened above");
        let pq_err = |e: String| Error::output(&partial(&self.parquet_path), e);
        let record = batch.to_record_batch(schema).map_err(pq_err)?;
        if let Some(w) = self.parquet.as_mut() {
            w.write(&record).map_err(|e| pq_err(e.to_string()))?;
        }
        if let (Some(out), Some(path)) = (self.csv.as_mut(), self.csv_path.as_ref()) {
            write_csv_rows(batch, out).map_err(|e| Error::io(&partial(path), e))?;
        }
        Ok(())
    }

    fn open(&mut self, first: &Table) -> Result<()> {
        let schema = first.schema();
        let path = partial(&self.parquet_path);
        let file = File::create(&path).map_err(|e| Error::io(&path, e))?;
        let props = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
            .set_created_by(format!("slim {}", env!("CARGO_PKG_VERSION")))
            .build();
        self.parquet = Some(
            ArrowWriter::try_new(file, schema.clone(), Some(props))
                .map_err(|e| Error::output(&path, e))?,
        );
        if let Some(csv_path) = &self.csv_path {
            let path = partial(csv_path);
            let mut out = BufWriter::new(File::create(&path).map_err(|e| Error::io(&path, e))?);
            let header: Vec<&str> = first.columns.iter().map(|(n, _)| n.as_str()).collect();
            writeln!(out, "{}", header.join(",")).map_err(|e| Error::io(&path, e))?;
            self.csv = Some(out);
        }
        self.schema = Some(schema);
        Ok(())
    }

    /// Closes the files and moves them into place. Returns the paths written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>> {
        let mut written = Vec::new();
        if let Some(w) = self.parquet.take() {
            let tmp = partial(&self.parquet_path);
            w.close().map_err(|e| Error::output(&tmp, e))?;
            commit(&tmp, &self.parquet_path)?;
            written.push(self.parquet_path.clone());
        }
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
