//! Jobs: the job table, its queue and the compute threads that run scenes.
//!
//! In: checked scenes ([`SceneText`]) and their plans. Out: job views (state, progress in
//! steps, plan, timings in seconds, error) and, for finished jobs, the folder of the run's
//! files. Scenes run on `workers` dedicated threads, each with its own rayon pool of
//! `job_threads` threads — never on the async runtime — so queries stay answered while
//! jobs compute; further jobs wait in a FIFO queue. Every state change is stored
//! ([`store`]) before it is shown.

use super::reply::{ApiError, ApiResult};
use super::scene_input::{check_files, SceneText};
use super::store::{self, unix_now, JobRecord, State};
use crate::budget::Budget;
use crate::error::{Error, Result};
use crate::output::record::RunRecord;
use crate::plan::Plan;
use crate::progress::Progress;
use crate::run::run_scene;
use crate::scene::Scene;
use crate::shard::slurm::{Batch, BatchState, Resources};
use crate::shard::By;
use serde::Serialize;
use std::collections::{HashMap, VecDeque};
use std::hash::{BuildHasher, Hasher};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};

/// How big a job's scene is, from its plan: what an engine holding it costs.
#[derive(Debug, Clone, Copy, Default)]
pub struct SceneSize {
    pub facets: usize,
    pub steps: usize,
    pub bodies: usize,
}

/// Live progress of one job, shared with its compute thread.
#[derive(Debug, Default)]
pub struct Live {
    done: AtomicU64,
    total: AtomicU64,
    cancel: AtomicBool,
}

impl Progress for Live {
    fn note(&self, _: &str) {}
    fn begin_steps(&self, steps: u64) {
        self.total.store(steps, Ordering::Relaxed);
    }
    fn step_done(&self) {
        self.done.fetch_add(1, Ordering::Relaxed);
    }
    fn end_steps(&self) {}
    fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
}

/// A job as the API shows it.
#[derive(Debug, Clone, Serialize)]
pub struct JobView {
    pub id: String,
    pub name: String,
    pub state: State,
    pub progress: ProgressView,
    pub plan: serde_json::Value,
    pub timings: TimingsView,
    pub error: Option<String>,
    /// Result files that can be downloaded (succeeded jobs only).
    pub results: Vec<String>,
}

/// Steps done out of the total.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ProgressView {
    pub steps_done: u64,
    pub steps_total: u64,
    pub fraction: f64,
}

/// When the job was submitted, started and finished (Unix seconds), how long it waited
/// and ran, and the run's stage timings (seconds).
#[derive(Debug, Clone, Serialize)]
pub struct TimingsView {
    pub submitted_unix_s: f64,
    pub started_unix_s: Option<f64>,
    pub finished_unix_s: Option<f64>,
    pub queued_s: Option<f64>,
    pub run_s: Option<f64>,
    pub stages_s: Vec<(String, f64)>,
}

/// The result files a finished job serves.
pub const RESULT_FILES: [&str; 4] = [
    "summary.parquet",
    "cdf.parquet",
    "geometry.parquet",
    "history.parquet",
];

struct Entry {
    record: JobRecord,
    scene: SceneText,
    live: Arc<Live>,
    /// The result files a succeeded job serves, found when it finished (or when the
    /// service started), so that listing jobs touches no disk under the lock.
    results: Vec<&'static str>,
}

impl Entry {
    fn new(record: JobRecord, scene: SceneText) -> Entry {
        Entry {
            record,
            scene,
            live: Arc::default(),
            results: Vec::new(),
        }
    }

    fn view(&self) -> JobView {
        let r = &self.record;
        let steps_total = match self.live.total.load(Ordering::Relaxed) {
            0 => r.plan["steps"].as_u64().unwrap_or(0),
            n => n,
        };
        let steps_done = match r.state {
            State::Succeeded => steps_total,
            _ => self.live.done.load(Ordering::Relaxed),
        };
        let results = self
            .results
            .iter()
            .map(|f| format!("/v1/jobs/{}/{f}", r.id))
            .collect();
        JobView {
            id: r.id.clone(),
            name: r.name.clone(),
            state: r.state,
            progress: ProgressView {
                steps_done,
                steps_total,
                fraction: if steps_total > 0 {
                    steps_done as f64 / steps_total as f64
                } else {
                    0.0
                },
            },
            plan: r.plan.clone(),
            timings: TimingsView {
                submitted_unix_s: r.submitted_unix_s,
                started_unix_s: r.started_unix_s,
                finished_unix_s: r.finished_unix_s,
                queued_s: r.started_unix_s.map(|s| s - r.submitted_unix_s),
                run_s: r.started_unix_s.zip(r.finished_unix_s).map(|(s, f)| f - s),
                stages_s: r.timings_s.clone(),
            },
            error: r.error.clone(),
            results,
        }
    }
}

#[derive(Default)]
struct Table {
    jobs: HashMap<String, Entry>,
    queue: VecDeque<String>,
}

struct Shared {
    dir: PathBuf,
    /// The memory each job may hold, checked again when it starts.
    budget: Budget,
    executor: Executor,
    table: Mutex<Table>,
    wake: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Table> {
        // A panic while holding the lock cannot leave the table inconsistent (every
        // change is one insert or field update), so a poisoned lock is used as it is.
        self.table.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The job table and its compute threads.
pub struct Jobs {
    shared: Arc<Shared>,
}

impl Jobs {
    /// Loads the stored jobs of `dir` and starts `workers` compute threads. Jobs that were
    /// running when the service stopped are marked `interrupted`; queued ones queue again;
    /// deletions cut short are finished.
    pub fn open(
        dir: &Path,
        workers: usize,
        job_threads: usize,
        budget: Budget,
        executor: Executor,
    ) -> Result<Jobs> {
        let (stored, notes) = store::load_all(dir)?;
        for note in notes {
            eprintln!("slim serve: {note}");
        }
        let mut table = Table::default();
        for store::StoredJob {
            mut record,
            scene_toml,
        } in stored
        {
            match record.state {
                State::Deleted => {
                    store::remove(dir, &record)?;
                    continue;
                }
                State::Running => {
                    record.state = State::Interrupted;
                    record.finished_unix_s = Some(unix_now());
                    record.error = Some(
                        "the service stopped while this job was running; submit it again".into(),
                    );
                    store::save(dir, &record)?;
                }
                State::Queued => table.queue.push_back(record.id.clone()),
                _ => {}
            }
            let scene = SceneText {
                toml: scene_toml,
                parse_path: record.parse_path.clone(),
            };
            let mut entry = Entry::new(record, scene);
            if entry.record.state == State::Succeeded {
                entry.results = result_files(&store::result_dir(dir, &entry.record.id));
            }
            table.jobs.insert(entry.record.id.clone(), entry);
        }
        let shared = Arc::new(Shared {
            dir: dir.to_path_buf(),
            budget,
            executor,
            table: Mutex::new(table),
            wake: Condvar::new(),
        });
        for _ in 0..workers.max(1) {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(job_threads.max(1))
                .build()
                .map_err(|e| Error::Usage(format!("cannot start compute threads: {e}")))?;
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("slim-job".into())
                .spawn(move || work(&shared, &pool))
                .map_err(|e| Error::Usage(format!("cannot start compute threads: {e}")))?;
        }
        Ok(Jobs { shared })
    }

    /// A new job id: 16 hex digits, random.
    pub fn new_id() -> String {
        let random = std::collections::hash_map::RandomState::new()
            .build_hasher()
            .finish();
        format!("{random:016x}")
    }

    /// Stores and queues a checked scene.
    pub fn submit(
        &self,
        id: String,
        scene: SceneText,
        name: String,
        plan: &Plan,
    ) -> ApiResult<JobView> {
        let record = JobRecord {
            id: id.clone(),
            name,
            state: State::Queued,
            parse_path: scene.parse_path.clone(),
            submitted_unix_s: unix_now(),
            started_unix_s: None,
            finished_unix_s: None,
            plan: serde_json::to_value(plan).unwrap_or_default(),
            timings_s: Vec::new(),
            error: None,
        };
        store::create(&self.shared.dir, &record, &scene.toml)
            .map_err(|e| ApiError::internal(format!("storing the job: {e}")))?;
        let entry = Entry::new(record, scene);
        let view = entry.view();
        let mut table = self.shared.lock();
        table.jobs.insert(id.clone(), entry);
        table.queue.push_back(id);
        drop(table);
        self.shared.wake.notify_one();
        Ok(view)
    }

    /// Every job, oldest first.
    pub fn list(&self) -> Vec<JobView> {
        let table = self.shared.lock();
        let mut views: Vec<JobView> = table.jobs.values().map(Entry::view).collect();
        views.sort_by(|a, b| {
            a.timings
                .submitted_unix_s
                .total_cmp(&b.timings.submitted_unix_s)
        });
        views
    }

    /// One job.
    pub fn get(&self, id: &str) -> ApiResult<JobView> {
        let table = self.shared.lock();
        find(&table, id).map(Entry::view)
    }

    /// The scene of a job (any state), and its facets from the plan.
    pub fn scene(&self, id: &str) -> ApiResult<(SceneText, SceneSize)> {
        let table = self.shared.lock();
        find(&table, id).map(|e| {
            let count = |key: &str| e.record.plan[key].as_u64().unwrap_or(0) as usize;
            let size = SceneSize {
                facets: count("facets"),
                steps: count("steps"),
                bodies: count("bodies"),
            };
            (e.scene.clone(), size)
        })
    }

    /// The result folder of a job that has succeeded.
    pub fn result_dir(&self, id: &str) -> ApiResult<PathBuf> {
        let table = self.shared.lock();
        let entry = find(&table, id)?;
        if entry.record.state != State::Succeeded {
            return Err(ApiError::conflict(
                "job_not_finished",
                format!(
                    "job {id} is {}: results exist only for succeeded jobs",
                    entry.record.state.name()
                ),
            ));
        }
        Ok(store::result_dir(&self.shared.dir, id))
    }

    /// Deletes a job: a queued one leaves the queue, a running one is stopped at its next
    /// step; its folder and results are removed.
    pub fn delete(&self, id: &str) -> ApiResult<()> {
        let mut table = self.shared.lock();
        let entry = table.jobs.remove(id).ok_or_else(|| unknown_job(id))?;
        table.queue.retain(|q| q != id);
        if entry.record.state == State::Running {
            // The compute thread removes the folder when it sees the job gone.
            entry.live.cancel.store(true, Ordering::Relaxed);
            let deleted = JobRecord {
                state: State::Deleted,
                ..entry.record
            };
            return store::save(&self.shared.dir, &deleted)
                .map_err(|e| ApiError::internal(format!("deleting the job: {e}")));
        }
        drop(table);
        store::remove(&self.shared.dir, &entry.record)
            .map_err(|e| ApiError::internal(format!("deleting the job: {e}")))
    }
}

fn find<'t>(table: &'t Table, id: &str) -> ApiResult<&'t Entry> {
    table.jobs.get(id).ok_or_else(|| unknown_job(id))
}

fn unknown_job(id: &str) -> ApiError {
    ApiError::not_found(
        "unknown_job",
        format!("no job '{id}' (GET /v1/jobs lists them)"),
    )
}

/// A compute thread: takes queued jobs one at a time and runs them in `pool`.
fn work(shared: &Shared, pool: &rayon::ThreadPool) {
    loop {
        let (id, scene, live) = next_job(shared);
        let dir = &shared.dir;
        let out = store::result_dir(dir, &id);
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            pool.install(|| {
                let scene = scene.parse(dir).map_err(|e| e.message)?;
                // The files were checked at submission; a link swapped in since must not
                // let the run read outside the data folder.
                check_files(dir, &scene).map_err(|e| e.message)?;
                let ran = match &shared.executor {
                    Executor::Local => run_scene(&scene, &out, &shared.budget, live.as_ref()),
                    Executor::Slurm { parts, resources } => {
                        run_on_slurm(&scene, &out, *parts, resources, live.as_ref())
                    }
                };
                ran.map_err(|e| match e {
                    Error::Cancelled => String::new(),
                    e => e.to_string().replace(&format!("{}/", dir.display()), ""),
                })
            })
        }))
        .unwrap_or_else(|_| Err("internal error: the run panicked".into()));
        finish(shared, &id, outcome);
    }
}

/// Where jobs compute.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum Executor {
    /// On this machine's compute threads.
    #[default]
    Local,
    /// As `parts` time parts of a Slurm array job and a merge job (the data folder must
    /// be on a file system the cluster's nodes share). Progress counts parts, not steps.
    Slurm { parts: usize, resources: Resources },
}

/// How often a Slurm job's state is read, and how often cancellation is looked for.
const SLURM_POLL: std::time::Duration = std::time::Duration::from_secs(2);
const CANCEL_POLL: std::time::Duration = std::time::Duration::from_millis(200);

/// Runs `scene` on Slurm into `out` ([`Batch`]): submits the parts and their merge, then
/// follows them, mirroring parts done in `live` and cancelling them when `live` is.
fn run_on_slurm(
    scene: &Scene,
    out: &Path,
    parts: usize,
    resources: &Resources,
    live: &Live,
) -> Result<RunRecord> {
    // A scene sent inline has only a virtual path (its relative paths resolve from the
    // data folder): the jobs need it as a file, so it is written there while they run.
    let written = (!scene.path.exists())
        .then(|| crate::atomic::write_atomic(&scene.path, &scene.source).map(|()| &scene.path))
        .transpose()?;
    let outcome = follow_batch(scene, out, parts, resources, live);
    if let Some(path) = written {
        let _ = std::fs::remove_file(path);
    }
    outcome
}

fn follow_batch(
    scene: &Scene,
    out: &Path,
    parts: usize,
    resources: &Resources,
    live: &Live,
) -> Result<RunRecord> {
    // Never more parts than steps, which would leave parts empty.
    let parts = parts
        .min(scene.step_count().min(usize::MAX as f64) as usize)
        .max(1);
    let batch = Batch::new(scene, out, parts, By::Time, resources.clone())?;
    let jobs = batch.submit()?;
    live.total.store(parts as u64, Ordering::Relaxed);
    loop {
        let polled = std::time::Instant::now();
        while polled.elapsed() < SLURM_POLL {
            if live.cancelled() {
                batch.cancel(&jobs)?;
                return Err(Error::Cancelled);
            }
            std::thread::sleep(CANCEL_POLL);
        }
        let status = batch.poll(&jobs)?;
        live.done.store(status.parts_done as u64, Ordering::Relaxed);
        match status.state {
            BatchState::Running => continue,
            BatchState::Done => return RunRecord::read(out),
            BatchState::Failed(what) => {
                return Err(Error::Usage(format!(
                    "on Slurm: {what} (logs in {})",
                    out.join("slurm/logs").display()
                )))
            }
        }
    }
}

/// The result files present in a finished job's folder.
fn result_files(folder: &Path) -> Vec<&'static str> {
    RESULT_FILES
        .iter()
        .copied()
        .filter(|f| folder.join(f).is_file())
        .collect()
}

/// Waits for a queued job, marks it running and returns what the run needs.
fn next_job(shared: &Shared) -> (String, SceneText, Arc<Live>) {
    let mut table = shared.lock();
    loop {
        while let Some(id) = table.queue.pop_front() {
            let Some(entry) = table.jobs.get_mut(&id) else {
                continue;
            };
            entry.record.state = State::Running;
            entry.record.started_unix_s = Some(unix_now());
            if let Err(e) = store::save(&shared.dir, &entry.record) {
                eprintln!("slim serve: job {id}: {e}");
            }
            return (id, entry.scene.clone(), Arc::clone(&entry.live));
        }
        table = shared.wake.wait(table).unwrap_or_else(|p| p.into_inner());
    }
}

/// Records a run's outcome; a job deleted meanwhile has its folder removed instead.
fn finish(
    shared: &Shared,
    id: &str,
    outcome: std::result::Result<crate::output::record::RunRecord, String>,
) {
    let results = match &outcome {
        Ok(_) => result_files(&store::result_dir(&shared.dir, id)),
        Err(_) => Vec::new(),
    };
    let mut table = shared.lock();
    let Some(entry) = table.jobs.get_mut(id) else {
        drop(table);
        let folder = store::job_dir(&shared.dir, id);
        if let Err(e) = std::fs::remove_dir_all(&folder) {
            eprintln!("slim serve: removing deleted job {id}: {e}");
        }
        return;
    };
    entry.results = results;
    let r = &mut entry.record;
    r.finished_unix_s = Some(unix_now());
    match outcome {
        Ok(run) => {
            r.state = State::Succeeded;
            r.plan = serde_json::to_value(&run.plan).unwrap_or_default();
            r.timings_s = run.timings_s;
        }
        Err(message) => {
            r.state = State::Failed;
            r.error = Some(message);
        }
    }
    if let Err(e) = store::save(&shared.dir, r) {
        eprintln!("slim serve: job {id}: {e}");
    }
}
