//! Merge: part folders of one run into the files of one run.
//!
//! In: the part folders (`slim run --shard K/N`, any order) and an output folder. Out: the
//! files one `slim run` of the scene writes, byte-identical but for `run.json`'s
//! description of the work (module [`super`] says why they are identical).
//!
//! Before anything is written the parts are checked: each is a finished part; all come
//! from the same scene file (SHA-256), kernels and slim version, split the same way and
//! hold the same statistics; parts 1 … N are there exactly once; the scene file read back
//! gives the same CDF bins and, for each part, the same geometry of its steps. Each
//! `part.bin` is read whole and its checksum checked before any of its numbers are used.
//! Memory: the merged statistics (what one run holds) plus four parts' files (the one
//! being merged, and the next ones, read and checked meanwhile by two threads); the
//! history is streamed step by step.
use super::part::{merge_part, open_part, read_part, Header, HistoryReader, PART_FILE};
use super::{geometry_sha256, By, Merged, ShardRecord};
use crate::budget::Budget;
use crate::error::{Error, Result};
use crate::output::record::RunRecord;
use crate::output::HistoryWriter;
use crate::prepare::{prepare, Prepared};
use crate::progress::{Progress, Timings};
use crate::run::{self, HistorySink, Outcome, Outputs, Tables};
use crate::scene::Scene;
use crate::simulate::StepIrradiance;
use crate::stats::FacetStats;
use std::path::{Path, PathBuf};

/// A part folder and its record.
struct Part {
    dir: PathBuf,
    record: RunRecord,
    shard: ShardRecord,
}

/// Merges the parts in `part_dirs` into `out_dir`. The scene is read from the path the
/// parts recorded, or from `scene_file` when given (it must be the same file content).
pub fn merge(
    part_dirs: &[PathBuf],
    out_dir: &Path,
    scene_file: Option<&Path>,
    budget: &Budget,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    let mut timings = Timings::default();
    let parts = timings.time("read parts", || read_records(part_dirs))?;
    let first = &parts[0];
    let scene_path = scene_file.map_or_else(|| first.shard.scene_file.clone(), Path::to_path_buf);
    let scene = Scene::load(&scene_path)?;
    let sha = crate::output::record::sha256_hex(&scene.source);
    if sha != first.record.scene.sha256 {
        return Err(Error::file(
            &scene_path,
            format!(
                "is not the scene the parts ran (its SHA-256 is {sha}, theirs {}): it changed \
                 since, or give the right one with --scene",
                first.record.scene.sha256
            ),
        ));
    }
    let Prepared {
        assembly,
        states,
        bins,
        plan,
        ..
    } = prepare(&scene, budget, &mut timings)?;
    check_against_scene(&parts, &states, bins)?;
    let previous = run::previous_outputs(out_dir)?;
    run::refuse_foreign_files(out_dir, &Tables.file_names(&scene), &previous)?;
    run::clear_previous_run(out_dir, previous)?;
    let world = &assembly.world;
    let by = first.shard.by;
    let history = match first.shard.history_values {
        0 => None,
        values => {
            let mut writer = HistoryWriter::new(out_dir, scene.output.csv, world);
            timings.time("history", || {
                merge_history(&parts, &states, values, &mut writer, progress)
            })?;
            Some(Box::new(writer) as Box<dyn HistorySink>)
        }
    };
    let statistics = timings.time("statistics", || merge_statistics(&parts, progress))?;
    let (total, named) = statistics.split_first().expect("the total is always there");
    let names = &first.shard.statistics[1..];
    let named: Vec<(String, &FacetStats)> = names.iter().cloned().zip(named).collect();
    let outputs = timings.time("output", || {
        run::write_results(out_dir, &scene, world, &states, total, &named, history)
    })?;
    let mut record = run::run_record(
        &scene,
        assembly,
        plan,
        merged_outcome(&parts),
        bins,
        timings,
        outputs,
        None,
        progress,
    )?;
    record.merged_from = Some(Merged {
        parts: parts.len(),
        by,
    });
    record.write(out_dir)?;
    Ok(record)
}

/// Reads every part's `run.json` and checks that they belong together and cover the run
/// exactly once; returns them in part order.
fn read_records(dirs: &[PathBuf]) -> Result<Vec<Part>> {
    if dirs.is_empty() {
        return Err(Error::file(
            Path::new("."),
            "no part folders given to merge",
        ));
    }
    let mut parts = dirs
        .iter()
        .map(|dir| {
            let record = RunRecord::read(dir)?;
            let shard = record.shard.clone().ok_or_else(|| {
                Error::file(
                    &dir.join("run.json"),
                    "is not a part: it has no `shard` (it was not run with --shard K/N)",
                )
            })?;
            Ok(Part {
                dir: dir.clone(),
                record,
                shard,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    parts.sort_by_key(|p| p.shard.index);
    let first = &parts[0];
    for p in &parts[1..] {
        let differs = |what: &str| {
            Error::file(
                &p.dir.join("run.json"),
                format!(
                    "is a part of another run than {}: its {what} differs",
                    first.dir.join("run.json").display()
                ),
            )
        };
        let (a, b) = (&first.record, &p.record);
        let kernels = |r: &RunRecord| {
            r.kernels
                .iter()
                .map(|k| k.sha256.clone())
                .collect::<Vec<_>>()
        };
        let checks = [
            (a.scene.sha256 == b.scene.sha256, "scene file (SHA-256)"),
            (kernels(a) == kernels(b), "SPICE kernels (SHA-256)"),
            (a.version == b.version, "slim version"),
            (a.bins_w_m2 == b.bins_w_m2, "CDF bins"),
            (first.shard.count == p.shard.count, "number of parts"),
            (first.shard.by == p.shard.by, "split (time or facets)"),
            (
                (first.shard.total_steps, first.shard.total_facets)
                    == (p.shard.total_steps, p.shard.total_facets),
                "number of steps or facets",
            ),
            (first.shard.statistics == p.shard.statistics, "statistics"),
            (
                first.shard.history_values == p.shard.history_values,
                "history",
            ),
            (
                first.shard.format_version == p.shard.format_version,
                "part layout version",
            ),
        ];
        if let Some((_, what)) = checks.iter().find(|(same, _)| !same) {
            return Err(differs(what));
        }
    }
    check_coverage(&parts)?;
    Ok(parts)
}

/// Parts 1 … N each exactly once (`parts` sorted by index).
fn check_coverage(parts: &[Part]) -> Result<()> {
    let n = parts[0].shard.count;
    for pair in parts.windows(2) {
        if pair[0].shard.index == pair[1].shard.index {
            return Err(Error::file(
                &pair[1].dir,
                format!(
                    "holds part {}/{n}, as {} does: give each part once",
                    pair[1].shard.index,
                    pair[0].dir.display()
                ),
            ));
        }
    }
    let missing: Vec<String> = (1..=n)
        .filter(|k| !parts.iter().any(|p| p.shard.index == *k))
        .map(|k| format!("{k}/{n}"))
        .collect();
    if !missing.is_empty() {
        return Err(Error::file(
            &parts[0].dir,
            format!(
                "the parts given lack part {} of the run: run {} and give {} too",
                missing.join(", "),
                if missing.len() == 1 { "it" } else { "them" },
                if missing.len() == 1 {
                    "its folder"
                } else {
                    "their folders"
                }
            ),
        ));
    }
    Ok(())
}

/// The scene read back must give each part's steps the geometry it ran with, and the
/// same bins.
fn check_against_scene(
    parts: &[Part],
    states: &[crate::ephemeris::EpochState],
    bins: crate::stats::Bins,
) -> Result<()> {
    for p in parts {
        let [start, end] = p.shard.steps;
        let json = p.dir.join("run.json");
        if p.shard.total_steps != states.len() || end > states.len() || start > end {
            return Err(Error::file(
                &json,
                format!(
                    "ran {} steps, the scene now gives {}",
                    p.shard.total_steps,
                    states.len()
                ),
            ));
        }
        if geometry_sha256(&states[start..end]) != p.shard.geometry_sha256
            || p.record.bins_w_m2 != bins
        {
            return Err(Error::file(
                &json,
                "ran with other geometry or bins than the scene gives now (other kernels or \
                 another slim?): run the parts again",
            ));
        }
    }
    Ok(())
}

/// The merged statistics (total first): time parts merged in time order, each read
/// straight into the sums; facet parts appended in facet order.
fn merge_statistics(parts: &[Part], progress: &dyn Progress) -> Result<Vec<FacetStats>> {
    progress.note(&format!("merging the statistics of {} parts", parts.len()));
    let (header, mut merged) = read_part(&parts[0].dir)?;
    fits(&parts[0], &header)?;
    match parts[0].shard.by {
        By::Time => merge_in_time(&parts[1..], &mut merged)?,
        By::Facets => append_facets(&parts[1..], &mut merged)?,
    }
    Ok(merged)
}

/// A part's statistics must be what its `run.json` says they are.
fn fits(p: &Part, header: &Header) -> Result<()> {
    let [f0, f1] = p.shard.facets;
    let [s0, s1] = p.shard.steps;
    if header.facets != f1 - f0
        || header.steps != (s1 - s0) as u64
        || header.statistics != p.shard.statistics
    {
        return Err(Error::file(
            &p.dir.join(PART_FILE),
            "does not hold what its run.json says (facets, steps or statistics)",
        ));
    }
    Ok(())
}

/// Merges time parts into `merged` in order, each straight into the sums. Reading a part
/// and checking its checksum costs more than merging it, so [`READERS`] threads read and
/// check the next parts (reader r takes every r-th) while this one is merged.
fn merge_in_time(parts: &[Part], merged: &mut [FacetStats]) -> Result<()> {
    std::thread::scope(|scope| {
        let mut readers = Vec::new();
        for r in 0..READERS {
            // A reader hands over one part at a time and reads the next into the memory
            // of one already merged: two parts' memory per reader.
            let (send, receive) = std::sync::mpsc::sync_channel(0);
            let (give_back, recycled) = std::sync::mpsc::channel::<Vec<u8>>();
            scope.spawn(move || {
                for p in parts.iter().skip(r).step_by(READERS) {
                    let buffer = recycled.try_recv().unwrap_or_default();
                    // The merge stopped (an error): nothing more to read.
                    if send.send(open_part(&p.dir, buffer)).is_err() {
                        break;
                    }
                }
            });
            readers.push((receive, give_back));
        }
        for (k, p) in parts.iter().enumerate() {
            let (receive, give_back) = &readers[k % READERS];
            let part = receive.recv().expect("a reader sends one part per part")?;
            let buffer = merge_part(part, merged, |h| fits(p, h))?;
            // The reader may have finished: the memory is then simply freed.
            let _ = give_back.send(buffer);
        }
        Ok(())
    })
}

/// Threads reading and checking parts during a merge in time.
const READERS: usize = 2;

/// Appends facet parts to `merged` in facet order.
fn append_facets(parts: &[Part], merged: &mut [FacetStats]) -> Result<()> {
    for p in parts {
        {
            let (header, sets) = read_part(&p.dir)?;
            fits(p, &header)?;
            for (into, set) in merged.iter_mut().zip(sets) {
                into.append(set)
                    .map_err(|e| Error::file(&p.dir.join(PART_FILE), e))?;
            }
        }
    }
    Ok(())
}

/// Streams the parts' history into `writer`, step by step in the order of one run.
fn merge_history(
    parts: &[Part],
    states: &[crate::ephemeris::EpochState],
    values: usize,
    writer: &mut HistoryWriter,
    progress: &dyn Progress,
) -> Result<()> {
    let open = |p: &Part| {
        let [s0, s1] = p.shard.steps;
        let [f0, f1] = p.shard.facets;
        HistoryReader::open(&p.dir, s1 - s0, values, f1 - f0)
    };
    let mut arrays = vec![Vec::new(); values];
    let mut write = |step: usize, arrays: &[Vec<f64>]| {
        let parts = (values == 3).then(|| (arrays[1].as_slice(), arrays[2].as_slice()));
        let irradiance = StepIrradiance {
            total: &arrays[0],
            parts,
        };
        writer.write_step(&states[step], irradiance)
    };
    progress.begin_steps(states.len() as u64);
    match parts[0].shard.by {
        By::Time => {
            for p in parts {
                let mut reader = open(p)?;
                for step in p.shard.steps[0]..p.shard.steps[1] {
                    arrays.iter_mut().for_each(Vec::clear);
                    reader.next_step(&mut arrays)?;
                    write(step, &arrays)?;
                    progress.step_done();
                }
            }
        }
        By::Facets => {
            let mut readers = parts.iter().map(open).collect::<Result<Vec<_>>>()?;
            for step in 0..states.len() {
                arrays.iter_mut().for_each(Vec::clear);
                for reader in &mut readers {
                    reader.next_step(&mut arrays)?;
                }
                write(step, &arrays)?;
                progress.step_done();
            }
        }
    }
    progress.end_steps();
    Ok(())
}

/// What the step loop did over the whole run: time parts' counts add up; facet parts
/// each did the whole run's work (every facet is lit and traced), so the first speaks
/// for all.
fn merged_outcome(parts: &[Part]) -> Outcome {
    let first = &parts[0].record;
    let mut outcome = Outcome {
        counts: first.counts,
        horizon_maps: first.horizon_maps.clone(),
        horizon_bounds: first.horizon_bounds.clone(),
        scatter: first.scatter.clone(),
    };
    if parts[0].shard.by == By::Time {
        for p in &parts[1..] {
            outcome.counts += p.record.counts;
            if let (Some(into), Some(later)) = (outcome.scatter.as_mut(), &p.record.scatter) {
                into.merge_later(later);
            }
        }
    }
    outcome
}
