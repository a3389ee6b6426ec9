//! Shard: one part of a run, by time or by facet, and the exact merge of the parts.
//!
//! In: a scene and `K/N` (`slim run SCENE --shard K/N --by time|facets`). Out: a part
//! folder holding
//! - `part.bin`: the exact partial state of every statistic ([`part`] has the layout);
//! - `part-history.bin`: its steps' irradiance, when the scene asks for history;
//! - `run.json`, whose `shard` ([`ShardRecord`]) says which part it is and of what.
//!
//! [`merge`] checks that the parts come from the same scene and inputs and cover the run
//! exactly once, then writes the files one `slim run` writes. They are **byte-identical**
//! to one run's for any N and any split, because every statistic merges exactly
//! ([`crate::stats`]: min and max, integer counts, exact integer sums; time parts are
//! merged in time order for the darkness runs, facet parts are concatenated), the
//! scattered-light stage of a time part starts where one run would stand
//! ([`crate::scatter::Scatter::prime`]), and the tables are written by the same code from
//! the same values. `run.json` differs only in what describes the work rather than the
//! result: `timings_s`, `threads`, `merged_from`, and where cached inputs came from (the
//! form factors' `build_s` and `source`, `horizon_maps`).
//!
//! A time part computes steps ⌊(K−1)·S/N⌋ … ⌊K·S/N⌋ of S; a facet part keeps statistics
//! for that share of the facets that get outputs (in output order) but lights and traces
//! every facet, against the whole world, at every step.

pub mod merge;
pub mod part;
pub mod slurm;

use crate::budget::Budget;
use crate::error::{Error, Result};
use crate::output::record::RunRecord;
pub use crate::output::record::{By, Merged, ShardRecord};
use crate::progress::Progress;
use crate::run::{run_with, HistorySink, Outputs, Results};
use crate::scene::Scene;
use crate::simulate::Slice;
use crate::world::World;
use part::{write_part, HistoryPart, FORMAT_VERSION, HISTORY_FILE, PART_FILE};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Runs part `shard` of `scene` within `budget` into the part folder `out_dir`.
pub fn run_shard(
    scene: &Scene,
    out_dir: &Path,
    budget: &Budget,
    shard: Shard,
    progress: &dyn Progress,
) -> Result<RunRecord> {
    run_with(scene, out_dir, budget, &shard, progress)
}

/// A part's outputs: `part.bin`, `part-history.bin` and the `shard` of `run.json`.
impl Outputs for Shard {
    fn file_names(&self, _: &Scene) -> Vec<String> {
        vec![PART_FILE.to_string(), HISTORY_FILE.to_string()]
    }

    fn slice(&self, steps: usize, facets: usize) -> Result<Slice> {
        Shard::slice(self, steps, facets)
            .map_err(|e| Error::Usage(format!("--shard {}/{}: {e}", self.index, self.count)))
    }

    fn history(&self, dir: &Path, _: &Scene, _: &World) -> Result<Box<dyn HistorySink>> {
        Ok(Box::new(HistoryPart::create(dir)?))
    }

    fn write(
        &self,
        dir: &Path,
        r: &Results,
        history: Option<Box<dyn HistorySink>>,
    ) -> Result<Vec<PathBuf>> {
        let all: Vec<(String, &crate::stats::FacetStats)> =
            std::iter::once(("total".into(), r.total))
                .chain(r.parts.iter().map(|(n, s)| (n.clone(), *s)))
                .collect();
        let mut files = vec![write_part(dir, &all)?];
        if let Some(h) = history {
            files.extend(h.finish()?);
        }
        Ok(files)
    }

    fn shard(&self, r: &Results) -> Option<ShardRecord> {
        let facets = r.world.output_facet_count();
        let steps = bounds(r.slice.steps.clone(), r.states.len());
        Some(ShardRecord {
            index: self.index,
            count: self.count,
            by: self.by,
            steps,
            facets: bounds(r.slice.facets.clone(), facets),
            total_steps: r.states.len(),
            total_facets: facets,
            scene_file: std::path::absolute(&r.scene.path).unwrap_or_else(|_| r.scene.path.clone()),
            geometry_sha256: geometry_sha256(&r.states[steps[0]..steps[1]]),
            statistics: std::iter::once("total".to_string())
                .chain(r.parts.iter().map(|(n, _)| n.clone()))
                .collect(),
            history_values: match (r.scene.output.history, r.scattered) {
                (false, _) => 0,
                (true, false) => 1,
                (true, true) => 3,
            },
            format_version: FORMAT_VERSION,
        })
    }
}

/// `[start, end]` of `range`, or of `0..total` for `None`.
fn bounds(range: Option<Range<usize>>, total: usize) -> [usize; 2] {
    let r = range.unwrap_or(0..total);
    [r.start, r.end]
}

/// Part `index` (1-based) of `count`, split by `by`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
    pub by: By,
}

impl Shard {
    /// Reads `K/N` (1 ≤ K ≤ N).
    pub fn parse(text: &str, by: By) -> Result<Shard, String> {
        let bad = || format!("'{text}' is not a part K/N with 1 ≤ K ≤ N (e.g. 3/8)");
        let (k, n) = text.split_once('/').ok_or_else(bad)?;
        let (index, count) = (
            k.trim().parse::<usize>().map_err(|_| bad())?,
            n.trim().parse::<usize>().map_err(|_| bad())?,
        );
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count, by })
    }

    /// The part of a run of `steps` steps and `facets` facets that get outputs, or an
    /// error when a part would be empty.
    pub fn slice(&self, steps: usize, facets: usize) -> Result<Slice, String> {
        let total = match self.by {
            By::Time => steps,
            By::Facets => facets,
        };
        if self.count > total {
            return Err(format!(
                "{} parts by {} of a run of {total} {}: at most {total} parts",
                self.count,
                self.by,
                if self.by == By::Time {
                    "steps"
                } else {
                    "facets that get outputs"
                }
            ));
        }
        let range = self.range(total);
        Ok(match self.by {
            By::Time => Slice {
                steps: Some(range),
                facets: None,
            },
            By::Facets => Slice {
                steps: None,
                facets: Some(range),
            },
        })
    }

    /// Items ⌊(K−1)·T/N⌋ … ⌊K·T/N⌋ of `total`.
    fn range(&self, total: usize) -> Range<usize> {
        let at = |k: usize| (k as u128 * total as u128 / self.count as u128) as usize;
        at(self.index - 1)..at(self.index)
    }
}

/// SHA-256 of the geometry of `states` (bit patterns, in order).
pub fn geometry_sha256(states: &[crate::ephemeris::EpochState]) -> String {
    use sha2::{Digest, Sha256};
    let mut hash = Sha256::new();
    for s in states {
        hash.update((s.step as u64).to_le_bytes());
        hash.update(s.epoch.to_tdb_seconds().to_le_bytes());
        for b in &s.bodies {
            let pose = &b.pose;
            let numbers = [
                b.sun_dir.x,
                b.sun_dir.y,
                b.sun_dir.z,
                b.sun_distance_m,
                b.flux_w_m2,
                pose.position_m.x,
                pose.position_m.y,
                pose.position_m.z,
            ];
            numbers
                .iter()
                .chain(pose.body_to_scene.to_cols_array().iter())
                .for_each(|x| hash.update(x.to_le_bytes()));
        }
    }
    crate::output::record::hex(&hash.finalize())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_are_read_and_cover_the_run_exactly_once() {
        assert!(Shard::parse("0/3", By::Time).is_err());
        assert!(Shard::parse("4/3", By::Time).is_err());
        assert!(Shard::parse("2-3", By::Time).is_err());
        assert!(Shard::parse("x/3", By::Time).is_err());
        for (total, n) in [(10, 1), (10, 3), (7, 7), (1000, 64)] {
            let mut next = 0;
            for k in 1..=n {
                let s = Shard::parse(&format!("{k}/{n}"), By::Time).unwrap();
                let r = s.slice(total, 5).unwrap().steps.unwrap();
                assert_eq!(r.start, next);
                assert!(!r.is_empty());
                next = r.end;
            }
            assert_eq!(next, total);
        }
        let too_many = Shard::parse("1/8", By::Facets).unwrap().slice(100, 7);
        assert!(too_many.unwrap_err().contains("at most 7 parts"));
    }
}
