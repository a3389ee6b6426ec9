//! Table files: Parquet and CSV written from one description, in batches.
//!
//! In: batches of named columns ([`super::columns::Table`]). Out: `NAME.parquet`
//! (Snappy-compressed, one row group per batch up to a size limit; see `parquet_file`)
//! and optionally `NAME.csv` with the same columns and values (`csv_file`). A build
//! without the `parquet` feature writes the CSV alone, whatever the scene asks. Each file
//! is encoded on a thread of its own while the caller builds the next batch. Files are
//! written as `NAME.ext.partial` and renamed only by [`TableWriter::finish`], so an
//! interrupted run never leaves a file that looks complete.

use super::columns::{Table, TableFile};
use super::csv_file::CsvFile;
#[cfg(feature = "parquet")]
use super::parquet_file::ParquetFile;
use crate::error::Result;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, SyncSender};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Writes one table as Parquet (and CSV if asked), batch by batch. Each file is encoded
/// on a thread of its own, so the caller builds the next batch while this one is
/// encoded, and the two formats are encoded side by side.
pub struct TableWriter {
    encoders: Vec<Encoder>,
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
        let mut files: Vec<Box<dyn TableFile>> = Vec::new();
        #[cfg(feature = "parquet")]
        files.push(Box::new(ParquetFile::new(
            dir.join(format!("{name}.parquet")),
        )));
        if csv || !cfg!(feature = "parquet") {
            files.push(Box::new(CsvFile::new(dir.join(format!("{name}.csv")))));
        }
        TableWriter {
            encoders: files.into_iter().map(Encoder::start).collect(),
        }
    }

    /// Appends a batch (the first batch fixes the columns). An error of an earlier batch
    /// may be the one returned.
    pub fn write(&mut self, batch: Table) -> Result<()> {
        let batch = Arc::new(batch);
        // The last file gets the batch itself: alone, it can then take the columns.
        let (last, others) = self.encoders.split_last().expect("a table has a file");
        let stopped = others.iter().any(|e| !e.send(Arc::clone(&batch))) || !last.send(batch);
        if !stopped {
            return Ok(());
        }
        // An encoder takes batches until it meets an error: that error is the answer.
        match self.join() {
            Err(e) => Err(e),
            Ok(_) => unreachable!("an encoder stops early only on an error"),
        }
    }

    /// Closes the files and moves them into place. Returns the paths written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>> {
        for e in &self.encoders {
            e.finish();
        }
        self.join()
    }

    /// Closes every channel and waits for every encoder; the paths written, or the first
    /// error. An encoder told to finish commits its file; any other leaves it partial.
    fn join(&mut self) -> Result<Vec<PathBuf>> {
        self.encoders.iter_mut().for_each(|e| e.batches = None);
        let ends: Vec<_> = self.encoders.iter_mut().map(Encoder::join).collect();
        ends.into_iter().filter_map(Result::transpose).collect()
    }
}

impl Drop for TableWriter {
    /// A writer dropped unfinished (an error elsewhere) still waits for its threads; its
    /// files stay under their `.partial` names.
    fn drop(&mut self) {
        self.encoders.iter_mut().for_each(|e| e.batches = None);
        for e in &mut self.encoders {
            if let Some(thread) = e.thread.take() {
                let _ = thread.join();
            }
        }
    }
}

/// What an encoder's thread is told.
enum Message {
    Batch(Arc<Table>),
    /// Every batch is sent: close the file and move it into place. A channel closed
    /// without it means the table was abandoned, and the file stays partial.
    Finish,
}

/// A file's thread and the channel that feeds it.
struct Encoder {
    batches: Option<SyncSender<Message>>,
    thread: Option<JoinHandle<Result<Option<PathBuf>>>>,
}

impl Encoder {
    fn start(mut file: Box<dyn TableFile>) -> Encoder {
        // One batch waits while another is encoded: at most two batches in memory
        // beside the one being built.
        let (batches, received) = sync_channel::<Message>(1);
        let thread = std::thread::spawn(move || {
            for message in received {
                match message {
                    Message::Batch(batch) => file.write(batch)?,
                    Message::Finish => return file.finish(),
                }
            }
            Ok(None)
        });
        Encoder {
            batches: Some(batches),
            thread: Some(thread),
        }
    }

    /// Hands `batch` over; false when the encoder has stopped (on an error).
    fn send(&self, batch: Arc<Table>) -> bool {
        self.batches
            .as_ref()
            .is_some_and(|b| b.send(Message::Batch(batch)).is_ok())
    }

    /// Tells the encoder to finish its file (an encoder stopped on an error ignores it,
    /// and [`Encoder::join`] gives that error).
    fn finish(&self) {
        if let Some(b) = &self.batches {
            let _ = b.send(Message::Finish);
        }
    }

    /// Waits for the thread (its channel closed first); `Ok(None)` when already joined or
    /// abandoned.
    fn join(&mut self) -> Result<Option<PathBuf>> {
        self.batches = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(written)) => written,
            Some(Err(panic)) => std::panic::resume_unwind(panic),
            None => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::columns::Values;
    use super::*;

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
        let dir = crate::TempDir::new("unit", "table-runs");
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
    }

    #[test]
    fn a_writer_dropped_unfinished_leaves_only_partial_files() {
        let dir = crate::TempDir::new("unit", "table-dropped");
        let mut writer = TableWriter::new(&dir, "t", true);
        writer
            .write(Table::default().with("x", Values::F64(vec![1.0])))
            .unwrap();
        drop(writer);
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert!(names.iter().all(|n| n.ends_with(".partial")), "{names:?}");
        assert!(names.contains(&"t.csv.partial".to_string()), "{names:?}");
    }

    #[test]
    fn an_encoders_error_reaches_the_caller_and_names_the_file() {
        let parent = crate::TempDir::new("unit", "table-missing");
        let dir = parent.join("not-there");
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
