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
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;

/// Writes one table as Parquet (and CSV if asked), batch by batch, on a thread of its
/// own: the caller builds the next batch while this one is encoded and written.
pub struct TableWriter {
    batches: Option<SyncSender<Table>>,
    encoder: Option<JoinHandle<Result<Vec<PathBuf>>>>,
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
        let files = TableFiles {
            #[cfg(feature = "parquet")]
            parquet: ParquetFile::new(dir.join(format!("{name}.parquet"))),
            csv_path: csv.then(|| dir.join(format!("{name}.csv"))),
            csv: None,
        };
        // One batch waits while another is encoded: at most two batches in memory
        // beside the one being built.
        let (batches, received) = sync_channel::<Table>(1);
        let encoder = std::thread::spawn(move || files.write_all(received));
        TableWriter {
            batches: Some(batches),
            encoder: Some(encoder),
        }
    }

    /// Appends a batch (the first batch fixes the columns). An error of an earlier batch
    /// may be the one returned.
    pub fn write(&mut self, batch: Table) -> Result<()> {
        let batches = self.batches.as_ref().expect("open until finished");
        if batches.send(batch).is_ok() {
            return Ok(());
        }
        // The encoder takes batches until it meets an error: that error is the answer.
        match self.join() {
            Err(e) => Err(e),
            Ok(_) => unreachable!("an encoder stops early only on an error"),
        }
    }

    /// Closes the files and moves them into place. Returns the paths written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>> {
        self.join()
    }

    fn join(&mut self) -> Result<Vec<PathBuf>> {
        self.batches = None;
        match self.encoder.take().map(JoinHandle::join) {
            Some(Ok(written)) => written,
            Some(Err(panic)) => std::panic::resume_unwind(panic),
            None => unreachable!("joined once: by finish, or by a write's error"),
        }
    }
}

impl Drop for TableWriter {
    /// A writer dropped unfinished (an error elsewhere) still waits for its thread; its
    /// files stay under their `.partial` names.
    fn drop(&mut self) {
        self.batches = None;
        if let Some(encoder) = self.encoder.take() {
            let _ = encoder.join();
        }
    }
}

/// The files of one table, owned by its encoding thread.
struct TableFiles {
    #[cfg(feature = "parquet")]
    parquet: ParquetFile,
    csv_path: Option<PathBuf>,
    csv: Option<BufWriter<File>>,
}

impl TableFiles {
    /// Writes every batch received, then finishes the files (when the sender is gone).
    fn write_all(mut self, batches: Receiver<Table>) -> Result<Vec<PathBuf>> {
        for batch in batches {
            self.write(batch)?;
        }
        self.finish()
    }

    fn write(&mut self, batch: Table) -> Result<()> {
        if let Some(path) = &self.csv_path {
            if self.csv.is_none() {
                self.csv = Some(create_csv(path, &batch)?);
            }
            let out = self.csv.as_mut().expect("created above");
            write_csv_rows(&batch, out).map_err(|e| Error::io(&partial(path), e))?;
        }
        #[cfg(feature = "parquet")]
        self.parquet.write(batch)?;
        Ok(())
    }

    fn finish(mut self) -> Result<Vec<PathBuf>> {
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
        Values::Runs(runs) => write_csv_text(run_text(runs, row), out),
    }
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

fn write_csv_text(s: &str, out: &mut impl Write) -> std::io::Result<()> {
    if s.contains([',', '"', '\n', '\r']) {
        write!(out, "\"{}\"", s.replace('"', "\"\""))
    } else {
        out.write_all(s.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folder(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("slim-table-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn csv_of(dir: &Path, batches: Vec<Table>) -> String {
        std::fs::create_dir_all(dir).unwrap();
        let mut writer = TableWriter::new(dir, "t", true);
        for batch in batches {
            writer.write(batch).unwrap();
        }
        let written = writer.finish().unwrap();
        assert!(written.iter().all(|p| p.exists()), "{written:?}");
        std::fs::read_to_string(dir.join("t.csv")).unwrap()
    }

    #[test]
    fn text_in_runs_writes_as_one_string_per_row() {
        let dir = folder("runs");
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let runs = Table::default()
            .with(
                "body",
                Values::Runs(vec![
                    ("phobos".into(), 2),
                    ("a,b".into(), 0),
                    ("mars".into(), 3),
                ]),
            )
            .with("facet", Values::U32(vec![0, 1, 0, 1, 2]));
        let strings = Table::default()
            .with(
                "body",
                Values::Str(names(&["phobos", "phobos", "mars", "mars", "mars"])),
            )
            .with("facet", Values::U32(vec![0, 1, 0, 1, 2]));
        assert_eq!(runs.rows(), 5);
        let a = csv_of(&dir.join("a"), vec![runs.clone(), runs]);
        let b = csv_of(&dir.join("b"), vec![strings.clone(), strings]);
        assert_eq!(a, b);
        assert!(
            a.starts_with("body,facet\nphobos,0\nphobos,1\nmars,0\n"),
            "{a}"
        );
        #[cfg(feature = "parquet")]
        assert_eq!(
            std::fs::read(dir.join("a/t.parquet")).unwrap(),
            std::fs::read(dir.join("b/t.parquet")).unwrap()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_encoders_error_reaches_the_caller_and_names_the_file() {
        let dir = folder("missing").join("not-there");
        let mut writer = TableWriter::new(&dir, "t", true);
        let batch = Table::default().with("x", Values::F64(vec![1.0]));
        // The error comes from the write that meets a stopped encoder, or from finish.
        let error = match writer.write(batch.clone()) {
            Err(e) => e,
            Ok(()) => match writer.write(batch) {
                Err(e) => e,
                Ok(()) => writer.finish().unwrap_err(),
            },
        };
        assert!(error.to_string().contains("not-there/t."), "{error}");
    }
}
