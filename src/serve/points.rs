//! Points: on-demand irradiance time series for a few facets or places of a job's scene,
//! computed for just those facets — no need to wait for, or even run, the whole job.
//!
//! In: a job's scene and a request naming targets (a facet id, a body-fixed point in
//! metres or a latitude/east longitude in degrees, each on a named body) and a step range.
//! Out: per target its facet and the irradiance (W/m²) at every step of the range, with
//! the steps' epochs (TDB seconds past J2000). The values are those `slim run` computes
//! for the same facets (same shadow predicate, same guards); the shadow structures are the
//! grid tracer's, which needs no per-step set-up.
//!
//! Each scene's meshes, ephemeris and grids are built once and kept by an engine thread
//! that owns them and answers requests through a channel; the service keeps engines
//! across requests within a byte budget, the least recently asked leaving first.

use super::limits::Limits;
use super::lru::Lru;
use super::query::{check_facet, nearest_facet, unknown_body, Place};
use super::reply::{ApiError, ApiResult};
use super::scene_input::{bad_scene, check_files, SceneText};
use crate::budget::{Budget, GEOMETRY_BYTES_PER_FACET};
use crate::ephemeris::Ephemeris;
use crate::illum::Direct;
use crate::prepare::assemble;
use crate::progress::Timings;
use crate::trace::TracerKind;
use crate::world::World;
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::Mutex;

/// One target of a request: a facet id, or a place on a body.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// Body name (default: the first body).
    pub body: Option<String>,
    pub facet: Option<usize>,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    /// Body-fixed point, metres.
    pub point_m: Option<[f64; 3]>,
}

/// The request body.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointsRequest {
    pub targets: Vec<Target>,
    /// First step (default 0).
    #[serde(default)]
    pub from_step: usize,
    /// Step after the last (default: the scene's step count).
    pub to_step: Option<usize>,
    /// Only steps at or after this epoch (TDB seconds past J2000).
    pub from_tdb_s: Option<f64>,
    /// Only steps before this epoch.
    pub to_tdb_s: Option<f64>,
}

impl PointsRequest {
    /// The request in a body, or a 400 saying why it is not one.
    pub fn from_body(body: &[u8]) -> ApiResult<PointsRequest> {
        serde_json::from_slice(body)
            .map_err(|e| ApiError::bad_request("malformed_body", format!("not a point query: {e}")))
    }
}

/// One target's time series.
#[derive(Debug, Clone, Serialize)]
pub struct Series {
    pub body: String,
    pub facet: usize,
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub irradiance_w_m2: Vec<f64>,
}

/// The answer.
#[derive(Debug, Clone, Serialize)]
pub struct PointsAnswer {
    pub steps: Vec<usize>,
    pub et_tdb_s: Vec<f64>,
    pub series: Vec<Series>,
}

/// A request on its way to an engine thread, with where to send the answer.
struct Ask {
    request: PointsRequest,
    max_values: usize,
    reply: tokio::sync::oneshot::Sender<ApiResult<PointsAnswer>>,
}

/// Engines by job id, within a byte budget (each engine holds its scene's meshes and
/// shadow index); the least recently asked goes first, and its thread ends once it has
/// answered what it was asked.
pub struct EngineCache {
    engines: Mutex<Lru<mpsc::Sender<Ask>>>,
}

impl EngineCache {
    /// An empty cache of at most `budget_bytes`.
    pub fn new(budget_bytes: u64) -> EngineCache {
        EngineCache {
            engines: Mutex::new(Lru::new(budget_bytes)),
        }
    }

    /// Answers `request` on job `id`'s scene of `facets` facets, starting its engine if
    /// needed, within `limits` (targets × steps per query, memory of the scene).
    pub async fn ask(
        &self,
        dir: &Path,
        id: &str,
        (scene, facets): (SceneText, usize),
        request: PointsRequest,
        limits: &Limits,
    ) -> ApiResult<PointsAnswer> {
        let (reply, answer) = tokio::sync::oneshot::channel();
        let ask = Ask {
            request,
            max_values: limits.max_query_values,
            reply,
        };
        {
            let mut engines = self.lock();
            let sender = match engines.get(id) {
                Some(s) => s,
                None => {
                    let s = start_engine(dir.to_path_buf(), scene, limits.job_budget())?;
                    let bytes = (facets as f64 * GEOMETRY_BYTES_PER_FACET) as u64;
                    engines.insert(id.to_string(), s.clone(), bytes);
                    s
                }
            };
            sender
                .send(ask)
                .map_err(|_| ApiError::internal("the point-query engine stopped"))?;
        }
        answer
            .await
            .map_err(|_| ApiError::internal("the point-query engine stopped"))?
    }

    /// Stops a job's engine (the job was deleted).
    pub fn forget(&self, id: &str) {
        self.lock().remove(id);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Lru<mpsc::Sender<Ask>>> {
        self.engines.lock().unwrap_or_else(|p| p.into_inner())
    }
}

fn start_engine(dir: PathBuf, scene: SceneText, budget: Budget) -> ApiResult<mpsc::Sender<Ask>> {
    let (tx, rx) = mpsc::channel::<Ask>();
    std::thread::Builder::new()
        .name("slim-points".into())
        .spawn(move || engine(&dir, &scene, &budget, rx))
        .map_err(|e| ApiError::internal(format!("cannot start a point-query engine: {e}")))?;
    Ok(tx)
}

/// The engine thread: builds the scene once, then answers until its sender is dropped.
fn engine(dir: &Path, scene: &SceneText, budget: &Budget, asks: mpsc::Receiver<Ask>) {
    match build(dir, scene, budget) {
        Ok((world, ephemeris)) => {
            let direct = Direct::new(&world, TracerKind::Grid);
            for ask in asks {
                let answer = answer(&world, ephemeris.as_ref(), &direct, &ask);
                let _ = ask.reply.send(answer);
            }
        }
        Err(e) => {
            for ask in asks {
                let _ = ask.reply.send(Err(e.clone()));
            }
        }
    }
}

fn build(dir: &Path, text: &SceneText, budget: &Budget) -> ApiResult<(World, Box<dyn Ephemeris>)> {
    let scene = text.parse(dir)?;
    check_files(dir, &scene)?;
    let assembly =
        assemble(&scene, budget, &mut Timings::default()).map_err(|e| bad_scene(dir, &e))?;
    Ok((assembly.world, assembly.ephemeris))
}

fn answer(
    world: &World,
    ephemeris: &dyn Ephemeris,
    direct: &Direct<'_>,
    ask: &Ask,
) -> ApiResult<PointsAnswer> {
    let request = &ask.request;
    let targets = request
        .targets
        .iter()
        .map(|t| resolve(world, t))
        .collect::<ApiResult<Vec<_>>>()?;
    let steps = step_range(request, ephemeris)?;
    let values = targets.len() * steps.len();
    if targets.is_empty() || values > ask.max_values {
        return Err(ApiError::unprocessable(
            "limit_exceeded",
            format!(
                "{} targets × {} steps asked: give 1 or more targets and at most {} values",
                targets.len(),
                steps.len(),
                ask.max_values
            ),
        ));
    }
    let mut out = PointsAnswer {
        steps: steps.clone().collect(),
        et_tdb_s: Vec::with_capacity(steps.len()),
        series: targets
            .iter()
            .map(|&(b, i)| {
                let body = &world.bodies[b];
                let (lat_deg, lon_deg) = crate::output::read::lat_lon_deg(body.mesh.centroids[i]);
                Series {
                    body: body.name.clone(),
                    facet: i,
                    lat_deg,
                    lon_deg,
                    irradiance_w_m2: Vec::with_capacity(steps.len()),
                }
            })
            .collect(),
    };
    for k in steps {
        let state = ephemeris
            .state(k)
            .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?;
        let values = direct
            .compute_facets(&state, &targets)
            .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?;
        out.et_tdb_s.push(state.epoch.to_tdb_seconds());
        for (series, e) in out.series.iter_mut().zip(values) {
            series.irradiance_w_m2.push(e);
        }
    }
    Ok(out)
}

/// A target as (body index, facet id).
fn resolve(world: &World, t: &Target) -> ApiResult<(usize, usize)> {
    let b = match &t.body {
        None => 0,
        Some(name) => world
            .bodies
            .iter()
            .position(|b| &b.name == name)
            .ok_or_else(|| {
                let names: Vec<&str> = world.bodies.iter().map(|b| b.name.as_str()).collect();
                unknown_body(name, &names)
            })?,
    };
    let body = &world.bodies[b];
    let place = || Place::from_parts(t.point_m, t.lat_deg, t.lon_deg);
    match (
        t.facet,
        t.point_m.is_some() || t.lat_deg.is_some() || t.lon_deg.is_some(),
    ) {
        (Some(i), false) => {
            check_facet(&body.name, body.mesh.len(), i)?;
            Ok((b, i))
        }
        (None, true) => {
            let i = nearest_facet(&body.mesh.centroids, place()?).ok_or_else(|| {
                ApiError::unprocessable("empty_body", format!("body '{}' has no facets", body.name))
            })?;
            Ok((b, i))
        }
        _ => Err(ApiError::bad_request(
            "bad_target",
            "each target gives either facet, or point_m, or lat_deg and lon_deg",
        )),
    }
}

/// The steps asked for: the step range, narrowed to the epoch window if one is given.
fn step_range(request: &PointsRequest, ephemeris: &dyn Ephemeris) -> ApiResult<Range<usize>> {
    let steps = ephemeris.steps();
    let to = request.to_step.unwrap_or(steps);
    let bad = |msg: String| ApiError::bad_request("bad_steps", msg);
    if request.from_step >= to || to > steps {
        return Err(bad(format!(
            "from_step {} to_step {to}: the scene has steps 0 to {} (to_step is exclusive)",
            request.from_step,
            steps.saturating_sub(1)
        )));
    }
    let mut range = request.from_step..to;
    if let Some(t) = request.from_tdb_s {
        range.start = first_step_at(ephemeris, range.clone(), t)?;
    }
    if let Some(t) = request.to_tdb_s {
        range.end = first_step_at(ephemeris, range.clone(), t)?;
    }
    if range.is_empty() {
        return Err(bad(
            "no step of the scene lies in the asked window (from_tdb_s inclusive, to_tdb_s \
             exclusive)"
                .into(),
        ));
    }
    Ok(range)
}

/// The first step of `range` whose epoch is at or after `tdb_s` (`range.end` if none), by
/// bisection: epochs grow with the step.
fn first_step_at(ephemeris: &dyn Ephemeris, range: Range<usize>, tdb_s: f64) -> ApiResult<usize> {
    if !tdb_s.is_finite() {
        return Err(ApiError::bad_request(
            "bad_steps",
            "from_tdb_s and to_tdb_s must be finite",
        ));
    }
    let (mut lo, mut hi) = (range.start, range.end);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        let epoch = ephemeris
            .state(mid)
            .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?
            .epoch
            .to_tdb_seconds();
        if epoch < tdb_s {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    Ok(lo)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// Facets computed one by one with the grid tracer get the same values, bit for bit,
    /// as the whole mesh computed by a run with the sunview tracer.
    #[test]
    fn facets_alone_match_the_whole_mesh() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
        let text = SceneText {
            toml: r#"
[ephemeris]
mode = "spin"
distance_au = 1.0
subsolar_latitude_deg = 20.0
steps_per_period = 48
[[body]]
name = "itokawa"
mesh = "shapes/itokawa/itokawa_8.obj"
units = "km"
spin_period_h = 12.0
"#
            .into(),
            parse_path: dir.join("t.toml"),
        };
        let (world, ephemeris) = build(&dir, &text, &Budget::machine()).unwrap();
        let grid = Direct::new(&world, TracerKind::Grid);
        let sunview = Direct::new(&world, TracerKind::Sunview);
        let facets: Vec<(usize, usize)> = (0..world.facet_count()).map(|i| (0, i)).collect();
        let mut all = vec![0.0; world.facet_count()];
        for k in 0..ephemeris.steps() {
            let state = ephemeris.state(k).unwrap();
            sunview.compute(&state, &mut all).unwrap();
            let alone = grid.compute_facets(&state, &facets).unwrap();
            for (i, (a, b)) in all.iter().zip(&alone).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "step {k} facet {i}: {a} vs {b}");
            }
        }
    }
}
