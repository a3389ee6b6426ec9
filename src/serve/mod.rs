//! Serve: the HTTP service behind `slim serve --data DIR --listen ADDR`.
//!
//! In: a data folder `DIR` (the catalogue — `DIR/shapes`, `DIR/kernels`, `DIR/scenes` — and
//! the job store `DIR/jobs`) and HTTP requests. Out: JSON documents (jobs, catalogue, facet
//! statistics in W/m², charging windows in seconds and J/m², irradiance time series) and
//! the Parquet files of finished jobs, byte for byte those `slim run` writes.
//!
//! Layout: [`routes`] holds the single route table the router and the OpenAPI test share;
//! [`jobs`] runs scenes on a bounded pool of compute threads outside the async runtime and
//! [`store`] keeps their records on disk; [`scene_input`] turns request bodies into scenes
//! whose files all lie inside `DIR` ([`catalogue`]); [`query`], [`windows`] and [`points`]
//! answer facet questions; [`traverse`] plans and evaluates rover routes; [`files`] serves result files with HTTP ranges; [`reply`] turns
//! every failure into a JSON error; [`limits`] holds the configurable bounds.

pub mod catalogue;
pub mod files;
pub mod jobs;
pub mod limits;
pub mod lru;
pub mod points;
pub mod query;
pub mod reply;
pub mod routes;
pub mod scene_input;
pub mod store;
pub mod traverse;
pub mod windows;

use crate::error::{Error, Result};
use limits::Limits;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

/// How the service runs.
#[derive(Debug, Clone)]
pub struct Config {
    /// The data folder (catalogue and job store).
    pub data_dir: PathBuf,
    /// Address to listen on (port 0: any free port, printed on start).
    pub listen: SocketAddr,
    /// Bearer token required by the mutating endpoints (none: no token needed).
    pub token: Option<String>,
    /// Whether the read endpoints need the token too.
    pub protect_reads: bool,
    /// Number of jobs computed at the same time.
    pub workers: usize,
    /// Threads each job computes with.
    pub job_threads: usize,
    pub limits: Limits,
    /// Where jobs compute: here, or on Slurm.
    pub executor: jobs::Executor,
}

/// Everything the handlers share.
pub struct App {
    /// The data folder, canonical.
    pub data_dir: PathBuf,
    pub config: Config,
    pub jobs: jobs::Jobs,
    pub results: query::ResultCache,
    pub points: points::EngineCache,
    /// Permits for heavy queries (point irradiance, windows): `limits.max_heavy_queries`.
    pub heavy: tokio::sync::Semaphore,
}

/// Shared handle on the service state.
pub type AppState = Arc<App>;

impl App {
    /// Opens the data folder: creates `DIR/jobs`, reloads the job store (jobs that were
    /// running when the service stopped become `interrupted`) and starts the workers.
    pub fn open(config: Config) -> Result<AppState> {
        let data_dir = config
            .data_dir
            .canonicalize()
            .map_err(|e| Error::io(&config.data_dir, e))?;
        if !data_dir.is_dir() {
            return Err(Error::file(&data_dir, "the data folder is not a folder"));
        }
        let jobs = jobs::Jobs::open(
            &data_dir,
            config.workers,
            config.job_threads,
            config.limits.job_budget(),
            config.executor.clone(),
        )?;
        Ok(Arc::new(App {
            data_dir,
            jobs,
            results: query::ResultCache::new(config.limits.cache_bytes),
            points: points::EngineCache::new(config.limits.cache_bytes),
            heavy: tokio::sync::Semaphore::new(config.limits.max_heavy_queries),
            config,
        }))
    }
}

/// Runs the service until Ctrl-C (or SIGTERM). Prints `listening on ADDR` to stderr once
/// the socket is bound.
pub fn serve(config: Config) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| Error::Usage(format!("cannot start the async runtime: {e}")))?;
    let listen = config.listen;
    let app = App::open(config)?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .map_err(|e| Error::Usage(format!("--listen {listen}: {e}")))?;
        let bound = listener
            .local_addr()
            .map_err(|e| Error::Usage(format!("--listen {listen}: {e}")))?;
        eprintln!("listening on {bound}");
        axum::serve(listener, routes::router(app))
            .with_graceful_shutdown(shutdown_signal())
            .await
            .map_err(|e| Error::Usage(format!("serving on {bound}: {e}")))
    })
}

/// Resolves on Ctrl-C or SIGTERM.
async fn shutdown_signal() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(s) => s,
                Err(_) => return ctrl_c.await.unwrap_or(()),
            };
        tokio::select! {
            _ = ctrl_c => {}
            _ = term.recv() => {}
        }
    }
    #[cfg(not(unix))]
    ctrl_c.await.unwrap_or(());
}
