//! CLI: the `slim` command — a thin layer over the library.
//!
//! `slim run SCENE.toml [-o DIR] [--threads N] [--quiet]` runs a scene; `slim info MESH`
//! loads a mesh and prints its inspection report; `slim report RUN_DIR` draws a finished
//! run's figures and HTML page (`slim run --report` does so right after the run); `slim
//! serve --data DIR` runs the HTTP service. Errors are printed as one line and the
//! exit code is non-zero.

use crate::error::{Error, Result};
use crate::mesh::{inspect::inspect, read_mesh, LengthUnit, Mesh, MeshFormat};
use crate::report::colormap::Colormap;
use crate::report::select::{FacetRef, LatLon};
use crate::report::{write_report, ReportOptions};
use crate::run::{run_scene, Progress};
use crate::scene::Scene;
use crate::serve::{self, limits::Limits};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
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
        /// Print nothing but errors.
        #[arg(short, long)]
        quiet: bool,
        /// Also write the report (figures and index.html) into OUTPUT/report.
        #[arg(long)]
        report: bool,
    },
    /// Draw a finished run's figures and its self-contained index.html.
    Report {
        /// The run folder (holding run.json).
        run_dir: PathBuf,
        /// Report folder (default: RUN_DIR/report).
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[command(flatten)]
        options: ReportArgs,
    },
    /// Serve jobs, result files and facet queries over HTTP (README: "Service").
    Serve(ServeArgs),
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
}

/// `slim serve` options.
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
    /// Most time steps per job.
    #[arg(long, default_value_t = Limits::default().max_steps)]
    max_steps: usize,
    /// Most facets or places per query.
    #[arg(long, default_value_t = Limits::default().max_query_targets)]
    max_query_targets: usize,
    /// Most values (targets × steps) per on-demand irradiance query.
    #[arg(long, default_value_t = Limits::default().max_query_values)]
    max_query_values: usize,
}

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
        Ok(serve::Config {
            data_dir: self.data,
            listen: self.listen,
            token,
            protect_reads: self.protect_reads,
            workers: self.workers.max(1),
            job_threads: self.job_threads.unwrap_or(cores.saturating_sub(1)).max(1),
            limits: Limits {
                max_body_bytes: self.max_body_bytes,
                max_facets: self.max_facets,
                max_steps: self.max_steps,
                max_query_targets: self.max_query_targets,
                max_query_values: self.max_query_values,
            },
        })
    }
}

/// What the report draws.
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
}

impl ReportArgs {
    fn options(self) -> ReportOptions {
        ReportOptions {
            facets: self.facets,
            near: self.near,
            threshold_w_m2: self.threshold,
            colormap: self.colormap,
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

/// Entry point of the binary: returns the process exit code.
pub fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    match execute(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("slim: error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run {
            scene,
            output,
            threads,
            quiet,
            report,
        } => {
            if let Some(n) = threads {
                set_threads(n)?;
            }
            let scene = Scene::load(&scene)?;
            let out = output.unwrap_or_else(|| PathBuf::from("results").join(&scene.name));
            let progress = TerminalProgress::new(quiet);
            let record = run_scene(&scene, &out, &progress)?;
            if !quiet {
                eprintln!(
                    "wrote {} files to {} ({} facets, {} steps, {} shadow rays)",
                    record.outputs.len(),
                    out.display(),
                    record.plan.facets,
                    record.plan.steps,
                    record.counts.rays
                );
            }
            if report {
                let written = write_report(&out, None, &ReportOptions::default())?;
                if !quiet {
                    eprintln!("wrote the report to {}", written.index.display());
                }
            }
            Ok(())
        }
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
        Command::Serve(args) => serve::serve(args.config()?),
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
            println!("{}", mesh.display());
            println!("{report}");
            Ok(())
        }
    }
}

fn set_threads(n: usize) -> Result<()> {
    if n == 0 {
        return Err(Error::Usage("--threads must be at least 1".into()));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| Error::Usage(format!("--threads: {e}")))
}

/// A progress bar on stderr when it is a terminal; notes on stderr unless quiet.
struct TerminalProgress {
    quiet: bool,
    bar: ProgressBar,
}

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
