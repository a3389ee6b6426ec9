//! `run.json`: the record of a run — program version, scene hash, input checksums, counts,
//! stage timings, the plan, mesh reports, warnings and the files written. One type,
//! [`RunRecord`], is both written and read back.

use crate::error::{Error, Result};
use crate::illum::StepCounts;
use crate::mesh::inspect::MeshReport;
use crate::plan::Plan;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// An input file and its SHA-256.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct InputFile {
    pub path: PathBuf,
    pub sha256: String,
}

/// One body's mesh as loaded.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct BodyRecord {
    pub name: String,
    /// The mesh file (none for a generated shape).
    pub mesh: Option<InputFile>,
    /// Where the shape came from, in words.
    pub shape: String,
    pub report: MeshReport,
    /// The mesh file of terrain around the body that only casts shadows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surroundings: Option<InputFile>,
}

/// Everything `run.json` holds: written by [`RunRecord::write`], read back by
/// [`RunRecord::read`]. Keys missing from an older record read as their defaults.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct RunRecord {
    pub program: String,
    pub version: String,
    pub name: String,
    pub scene: InputFile,
    /// SPICE kernels used, with checksums.
    pub kernels: Vec<InputFile>,
    /// The bodies that get statistics and output files.
    pub bodies: Vec<BodyRecord>,
    /// The bodies that only cast shadows and scatter light (`outputs = false`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub occluders: Vec<BodyRecord>,
    pub plan: Plan,
    pub counts: StepCounts,
    /// Where each horizon map came from (none when no body used one).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub horizon_maps: Vec<crate::horizon::shadows::MapRecord>,
    /// Where each horizon bound of the BVH tracer came from (none when no body used one).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub horizon_bounds: Vec<crate::horizon::shadows::BoundRecord>,
    /// The scattered-light stage: form factors per body and the solver's report over all
    /// steps (absent without scattering).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scatter: Option<crate::scatter::ScatterRecord>,
    pub bins_w_m2: crate::stats::Bins,
    pub duration_s: f64,
    pub threads: usize,
    /// Wall time per stage, seconds.
    pub timings_s: Vec<(String, f64)>,
    pub warnings: Vec<String>,
    /// Files written, by name, in the output folder (`run.json` last).
    pub outputs: Vec<String>,
    /// In a part folder: which part of which run it holds (`slim run --shard`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shard: Option<ShardRecord>,
    /// In a merged folder: how many parts, split by what (`slim merge`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub merged_from: Option<Merged>,
}

/// What a run is split by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum By {
    /// Consecutive ranges of steps.
    #[default]
    Time,
    /// Consecutive ranges of the facets that get outputs.
    Facets,
}

impl std::str::FromStr for By {
    type Err = String;
    fn from_str(text: &str) -> Result<By, String> {
        match text {
            "time" => Ok(By::Time),
            "facets" => Ok(By::Facets),
            _ => Err(format!("'{text}': split by 'time' or 'facets'")),
        }
    }
}

impl std::fmt::Display for By {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            By::Time => "time",
            By::Facets => "facets",
        })
    }
}

/// Which part of which run a part folder holds (`run.json`'s `shard`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardRecord {
    /// Part K of N (1-based), and what the run is split by.
    pub index: usize,
    pub count: usize,
    pub by: By,
    /// The steps [start, end) and facets [start, end) (among those that get outputs)
    /// this part holds statistics of.
    pub steps: [usize; 2],
    pub facets: [usize; 2],
    /// The whole run's steps and facets that get outputs.
    pub total_steps: usize,
    pub total_facets: usize,
    /// The scene file, as an absolute path, for the merge to read back.
    pub scene_file: PathBuf,
    /// SHA-256 of the geometry of this part's steps (epochs, Sun vectors, fluxes, poses):
    /// the merge recomputes it from the scene to be sure the parts saw the same inputs.
    pub geometry_sha256: String,
    /// The statistics in `part.bin`, in order: `total`, then the named parts.
    pub statistics: Vec<String>,
    /// Whether `part-history.bin` holds the history and how many values per facet and
    /// step it has (1, or 3 with scattered light).
    pub history_values: usize,
    /// The layout version of `part.bin`.
    pub format_version: u32,
}

/// How a merged folder came to be (`run.json`'s `merged_from`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Merged {
    pub parts: usize,
    pub by: By,
}

/// SHA-256 of a byte string, hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// Bytes (a digest) as lowercase hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The SHA-256 record of a file on disk.
pub fn input_file(path: &Path) -> Result<InputFile> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    Ok(InputFile {
        path: path.to_path_buf(),
        sha256: sha256_hex(&bytes),
    })
}

impl RunRecord {
    /// Reads `DIR/run.json`; a folder without one is not a finished run.
    pub fn read(dir: &Path) -> Result<RunRecord> {
        let path = dir.join("run.json");
        if !path.is_file() {
            return Err(Error::file(
                dir,
                "not a finished run: no run.json in this folder (run `slim run` first)",
            ));
        }
        let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
        serde_json::from_slice(&bytes).map_err(|e| Error::file(&path, e.to_string()))
    }

    /// Writes `DIR/run.json` atomically.
    pub fn write(&self, dir: &Path) -> Result<PathBuf> {
        let path = dir.join("run.json");
        let json = serde_json::to_vec_pretty(self).map_err(|e| Error::output(&path, e))?;
        crate::atomic::write_atomic(&path, &json)?;
        Ok(path)
    }
}
