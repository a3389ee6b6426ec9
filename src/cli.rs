//! CLI: the `slim` command — a thin layer over the library.
//!
//! `slim run SCENE.toml [-o DIR] [--threads N] [--quiet]` runs a scene; `slim info MESH`
//! loads a mesh and prints its inspection report. Errors are printed as one line and the
//! exit code is non-zero.

use crate::error::{Error, Result};
use crate::mesh::{inspect::inspect, read_mesh, LengthUnit, Mesh, MeshFormat};
use crate::run::{run_scene, Progress};
use crate::scene::Scene;
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
            Ok(())
        }
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
