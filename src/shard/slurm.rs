//! Slurm: a scene's parts as one array job, and their merge as a job that waits for it.
//!
//! In: a scene, the number of parts and the job's resources. Out, in the run's folder
//! `OUT`:
//! - `slurm/parts.sh`: an sbatch array script, task K running `slim run --shard K/N` into
//!   `OUT/parts/K`;
//! - `slurm/merge.sh`: an sbatch script running `slim merge` of those folders into `OUT`;
//! - `slurm/logs/`: the jobs' output (Slurm will not create it; a job whose log folder is
//!   missing fails at launch);
//! - with [`Batch::submit`], `slurm/jobs.json`: the two job ids. The merge is submitted
//!   with `--dependency=afterok:ARRAY --kill-on-invalid-dep=yes`, so a failed or
//!   cancelled part cancels it instead of leaving it pending for ever.
//!
//! [`estimate`] says what one part needs before anything is submitted: it runs the first
//! steps of the scene here as a probe (setup, then a few steps) and scales them.
//! [`Batch::poll`] and [`Batch::cancel`] map the jobs' state to `squeue` and `scancel`.

use super::{By, Shard};
use crate::budget::Budget;
use crate::error::{Error, Result};
use crate::output::record::RunRecord;
use crate::scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What each job asks Slurm for (`None`: the cluster's default).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Resources {
    pub partition: Option<String>,
    /// Wall time per task, in Slurm's format (e.g. `2:00:00`).
    pub time: Option<String>,
    /// Memory per task, in Slurm's format (e.g. `8G`).
    pub mem: Option<String>,
    /// CPUs per task; slim uses as many threads.
    pub cpus: usize,
}

/// A scene's parts and merge as Slurm jobs.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The `slim` program the jobs run (absolute).
    pub program: PathBuf,
    /// The scene file (absolute).
    pub scene: PathBuf,
    /// The run's folder (absolute): parts in `parts/K`, the merged files in it.
    pub out: PathBuf,
    pub parts: usize,
    pub by: By,
    pub resources: Resources,
    /// The job name.
    pub name: String,
}

/// The ids of a submitted batch (`slurm/jobs.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Submitted {
    pub array: String,
    pub merge: String,
}

/// Where a submitted batch stands.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// Parts finished successfully, of `parts`.
    pub parts_done: usize,
    pub parts: usize,
    pub state: BatchState,
}

/// The state of a batch as a whole.
#[derive(Debug, Clone, PartialEq)]
pub enum BatchState {
    /// Waiting or running (parts or merge).
    Running,
    /// The merge job completed.
    Done,
    /// A part or the merge failed or was cancelled: what Slurm said.
    Failed(String),
}

/// Quotes `text` for a POSIX shell.
fn quoted(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

fn quoted_path(path: &Path) -> String {
    quoted(&path.display().to_string())
}

impl Batch {
    /// A batch of `parts` parts of the scene at `scene` into `out`, run by this program.
    pub fn new(
        scene: &Scene,
        out: &Path,
        parts: usize,
        by: By,
        resources: Resources,
    ) -> Result<Batch> {
        let absolute = |p: &Path| std::path::absolute(p).map_err(|e| Error::io(p, e));
        let program = std::env::current_exe().map_err(|e| Error::io(Path::new("slim"), e))?;
        Ok(Batch {
            program,
            scene: absolute(&scene.path)?,
            out: absolute(out)?,
            parts,
            by,
            resources,
            name: format!("slim-{}", scene.name),
        })
    }

    fn slurm_dir(&self) -> PathBuf {
        self.out.join("slurm")
    }

    /// The folder of part `k`.
    pub fn part_dir(&self, k: usize) -> PathBuf {
        self.out.join("parts").join(k.to_string())
    }

    /// `#SBATCH` lines shared by both scripts.
    fn directives(&self, name: &str, log: &str) -> String {
        let r = &self.resources;
        let mut lines = vec![
            format!("#SBATCH --job-name={name}"),
            format!(
                "#SBATCH --output={}",
                self.slurm_dir().join("logs").join(log).display()
            ),
            format!("#SBATCH --cpus-per-task={}", r.cpus),
        ];
        let optional = [
            ("partition", &r.partition),
            ("time", &r.time),
            ("mem", &r.mem),
        ];
        for (key, value) in optional {
            if let Some(v) = value {
                lines.push(format!("#SBATCH --{key}={v}"));
            }
        }
        lines.join("\n")
    }

    /// The array script: task K runs part K of N.
    pub fn parts_script(&self) -> String {
        format!(
            "#!/bin/bash\n\
             # Written by `slim slurm`: part K of {n} of the scene per array task; the merge\n\
             # job (merge.sh) waits for every task. Submit both with `slim slurm --submit`.\n\
             {directives}\n\
             #SBATCH --array=1-{n}\n\
             set -euo pipefail\n\
             K=\"${{SLURM_ARRAY_TASK_ID:?run this as an array task}}\"\n\
             exec {program} run {scene} --shard \"$K/{n}\" --by {by} \\\n  \
             -o {parts}/\"$K\" --threads \"${{SLURM_CPUS_PER_TASK:-{cpus}}}\" --quiet\n",
            n = self.parts,
            directives = self.directives(&self.name, "part-%a.out"),
            program = quoted_path(&self.program),
            scene = quoted_path(&self.scene),
            by = self.by,
            parts = quoted_path(&self.out.join("parts")),
            cpus = self.resources.cpus,
        )
    }

    /// The merge script: every part's folder into the run's folder.
    pub fn merge_script(&self) -> String {
        let parts: Vec<String> = (1..=self.parts)
            .map(|k| quoted_path(&self.part_dir(k)))
            .collect();
        format!(
            "#!/bin/bash\n\
             # Written by `slim slurm`: merges the {n} parts into the files of one run.\n\
             {directives}\n\
             set -euo pipefail\n\
             exec {program} merge \\\n  {parts} \\\n  -o {out} --scene {scene} --quiet\n",
            n = self.parts,
            directives = self.directives(&format!("{}-merge", self.name), "merge.out"),
            program = quoted_path(&self.program),
            parts = parts.join(" \\\n  "),
            out = quoted_path(&self.out),
            scene = quoted_path(&self.scene),
        )
    }

    /// Writes both scripts and creates the logs folder; returns the scripts' paths.
    pub fn write(&self) -> Result<(PathBuf, PathBuf)> {
        let logs = self.slurm_dir().join("logs");
        std::fs::create_dir_all(&logs).map_err(|e| Error::io(&logs, e))?;
        let parts = self.slurm_dir().join("parts.sh");
        let merge = self.slurm_dir().join("merge.sh");
        crate::atomic::write_atomic(&parts, self.parts_script().as_bytes())?;
        crate::atomic::write_atomic(&merge, self.merge_script().as_bytes())?;
        Ok((parts, merge))
    }

    /// Writes the scripts, submits the array and then the merge depending on it, and
    /// records both ids in `slurm/jobs.json`.
    pub fn submit(&self) -> Result<Submitted> {
        let (parts, merge) = self.write()?;
        let array = sbatch(&[], &parts)?;
        let dependency = format!("--dependency=afterok:{array}");
        let merge = sbatch(&[&dependency, "--kill-on-invalid-dep=yes"], &merge)?;
        let submitted = Submitted { array, merge };
        let path = self.slurm_dir().join("jobs.json");
        let json = serde_json::to_vec_pretty(&submitted).map_err(|e| Error::output(&path, e))?;
        crate::atomic::write_atomic(&path, &json)?;
        Ok(submitted)
    }

    /// Where the submitted jobs stand, from `squeue` (finished jobs stay listed for the
    /// cluster's MinJobAge). A job `squeue` no longer knows counts as done when its
    /// output exists (the merge's `run.json`), else as lost.
    pub fn poll(&self, jobs: &Submitted) -> Result<Status> {
        let ids = format!("{},{}", jobs.array, jobs.merge);
        let out = Command::new("squeue")
            .args(["-h", "-r", "-t", "all", "-j", &ids, "-o", "%F|%K|%T|%r"])
            .output()
            .map_err(|e| Error::io(Path::new("squeue"), e))?;
        let text = String::from_utf8_lossy(&out.stdout);
        let rows: Vec<(&str, &str, &str)> = text
            .lines()
            .filter_map(|l| {
                let mut f = l.split('|');
                Some((f.next()?, f.next()?, f.next()?))
            })
            .collect();
        let parts_done = (1..=self.parts)
            .filter(|k| RunRecord::read(&self.part_dir(*k)).is_ok())
            .count();
        let failed = rows.iter().find(|(_, _, state)| {
            matches!(
                *state,
                "FAILED"
                    | "CANCELLED"
                    | "TIMEOUT"
                    | "OUT_OF_MEMORY"
                    | "NODE_FAIL"
                    | "BOOT_FAIL"
                    | "DEADLINE"
                    | "PREEMPTED"
            )
        });
        let merged = RunRecord::read(&self.out).is_ok_and(|r| r.merged_from.is_some());
        let merge_row = rows.iter().find(|(id, _, _)| *id == jobs.merge);
        let state = match (failed, merge_row) {
            (Some((id, task, state)), _) => BatchState::Failed(if *task == "N/A" {
                format!("job {id} {state}")
            } else {
                format!("part {task} (job {id}) {state}")
            }),
            (None, Some((_, _, "COMPLETED"))) if merged => BatchState::Done,
            (None, Some(_)) => BatchState::Running,
            (None, None) if merged => BatchState::Done,
            (None, None) if !out.status.success() || rows.is_empty() => BatchState::Failed(
                "Slurm no longer knows the jobs and the merged run is not there".into(),
            ),
            (None, None) => BatchState::Running,
        };
        Ok(Status {
            parts_done,
            parts: self.parts,
            state,
        })
    }

    /// Cancels the parts and the merge (`scancel`).
    pub fn cancel(&self, jobs: &Submitted) -> Result<()> {
        let status = Command::new("scancel")
            .args([&jobs.array, &jobs.merge])
            .status()
            .map_err(|e| Error::io(Path::new("scancel"), e))?;
        if !status.success() {
            return Err(Error::Usage(format!(
                "scancel {} {} failed ({status})",
                jobs.array, jobs.merge
            )));
        }
        Ok(())
    }
}

/// Submits `script` with `sbatch --parsable` and `args`; returns the job id.
fn sbatch(args: &[&str], script: &Path) -> Result<String> {
    let out = Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .arg(script)
        .output()
        .map_err(|e| {
            Error::io(
                Path::new("sbatch"),
                std::io::Error::new(e.kind(), format!("{e} (is Slurm installed here?)")),
            )
        })?;
    let text = String::from_utf8_lossy(&out.stdout);
    // `--parsable` prints "ID" or "ID;CLUSTER".
    let id = text
        .trim()
        .split(';')
        .next()
        .unwrap_or_default()
        .to_string();
    if !out.status.success() || id.is_empty() {
        return Err(Error::file(
            script,
            format!(
                "sbatch refused it: {}",
                crate::error::printable(String::from_utf8_lossy(&out.stderr).trim(), 400)
            ),
        ));
    }
    Ok(id)
}

/// What one part of a batch needs, measured on a probe here and scaled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Estimate {
    /// Steps the probe ran and the threads it had.
    pub probe_steps: usize,
    pub probe_threads: usize,
    /// Seconds before the first step (inputs, ephemeris, trees, maps, form factors).
    pub setup_s: f64,
    /// Seconds per step of one part (lighting every facet, statistics of its share).
    pub step_s: f64,
    /// Seconds to write one part's files.
    pub output_s: f64,
    /// Steps of the longest part.
    pub part_steps: usize,
    /// Seconds per part: setup + steps × step + output, on this machine's threads.
    pub part_s: f64,
    /// Bytes one part holds at its peak: the plan's estimate scaled to the part, and the
    /// probe's measured peak (resident set) scaled the same way.
    pub part_bytes_planned: u64,
    pub part_bytes_probe: u64,
}

/// Stages whose time grows with the steps, and those of them that grow with the facets
/// that keep statistics (a facet part pays its share).
const STEP_STAGES: [&str; 5] = [
    "direct irradiance",
    "scattered light",
    "spectral bands",
    "statistics",
    "history",
];
const FACET_SHARE_STAGES: [&str; 2] = ["statistics", "history"];
/// Items of the memory estimate that a facet part holds its share of.
const FACET_SHARE_ITEMS: [&str; 3] = ["statistics", "CDF table batches", "history buffer"];

/// Runs the first `probe_steps` steps of `scene` as a time part in `scratch` and scales
/// what it took to a part of `parts` split `by`.
pub fn estimate(
    scene: &Scene,
    budget: &Budget,
    parts: usize,
    by: By,
    probe_steps: usize,
    scratch: &Path,
) -> Result<Estimate> {
    // The probe is part 1 of as many parts as hold about `probe_steps` steps each,
    // counted from the scene alone; its run.json then gives the steps and the plan.
    let asked = scene.step_count().min(usize::MAX as f64) as usize;
    let probe_parts = (asked / probe_steps.max(1)).max(1);
    let probe = Shard {
        index: 1,
        count: probe_parts,
        by: By::Time,
    };
    let clock = StepClock::default();
    let record = super::run_shard(scene, scratch, budget, probe, &clock)?;
    let steps = record.plan.steps;
    let memory = &record.plan.memory;
    let ran = record
        .shard
        .as_ref()
        .map_or(1, |s| s.steps[1] - s.steps[0])
        .max(1);
    let share = match by {
        By::Time => 1.0,
        By::Facets => 1.0 / parts as f64,
    };
    let stage = |name: &str| {
        record
            .timings_s
            .iter()
            .filter(|(s, _)| s == name)
            .map(|(_, t)| t)
            .sum::<f64>()
    };
    let per_step_total: f64 = STEP_STAGES.iter().map(|s| stage(s)).sum();
    let shared: f64 = FACET_SHARE_STAGES.iter().map(|s| stage(s)).sum();
    // A facet part keeps statistics of its share of the facets only.
    let facet_share = 1.0 - (1.0 - share) * shared / per_step_total.max(f64::MIN_POSITIVE);
    let step_s = clock.steady_step_s().unwrap_or(per_step_total / ran as f64) * facet_share;
    let total: f64 = record.timings_s.iter().map(|(_, t)| t).sum();
    let output_s = stage("output") * share;
    let setup_s = total - per_step_total - stage("output");
    let part_steps = match by {
        By::Time => steps.div_ceil(parts),
        By::Facets => steps,
    };
    let scaled =
        |bytes: f64, facet_bytes: f64| (bytes - facet_bytes * (1.0 - share)).max(0.0) as u64;
    let facet_items: u64 = memory
        .items
        .iter()
        .filter(|i| FACET_SHARE_ITEMS.contains(&i.what.as_str()))
        .map(|i| i.bytes)
        .sum();
    Ok(Estimate {
        probe_steps: ran,
        probe_threads: rayon::current_num_threads(),
        setup_s,
        step_s,
        output_s,
        part_steps,
        part_s: setup_s + part_steps as f64 * step_s + output_s,
        part_bytes_planned: scaled(memory.total_bytes() as f64, facet_items as f64),
        part_bytes_probe: scaled(peak_resident_bytes() as f64, facet_items as f64),
    })
}

/// Progress that notes when each step ends, for the probe's time per step.
#[derive(Default)]
struct StepClock {
    ends: std::sync::Mutex<Vec<std::time::Instant>>,
}

impl crate::progress::Progress for StepClock {
    fn note(&self, _: &str) {}
    fn begin_steps(&self, _: u64) {}
    fn step_done(&self) {
        if let Ok(mut ends) = self.ends.lock() {
            ends.push(std::time::Instant::now());
        }
    }
    fn end_steps(&self) {}
}

impl StepClock {
    /// Seconds per step over the second half of the steps: the first steps are slower
    /// (memory touched for the first time), and a long part is made of the later kind.
    fn steady_step_s(&self) -> Option<f64> {
        let ends = self.ends.lock().ok()?;
        let half = &ends[ends.len() / 2..];
        let (first, last) = (half.first()?, half.last()?);
        (half.len() >= 2)
            .then(|| last.duration_since(*first).as_secs_f64() / (half.len() - 1) as f64)
    }
}

/// This process's peak resident set (bytes), from `/proc/self/status` (0 where there is
/// no such file).
fn peak_resident_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
            let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kb * 1024)
        })
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn batch() -> Batch {
        Batch {
            program: "/opt/slim/bin/slim".into(),
            scene: "/data/it's here/phobos.toml".into(),
            out: "/scratch/run".into(),
            parts: 4,
            by: By::Time,
            resources: Resources {
                partition: Some("long".into()),
                time: Some("2:00:00".into()),
                mem: None,
                cpus: 8,
            },
            name: "slim-phobos".into(),
        }
    }

    #[test]
    fn the_array_script_runs_part_k_of_n_and_the_merge_takes_every_part() {
        let b = batch();
        let parts = b.parts_script();
        assert!(parts.contains("#SBATCH --array=1-4"), "{parts}");
        assert!(parts.contains("#SBATCH --partition=long"));
        assert!(parts.contains("#SBATCH --time=2:00:00"));
        assert!(!parts.contains("--mem"));
        assert!(parts.contains("#SBATCH --output=/scratch/run/slurm/logs/part-%a.out"));
        assert!(
            parts.contains(r"'/data/it'\''s here/phobos.toml' --shard "),
            "{parts}"
        );
        assert!(parts.contains("--shard \"$K/4\" --by time"), "{parts}");
        let merge = b.merge_script();
        for k in 1..=4 {
            assert!(
                merge.contains(&format!("'/scratch/run/parts/{k}'")),
                "{merge}"
            );
        }
        assert!(
            merge.contains("merge \\") && merge.contains("-o '/scratch/run'"),
            "{merge}"
        );
    }
}
