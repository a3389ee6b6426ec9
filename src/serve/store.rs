//! Store: job records on disk, so jobs outlive the process.
//!
//! In: [`JobRecord`]s and scene texts. Out: `DIR/jobs/ID/job.json` (the record),
//! `DIR/jobs/ID/scene.toml` (the scene as submitted, TOML) and the run's files in
//! `DIR/jobs/ID/result/`. Every record is written to a temporary file and renamed, so a
//! crash leaves either the old record or the new one, never half of one; a run's files
//! are complete exactly when the record says `succeeded` (`run.json` is written last).

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// Waiting for a compute thread.
    Queued,
    /// Computing.
    Running,
    /// Finished; its results can be downloaded and queried.
    Succeeded,
    /// Stopped by an error (see `error`).
    Failed,
    /// The service stopped while the job was running; it has no results.
    Interrupted,
    /// Deleted; the folder is being removed (finished on the next start if interrupted).
    Deleted,
}

impl State {
    /// The name the API and the records use.
    pub fn name(self) -> &'static str {
        match self {
            State::Queued => "queued",
            State::Running => "running",
            State::Succeeded => "succeeded",
            State::Failed => "failed",
            State::Interrupted => "interrupted",
            State::Deleted => "deleted",
        }
    }
}

/// Everything known about a job that must survive a restart.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JobRecord {
    pub id: String,
    /// The run's name (scene `[run] name`, or the scene file's stem).
    pub name: String,
    pub state: State,
    /// The path the scene is parsed as (its mesh and kernel paths are relative to it).
    pub parse_path: PathBuf,
    /// Unix time, seconds.
    pub submitted_unix_s: f64,
    pub started_unix_s: Option<f64>,
    pub finished_unix_s: Option<f64>,
    /// The plan (sizes and stages, as in `run.json`).
    pub plan: serde_json::Value,
    /// Wall time per stage of a finished run, seconds (as in `run.json`).
    pub timings_s: Vec<(String, f64)>,
    pub error: Option<String>,
}

/// `DIR/jobs`.
pub fn jobs_dir(dir: &Path) -> PathBuf {
    dir.join("jobs")
}

/// `DIR/jobs/ID`.
pub fn job_dir(dir: &Path, id: &str) -> PathBuf {
    jobs_dir(dir).join(id)
}

/// `DIR/jobs/ID/result`: the run's output folder.
pub fn result_dir(dir: &Path, id: &str) -> PathBuf {
    job_dir(dir, id).join("result")
}

fn record_path(dir: &Path, id: &str) -> PathBuf {
    job_dir(dir, id).join("job.json")
}

fn scene_path(dir: &Path, id: &str) -> PathBuf {
    job_dir(dir, id).join("scene.toml")
}

/// Creates a job's folder with its scene and first record.
pub fn create(dir: &Path, record: &JobRecord, scene_toml: &str) -> Result<()> {
    let folder = job_dir(dir, &record.id);
    // Not create_dir_all: an existing folder (an id drawn twice) must not be reused.
    std::fs::create_dir(&folder).map_err(|e| Error::io(&folder, e))?;
    write_atomic(&scene_path(dir, &record.id), scene_toml.as_bytes())?;
    save(dir, record)
}

/// Replaces a job's record atomically.
pub fn save(dir: &Path, record: &JobRecord) -> Result<()> {
    let path = record_path(dir, &record.id);
    let json = serde_json::to_vec_pretty(record).map_err(|e| Error::output(&path, e))?;
    write_atomic(&path, &json)
}

/// Marks a job deleted on disk, then removes its folder.
pub fn remove(dir: &Path, record: &JobRecord) -> Result<()> {
    let deleted = JobRecord {
        state: State::Deleted,
        ..record.clone()
    };
    save(dir, &deleted)?;
    let folder = job_dir(dir, &record.id);
    std::fs::remove_dir_all(&folder).map_err(|e| Error::io(&folder, e))
}

/// A job read back from disk: its record and scene text.
pub struct StoredJob {
    pub record: JobRecord,
    pub scene_toml: String,
}

/// Every stored job (oldest first), and notes on folders skipped because they hold no
/// readable record (a job whose creation was cut short).
pub fn load_all(dir: &Path) -> Result<(Vec<StoredJob>, Vec<String>)> {
    let folder = jobs_dir(dir);
    std::fs::create_dir_all(&folder).map_err(|e| Error::io(&folder, e))?;
    let mut jobs = Vec::new();
    let mut notes = Vec::new();
    for entry in std::fs::read_dir(&folder).map_err(|e| Error::io(&folder, e))? {
        let Ok(entry) = entry else { continue };
        let id = entry.file_name().to_string_lossy().into_owned();
        if !entry.path().is_dir() {
            continue;
        }
        match read_job(dir, &id) {
            Ok(job) => jobs.push(job),
            Err(e) => notes.push(format!("job {id} skipped: {e}")),
        }
    }
    jobs.sort_by(|a, b| {
        a.record
            .submitted_unix_s
            .total_cmp(&b.record.submitted_unix_s)
    });
    Ok((jobs, notes))
}

fn read_job(dir: &Path, id: &str) -> Result<StoredJob> {
    let path = record_path(dir, id);
    let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
    let record: JobRecord =
        serde_json::from_slice(&bytes).map_err(|e| Error::file(&path, e.to_string()))?;
    // The folder is removed by the record's id: a record naming another folder (a copied
    // or crafted job.json) must not make the service delete that one.
    if record.id != id {
        return Err(Error::file(
            &path,
            format!("names job {:?} but lies in folder {id:?}", record.id),
        ));
    }
    let scene = scene_path(dir, id);
    let scene_toml = std::fs::read_to_string(&scene).map_err(|e| Error::io(&scene, e))?;
    Ok(StoredJob { record, scene_toml })
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}
