//! Reading a finished run back: `run.json`, `summary`, `cdf` and `geometry` Parquet
//! tables and each body's PLY — the files the rest of [`crate::output`] writes, read with
//! the same types.
//!
//! In: a run folder. Out: [`RunData`] — the run record ([`RunRecord`], as written), per body the facet table
//! (areas m², centroids and normals in the body frame, metres; min/max/mean W/m²; lit
//! fraction), the CDF F(x) per facet at the run's thresholds (W/m²), the mesh (metres,
//! from `BODY.ply`, when written) and the geometry rows. Nothing is recomputed. A folder
//! without `run.json` is refused; missing or malformed tables are errors naming the file,
//! never panics.

use super::record::RunRecord;
use crate::error::{Error, Result};
use crate::mesh::{read_mesh, LengthUnit, Mesh, MeshFormat};
use crate::stats::Bins;
use arrow_array::{Array, Float64Array, RecordBatch, StringArray, UInt32Array, UInt64Array};
use glam::DVec3;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One body's `summary` rows, indexed by facet id (NaN where a row is missing).
#[derive(Debug, Clone, Default)]
pub struct Facets {
    pub area_m2: Vec<f64>,
    pub centroid_m: Vec<DVec3>,
    pub normal: Vec<DVec3>,
    pub min_w_m2: Vec<f64>,
    pub max_w_m2: Vec<f64>,
    pub mean_w_m2: Vec<f64>,
    pub lit_fraction: Vec<f64>,
    /// The mean of each part of the light the table holds (`direct`, `scattered`,
    /// `planet`), in that order, when it holds them (runs with scattered light).
    pub part_means_w_m2: Vec<(&'static str, Vec<f64>)>,
}

impl Facets {
    /// Number of facets.
    pub fn len(&self) -> usize {
        self.area_m2.len()
    }

    /// True when the body has no facets.
    pub fn is_empty(&self) -> bool {
        self.area_m2.is_empty()
    }

    fn with_len(n: usize) -> Facets {
        Facets {
            area_m2: vec![f64::NAN; n],
            centroid_m: vec![DVec3::NAN; n],
            normal: vec![DVec3::NAN; n],
            min_w_m2: vec![f64::NAN; n],
            max_w_m2: vec![f64::NAN; n],
            mean_w_m2: vec![f64::NAN; n],
            lit_fraction: vec![f64::NAN; n],
            part_means_w_m2: Vec::new(),
        }
    }

    /// Planetocentric latitude and east-positive longitude of facet `i`'s centroid, degrees.
    pub fn lat_lon_deg(&self, i: usize) -> (f64, f64) {
        lat_lon_deg(self.centroid_m[i])
    }
}

/// Planetocentric latitude and east-positive longitude of a point, degrees.
pub fn lat_lon_deg(p: DVec3) -> (f64, f64) {
    let r = p.length();
    if r == 0.0 || !r.is_finite() {
        return (f64::NAN, f64::NAN);
    }
    (
        (p.z / r).clamp(-1.0, 1.0).asin().to_degrees(),
        p.y.atan2(p.x).to_degrees(),
    )
}

/// F(x) per facet at the run's thresholds.
#[derive(Debug, Clone, Default)]
pub struct Cdf {
    /// Thresholds x_b, W/m².
    pub thresholds_w_m2: Vec<f64>,
    /// F(x_b) for facet k at `values[k * thresholds.len() + b]`; NaN where missing.
    pub values: Vec<f64>,
}

impl Cdf {
    /// F(x_b) of facet `k` for every threshold.
    pub fn facet(&self, k: usize) -> &[f64] {
        let n = self.thresholds_w_m2.len();
        self.values.get(k * n..(k + 1) * n).unwrap_or(&[])
    }
}

/// One body of the run.
#[derive(Debug, Clone)]
pub struct BodyData {
    pub name: String,
    pub facets: Facets,
    pub cdf: Cdf,
    /// The mesh from `BODY.ply` (metres), or why there is none.
    pub mesh: std::result::Result<Mesh, String>,
}

/// One row of `geometry`: the Sun seen from one body at one step.
#[derive(Debug, Clone)]
pub struct GeometryRow {
    pub step: u64,
    pub utc: String,
    pub body: String,
    /// Unit vector toward the Sun, body frame.
    pub sun: DVec3,
    pub sun_distance_km: f64,
    pub flux_w_m2: f64,
}

/// Everything a report is drawn from.
#[derive(Debug, Clone)]
pub struct RunData {
    pub dir: PathBuf,
    /// `run.json`.
    pub record: RunRecord,
    pub bodies: Vec<BodyData>,
    pub geometry: Vec<GeometryRow>,
}

impl RunData {
    /// The memory the run takes once read, bytes (for caches that keep runs): per facet
    /// its row of the summary, its CDF and its mesh, and the geometry rows.
    pub fn bytes(&self) -> u64 {
        const FACET_ROW: usize = 7 * 8 + 2 * 24;
        const MESH_PER_FACET: usize = 12 + 2 * 24 + 8 + 12;
        const GEOMETRY_ROW: usize = 160;
        let bodies: usize = self
            .bodies
            .iter()
            .map(|b| {
                let mesh = b.mesh.as_ref().map_or(0, |m| m.len() * MESH_PER_FACET);
                b.facets.len() * FACET_ROW + b.cdf.values.len() * 8 + mesh
            })
            .sum();
        (bodies + self.geometry.len() * GEOMETRY_ROW) as u64
    }

    /// Reads the finished run in `dir`.
    pub fn read(dir: &Path) -> Result<RunData> {
        let record = RunRecord::read(dir)?;
        let mut bodies = read_summary(dir, &record)?;
        read_cdf(dir, &record.bins_w_m2, &mut bodies)?;
        for body in &mut bodies {
            body.mesh = read_body_mesh(dir, &body.name, body.facets.len());
        }
        let geometry = read_geometry(dir)?;
        Ok(RunData {
            dir: dir.to_path_buf(),
            record,
            bodies,
            geometry,
        })
    }

    /// Total number of facets over all bodies.
    pub fn facet_count(&self) -> usize {
        self.bodies.iter().map(|b| b.facets.len()).sum()
    }
}

/// All record batches of a Parquet file.
fn read_batches(path: &Path) -> Result<Vec<RecordBatch>> {
    batches(path)?.collect()
}

/// The record batches of a Parquet file, read one at a time.
pub(crate) fn batches(path: &Path) -> Result<impl Iterator<Item = Result<RecordBatch>> + '_> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .and_then(|b| b.build())
        .map_err(|e| Error::file(path, e.to_string()))?;
    Ok(reader.map(move |b| b.map_err(|e| Error::file(path, e.to_string()))))
}

/// A typed column of a batch, or an error naming the file and column.
pub(crate) fn column<'a, T: Array + 'static>(
    batch: &'a RecordBatch,
    name: &str,
    path: &Path,
) -> Result<&'a T> {
    batch
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<T>())
        .ok_or_else(|| Error::file(path, format!("missing or mistyped column '{name}'")))
}

/// Parts of the light a summary may hold beside the total, in the order maps show them.
const PARTS: [&str; 3] = ["direct", "scattered", "planet"];

/// Reads `summary.parquet` into one [`BodyData`] per body (run.json's order first).
fn read_summary(dir: &Path, record: &RunRecord) -> Result<Vec<BodyData>> {
    let path = dir.join("summary.parquet");
    let batches = read_batches(&path)?;
    let mut rows: Vec<(String, usize, [f64; 11])> = Vec::new();
    // Parts present in every batch, with each row's means.
    let parts: Vec<&'static str> = PARTS
        .into_iter()
        .filter(|p| {
            let name = format!("{p}_mean_w_m2");
            batches
                .iter()
                .all(|b| column::<Float64Array>(b, &name, &path).is_ok())
        })
        .collect();
    let mut part_rows: Vec<Vec<f64>> = Vec::new();
    for batch in &batches {
        let part_cols = parts
            .iter()
            .map(|p| column::<Float64Array>(batch, &format!("{p}_mean_w_m2"), &path))
            .collect::<Result<Vec<_>>>()?;
        for r in 0..batch.num_rows() {
            part_rows.push(part_cols.iter().map(|c| c.value(r)).collect());
        }
        let body = column::<StringArray>(batch, "body", &path)?;
        let facet = column::<UInt32Array>(batch, "facet", &path)?;
        let names = [
            "area_m2",
            "centroid_x_m",
            "centroid_y_m",
            "centroid_z_m",
            "normal_x",
            "normal_y",
            "normal_z",
            "min_w_m2",
            "max_w_m2",
            "mean_w_m2",
            "lit_fraction",
        ];
        let cols = names
            .iter()
            .map(|n| column::<Float64Array>(batch, n, &path))
            .collect::<Result<Vec<_>>>()?;
        for r in 0..batch.num_rows() {
            let values = std::array::from_fn(|k| cols[k].value(r));
            rows.push((body.value(r).to_string(), facet.value(r) as usize, values));
        }
    }
    if rows.is_empty() {
        return Err(Error::file(&path, "the table holds no facets"));
    }
    let order = body_order(record, rows.iter().map(|(b, _, _)| b.as_str()));
    let mut bodies: Vec<BodyData> = order
        .iter()
        .map(|name| {
            let n = rows
                .iter()
                .filter(|(b, _, _)| b == name)
                .map(|(_, f, _)| f + 1)
                .max()
                .unwrap_or(0);
            let mut facets = Facets::with_len(n);
            facets.part_means_w_m2 = parts.iter().map(|p| (*p, vec![f64::NAN; n])).collect();
            BodyData {
                name: name.clone(),
                facets,
                cdf: Cdf::default(),
                mesh: Err(String::new()),
            }
        })
        .collect();
    let index: HashMap<&str, usize> = order
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i))
        .collect();
    for ((body, facet, v), means) in rows.iter().zip(&part_rows) {
        let f = &mut bodies[index[body.as_str()]].facets;
        for ((_, column), m) in f.part_means_w_m2.iter_mut().zip(means) {
            column[*facet] = *m;
        }
        f.area_m2[*facet] = v[0];
        f.centroid_m[*facet] = DVec3::new(v[1], v[2], v[3]);
        f.normal[*facet] = DVec3::new(v[4], v[5], v[6]);
        f.min_w_m2[*facet] = v[7];
        f.max_w_m2[*facet] = v[8];
        f.mean_w_m2[*facet] = v[9];
        f.lit_fraction[*facet] = v[10];
    }
    Ok(bodies)
}

/// Body names: those of run.json in its order, then any others met in the table.
fn body_order<'a>(record: &'a RunRecord, names: impl Iterator<Item = &'a str>) -> Vec<String> {
    let mut order: Vec<String> = Vec::new();
    let known = record.bodies.iter().map(|b| b.name.as_str());
    for name in known.chain(names) {
        if !order.iter().any(|n| n == name) {
            order.push(name.to_string());
        }
    }
    order
}

/// Reads `cdf.parquet` into each body's [`Cdf`] (thresholds from run.json's bins).
fn read_cdf(dir: &Path, bins: &Bins, bodies: &mut [BodyData]) -> Result<()> {
    let path = dir.join("cdf.parquet");
    if bins.width_w_m2.is_nan() || bins.width_w_m2 <= 0.0 || bins.count == 0 {
        return Err(Error::file(
            &dir.join("run.json"),
            "bins_w_m2 has no valid width and count",
        ));
    }
    let thresholds: Vec<f64> = (0..bins.count)
        .map(|b| b as f64 * bins.width_w_m2)
        .collect();
    for body in bodies.iter_mut() {
        body.cdf = Cdf {
            thresholds_w_m2: thresholds.clone(),
            values: vec![f64::NAN; body.facets.len() * bins.count],
        };
    }
    let index: HashMap<String, usize> = bodies
        .iter()
        .enumerate()
        .map(|(i, b)| (b.name.clone(), i))
        .collect();
    for batch in read_batches(&path)? {
        let body = column::<StringArray>(&batch, "body", &path)?;
        let facet = column::<UInt32Array>(&batch, "facet", &path)?;
        let x = column::<Float64Array>(&batch, "irradiance_w_m2", &path)?;
        let f = column::<Float64Array>(&batch, "cdf", &path)?;
        for r in 0..batch.num_rows() {
            let bin = (x.value(r) / bins.width_w_m2).round();
            let Some(&b) = index.get(body.value(r)) else {
                continue;
            };
            let cdf = &mut bodies[b].cdf;
            let slot = facet.value(r) as usize * bins.count + bin as usize;
            if bin >= 0.0 && (bin as usize) < bins.count && slot < cdf.values.len() {
                cdf.values[slot] = f.value(r);
            }
        }
    }
    Ok(())
}

/// The mesh of `BODY.ply` (metres), if it was written and matches the facet count.
fn read_body_mesh(dir: &Path, name: &str, facets: usize) -> std::result::Result<Mesh, String> {
    let path = dir.join(format!("{name}.ply"));
    if !path.is_file() {
        return Err(format!(
            "no {name}.ply in the run folder (the run had [output] ply = false)"
        ));
    }
    let raw = read_mesh(&path, Some(MeshFormat::Ply)).map_err(|e| e.to_string())?;
    let mesh = Mesh::from_raw(raw, LengthUnit::M);
    if mesh.len() != facets {
        return Err(format!(
            "{name}.ply has {} facets but the summary has {facets}",
            mesh.len()
        ));
    }
    Ok(mesh)
}

/// Reads `geometry.parquet`.
fn read_geometry(dir: &Path) -> Result<Vec<GeometryRow>> {
    let path = dir.join("geometry.parquet");
    let mut rows = Vec::new();
    for batch in read_batches(&path)? {
        let step = column::<UInt64Array>(&batch, "step", &path)?;
        let utc = column::<StringArray>(&batch, "utc", &path)?;
        let body = column::<StringArray>(&batch, "body", &path)?;
        let f64s = ["sun_x", "sun_y", "sun_z", "sun_distance_km", "flux_w_m2"]
            .iter()
            .map(|n| column::<Float64Array>(&batch, n, &path))
            .collect::<Result<Vec<_>>>()?;
        for r in 0..batch.num_rows() {
            rows.push(GeometryRow {
                step: step.value(r),
                utc: utc.value(r).to_string(),
                body: body.value(r).to_string(),
                sun: DVec3::new(f64s[0].value(r), f64s[1].value(r), f64s[2].value(r)),
                sun_distance_km: f64s[3].value(r),
                flux_w_m2: f64s[4].value(r),
            });
        }
    }
    Ok(rows)
}
