//! CLI: the `slim` command — a thin layer over the library, compiled into the binary
//! (`src/main.rs`), not the library.
//!
//! `slim run SCENE.toml [-o DIR] [--threads N] [--quiet]` runs a scene; `slim info MESH`
//! loads a mesh and prints its inspection report; `slim report RUN_DIR` draws a finished
//! run's figures and HTML page (`slim run --report` does so right after the run);
//! `slim render SCENE.toml` writes simulated camera images; `slim fit SCENE.toml IMAGES`
//! fits reflectance parameters to observed images; `slim compare A B` compares two
//! images' histograms with a χ² test; `slim photometry MODEL ...` prints a reflectance
//! model's r and I/F at one geometry; `slim serve --data DIR` runs the HTTP service.
//! Errors are printed as one line and the exit code is non-zero. Commands whose Cargo
//! feature is off (`serve`, `report`, `imaging`) are not built in.

use clap::error::ErrorKind;
use clap::{Parser, Subcommand, ValueEnum};
#[cfg(feature = "terminal")]
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use slim::budget::{parse_bytes, Budget};
#[cfg(feature = "imaging")]
use slim::compare::{compare_images, ValueBins};
use slim::error::{printable, Error, Result};
#[cfg(feature = "imaging")]
use slim::fit::job::fit_scene;
#[cfg(feature = "imaging")]
use slim::image::read_image;
use slim::mesh::{inspect::inspect, read_mesh, LengthUnit, Mesh, MeshFormat};
use slim::photometry::hapke::HFunction;
use slim::photometry::{i_over_f, Angles, Material, Reflectance};
use slim::progress::Progress;
#[cfg(feature = "imaging")]
use slim::render::job::render_scene;
#[cfg(feature = "report")]
use slim::report::colormap::Colormap;
#[cfg(feature = "report")]
use slim::report::select::{FacetRef, LatLon};
#[cfg(feature = "report")]
use slim::report::{write_report, ReportOptions};
use slim::run::run_scene;
use slim::scene::Scene;
#[cfg(feature = "serve")]
use slim::serve::jobs::Executor;
#[cfg(feature = "serve")]
use slim::serve::{self, limits::Limits};
use slim::shard::merge::merge;
use slim::shard::slurm::{estimate, Batch, Estimate as SlurmEstimate, Resources};
use slim::shard::{run_shard, Shard};
#[cfg(feature = "imaging")]
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "slim",
    version,
    about = "Sunlight on airless bodies: shadowed irradiance and per-facet statistics"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a scene and write its results.
    Run {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Output folder (default: results/<scene name>).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Worker threads (default: all cores). Results are identical for any number.
        #[arg(long)]
        threads: Option<usize>,
        /// Most memory the run may hold, e.g. 8G or 512M (default: three quarters of the
        /// machine's memory). The plan prints the estimate; a run above it is refused
        /// before it starts, naming what to change.
        #[arg(long, value_name = "SIZE", value_parser = size)]
        max_memory: Option<u64>,
        /// Print nothing but errors.
        #[arg(short, long)]
        quiet: bool,
        /// Also write the report (figures and index.html) into OUTPUT/report.
        #[cfg(feature = "report")]
        #[arg(long)]
        report: bool,
        /// Run only part K of N (e.g. 3/8) and write its partial state into the output
        /// folder, for `slim merge` (docs/shards.md).
        #[arg(long, value_name = "K/N")]
        shard: Option<String>,
        /// What the parts split: consecutive steps, or consecutive facets.
        #[arg(
            long,
            value_name = "time|facets",
            default_value = "time",
            requires = "shard"
        )]
        by: slim::shard::By,
    },
    /// Write (and with --submit, submit) Slurm jobs that run a scene in parts as an array
    /// job and merge them when every part is done (docs/shards.md).
    Slurm {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Number of parts (array tasks).
        #[arg(long, value_name = "N")]
        shards: usize,
        /// What the parts split: consecutive steps, or consecutive facets.
        #[arg(long, value_name = "time|facets", default_value = "time")]
        by: slim::shard::By,
        /// The run's folder: parts in OUTPUT/parts/K, scripts and logs in OUTPUT/slurm,
        /// the merged files in OUTPUT (default: results/<scene name>).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Slurm partition.
        #[arg(long)]
        partition: Option<String>,
        /// Wall time per part, in Slurm's format (e.g. 2:00:00).
        #[arg(long)]
        time: Option<String>,
        /// Memory per part, in Slurm's format (e.g. 8G).
        #[arg(long)]
        mem: Option<String>,
        /// CPUs per part; slim runs as many threads.
        #[arg(long, default_value_t = 1)]
        cpus_per_task: usize,
        /// Submit the jobs with sbatch (the merge waits for every part).
        #[arg(long, conflicts_with = "dry_run")]
        submit: bool,
        /// Write nothing: run a short probe of the scene here and print what each part
        /// needs (time and memory), and the scripts.
        #[arg(long)]
        dry_run: bool,
        /// Steps the dry run's probe computes (its first steps are slower; 32 keep the
        /// estimate within 10 % on a 786k-facet year, docs/performance.md).
        #[arg(long, default_value_t = 32, value_name = "STEPS")]
        probe_steps: usize,
        /// Print nothing but errors (and the dry run's estimate).
        #[arg(short, long)]
        quiet: bool,
        /// Most memory the probe may use (e.g. 8G; default: three quarters of this
        /// machine's).
        #[arg(long, value_name = "SIZE", value_parser = size)]
        max_memory: Option<u64>,
    },
    /// Merge the part folders of a run (`slim run --shard K/N`) into the files of one run,
    /// byte-identical to a single `slim run` (docs/shards.md).
    Merge {
        /// The part folders, in any order.
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        /// Output folder.
        #[arg(short, long)]
        output: PathBuf,
        /// The scene file, when it has moved since the parts ran (same content).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Most memory the merge may hold (e.g. 8G; default: three quarters of this
        /// machine's).
        #[arg(long, value_name = "SIZE", value_parser = size)]
        max_memory: Option<u64>,
        /// Print nothing but errors.
        #[arg(short, long)]
        quiet: bool,
    },
    /// Draw a finished run's figures and its self-contained index.html.
    #[cfg(feature = "report")]
    Report {
        /// The run folder (holding run.json).
        run_dir: PathBuf,
        /// Report folder (default: RUN_DIR/report).
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[command(flatten)]
        options: ReportArgs,
    },
    /// Serve jobs, result files and facet queries over HTTP (docs/service.md).
    #[cfg(feature = "serve")]
    Serve(ServeArgs),
    /// Answer a place query on a scene, as the service's /irradiance does: irradiance of
    /// facets or places, panels at a height, a battery, other bodies' sight (JSON).
    #[cfg(feature = "serve")]
    Place {
        /// The scene file (TOML).
        scene: PathBuf,
        /// The query, as JSON (`-` for standard input); docs/service.md has examples.
        query: PathBuf,
        /// Write the answer here instead of to standard output.
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
    /// Plan a rover's route between two places, or evaluate one through waypoints, as
    /// the service's /route does (GeoJSON-like JSON; docs/service.md#routes).
    #[cfg(feature = "serve")]
    Route {
        /// The scene file (TOML).
        scene: PathBuf,
        /// The request, as JSON (`-` for standard input).
        request: PathBuf,
        /// Write the answer here instead of to standard output.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Most memory the run may use (e.g. 8G; default: three quarters of this machine's).
        #[arg(long, value_name = "SIZE", value_parser = size)]
        max_memory: Option<u64>,
        /// No progress bar.
        #[arg(short, long)]
        quiet: bool,
    },
    /// List the cache folder's files (horizon maps and bounds, form factors, build
    /// journals), least recently used first, and delete those no run has used for a while.
    Cache {
        /// The folder (default: $SLIM_CACHE_DIR, else $XDG_CACHE_HOME/slim, else
        /// ~/.cache/slim; a scene's run.cache_dir names its own).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// Delete the files no run has read or written for this many days (a build's
        /// journal only when no build holds it); other files in the folder are never
        /// touched.
        #[arg(long, value_name = "DAYS")]
        prune_unused: Option<f64>,
    },
    /// Load a mesh and report its size, topology and orientation.
    Info {
        /// The mesh file.
        mesh: PathBuf,
        /// Length unit of the file.
        #[arg(long, value_enum, default_value_t = Unit::Km)]
        units: Unit,
        /// Format (default: from the extension).
        #[arg(long, value_enum)]
        format: Option<Format>,
    },
    #[cfg(feature = "imaging")]
    /// Render a scene's [camera] view: radiance and I/F images (FITS, PNG) per step and band.
    Render {
        /// The scene file (TOML) with a [camera] section and a material per body.
        scene: PathBuf,
        /// Output folder (default: results/<scene name>/images).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
    #[cfg(feature = "imaging")]
    /// Fit reflectance parameters of one body to observed images (FITS with STEP, BAND).
    Fit {
        /// The scene file (TOML) with [camera] and materials (the starting values).
        scene: PathBuf,
        /// Observed images (FITS or PNG) with STEP (and BAND) header keywords.
        #[arg(required = true)]
        images: Vec<PathBuf>,
        /// Parameters to fit, comma-separated (e.g. w,xi,theta_bar_deg).
        #[arg(long, value_delimiter = ',', required = true)]
        params: Vec<String>,
        /// The body whose material is fitted (default: the first).
        #[arg(long)]
        body: Option<String>,
        /// Folder for the residual images (default: results/<scene name>/fit).
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
    #[cfg(feature = "imaging")]
    /// Compare two images' value distributions (IPDF) with a two-sample χ² test.
    Compare {
        /// First image (FITS or PNG).
        a: PathBuf,
        /// Second image (FITS or PNG).
        b: PathBuf,
        /// Bin width, in the images' unit (the paper: 10 W/m²).
        #[arg(long, default_value_t = 10.0)]
        bin_width: f64,
        /// Lower edge of the first bin.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        start: f64,
        /// Upper end of the bins (default: the larger image maximum).
        #[arg(long)]
        end: Option<f64>,
        /// Leave out pixels at or below this value (e.g. 0 for black sky).
        #[arg(long, allow_hyphen_values = true)]
        above: Option<f64>,
    },
    /// Print a reflectance model's r (sr⁻¹) and I/F at one geometry (angles in degrees).
    Photometry {
        /// Model: lambert, lommel_seeliger or hapke.
        model: String,
        #[command(flatten)]
        params: MaterialArgs,
        /// Incidence angle i from the normal to the Sun, degrees.
        #[arg(long)]
        incidence: f64,
        /// Emission angle e from the normal to the observer, degrees.
        #[arg(long)]
        emission: f64,
        /// Phase angle g between Sun and observer, degrees.
        #[arg(long)]
        phase: f64,
    },
}

/// Reflectance-model parameters on the command line (each model takes its own subset).
#[derive(clap::Args, Debug)]
struct MaterialArgs {
    /// Lambert albedo.
    #[arg(long)]
    albedo: Option<f64>,
    /// Single scattering albedo (lommel_seeliger, hapke).
    #[arg(long)]
    w: Option<f64>,
    /// Hapke opposition surge amplitude B0.
    #[arg(long)]
    b0: Option<f64>,
    /// Hapke opposition surge width h.
    #[arg(long)]
    h: Option<f64>,
    /// Hapke one-lobe Henyey–Greenstein asymmetry (negative: back-scattering).
    #[arg(long, allow_hyphen_values = true)]
    xi: Option<f64>,
    /// Hapke two-lobe Henyey–Greenstein lobe width b.
    #[arg(long)]
    b: Option<f64>,
    /// Hapke two-lobe Henyey–Greenstein back-scattering weight c.
    #[arg(long, allow_hyphen_values = true)]
    c: Option<f64>,
    /// Hapke macroscopic roughness (mean slope angle), degrees.
    #[arg(long)]
    theta_bar: Option<f64>,
    /// Hapke H-function approximation: 1981 or 2002.
    #[arg(long, value_parser = ["1981", "2002"])]
    h_function: Option<String>,
}

impl MaterialArgs {
    fn material(&self, model: &str) -> Result<Material> {
        let named = [
            ("albedo", self.albedo),
            ("w", self.w),
            ("b0", self.b0),
            ("h", self.h),
            ("xi", self.xi),
            ("b", self.b),
            ("c", self.c),
            ("theta_bar_deg", self.theta_bar),
        ];
        let params: Vec<(String, f64)> = named
            .iter()
            .filter_map(|(n, v)| v.map(|v| (n.to_string(), v)))
            .collect();
        let h_function = self.h_function.as_deref().map(|f| match f {
            "1981" => HFunction::Hapke1981,
            _ => HFunction::Hapke2002,
        });
        Material::from_params(model, &params, h_function)
    }
}

/// `slim serve` options.
#[cfg(feature = "serve")]
#[derive(clap::Args, Debug)]
struct ServeArgs {
    /// The data folder: the catalogue (shapes/, kernels/, scenes/) and the job store (jobs/).
    #[arg(long)]
    data: PathBuf,
    /// Address to listen on (port 0: any free port; the bound address is printed).
    #[arg(long, default_value = "127.0.0.1:8080")]
    listen: std::net::SocketAddr,
    /// File holding the API token required (as "Authorization: Bearer TOKEN") by the
    /// endpoints that submit or delete jobs. Without it the service is open.
    #[arg(long, value_name = "FILE")]
    token_file: Option<PathBuf>,
    /// Require the token for the read endpoints too.
    #[arg(long, requires = "token_file")]
    protect_reads: bool,
    /// Jobs computed at the same time (others queue).
    #[arg(long, default_value_t = 1)]
    workers: usize,
    /// Threads per job (default: all cores but one, at least one).
    #[arg(long)]
    job_threads: Option<usize>,
    /// Largest request body, bytes.
    #[arg(long, default_value_t = Limits::default().max_body_bytes)]
    max_body_bytes: usize,
    /// Most facets per job.
    #[arg(long, default_value_t = Limits::default().max_facets)]
    max_facets: usize,
    /// Most bodies per job.
    #[arg(long, default_value_t = Limits::default().max_bodies)]
    max_bodies: usize,
    /// Most memory one job may hold, e.g. 4G (default: three eighths of the machine's
    /// memory). Jobs whose estimate is above it are refused with 422.
    #[arg(long, value_name = "SIZE", value_parser = size)]
    max_job_memory: Option<u64>,
    /// Most time steps per job.
    #[arg(long, default_value_t = Limits::default().max_steps)]
    max_steps: usize,
    /// Most memory each of the two caches may hold (finished runs for queries, scenes
    /// built for point queries), e.g. 1G.
    #[arg(long, value_name = "SIZE", value_parser = size)]
    cache_memory: Option<u64>,
    /// Most heavy queries (point irradiance, windows) computed at once; more get 503
    /// (default: the number of cores; 0 switches them off).
    #[arg(long)]
    max_heavy_queries: Option<usize>,
    /// Longest a heavy query may take, seconds; slower ones get 503.
    #[arg(long, default_value_t = Limits::default().query_timeout_s)]
    query_timeout_s: u64,
    /// Most facets or places per query.
    #[arg(long, default_value_t = Limits::default().max_query_targets)]
    max_query_targets: usize,
    /// Most values (steps × series: targets, their panels and sights) per on-demand
    /// irradiance query.
    #[arg(long, default_value_t = Limits::default().max_query_values)]
    max_query_values: usize,
    /// Most labels a route plan may take (at most 240 bytes each).
    #[arg(long, default_value_t = Limits::default().max_route_labels)]
    max_route_labels: usize,
    /// Where jobs compute: on this machine, or as Slurm array jobs plus a merge (the data
    /// folder must be shared with the cluster's nodes; docs/shards.md).
    #[arg(long, value_name = "local|slurm", default_value = "local")]
    executor: String,
    /// With --executor slurm: time parts per job.
    #[arg(long, default_value_t = 4, value_name = "N")]
    slurm_parts: usize,
    /// With --executor slurm: the partition.
    #[arg(long)]
    slurm_partition: Option<String>,
    /// With --executor slurm: wall time per part (Slurm's format, e.g. 2:00:00).
    #[arg(long)]
    slurm_time: Option<String>,
    /// With --executor slurm: memory per part (Slurm's format, e.g. 8G).
    #[arg(long)]
    slurm_mem: Option<String>,
    /// With --executor slurm: CPUs per part.
    #[arg(long, default_value_t = 1)]
    slurm_cpus_per_task: usize,
}

#[cfg(feature = "serve")]
impl ServeArgs {
    fn config(self) -> Result<serve::Config> {
        let token = match &self.token_file {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
                let token = text.trim().to_string();
                if token.is_empty() {
                    return Err(Error::file(path, "the token file is empty"));
                }
                Some(token)
            }
            None => None,
        };
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let defaults = Limits::default();
        let executor = match self.executor.as_str() {
            "local" => Executor::Local,
            "slurm" => Executor::Slurm {
                parts: self.slurm_parts.max(1),
                resources: Resources {
                    partition: self.slurm_partition,
                    time: self.slurm_time,
                    mem: self.slurm_mem,
                    cpus: self.slurm_cpus_per_task.max(1),
                },
            },
            other => {
                return Err(Error::Usage(format!(
                    "--executor {other}: use 'local' or 'slurm'"
                )))
            }
        };
        Ok(serve::Config {
            executor,
            data_dir: self.data,
            listen: self.listen,
            token,
            protect_reads: self.protect_reads,
            workers: self.workers.max(1),
            job_threads: match self.job_threads {
                Some(n) => checked_threads("--job-threads", n)?,
                None => cores.saturating_sub(1).max(1),
            },
            limits: Limits {
                max_body_bytes: self.max_body_bytes,
                max_facets: self.max_facets,
                max_bodies: self.max_bodies,
                max_job_memory_bytes: self.max_job_memory.unwrap_or(defaults.max_job_memory_bytes),
                cache_bytes: self.cache_memory.unwrap_or(defaults.cache_bytes),
                max_heavy_queries: self.max_heavy_queries.unwrap_or(defaults.max_heavy_queries),
                query_timeout_s: self.query_timeout_s.max(1),
                max_steps: self.max_steps,
                max_query_targets: self.max_query_targets,
                max_query_values: self.max_query_values,
                max_route_labels: self.max_route_labels,
            },
        })
    }
}

/// What the report draws.
#[cfg(feature = "report")]
#[derive(clap::Args, Debug)]
struct ReportArgs {
    /// Plot the CDF of this facet (BODY:ID; repeatable).
    #[arg(long = "facet", value_name = "BODY:ID")]
    facets: Vec<FacetRef>,
    /// Plot the CDF of the facet nearest to this latitude,longitude (degrees, east-positive;
    /// repeatable).
    #[arg(long, value_name = "LAT,LON", allow_hyphen_values = true)]
    near: Vec<LatLon>,
    /// Threshold of the "time above" map, W/m².
    #[arg(long, value_name = "W/m2", default_value_t = 100.0)]
    threshold: f64,
    /// Colour map: viridis or cividis.
    #[arg(long, default_value = "viridis")]
    colormap: Colormap,
    /// Draw this rover route (a `slim route` answer) on its body's maps (repeatable).
    #[arg(long = "route", value_name = "ROUTE.json")]
    routes: Vec<PathBuf>,
}

#[cfg(feature = "report")]
impl ReportArgs {
    fn options(self) -> ReportOptions {
        ReportOptions {
            facets: self.facets,
            near: self.near,
            threshold_w_m2: self.threshold,
            colormap: self.colormap,
            routes: self.routes,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Unit {
    M,
    Km,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Format {
    Obj,
    Ply,
    Stl,
    Pds,
}

/// Entry point of the binary: returns the process exit code. Every error, a mistyped
/// argument included, is one line on stderr and exit code 1; `--help` and `--version`
/// print as usual. Output cut short by a closed pipe (`slim info MESH | head -1`) ends
/// the program quietly.
pub fn main() -> std::process::ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) => {
            let _ = e.print();
            return std::process::ExitCode::SUCCESS;
        }
        Err(e) => return fail(&usage_error(&e)),
    };
    match execute(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(Error::Io { source, .. }) if source.kind() == std::io::ErrorKind::BrokenPipe => {
            std::process::ExitCode::SUCCESS
        }
        Err(e) => fail(&e.to_string()),
    }
}

/// Prints `message` as one line and returns the failure exit code. Control characters
/// (from a broken file's bytes, or a line break) are written as escapes, so that a bad
/// file can neither drive the terminal nor split the line.
fn fail(message: &str) -> std::process::ExitCode {
    eprintln!("slim: error: {}", printable(message, usize::MAX));
    std::process::ExitCode::FAILURE
}

/// A command-line mistake as one line: clap's message, the usage line and where to look.
fn usage_error(e: &clap::Error) -> String {
    let rendered = e.render().to_string();
    let mut lines = rendered.lines().map(str::trim).filter(|l| !l.is_empty());
    let message = lines
        .next()
        .unwrap_or("invalid arguments")
        .trim_start_matches("error:")
        .trim();
    let usage = lines.find_map(|l| l.strip_prefix("Usage:")).map(str::trim);
    match usage {
        Some(usage) => format!("{message} (usage: {usage}; more with --help)"),
        None => format!("{message} (more with --help)"),
    }
}

/// `slim cache`: the folder's files, or (with `prune_unused` days) those it deleted.
fn cache_folder(dir: Option<PathBuf>, prune_unused: Option<f64>) -> Result<String> {
    use slim::budget::human_bytes;
    use std::time::{Duration, SystemTime};
    let dir = dir.or_else(slim::cache::default_dir).ok_or_else(|| {
        Error::Usage(
            "no cache folder: none of SLIM_CACHE_DIR, XDG_CACHE_HOME, HOME is set; give --dir"
                .into(),
        )
    })?;
    let now = SystemTime::now();
    let days_ago =
        |t: SystemTime| now.duration_since(t).unwrap_or_default().as_secs_f64() / 86_400.0;
    let line = |e: &slim::cache::Entry| {
        let name = e.path.file_name().unwrap_or_default().to_string_lossy();
        format!(
            "{:<24} {:>10}  {:>7.1} days ago  {name}\n",
            e.what,
            human_bytes(e.bytes),
            days_ago(e.last_used)
        )
    };
    let total = |entries: &[slim::cache::Entry]| {
        let n = entries.len();
        let bytes = human_bytes(entries.iter().map(|e| e.bytes).sum());
        format!("{n} file{}, {bytes}", if n == 1 { "" } else { "s" })
    };
    let Some(days) = prune_unused else {
        let entries = slim::cache::entries(&dir)?;
        let mut text = format!("{}: {}\n", dir.display(), total(&entries));
        entries.iter().for_each(|e| text += &line(e));
        return Ok(text);
    };
    if !(days.is_finite() && days >= 0.0) {
        return Err(Error::Usage(format!(
            "--prune-unused {days}: give a number of days, 0 or more"
        )));
    }
    let before = now - Duration::from_secs_f64(days * 86_400.0);
    let deleted = slim::cache::prune(&dir, before)?;
    let mut text = format!(
        "{}: deleted {} (unused for {days} days or more)\n",
        dir.display(),
        total(&deleted)
    );
    deleted.iter().for_each(|e| text += &line(e));
    Ok(text)
}

/// Writes `text` to stdout. A reader that has gone away (a closed pipe) is an
/// [`Error::Io`] of kind `BrokenPipe`, which [`main`] ends on quietly.
fn emit(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .map_err(|e| Error::io(std::path::Path::new("standard output"), e))
}

/// The text of a query file, or of standard input for `-`.
#[cfg(feature = "serve")]
fn read_query(path: &std::path::Path) -> Result<String> {
    if path == std::path::Path::new("-") {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut std::io::stdin(), &mut text)
            .map_err(|e| Error::io(std::path::Path::new("standard input"), e))?;
        Ok(text)
    } else {
        std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
    }
}

/// `slim route`: one route query on a scene, answered as GeoJSON-like JSON.
#[cfg(feature = "serve")]
fn route(
    scene_path: &std::path::Path,
    request_path: &std::path::Path,
    output: Option<&std::path::Path>,
    budget: Budget,
    progress: &dyn Progress,
) -> Result<()> {
    let text = read_query(request_path)?;
    let request =
        serve::traverse::RouteRequest::from_body(text.as_bytes()).map_err(|e| Error::File {
            path: request_path.to_path_buf(),
            msg: e.message,
        })?;
    let scene = slim::scene::Scene::load(scene_path)?;
    let limits = serve::limits::RouteLimits {
        budget,
        max_labels: serve::limits::Limits::default().max_route_labels,
        max_waypoints: usize::MAX,
    };
    let answer = serve::traverse::answer(None, &scene, &request, &limits, progress)
        .map_err(|e| Error::Usage(format!("{} ({})", e.message, e.code)))?;
    write_json(&answer, output)
}

/// `answer` as pretty JSON to `output` (written whole, then renamed) or standard output.
#[cfg(feature = "serve")]
fn write_json(answer: &impl serde::Serialize, output: Option<&std::path::Path>) -> Result<()> {
    let json = serde_json::to_string_pretty(answer).expect("answers serialise") + "\n";
    match output {
        Some(path) => slim::atomic::write_atomic(path, json.as_bytes()),
        None => emit(&json),
    }
}

/// `slim place`: one place query on a scene, answered as JSON.
#[cfg(feature = "serve")]
fn place(
    scene: &std::path::Path,
    query: &std::path::Path,
    output: Option<&std::path::Path>,
) -> Result<()> {
    let text = read_query(query)?;
    let request =
        serve::points::PointsRequest::from_body(text.as_bytes()).map_err(|e| Error::File {
            path: query.to_path_buf(),
            msg: e.message,
        })?;
    let answer = serve::points::answer_scene_file(scene, &request)?;
    write_json(&answer, output)
}

/// The memory budget `--max-memory` sets, or the machine's.
fn budget_of(max_memory: Option<u64>) -> Budget {
    match max_memory {
        Some(max_bytes) => Budget {
            max_bytes,
            source: "--max-memory",
        },
        None => Budget::machine(),
    }
}

/// Prints what each part of a Slurm batch needs.
fn print_estimate(name: &str, parts: usize, by: slim::shard::By, e: &SlurmEstimate) {
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    println!(
        "{name}: {parts} parts by {by}; per part, from a probe of {} steps here ({} threads):",
        e.probe_steps, e.probe_threads
    );
    println!(
        "  time:   {:.1} s setup + {} steps × {:.4} s + {:.1} s output = {:.1} s ({:.1} min)",
        e.setup_s,
        e.part_steps,
        e.step_s,
        e.output_s,
        e.part_s,
        e.part_s / 60.0
    );
    println!(
        "  memory: {:.2} GiB planned, {:.2} GiB measured at the probe's peak",
        gib(e.part_bytes_planned),
        gib(e.part_bytes_probe)
    );
    let mem_gib = gib(e.part_bytes_planned.max(e.part_bytes_probe)) * 1.5;
    let minutes = (e.part_s * 1.5 / 60.0).ceil().max(1.0) as u64;
    println!(
        "  ask for (×1.5, on as many CPUs as the probe had): --mem={}G --time={}:{:02}:00",
        mem_gib.ceil().max(1.0) as u64,
        minutes / 60,
        minutes % 60
    );
}

/// `results/NAME`, or `results/NAME/parts/K` for part K.
fn default_output(scene: &Scene, shard: Option<Shard>) -> PathBuf {
    let run = PathBuf::from("results").join(&scene.name);
    match shard {
        Some(s) => run.join("parts").join(s.index.to_string()),
        None => run,
    }
}

fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run {
            scene,
            output,
            threads,
            max_memory,
            quiet,
            #[cfg(feature = "report")]
            report,
            shard,
            by,
        } => {
            if let Some(n) = threads {
                set_threads(n)?;
            }
            let shard = shard
                .map(|text| Shard::parse(&text, by))
                .transpose()
                .map_err(|e| Error::Usage(format!("--shard: {e}")))?;
            let scene = Scene::load(&scene)?;
            let out = output.unwrap_or_else(|| default_output(&scene, shard));
            let progress = TerminalProgress::new(quiet);
            let budget = budget_of(max_memory);
            let record = match shard {
                Some(part) => run_shard(&scene, &out, &budget, part, &progress)?,
                None => run_scene(&scene, &out, &budget, &progress)?,
            };
            if !quiet {
                // The counts cover every step; repeated steps were not traced again.
                let repeated = match record.plan.repeats() {
                    true => ", counted over every step: the later periods repeat the first's",
                    false => "",
                };
                eprintln!(
                    "wrote {} files to {} ({} facets, {} steps, {} shadow rays{repeated})",
                    record.outputs.len(),
                    out.display(),
                    record.plan.facets,
                    record.plan.steps,
                    record.counts.rays
                );
            }
            #[cfg(feature = "report")]
            if report && shard.is_none() {
                let written = write_report(&out, None, &ReportOptions::default())?;
                if !quiet {
                    eprintln!("wrote the report to {}", written.index.display());
                }
            }
            Ok(())
        }
        Command::Slurm {
            scene,
            shards,
            by,
            output,
            partition,
            time,
            mem,
            cpus_per_task,
            submit,
            dry_run,
            probe_steps,
            max_memory,
            quiet,
        } => {
            let scene = Scene::load(&scene)?;
            let out = output.unwrap_or_else(|| default_output(&scene, None));
            let resources = Resources {
                partition,
                time,
                mem,
                cpus: cpus_per_task.max(1),
            };
            let batch = Batch::new(&scene, &out, shards, by, resources)?;
            if dry_run {
                let scratch =
                    std::env::temp_dir().join(format!("slim-probe-{}", std::process::id()));
                let estimate = estimate(
                    &scene,
                    &budget_of(max_memory),
                    shards,
                    by,
                    probe_steps,
                    &scratch,
                );
                let _ = std::fs::remove_dir_all(&scratch);
                print_estimate(&scene.name, shards, by, &estimate?);
                println!(
                    "\n# {}\n{}",
                    batch.out.join("slurm/parts.sh").display(),
                    batch.parts_script()
                );
                println!(
                    "# {}\n{}",
                    batch.out.join("slurm/merge.sh").display(),
                    batch.merge_script()
                );
            } else if submit {
                let jobs = batch.submit()?;
                if !quiet {
                    eprintln!(
                        "submitted the {shards} parts as array job {} and their merge as job {} \
                     (ids in {}); results in {}",
                        jobs.array,
                        jobs.merge,
                        batch.out.join("slurm/jobs.json").display(),
                        batch.out.display()
                    );
                }
            } else {
                let (parts, merge) = batch.write()?;
                if !quiet {
                    eprintln!(
                        "wrote {} and {}; submit with `slim slurm ... --submit`, or by hand:\n  \
                     A=$(sbatch --parsable {})\n  \
                     sbatch --dependency=afterok:$A --kill-on-invalid-dep=yes {}",
                        parts.display(),
                        merge.display(),
                        parts.display(),
                        merge.display()
                    );
                }
            }
            Ok(())
        }
        Command::Merge {
            parts,
            output,
            scene,
            max_memory,
            quiet,
        } => {
            let progress = TerminalProgress::new(quiet);
            let budget = budget_of(max_memory);
            let record = merge(&parts, &output, scene.as_deref(), &budget, &progress)?;
            if !quiet {
                eprintln!(
                    "merged {} parts into {} files in {}",
                    parts.len(),
                    record.outputs.len(),
                    output.display()
                );
            }
            Ok(())
        }
        #[cfg(feature = "report")]
        Command::Report {
            run_dir,
            output,
            options,
        } => {
            let written = write_report(&run_dir, output.as_deref(), &options.options())?;
            eprintln!(
                "wrote {} files to {}; open {}",
                written.files.len(),
                written.dir.display(),
                written.index.display()
            );
            Ok(())
        }
        #[cfg(feature = "serve")]
        Command::Serve(args) => serve::serve(args.config()?),
        #[cfg(feature = "serve")]
        Command::Place {
            scene,
            query,
            output,
        } => place(&scene, &query, output.as_deref()),
        #[cfg(feature = "serve")]
        Command::Route {
            scene,
            request,
            output,
            max_memory,
            quiet,
        } => route(
            &scene,
            &request,
            output.as_deref(),
            budget_of(max_memory),
            &TerminalProgress::new(quiet),
        ),
        Command::Cache { dir, prune_unused } => emit(&cache_folder(dir, prune_unused)?),
        Command::Info {
            mesh,
            units,
            format,
        } => {
            let format = format.map(|f| match f {
                Format::Obj => MeshFormat::Obj,
                Format::Ply => MeshFormat::Ply,
                Format::Stl => MeshFormat::Stl,
                Format::Pds => MeshFormat::Pds,
            });
            let unit = match units {
                Unit::M => LengthUnit::M,
                Unit::Km => LengthUnit::Km,
            };
            let raw = read_mesh(&mesh, format)?;
            let report = inspect(&Mesh::from_raw(raw, unit));
            emit(&format!("{}\n{report}\n", mesh.display()))
        }
        #[cfg(feature = "imaging")]
        Command::Render {
            scene,
            output,
            threads,
        } => {
            if let Some(n) = threads {
                set_threads(n)?;
            }
            let scene = Scene::load(&scene)?;
            let out =
                output.unwrap_or_else(|| PathBuf::from("results").join(&scene.name).join("images"));
            let files = render_scene(&scene, &out)?;
            eprintln!("wrote {} files to {}", files.len(), out.display());
            Ok(())
        }
        #[cfg(feature = "imaging")]
        Command::Fit {
            scene,
            images,
            params,
            body,
            output,
        } => {
            let scene = Scene::load(&scene)?;
            let out =
                output.unwrap_or_else(|| PathBuf::from("results").join(&scene.name).join("fit"));
            let (r, files) = fit_scene(&scene, &images, &params, body.as_deref(), &out)?;
            let mut text = format!(
                "fitted {} pixels in {} iterations; residual RMS {:.6e}\n",
                r.pixels, r.iterations, r.rms
            );
            for (j, name) in r.names.iter().enumerate() {
                let bound = if r.at_bound[j] { "  (at a bound)" } else { "" };
                let _ = writeln!(
                    text,
                    "{name} = {:.6} ± {:.6}{bound}",
                    r.values[j], r.sigmas[j]
                );
            }
            text.push_str("correlations:\n");
            for (name, row) in r.names.iter().zip(&r.correlation) {
                let cells: Vec<String> = row.iter().map(|c| format!("{c:+.3}")).collect();
                let _ = writeln!(text, "  {name:>14} {}", cells.join(" "));
            }
            let _ = writeln!(text, "{}", r.material.describe());
            emit(&text)?;
            eprintln!("wrote {} residual images to {}", files.len(), out.display());
            Ok(())
        }
        #[cfg(feature = "imaging")]
        Command::Compare {
            a,
            b,
            bin_width,
            start,
            end,
            above,
        } => {
            let (ia, ib) = (read_image(&a)?, read_image(&b)?);
            let end = end.unwrap_or_else(|| ia.max().max(ib.max()));
            let bins = ValueBins::covering(start, end.max(start), bin_width)?;
            let c = compare_images(&ia, &ib, bins, above)?;
            let mut text = String::from("bin_start,bin_end,count_a,count_b\n");
            for (k, (x, y)) in c.counts_a.iter().zip(&c.counts_b).enumerate() {
                let lo = bins.start + k as f64 * bins.width;
                let _ = writeln!(text, "{lo},{},{x},{y}", lo + bins.width);
            }
            let t = c.chi_square;
            let _ = writeln!(
                text,
                "chi2 = {:.6e}, dof = {}, p = {:.6e}  (H0: both histograms come from the same \
                 distribution; p < 0.05 rejects it)",
                t.statistic, t.dof, t.p_value
            );
            emit(&text)
        }
        Command::Photometry {
            model,
            params,
            incidence,
            emission,
            phase,
        } => {
            let material = params.material(&model)?;
            let angles = Angles::from_degrees(incidence, emission, phase)?;
            let r = material.reflectance(&angles);
            emit(&format!(
                "{}\ni={incidence} e={emission} g={phase} (degrees)\nr = {r:.9e} sr^-1\n\
                 I/F = {:.9e}\n",
                material.describe(),
                i_over_f(r)
            ))
        }
    }
}

/// A memory size from the command line (`8G`, `512M`, bytes), see [`parse_bytes`].
fn size(text: &str) -> std::result::Result<u64, String> {
    parse_bytes(text).ok_or_else(|| format!("'{text}' is not a size such as 8G, 512M or 1000000"))
}

/// The most worker threads a run may ask for: eight per core. More only add memory and
/// scheduling (results are the same for any count), and an absurd count would spawn
/// threads without end.
fn thread_limit() -> usize {
    8 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `n` worker threads, or an error naming `flag` when `n` is 0 or over [`thread_limit`].
fn checked_threads(flag: &str, n: usize) -> Result<usize> {
    let max = thread_limit();
    if n == 0 || n > max {
        return Err(Error::Usage(format!(
            "{flag} {n}: give 1 to {max} (eight per core on this machine)"
        )));
    }
    Ok(n)
}

fn set_threads(n: usize) -> Result<()> {
    let n = checked_threads("--threads", n)?;
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| Error::Usage(format!("--threads: {e}")))
}

/// A progress bar on stderr when it is a terminal (with the `terminal` feature); notes on
/// stderr unless quiet.
struct TerminalProgress {
    quiet: bool,
    #[cfg(feature = "terminal")]
    bar: ProgressBar,
}

#[cfg(not(feature = "terminal"))]
impl TerminalProgress {
    fn new(quiet: bool) -> TerminalProgress {
        TerminalProgress { quiet }
    }
}

#[cfg(not(feature = "terminal"))]
impl Progress for TerminalProgress {
    fn note(&self, line: &str) {
        if !self.quiet {
            eprintln!("{}", line.trim_end());
        }
    }
    fn begin_steps(&self, _: u64) {}
    fn step_done(&self) {}
    fn end_steps(&self) {}
}

#[cfg(feature = "terminal")]
impl TerminalProgress {
    fn new(quiet: bool) -> TerminalProgress {
        let target = if quiet {
            ProgressDrawTarget::hidden()
        } else {
            ProgressDrawTarget::stderr()
        };
        let bar = ProgressBar::with_draw_target(None, target);
        bar.set_style(
            ProgressStyle::with_template(
                "{bar:40} {pos}/{len} steps  {elapsed} elapsed, {eta} left",
            )
            .expect("valid template"),
        );
        TerminalProgress { quiet, bar }
    }
}

#[cfg(feature = "terminal")]
impl Progress for TerminalProgress {
    fn note(&self, line: &str) {
        if !self.quiet {
            self.bar.suspend(|| eprintln!("{}", line.trim_end()));
        }
    }
    fn begin_steps(&self, steps: u64) {
        self.bar.set_length(steps);
    }
    fn step_done(&self) {
        self.bar.inc(1);
    }
    fn end_steps(&self) {
        self.bar.finish_and_clear();
    }
}
