//! Output: the files a run leaves behind.
//!
//! In: the world, the per-step geometry, the per-facet statistics. Out, in the output
//! folder (every table as Parquet, and as CSV when asked):
//! - `summary`: one row per facet — body, facet, area_m2, centroid and normal (body frame,
//!   metres), min/max/mean/std irradiance (W/m²), lit_fraction;
//! - `cdf`: one row per facet and threshold — F_k(x) = share of time with E ≤ x;
//! - `geometry`: one row per step and body — epoch, Sun unit vector (body frame), Sun
//!   distance (km), flux (W/m²), and the pose: body centre in the scene frame (km) and
//!   body → scene rotation (unit quaternion, w ≥ 0); for SPICE scenes the scene frame has
//!   J2000 axes and the first body at its origin;
//! - `history` (when asked): one row per step and facet, streamed as the run goes;
//! - `BODY.ply` per body with per-face statistics; `run.json` (see [`record`]).
//!
//! Every file is written under a `.partial` name and renamed when complete; `run.json` is
//! written last, so a folder holds a complete run exactly when it holds `run.json`.

pub mod columns;
mod csv_file;
#[cfg(feature = "parquet")]
mod parquet_file;
pub mod ply;
#[cfg(feature = "parquet")]
pub mod read;
pub mod record;
pub mod table;

use crate::budget::CDF_ROWS_PER_BATCH;
use crate::ephemeris::EpochState;
use crate::error::Result;
use crate::simulate::StepIrradiance;
use crate::stats::FacetStats;
use crate::world::World;
use columns::{Table, Values};
use std::path::{Path, PathBuf};
use table::TableWriter;

/// The names of the files a run writes into its folder, `run.json` aside: the tables
/// (`history` when asked for), and a PLY per body when asked for.
pub fn file_names(csv: bool, history: bool, ply: bool, bodies: &[&str]) -> Vec<String> {
    let tables = ["summary", "cdf", "geometry"]
        .into_iter()
        .chain(history.then_some("history"));
    let plys = ply
        .then(|| bodies.iter().map(|b| format!("{b}.ply")))
        .into_iter()
        .flatten();
    tables
        .flat_map(|t| table::file_names(t, csv))
        .chain(plys)
        .collect()
}

/// Rows per batch when writing the per-facet tables.
const FACETS_PER_BATCH: usize = 1 << 14;

/// Named statistics beside the total: `direct` and `scattered` with scattered light,
/// `band_NAME` and `bands` with spectral bands.
pub type NamedStats<'a> = &'a [(String, &'a FacetStats)];

/// Adds min, max, mean and std of `stats` for facets `global` as `PREFIXmin_w_m2`, …
/// (`prefix` empty for the total, `NAME_` for a part).
fn with_stat_columns(
    batch: Table,
    prefix: &str,
    stats: &FacetStats,
    global: impl Iterator<Item = usize> + Clone,
) -> Table {
    let column = |f: &dyn Fn(usize) -> f64| Values::F64(global.clone().map(f).collect());
    batch
        .with(format!("{prefix}min_w_m2"), column(&|g| stats.min(g)))
        .with(format!("{prefix}max_w_m2"), column(&|g| stats.max(g)))
        .with(format!("{prefix}mean_w_m2"), column(&|g| stats.mean(g)))
        .with(format!("{prefix}std_w_m2"), column(&|g| stats.std(g)))
}

/// Writes `summary` (one row per facet). The min/max/mean/std/lit columns are of the
/// total irradiance, with the longest run of dark steps (E ≤ 0) and, when the steps are
/// `step_s` seconds apart, its duration in hours (each step standing for `step_s`; NaN
/// when the steps are not evenly spaced in time); each of `parts` adds the same statistics as `NAME_*` columns
/// (`direct_*` and `scattered_*`, `band_NAME_*`, `bands_*`).
pub fn write_summary(
    dir: &Path,
    csv: bool,
    world: &World,
    stats: &FacetStats,
    parts: NamedStats,
    step_s: Option<f64>,
) -> Result<Vec<PathBuf>> {
    let mut writer = TableWriter::new(dir, "summary", csv);
    for_facet_batches(world, FACETS_PER_BATCH, |body, range, offset| {
        let mesh = &world.bodies[body].mesh;
        let global = || range.clone().map(|i| offset + i);
        let vec_column = |f: &dyn Fn(usize) -> f64| Values::F64(range.clone().map(f).collect());
        let batch = Table::default()
            .with(
                "body",
                Values::Runs(vec![(world.bodies[body].name.clone(), range.len())]),
            )
            .with(
                "facet",
                Values::U32(range.clone().map(|i| i as u32).collect()),
            )
            .with("area_m2", vec_column(&|i| mesh.areas[i]))
            .with("centroid_x_m", vec_column(&|i| mesh.centroids[i].x))
            .with("centroid_y_m", vec_column(&|i| mesh.centroids[i].y))
            .with("centroid_z_m", vec_column(&|i| mesh.centroids[i].z))
            .with("normal_x", vec_column(&|i| mesh.normals[i].x))
            .with("normal_y", vec_column(&|i| mesh.normals[i].y))
            .with("normal_z", vec_column(&|i| mesh.normals[i].z));
        let dark_h = |g: usize| {
            step_s.map_or(f64::NAN, |s| {
                stats.longest_dark_steps(g) as f64 * s / 3600.0
            })
        };
        let batch = with_stat_columns(batch, "", stats, global())
            .with(
                "lit_fraction",
                Values::F64(global().map(|g| stats.lit_fraction(g)).collect()),
            )
            .with(
                "longest_dark_steps",
                Values::U32(global().map(|g| stats.longest_dark_steps(g)).collect()),
            )
            .with(
                "longest_dark_h",
                Values::F64(global().map(dark_h).collect()),
            );
        let batch = parts.iter().fold(batch, |batch, (name, stats)| {
            with_stat_columns(batch, &format!("{name}_"), stats, global())
        });
        writer.write(batch)
    })?;
    writer.finish()
}

/// Writes `cdf` (one row per facet and threshold): `cdf` of the total irradiance; each of
/// `parts` adds `cdf_NAME` at the same thresholds.
pub fn write_cdf(
    dir: &Path,
    csv: bool,
    world: &World,
    stats: &FacetStats,
    parts: NamedStats,
) -> Result<Vec<PathBuf>> {
    let mut writer = TableWriter::new(dir, "cdf", csv);
    let bins = stats.bins();
    // A batch holds facets × thresholds rows: bound the rows, not the facets.
    let per_batch = (CDF_ROWS_PER_BATCH / bins.count).clamp(1, FACETS_PER_BATCH);
    for_facet_batches(world, per_batch, |body, range, offset| {
        let rows = range.len() * bins.count;
        let mut facet = Vec::with_capacity(rows);
        let mut threshold = Vec::with_capacity(rows);
        let mut cdf = Vec::with_capacity(rows);
        for i in range.clone() {
            for (b, f) in stats.cdf(offset + i).into_iter().enumerate() {
                facet.push(i as u32);
                threshold.push(bins.threshold(b));
                cdf.push(f);
            }
        }
        let batch = Table::default()
            .with(
                "body",
                Values::Runs(vec![(world.bodies[body].name.clone(), rows)]),
            )
            .with("facet", Values::U32(facet))
            .with("irradiance_w_m2", Values::F64(threshold))
            .with("cdf", Values::F64(cdf));
        let all_cdfs =
            |s: &FacetStats| Values::F64(range.clone().flat_map(|i| s.cdf(offset + i)).collect());
        let batch = parts.iter().fold(batch, |batch, (name, stats)| {
            batch.with(format!("cdf_{name}"), all_cdfs(stats))
        });
        writer.write(batch)
    })?;
    writer.finish()
}

/// Writes `geometry` (one row per step and body).
pub fn write_geometry(
    dir: &Path,
    csv: bool,
    world: &World,
    states: &[EpochState],
) -> Result<Vec<PathBuf>> {
    let mut writer = TableWriter::new(dir, "geometry", csv);
    let rows = || {
        states
            .iter()
            .flat_map(|s| s.bodies.iter().enumerate().map(move |(b, x)| (s, b, x)))
    };
    let column = |f: &dyn Fn(&crate::ephemeris::BodyState) -> f64| {
        Values::F64(rows().map(|(_, _, x)| f(x)).collect())
    };
    let batch = Table::default()
        .with(
            "step",
            Values::U64(rows().map(|(s, _, _)| s.step as u64).collect()),
        )
        .with(
            "et_tdb_s",
            Values::F64(rows().map(|(s, _, _)| et_tdb_s(s)).collect()),
        )
        .with(
            "utc",
            Values::Str(rows().map(|(s, _, _)| utc_string(s)).collect()),
        )
        .with(
            "body",
            Values::Str(
                rows()
                    .map(|(_, b, _)| world.bodies[b].name.clone())
                    .collect(),
            ),
        )
        .with("sun_x", column(&|x| x.sun_dir.x))
        .with("sun_y", column(&|x| x.sun_dir.y))
        .with("sun_z", column(&|x| x.sun_dir.z))
        .with("sun_distance_km", column(&|x| x.sun_distance_m / 1000.0))
        .with("flux_w_m2", column(&|x| x.flux_w_m2))
        .with("position_x_km", column(&|x| x.pose.position_m.x / 1000.0))
        .with("position_y_km", column(&|x| x.pose.position_m.y / 1000.0))
        .with("position_z_km", column(&|x| x.pose.position_m.z / 1000.0))
        .with("rotation_w", column(&|x| quaternion(x).w))
        .with("rotation_x", column(&|x| quaternion(x).x))
        .with("rotation_y", column(&|x| quaternion(x).y))
        .with("rotation_z", column(&|x| quaternion(x).z));
    writer.write(batch)?;
    writer.finish()
}

/// The body → scene rotation as a unit quaternion with w ≥ 0.
fn quaternion(state: &crate::ephemeris::BodyState) -> glam::DQuat {
    let q = glam::DQuat::from_mat3(&state.pose.body_to_scene);
    if q.w < 0.0 {
        -q
    } else {
        q
    }
}

/// TDB seconds past J2000 of a step.
pub fn et_tdb_s(state: &EpochState) -> f64 {
    state.epoch.to_tdb_seconds()
}

/// ISO-8601 UTC of a step, millisecond precision.
pub fn utc_string(state: &EpochState) -> String {
    let (y, mo, d, h, mi, s, ns) = state.epoch.to_gregorian_utc();
    format!(
        "{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}.{:03}Z",
        ns / 1_000_000
    )
}

/// Calls `f(body, local facet range, body offset among the statistics)` for batches of
/// `per_batch` facets, body by body, over the bodies that get outputs.
fn for_facet_batches(
    world: &World,
    per_batch: usize,
    mut f: impl FnMut(usize, std::ops::Range<usize>, usize) -> Result<()>,
) -> Result<()> {
    for (b, offset) in world.output_offsets().into_iter().enumerate() {
        if !world.bodies[b].outputs {
            continue;
        }
        let n = world.bodies[b].mesh.len();
        for start in (0..n).step_by(per_batch) {
            f(b, start..(start + per_batch).min(n), offset)?;
        }
    }
    Ok(())
}

/// Streams the irradiance history: one batch per step.
pub struct HistoryWriter {
    writer: TableWriter,
    /// The body and facet columns, the same every step.
    body: Values,
    facet: Values,
}

impl HistoryWriter {
    /// A writer for `history.parquet` (and `.csv`) of the bodies that get outputs.
    pub fn new(dir: &Path, csv: bool, world: &World) -> HistoryWriter {
        let bodies = || world.bodies.iter().filter(|b| b.outputs);
        HistoryWriter {
            writer: TableWriter::new(dir, "history", csv),
            body: Values::Runs(bodies().map(|b| (b.name.clone(), b.mesh.len())).collect()),
            facet: Values::U32(bodies().flat_map(|b| 0..b.mesh.len() as u32).collect()),
        }
    }

    /// Appends one step's irradiance (the facets that get outputs, body by body):
    /// `irradiance_w_m2` is the total; with scattering, `direct_w_m2` and
    /// `scattered_w_m2` follow.
    pub fn write_step(&mut self, state: &EpochState, step: StepIrradiance) -> Result<()> {
        let n = step.total.len();
        let batch = Table::default()
            .with("step", Values::U64(vec![state.step as u64; n]))
            .with("et_tdb_s", Values::F64(vec![et_tdb_s(state); n]))
            .with("body", self.body.clone())
            .with("facet", self.facet.clone())
            .with("irradiance_w_m2", Values::F64(step.total.to_vec()));
        let batch = match step.parts {
            Some((direct, scattered)) => batch
                .with("direct_w_m2", Values::F64(direct.to_vec()))
                .with("scattered_w_m2", Values::F64(scattered.to_vec())),
            None => batch,
        };
        self.writer.write(batch)
    }

    /// Finishes the files.
    pub fn finish(self) -> Result<Vec<PathBuf>> {
        self.writer.finish()
    }
}
