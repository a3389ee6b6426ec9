//! Points: on-demand irradiance time series for a few facets or places of a job's scene,
//! computed for just those facets — no need to wait for, or even run, the whole job.
//!
//! In: a job's scene and a request naming targets (a facet id, a body-fixed point in
//! metres or a latitude/east longitude in degrees, each on a named body) and a step range.
//! Out: per target its facet and the irradiance (W/m²) at every step of the range, with
//! the steps' epochs (TDB seconds past J2000). A target with a height or a panel also
//! gets the panel's series ([`crate::panel`]): irradiance on the panel under the horizon
//! seen from that height, with the scene's point or disk Sun, its power and the share of
//! the Sun seen. The values are those `slim run` computes with shadow rays
//! for the same facets (same shadow predicate, same guards), bit for bit. The rays go
//! through each body's tree ([`Bvh`], no per-step set-up; the panels' horizons search the
//! same tree). Steps are computed in parallel.
//!
//! Each scene's meshes, ephemeris and trees are built once and kept by an engine thread
//! that owns them and answers requests through a channel; the service keeps engines
//! across requests within a byte budget, the least recently asked leaving first.

use super::jobs::SceneSize;
use super::limits::Limits;
use super::lru::Lru;
use super::query::{locate, unknown_body};
use super::reply::{ApiError, ApiResult};
use super::scene_input::{bad_scene, check_files, SceneText};
use crate::budget::{Budget, GEOMETRY_BYTES_PER_FACET};
use crate::ephemeris::{Ephemeris, EpochState};
use crate::horizon::disk::SolarDisk;
use crate::horizon::map::PointHorizon;
use crate::horizon::{Shadows, SunShape};
use crate::illum::Direct;
use crate::panel::{Battery, Charge, Orientation, Panel, PanelLight, Site, PANEL_AZIMUTHS};
use crate::prepare::assemble;
use crate::progress::Timings;
use crate::scatter::to_panel::{self, TerrainView};
use crate::sight::{windows_above, Sighting};
use crate::trace::bvh::Bvh;
use crate::trace::Tracer;
use crate::world::World;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::collections::HashMap;
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
    /// Height of a panel above the place, metres (default 1 m when a panel is given).
    pub height_m: Option<f64>,
    /// A panel at the place (default with a height: one facing the Sun, 1 m², 100 %).
    pub panel: Option<PanelSpec>,
    /// A battery the panel charges while a load draws on it.
    pub battery: Option<BatterySpec>,
    /// Other bodies of the scene whose elevation over the horizon, seen from the place
    /// (at `height_m`, default 1 m), is wanted: the Earth for direct-to-Earth links.
    #[serde(default)]
    pub sight_of: Vec<String>,
}

/// A panel as a request gives it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PanelSpec {
    /// "fixed" (default), "azimuth_tracking" (turns about the vertical) or "sun_tracking".
    #[serde(default)]
    pub mount: Mount,
    /// Tilt from horizontal, degrees (default 90: vertical); fixed and azimuth tracking.
    #[serde(default = "vertical")]
    pub tilt_deg: f64,
    /// Facing azimuth from north toward east, degrees (default 0); fixed only.
    #[serde(default)]
    pub azimuth_deg: f64,
    /// Area, m² (default 1).
    #[serde(default = "one")]
    pub area_m2: f64,
    /// Efficiency, 0 to 1 (default 1).
    #[serde(default = "one")]
    pub efficiency: f64,
}

/// A battery as a request gives it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BatterySpec {
    pub capacity_wh: f64,
    /// Energy at the first step, Wh (default: full).
    pub initial_wh: Option<f64>,
    /// Default 1.
    #[serde(default = "one")]
    pub charge_efficiency: f64,
    /// Default 1.
    #[serde(default = "one")]
    pub discharge_efficiency: f64,
    /// The load, W: one number for every step, or one per step asked for.
    pub load_w: Load,
    /// The low mark, Wh: time below it is reported (default 0).
    #[serde(default)]
    pub low_wh: f64,
}

/// A checked battery request: the battery, its load per step (W) and low mark (Wh).
struct ChargedBattery {
    battery: Battery,
    load_w: Vec<f64>,
    low_wh: f64,
}

/// A constant load or one per step.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum Load {
    Constant(f64),
    PerStep(Vec<f64>),
}

impl BatterySpec {
    /// The battery with the load at each of `steps` steps and its low mark, or a 400
    /// naming the bad field.
    fn battery(&self, steps: usize) -> ApiResult<ChargedBattery> {
        let bad = |field: &str, msg: String| {
            ApiError::bad_request("bad_battery", format!("battery.{field}: {msg}"))
        };
        let battery = Battery::checked(
            self.capacity_wh,
            self.initial_wh,
            self.charge_efficiency,
            self.discharge_efficiency,
        )
        .map_err(|(field, why)| bad(field, why.into()))?;
        if !self.low_wh.is_finite() {
            return Err(bad("low_wh", "must be finite".into()));
        }
        let load = match &self.load_w {
            Load::Constant(w) => vec![*w; steps],
            Load::PerStep(list) if list.len() == steps => list.clone(),
            Load::PerStep(list) => {
                return Err(bad(
                    "load_w",
                    format!(
                        "{} values for {steps} steps: give one per step, or one number",
                        list.len()
                    ),
                ))
            }
        };
        if load.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(bad("load_w", "loads must be finite and ≥ 0".into()));
        }
        Ok(ChargedBattery {
            battery,
            load_w: load,
            low_wh: self.low_wh,
        })
    }
}

/// How a panel is mounted.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub enum Mount {
    #[default]
    Fixed,
    AzimuthTracking,
    SunTracking,
}

fn vertical() -> f64 {
    90.0
}
fn one() -> f64 {
    1.0
}

impl PanelSpec {
    /// The panel, or a 400 naming the bad field.
    fn panel(&self) -> ApiResult<Panel> {
        let bad = |field: &str, msg: &str| {
            ApiError::bad_request("bad_panel", format!("panel.{field}: {msg}"))
        };
        if !(0.0..=180.0).contains(&self.tilt_deg) {
            return Err(bad("tilt_deg", "must be 0 to 180"));
        }
        if !self.azimuth_deg.is_finite() {
            return Err(bad("azimuth_deg", "must be finite"));
        }
        if !(self.area_m2.is_finite() && self.area_m2 > 0.0) {
            return Err(bad("area_m2", "must be above 0"));
        }
        if !(0.0..=1.0).contains(&self.efficiency) {
            return Err(bad("efficiency", "must be 0 to 1"));
        }
        Ok(Panel {
            orientation: match self.mount {
                Mount::Fixed => Orientation::Fixed {
                    tilt_deg: self.tilt_deg,
                    azimuth_deg: self.azimuth_deg,
                },
                Mount::AzimuthTracking => Orientation::AzimuthTracking {
                    tilt_deg: self.tilt_deg,
                },
                Mount::SunTracking => Orientation::SunTracking,
            },
            area_m2: self.area_m2,
            efficiency: self.efficiency,
        })
    }
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
    /// With a height or a panel: what the panel receives.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub panel: Option<PanelSeries>,
    /// Per body of `sight_of`: where it stands over the place's horizon.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub sight: Vec<SightSeries>,
}

/// Another body seen from a target's place ([`crate::sight`]).
#[derive(Debug, Clone, Serialize)]
pub struct SightSeries {
    pub body: String,
    /// Elevation of its centre above the local horizontal, degrees, per step.
    pub elevation_deg: Vec<f64>,
    /// Elevation of the terrain's horizon toward it, degrees, per step.
    pub horizon_deg: Vec<f64>,
    /// Its centre above the horizon, per step.
    pub seen: Vec<bool>,
    /// When it is seen, edges refined between steps, cut ones flagged.
    pub windows: Vec<crate::sight::Window>,
}

/// A panel's series at one target.
#[derive(Debug, Clone, Serialize)]
pub struct PanelSeries {
    pub height_m: f64,
    /// Where the panel stands, body frame, metres.
    pub point_m: [f64; 3],
    pub irradiance_w_m2: Vec<f64>,
    pub power_w: Vec<f64>,
    /// Share of the Sun's flux above the horizon from the panel, 0 to 1.
    pub sun_visible: Vec<f64>,
    /// Energy over the steps, Wh: each step's power held until the next step (the last
    /// for as long as the one before it).
    pub energy_wh: f64,
    /// Share of steps in which some of the Sun is seen from the panel.
    pub lit_fraction: f64,
    /// The longest run of steps with none of the Sun seen, s (each step held as for the
    /// energy).
    pub longest_dark_s: f64,
    /// With a battery: its charge along the steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub battery: Option<Charge>,
    /// When the scene scatters light: the terrain's part of `irradiance_w_m2`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scattered: Option<TerrainLight>,
}

/// Light scattered by the terrain onto a panel ([`crate::scatter::to_panel`]): first order,
/// from the facets the panel sees.
#[derive(Debug, Clone, Serialize)]
pub struct TerrainLight {
    /// Irradiance from the terrain, W/m², per step (counted in the panel's irradiance,
    /// power and energy).
    pub irradiance_w_m2: Vec<f64>,
    /// The facets counted.
    pub facets: usize,
    /// The most form factor the visible facets left out could hold (Σ Ω/π).
    pub left_out: f64,
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
        (scene, size): (SceneText, SceneSize),
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
                    let geometry = size.facets as f64 * GEOMETRY_BYTES_PER_FACET;
                    let states = (size.steps * size.bodies.max(1) * STATE_BYTES_PER_BODY) as f64;
                    let bytes = (geometry + states + KEPT_HORIZON_BYTES) as u64;
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

/// What an engine keeps of its scene.
struct Engine<'w> {
    world: &'w World,
    ephemeris: &'w dyn Ephemeris,
    /// The trees with the scene's Sun (point or disk): facets' light as the scene's step
    /// loop gives it, and other bodies' shadows on panels (an eclipse by the Earth seen
    /// from the Moon).
    direct: Direct<'w>,
    /// Each body's tree over its shadow mesh (with its surroundings): the facets' shadow
    /// rays, and the horizons of panels and facets.
    bvhs: &'w [Bvh<'w>],
    /// The scene's Sun: a disk (with its limb darkening) or a point.
    disk: Option<SolarDisk>,
    /// Every facet's albedo when the scene scatters light ([`Light::albedo`]).
    albedo: Option<Vec<f64>>,
    /// What the panels asked for see of the terrain (same keys as `horizons`), when the
    /// scene scatters light.
    views: RefCell<HashMap<HorizonKey, TerrainView>>,
    /// Each step's geometry once computed: the ephemeris is the costliest part of a
    /// query, and later queries on the same job ask for the same steps.
    states: RefCell<Vec<Option<EpochState>>>,
    /// Horizons of the places asked for (body, surface point and height bits), at most
    /// [`KEPT_HORIZONS`] (16 kB each), so that asking again skips the search.
    horizons: RefCell<HashMap<HorizonKey, PointHorizon>>,
}

/// A place's horizon: its body, surface point (bits of x, y, z) and height (bits).
type HorizonKey = (usize, [u64; 3], u64);

/// Horizons an engine keeps; beyond this they are dropped and built again when asked.
const KEPT_HORIZONS: usize = 256;

/// Memory of one body's geometry at one step, kept by an engine (bytes, with room for the
/// step's own fields).
const STATE_BYTES_PER_BODY: usize = 192;

/// Memory of the kept horizons (two f64 per wedge) and terrain views (up to 128 facets of
/// 80 bytes each) at most, bytes.
const KEPT_HORIZON_BYTES: f64 =
    (KEPT_HORIZONS * (PANEL_AZIMUTHS as usize * 16 + to_panel::MOST_FACETS * 80)) as f64;

/// The engine thread: builds the scene once, then answers until its sender is dropped.
fn engine(dir: &Path, scene: &SceneText, budget: &Budget, asks: mpsc::Receiver<Ask>) {
    match build(dir, scene, budget) {
        Ok((world, ephemeris, light)) => {
            let bvhs = body_trees(&world);
            let engine = Engine::new(&world, &bvhs, ephemeris.as_ref(), light);
            for ask in asks {
                let answer = engine.answer(&ask.request, ask.max_values);
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

/// Each body's tree over its shadow mesh, in scene order.
fn body_trees(world: &World) -> Vec<Bvh<'_>> {
    world
        .bodies
        .iter()
        .map(|b| Bvh::build(b.shadow_mesh()))
        .collect()
}

/// The scene's world, ephemeris and light.
type Built = (World, Box<dyn Ephemeris>, Light);

/// What a scene says of its light beyond the geometry.
struct Light {
    /// The scene's shadow settings: its Sun's shape (and the disk's limb darkening) and
    /// samples, for panels and other bodies' shadows on them.
    shadows: Shadows,
    /// Every facet's albedo (global ids) when the scene scatters light: the terrain then
    /// lights panels too.
    albedo: Option<Vec<f64>>,
}

impl Light {
    fn of(scene: &crate::scene::Scene, world: &World) -> crate::Result<Light> {
        Ok(Light {
            shadows: scene.shadows(),
            albedo: crate::scatter::albedo::facet_albedo(scene, world)?,
        })
    }
}

fn build(dir: &Path, text: &SceneText, budget: &Budget) -> ApiResult<Built> {
    let scene = text.parse(dir)?;
    check_files(dir, &scene)?;
    let assembly =
        assemble(&scene, budget, &mut Timings::default()).map_err(|e| bad_scene(dir, &e))?;
    let light = Light::of(&scene, &assembly.world).map_err(|e| bad_scene(dir, &e))?;
    Ok((assembly.world, assembly.ephemeris, light))
}

/// Answers one query on a scene file without the service (`slim place`): the scene is
/// read as `slim run` reads it (paths beside it), within the machine's memory.
pub fn answer_scene_file(scene: &Path, request: &PointsRequest) -> crate::Result<PointsAnswer> {
    let scene = crate::scene::Scene::load(scene)?;
    let assembly = assemble(&scene, &Budget::machine(), &mut Timings::default())?;
    let light = Light::of(&scene, &assembly.world)?;
    let bvhs = body_trees(&assembly.world);
    let engine = Engine::new(&assembly.world, &bvhs, assembly.ephemeris.as_ref(), light);
    let answer = engine.answer(request, usize::MAX);
    answer.map_err(|e| crate::Error::Usage(format!("{} ({})", e.message, e.code)))
}

impl<'w> Engine<'w> {
    fn new(
        world: &'w World,
        bvhs: &'w [Bvh<'w>],
        ephemeris: &'w dyn Ephemeris,
        light: Light,
    ) -> Engine<'w> {
        let tracers = || {
            bvhs.iter()
                .map(|t| Box::new(t) as Box<dyn Tracer + 'w>)
                .collect()
        };
        Engine {
            world,
            ephemeris,
            direct: Direct::with_tracers(world, tracers(), &light.shadows),
            bvhs,
            disk: (light.shadows.sun == SunShape::Disk).then_some(light.shadows.disk),
            albedo: light.albedo,
            states: RefCell::new(vec![None; ephemeris.steps()]),
            horizons: RefCell::new(HashMap::new()),
            views: RefCell::new(HashMap::new()),
        }
    }

    fn answer(&self, request: &PointsRequest, max_values: usize) -> ApiResult<PointsAnswer> {
        let (world, ephemeris) = (self.world, self.ephemeris);
        let targets = request
            .targets
            .iter()
            .map(|t| resolve(world, t))
            .collect::<ApiResult<Vec<_>>>()?;
        let steps = step_range(request, ephemeris)?;
        // Each target's series, its panel's (twice when the terrain lights it) and each
        // sight's count against the limit.
        let panel_series = 1 + self.albedo.is_some() as usize;
        let series: usize = targets
            .iter()
            .map(|t| 1 + t.panel as usize * panel_series + t.sight_of.len())
            .sum();
        let values = series.saturating_mul(steps.len());
        if targets.is_empty() || values > max_values {
            return Err(ApiError::unprocessable(
                "limit_exceeded",
                format!(
                    "{} series (targets, panels and sights) × {} steps asked: give 1 or more \
                     targets and at most {} values",
                    series,
                    steps.len(),
                    max_values
                ),
            ));
        }
        let facets: Vec<(usize, usize)> = targets.iter().map(|t| (t.body, t.facet)).collect();
        let sites = request
            .targets
            .iter()
            .zip(&targets)
            .map(|(t, r)| self.site(t, r))
            .collect::<ApiResult<Vec<_>>>()?;
        // Batteries are checked before any step is computed.
        let batteries = request
            .targets
            .iter()
            .map(|t| {
                t.battery
                    .as_ref()
                    .map(|b| b.battery(steps.len()))
                    .transpose()
            })
            .collect::<ApiResult<Vec<_>>>()?;
        let mut out = PointsAnswer {
            steps: steps.clone().collect(),
            et_tdb_s: Vec::with_capacity(steps.len()),
            series: targets
                .iter()
                .zip(&sites)
                .map(|(r, site)| {
                    let point = site.as_ref().map(|(site, _)| site.point());
                    empty_series(world, r, point, steps.len())
                })
                .collect(),
        };
        let terrains: Vec<Option<Terrain>> = targets
            .iter()
            .zip(&sites)
            .map(|(r, site)| self.terrain(r, site.as_ref().map(|(site, _)| site)))
            .collect();
        for (series, terrain) in out.series.iter_mut().zip(&terrains) {
            if let (Some(p), Some(t)) = (series.panel.as_mut(), terrain) {
                p.scattered = Some(TerrainLight {
                    irradiance_w_m2: Vec::with_capacity(steps.len()),
                    facets: t.facets.len(),
                    left_out: t.view.left_out(),
                });
            }
        }
        let work = StepWork {
            direct: &self.direct,
            disk: self.disk.as_ref(),
            facets,
            sites: &sites,
            targets: &targets,
            terrains: &terrains,
        };
        self.fill_states(steps.clone())?;
        let kept = self.states.borrow();
        let states = steps
            .map(|k| kept[k].as_ref())
            .collect::<Option<Vec<&EpochState>>>()
            .ok_or_else(|| ApiError::internal("a step's geometry was not kept"))?;
        // Steps are independent: computed in parallel, gathered in order.
        let per_step = states
            .into_par_iter()
            .map(|state| work.at(state))
            .collect::<ApiResult<Vec<StepValues>>>()?;
        for (epoch, values) in per_step {
            out.et_tdb_s.push(epoch);
            for (series, value) in out.series.iter_mut().zip(values) {
                series.push(value);
            }
        }
        let durations = step_durations(&out.et_tdb_s);
        for (series, battery) in out.series.iter_mut().zip(&batteries) {
            if let Some(p) = series.panel.as_mut() {
                p.sum_up(&durations, battery.as_ref());
            }
            for sight in &mut series.sight {
                sight.windows = sight.windows(&out.et_tdb_s);
            }
        }
        Ok(out)
    }

    /// Computes the geometry of the steps in `steps` not yet kept.
    fn fill_states(&self, steps: Range<usize>) -> ApiResult<()> {
        let mut states = self.states.borrow_mut();
        for k in steps {
            if states[k].is_some() {
                continue;
            }
            let state = self
                .ephemeris
                .state(k)
                .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?;
            states[k] = Some(state);
        }
        Ok(())
    }

    /// The site of a target that has a height, a panel or a sight, with its panel.
    fn site(&self, t: &Target, r: &Resolved) -> ApiResult<Option<(Site<'_>, Panel)>> {
        if t.battery.is_some() && t.height_m.is_none() && t.panel.is_none() {
            return Err(ApiError::bad_request(
                "bad_battery",
                "a battery needs a panel (or a height for the default Sun-tracking one)",
            ));
        }
        if t.height_m.is_none() && t.panel.is_none() && t.sight_of.is_empty() {
            return Ok(None);
        }
        let panel = match &t.panel {
            Some(spec) => spec.panel()?,
            None => Panel {
                orientation: Orientation::SunTracking,
                area_m2: 1.0,
                efficiency: 1.0,
            },
        };
        // The panel sees the body's surroundings too, where it has them.
        let mesh = self.world.bodies[r.body].shadow_mesh();
        let key = r.place_key();
        let kept = self.horizons.borrow().get(&key).cloned();
        let site = Site::with_horizon(mesh, &self.bvhs[r.body], r.surface_m, r.height_m, kept)
            .map_err(|why| ApiError::bad_request("bad_target", why))?;
        if !self.horizons.borrow().contains_key(&key) {
            keep(&self.horizons, key, site.horizon().clone(), KEPT_HORIZONS);
        }
        Ok(Some((site, panel)))
    }

    /// What the panel of a target sees of its body's terrain, with each facet kept's
    /// albedo, when the scene scatters light and the target has a panel.
    fn terrain(&self, r: &Resolved, site: Option<&Site<'_>>) -> Option<Terrain> {
        let (albedo, site) = (self.albedo.as_ref()?, site.filter(|_| r.panel)?);
        let key = r.place_key();
        let body = &self.world.bodies[r.body];
        let kept = self.views.borrow().get(&key).cloned();
        let view = kept.unwrap_or_else(|| {
            let view = TerrainView::new(
                body.shadow_mesh(),
                body.mesh.len(),
                &self.bvhs[r.body],
                site.point(),
            );
            keep(&self.views, key, view.clone(), KEPT_HORIZONS);
            view
        });
        let offset = self.world.offsets()[r.body];
        let facets: Vec<(usize, usize)> = view
            .facets()
            .iter()
            .map(|&j| (r.body, j as usize))
            .collect();
        Some(Terrain {
            albedo: facets.iter().map(|&(_, j)| albedo[offset + j]).collect(),
            facets,
            view,
        })
    }
}

/// Keeps `value` under `key` in `cache`, emptying it first when it holds `most`.
fn keep<K: std::hash::Hash + Eq, V>(cache: &RefCell<HashMap<K, V>>, key: K, value: V, most: usize) {
    let mut kept = cache.borrow_mut();
    if kept.len() >= most {
        kept.clear();
    }
    kept.insert(key, value);
}

/// A panel's terrain: what it sees, and what each facet seen needs to give its light.
struct Terrain {
    view: TerrainView,
    /// The facets of the view as (body, facet), and each facet's albedo.
    facets: Vec<(usize, usize)>,
    albedo: Vec<f64>,
}

impl Terrain {
    /// The irradiance (W/m²) the terrain sends at `state` onto a panel of unit normal
    /// `normal`: each facet's first-order radiosity ρ·E from its direct irradiance.
    fn light(&self, direct: &Direct<'_>, state: &EpochState, normal: DVec3) -> ApiResult<f64> {
        let direct = direct
            .compute_facets(state, &self.facets)
            .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?;
        let radiosity: Vec<f64> = direct
            .iter()
            .zip(&self.albedo)
            .map(|(e, a)| e * a)
            .collect();
        Ok(self.view.irradiance(normal, &radiosity))
    }
}

/// What every step of a query needs, shared by the threads that compute the steps.
struct StepWork<'a> {
    direct: &'a Direct<'a>,
    disk: Option<&'a SolarDisk>,
    facets: Vec<(usize, usize)>,
    sites: &'a [Option<(Site<'a>, Panel)>],
    targets: &'a [Resolved],
    terrains: &'a [Option<Terrain>],
}

/// One step's epoch (TDB s) and what each target gets at it.
type StepValues = (f64, Vec<TargetStep>);

/// What one target gets at one step.
struct TargetStep {
    /// On the facet, W/m².
    facet_w_m2: f64,
    /// The panel's light, terrain's included, and the terrain's part (W/m²).
    panel: Option<(PanelLight, Option<f64>)>,
    sightings: Vec<Sighting>,
}

impl StepWork<'_> {
    /// Every target's values at `state`.
    fn at(&self, state: &EpochState) -> ApiResult<StepValues> {
        let values = self
            .direct
            .compute_facets(state, &self.facets)
            .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?;
        let mut targets = Vec::with_capacity(values.len());
        for (((facet_w_m2, site), r), terrain) in values
            .into_iter()
            .zip(self.sites)
            .zip(self.targets)
            .zip(self.terrains)
        {
            let Some((site, panel)) = site else {
                targets.push(TargetStep {
                    facet_w_m2,
                    panel: None,
                    sightings: Vec::new(),
                });
                continue;
            };
            let sightings = r
                .sight_of
                .iter()
                .map(|&t| Sighting::of(site, state, r.body, t))
                .collect();
            let sun = &state.bodies[r.body];
            let disk = self
                .disk
                .map(|d| (d, SolarDisk::angular_radius(sun.sun_distance_m)));
            let light = r
                .panel
                .then(|| -> ApiResult<PanelLight> {
                    let light = site.sunlight(panel, sun.sun_dir, sun.flux_w_m2, disk);
                    let share = self
                        .direct
                        .share_past_others(r.body, state, site.point())
                        .map_err(|e| ApiError::unprocessable("bad_scene", e.to_string()))?;
                    Ok(light.dimmed(share))
                })
                .transpose()?
                .map(|light| match terrain {
                    Some(t) => t
                        .light(self.direct, state, light.normal)
                        .map(|w| (with_terrain(light, panel, w), Some(w))),
                    None => Ok((light, None)),
                })
                .transpose()?;
            targets.push(TargetStep {
                facet_w_m2,
                panel: light,
                sightings,
            });
        }
        Ok((state.epoch.to_tdb_seconds(), targets))
    }
}

/// `light` with `terrain_w_m2` more irradiance from the terrain, and its power on `panel`.
fn with_terrain(light: PanelLight, panel: &Panel, terrain_w_m2: f64) -> PanelLight {
    let irradiance_w_m2 = light.irradiance_w_m2 + terrain_w_m2;
    PanelLight {
        irradiance_w_m2,
        power_w: irradiance_w_m2 * panel.area_m2 * panel.efficiency,
        ..light
    }
}

impl Series {
    /// Appends one step's values.
    fn push(&mut self, step: TargetStep) {
        self.irradiance_w_m2.push(step.facet_w_m2);
        for (sight, at) in self.sight.iter_mut().zip(step.sightings) {
            sight.elevation_deg.push(at.elevation.to_degrees());
            sight.horizon_deg.push(at.horizon.to_degrees());
            sight.seen.push(at.seen());
        }
        if let (Some(p), Some((light, terrain))) = (self.panel.as_mut(), step.panel) {
            p.irradiance_w_m2.push(light.irradiance_w_m2);
            p.power_w.push(light.power_w);
            p.sun_visible.push(light.sun_visible);
            if let (Some(s), Some(w)) = (p.scattered.as_mut(), terrain) {
                s.irradiance_w_m2.push(w);
            }
        }
    }
}

/// A target's series before its steps: the facet's, and the panel's and sights' when
/// asked for (`panel_point`: where its site's panel stands, if it has a site).
fn empty_series(world: &World, r: &Resolved, panel_point: Option<DVec3>, steps: usize) -> Series {
    let body = &world.bodies[r.body];
    let (lat_deg, lon_deg) = crate::output::read::lat_lon_deg(body.mesh.centroids[r.facet]);
    Series {
        body: body.name.clone(),
        facet: r.facet,
        lat_deg,
        lon_deg,
        irradiance_w_m2: Vec::with_capacity(steps),
        panel: panel_point.filter(|_| r.panel).map(|point| PanelSeries {
            height_m: r.height_m,
            point_m: point.to_array(),
            irradiance_w_m2: Vec::with_capacity(steps),
            power_w: Vec::with_capacity(steps),
            sun_visible: Vec::with_capacity(steps),
            energy_wh: 0.0,
            lit_fraction: 0.0,
            longest_dark_s: 0.0,
            battery: None,
            scattered: None,
        }),
        sight: r
            .sight_of
            .iter()
            .map(|&t| SightSeries {
                body: world.bodies[t].name.clone(),
                elevation_deg: Vec::with_capacity(steps),
                horizon_deg: Vec::with_capacity(steps),
                seen: Vec::with_capacity(steps),
                windows: Vec::new(),
            })
            .collect(),
    }
}

impl PanelSeries {
    /// The totals over the steps of `durations` (s): energy, lit share, longest darkness,
    /// and the battery's charge when one is asked for.
    fn sum_up(&mut self, durations: &[f64], battery: Option<&ChargedBattery>) {
        let joules: f64 = self
            .power_w
            .iter()
            .zip(durations)
            .map(|(w, dt)| w * dt)
            .sum();
        self.energy_wh = joules / 3600.0;
        let dark: Vec<bool> = self.sun_visible.iter().map(|&v| v == 0.0).collect();
        self.lit_fraction = dark.iter().filter(|&&d| !d).count() as f64 / dark.len() as f64;
        self.longest_dark_s = longest_run_s(&dark, durations);
        self.battery =
            battery.map(|b| b.battery.run(&self.power_w, &b.load_w, durations, b.low_wh));
    }
}

impl SightSeries {
    /// The windows in which the body is above the horizon, at epochs `t` (TDB s).
    fn windows(&self, t: &[f64]) -> Vec<crate::sight::Window> {
        let margin: Vec<f64> = self
            .elevation_deg
            .iter()
            .zip(&self.horizon_deg)
            .map(|(e, h)| e - h)
            .collect();
        windows_above(t, &margin)
    }
}

/// How long each of the steps at epochs `t` (s) lasts: until the next epoch, the last as
/// long as the one before it (0 for a single step).
fn step_durations(t: &[f64]) -> Vec<f64> {
    let last = match t {
        [.., a, b] => b - a,
        _ => 0.0,
    };
    (0..t.len())
        .map(|k| t.get(k + 1).map_or(last, |next| next - t[k]))
        .collect()
}

/// The longest run of `true` in `flags`, as the sum of those steps' `durations` (s).
fn longest_run_s(flags: &[bool], durations: &[f64]) -> f64 {
    let (mut run, mut longest) = (0.0f64, 0.0f64);
    for (&on, &dt) in flags.iter().zip(durations) {
        run = if on { run + dt } else { 0.0 };
        longest = longest.max(run);
    }
    longest
}

/// A target resolved: its body, facet and the surface point a panel stands on (metres,
/// body frame: the point given, else the facet's centroid).
struct Resolved {
    body: usize,
    facet: usize,
    surface_m: DVec3,
    /// Whether a panel's series is asked for (a height or a panel given).
    panel: bool,
    /// Height of the panel or viewpoint above the surface, m (default 1).
    height_m: f64,
    /// The bodies of `sight_of`.
    sight_of: Vec<usize>,
}

/// A target resolved, or an error naming what is wrong: an unknown body or facet, or a
/// place off the mesh ([`on_mesh`]).
fn resolve(world: &World, t: &Target) -> ApiResult<Resolved> {
    let b = match &t.body {
        None => 0,
        Some(name) => body_index(world, name)?,
    };
    let body = &world.bodies[b];
    let (facet, surface_m) = locate(body, t.facet, t.point_m, t.lat_deg, t.lon_deg)?;
    let sight_of = t
        .sight_of
        .iter()
        .enumerate()
        .map(|(k, name)| match body_index(world, name)? {
            same if same == b => Err(ApiError::bad_request(
                "bad_target",
                format!("sight_of names '{name}', the body the place is on"),
            )),
            _ if t.sight_of[..k].contains(name) => Err(ApiError::bad_request(
                "bad_target",
                format!("sight_of names '{name}' twice"),
            )),
            other => Ok(other),
        })
        .collect::<ApiResult<Vec<_>>>()?;
    Ok(Resolved {
        body: b,
        facet,
        surface_m,
        panel: t.height_m.is_some() || t.panel.is_some(),
        height_m: t.height_m.unwrap_or(1.0),
        sight_of,
    })
}

impl Resolved {
    /// The key of its place in the engine's caches.
    fn place_key(&self) -> HorizonKey {
        (
            self.body,
            self.surface_m.to_array().map(f64::to_bits),
            self.height_m.to_bits(),
        )
    }
}

/// The index of the body named `name`, or a 404 listing the names.
pub(super) fn body_index(world: &World, name: &str) -> ApiResult<usize> {
    world
        .bodies
        .iter()
        .position(|b| b.name == name)
        .ok_or_else(|| {
            let names: Vec<&str> = world.bodies.iter().map(|b| b.name.as_str()).collect();
            unknown_body(name, &names)
        })
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
    use crate::trace::TracerKind;
    use std::path::Path;

    /// Facets computed one by one get the same values, bit for bit, as the whole mesh
    /// computed by a run with the sunview tracer: with the grid tracer, and as the engine
    /// computes them (rays through the body's tree).
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
        let (world, ephemeris, _) = build(&dir, &text, &Budget::machine()).unwrap();
        let grid = Direct::new(&world, TracerKind::Grid);
        let sunview = Direct::new(&world, TracerKind::Sunview);
        let bvhs = body_trees(&world);
        let light = Light {
            shadows: Shadows::default(),
            albedo: None,
        };
        let engine = Engine::new(&world, &bvhs, ephemeris.as_ref(), light);
        let facets: Vec<(usize, usize)> = (0..world.facet_count()).map(|i| (0, i)).collect();
        let mut all = vec![0.0; world.facet_count()];
        for k in 0..ephemeris.steps() {
            let state = ephemeris.state(k).unwrap();
            sunview.compute(&state, &mut all).unwrap();
            let alone = grid.compute_facets(&state, &facets).unwrap();
            let engines = engine.direct.compute_facets(&state, &facets).unwrap();
            for (i, ((a, b), c)) in all.iter().zip(&alone).zip(&engines).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "step {k} facet {i}: {a} vs {b}");
                assert_eq!(a.to_bits(), c.to_bits(), "step {k} facet {i}: {a} vs {c}");
            }
        }
    }
}
