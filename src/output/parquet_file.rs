//! Parquet files from [`super::columns::Table`] batches, through arrow (the `parquet` feature).
//!
//! In: batches of named columns, the first fixing the schema. Out: one Snappy-compressed
//! Parquet file, one row group per batch up to [`ROW_GROUP_ROWS`] rows, written under its
//! `.partial` name and renamed when finished.

use super::columns::{Table, TableFile, Values};
use crate::atomic::{commit, partial};
use crate::error::{Error, Result};
use arrow_array::{ArrayRef, Float64Array, RecordBatch, StringArray, UInt32Array, UInt64Array};
use arrow_buffer::{Buffer, OffsetBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::WriterProperties;
use std::fs::File;
use std::path::PathBuf;
use std::sync::Arc;

/// Largest row group written, rows.
const ROW_GROUP_ROWS: usize = 1 << 20;

/// One Parquet file being written.
pub(super) struct ParquetFile {
    path: PathBuf,
    writer: Option<(ArrowWriter<File>, SchemaRef)>,
}

impl ParquetFile {
    pub(super) fn new(path: PathBuf) -> ParquetFile {
        ParquetFile { path, writer: None }
    }
}

impl TableFile for ParquetFile {
    /// Appends a batch (the first batch fixes the columns). Its columns move into Arrow
    /// when no other file of the table still reads them, and are copied otherwise.
    fn write(&mut self, batch: Arc<Table>) -> Result<()> {
        let batch = Arc::try_unwrap(batch).unwrap_or_else(|shared| (*shared).clone());
        let tmp = partial(&self.path);
        if self.writer.is_none() {
            let schema = schema(&batch);
            let file = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
            let props = WriterProperties::builder()
                .set_compression(Compression::SNAPPY)
                .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
                .set_created_by(format!("slim {}", env!("CARGO_PKG_VERSION")))
                .build();
            let writer = ArrowWriter::try_new(file, schema.clone(), Some(props))
                .map_err(|e| Error::output(&tmp, e))?;
            self.writer = Some((writer, schema));
        }
        let (writer, schema) = self.writer.as_mut().expect("opened above");
        let record = record_batch(batch, schema.clone()).map_err(|e| Error::output(&tmp, e))?;
        writer.write(&record).map_err(|e| Error::output(&tmp, e))
    }

    fn finish(self: Box<Self>) -> Result<Option<PathBuf>> {
        let Some((writer, _)) = self.writer else {
            return Ok(None);
        };
        let tmp = partial(&self.path);
        writer.close().map_err(|e| Error::output(&tmp, e))?;
        commit(&tmp, &self.path)?;
        Ok(Some(self.path))
    }
}

fn data_type(values: &Values) -> DataType {
    match values {
        Values::F64(_) => DataType::Float64,
        Values::U32(_) => DataType::UInt32,
        Values::U64(_) => DataType::UInt64,
        Values::Str(_) | Values::Runs(_) => DataType::Utf8,
    }
}

/// The column as an Arrow array, taking its values (no copy of numbers).
fn to_arrow(values: Values) -> ArrayRef {
    match values {
        Values::F64(v) => Arc::new(Float64Array::from(v)),
        Values::U32(v) => Arc::new(UInt32Array::from(v)),
        Values::U64(v) => Arc::new(UInt64Array::from(v)),
        Values::Str(v) => Arc::new(StringArray::from(v)),
        Values::Runs(runs) => Arc::new(runs_array(&runs)),
    }
}

/// A text column in runs as one buffer of bytes and its offsets: the same array as one
/// string per row, without a string per row.
fn runs_array(runs: &[(String, usize)]) -> StringArray {
    let rows: usize = runs.iter().map(|(_, n)| n).sum();
    let mut text = Vec::with_capacity(runs.iter().map(|(t, n)| t.len() * n).sum());
    let mut offsets = Vec::with_capacity(rows + 1);
    offsets.push(0i32);
    for (t, n) in runs {
        let start = text.len();
        text.extend_from_slice(&t.as_bytes().repeat(*n));
        let end =
            |k: usize| i32::try_from(start + k * t.len()).expect("a batch's text under 2 GiB");
        offsets.extend((1..=*n).map(end));
    }
    StringArray::new(
        OffsetBuffer::new(ScalarBuffer::from(offsets)),
        Buffer::from_vec(text),
        None,
    )
}

fn schema(table: &Table) -> SchemaRef {
    Arc::new(Schema::new(
        table
            .columns
            .iter()
            .map(|(n, v)| Field::new(n.as_str(), data_type(v), false))
            .collect::<Vec<_>>(),
    ))
}

fn record_batch(table: Table, schema: SchemaRef) -> std::result::Result<RecordBatch, String> {
    RecordBatch::try_new(
        schema,
        table
            .columns
            .into_iter()
            .map(|(_, v)| to_arrow(v))
            .collect(),
    )
    .map_err(|e| e.to_string())
}
