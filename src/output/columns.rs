//! Tables as named columns: the one description every table file is written from.
//!
//! In: the values of each column, as built by [`super`] (names carry units:
//! `mean_w_m2`). Out: a [`Table`] batch that the CSV and Parquet writers read alike, and
//! `TableFile`, what each of those file formats implements.

use crate::error::Result;
use std::path::PathBuf;
use std::sync::Arc;

/// One column of a batch.
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    F64(Vec<f64>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    Str(Vec<String>),
    /// Text in runs: each text repeated on its number of rows (a body's name over its
    /// facets), so that no row needs a string of its own.
    Runs(Vec<(String, usize)>),
}

impl Values {
    /// Number of values (rows).
    pub fn len(&self) -> usize {
        match self {
            Values::F64(v) => v.len(),
            Values::U32(v) => v.len(),
            Values::U64(v) => v.len(),
            Values::Str(v) => v.len(),
            Values::Runs(runs) => runs.iter().map(|(_, n)| n).sum(),
        }
    }

    /// True when the column holds no values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
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

/// One file of a table, written batch by batch on its own thread (`super::table`).
pub(super) trait TableFile: Send + 'static {
    /// Appends a batch (shared with the table's other files; the first fixes the columns).
    fn write(&mut self, batch: Arc<Table>) -> Result<()>;
    /// Closes the file and moves it into place; its path, if anything was written.
    fn finish(self: Box<Self>) -> Result<Option<PathBuf>>;
}
