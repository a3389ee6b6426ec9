//! Traverse: the service's route query — plan a rover's route between two places, or
//! evaluate one through waypoints — on a job's scene, answered as GeoJSON-like JSON.
//!
//! In: a scene and a [`RouteRequest`] (body, `from` and `to` or `waypoints`, each a facet
//! id, a body-fixed point in metres or a latitude/east longitude in degrees; the
//! departure step or epoch; the rover: speed m/s, slope limit degrees, deck panel, battery
//! Wh, loads W; cost weights). Out: a [`RouteAnswer`], a GeoJSON `Feature` whose
//! `LineString` runs through the visited facets' centroids as [longitude °, latitude °,
//! radius m], with the route's times (TDB s and UTC), charge, legs and totals in its
//! `properties` ([`crate::route`] has the model). The light comes from the scene's own
//! step loop from the departure on, so it is what `slim run` computes for those facets.

use super::limits::RouteLimits;
use super::points::body_index;
use super::query::locate;
use super::reply::{ApiError, ApiResult};
use super::scene_input::bad_scene;
use crate::budget::{Budget, Estimate, Item};
use crate::ephemeris::utc_text;
use crate::ephemeris::EpochState;
use crate::prepare::prepare;
use crate::progress::{Progress, Timings};
use crate::route::gravity::up_vectors;
use crate::route::{
    self, evaluate, Light, Model, Route, Rover, SearchLimits, Terrain, Waypoint, Weights,
};
use crate::scene::Scene;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// The request body.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteRequest {
    /// Body driven on (default: the first).
    pub body: Option<String>,
    /// To plan: where the rover starts and where it goes.
    pub from: Option<Stop>,
    pub to: Option<Stop>,
    /// To evaluate: the places it drives through, in order (at least two).
    pub waypoints: Option<Vec<Stop>>,
    /// Departure: the first step at or after this epoch (TDB s past J2000) ...
    pub depart_tdb_s: Option<f64>,
    /// ... or this step (default 0).
    #[serde(default)]
    pub depart_step: usize,
    pub rover: RoverSpec,
    #[serde(default)]
    pub weights: WeightsSpec,
    /// Quanta per step (default: a median edge takes at least four).
    pub substeps: Option<u32>,
    /// Most labels the planner takes (default and upper bound: the service's limit).
    pub max_labels: Option<usize>,
    /// Slopes from the local vertical of the body's gravity and spin instead of the
    /// radial direction.
    pub gravity: Option<GravitySpec>,
    /// The plan may cost up to `1 + optimality_gap` times the cheapest route (default 0:
    /// the cheapest); a gap of 0.2 to 0.5 makes long routes much faster to find.
    #[serde(default)]
    pub optimality_gap: f64,
}

/// The body's gravity: a uniform density; the spin comes from the scene.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GravitySpec {
    pub density_kg_m3: f64,
}

/// A place on the route: a facet, a point or a latitude and longitude; on a waypoint,
/// optionally the epoch before which the rover does not leave it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stop {
    pub facet: Option<usize>,
    pub point_m: Option<[f64; 3]>,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    pub depart_tdb_s: Option<f64>,
}

/// The rover as a request gives it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoverSpec {
    pub speed_m_s: f64,
    /// Default 20.
    #[serde(default = "twenty")]
    pub max_slope_deg: f64,
    #[serde(default)]
    pub panel: DeckPanel,
    pub battery: RoverBattery,
    /// Default 0.
    #[serde(default)]
    pub idle_load_w: f64,
    /// Default: the idle load.
    pub drive_load_w: Option<f64>,
}

/// The panel on the deck, lying flat.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeckPanel {
    #[serde(default = "one")]
    pub area_m2: f64,
    #[serde(default = "one")]
    pub efficiency: f64,
}

impl Default for DeckPanel {
    fn default() -> DeckPanel {
        DeckPanel {
            area_m2: 1.0,
            efficiency: 1.0,
        }
    }
}

/// The rover's battery.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoverBattery {
    pub capacity_wh: f64,
    /// Default: full.
    pub initial_wh: Option<f64>,
    #[serde(default = "one")]
    pub charge_efficiency: f64,
    #[serde(default = "one")]
    pub discharge_efficiency: f64,
    /// Least charge allowed, Wh (default 0).
    #[serde(default)]
    pub min_charge_wh: f64,
}

/// Cost weights (each default 1).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WeightsSpec {
    #[serde(default = "one")]
    pub illumination: f64,
    #[serde(default = "one")]
    pub slope: f64,
    #[serde(default = "one")]
    pub roughness: f64,
    #[serde(default = "one")]
    pub waiting: f64,
}

impl Default for WeightsSpec {
    fn default() -> WeightsSpec {
        let w = Weights::default();
        WeightsSpec {
            illumination: w.illumination,
            slope: w.slope,
            roughness: w.roughness,
            waiting: w.waiting,
        }
    }
}

fn one() -> f64 {
    1.0
}
fn twenty() -> f64 {
    20.0
}

impl RouteRequest {
    /// The request in a body, or a 400 saying why it is not one.
    pub fn from_body(body: &[u8]) -> ApiResult<RouteRequest> {
        serde_json::from_slice(body)
            .map_err(|e| ApiError::bad_request("malformed_body", format!("not a route query: {e}")))
    }
}

/// The answer: a GeoJSON Feature.
#[derive(Debug, Clone, Serialize)]
pub struct RouteAnswer {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub geometry: LineString,
    pub properties: RouteProperties,
}

/// The route's line: [longitude °, latitude °, radius m] per visited facet.
#[derive(Debug, Clone, Serialize)]
pub struct LineString {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub coordinates: Vec<[f64; 3]>,
}

/// What is known of the route besides its line.
#[derive(Debug, Clone, Serialize)]
pub struct RouteProperties {
    pub body: String,
    /// "plan" or "evaluate".
    pub mode: &'static str,
    /// Arrival at each visited facet, UTC.
    pub arrive_utc: Vec<String>,
    #[serde(flatten)]
    pub route: Route,
    /// The cost's total, metres-equivalent (its terms are in `cost`).
    pub cost_total: f64,
    /// The window searched: its first step and epoch, and its steps.
    pub first_step: usize,
    pub steps: usize,
    /// Labels the planner took (0 when evaluating).
    pub labels: usize,
    /// Wall time computing the light (the scene's step loop) and searching or walking
    /// the route, s.
    pub light_s: f64,
    pub search_s: f64,
}

/// Answers `request` on `scene`, within `limits`; `progress` sees the scene's step loop.
/// Errors about the scene show its paths relative to `dir` when one is given (the
/// service's data folder). The request itself is checked before anything is built.
pub fn answer(
    dir: Option<&Path>,
    scene: &Scene,
    request: &RouteRequest,
    limits: &RouteLimits,
    progress: &dyn Progress,
) -> ApiResult<RouteAnswer> {
    let scene_error = |e: &crate::Error| match dir {
        Some(dir) => bad_scene(dir, e),
        None => ApiError::unprocessable("bad_scene", e.to_string()),
    };
    let stops = stops(request, limits)?;
    if let Some(g) = &request.gravity {
        if !(g.density_kg_m3.is_finite() && g.density_kg_m3 > 0.0) {
            return Err(ApiError::bad_request(
                "bad_route",
                "gravity.density_kg_m3 must be above 0",
            ));
        }
    }
    let rover = rover(&request.rover)?;
    let weights = weights(&request.weights)?;
    let search = search_limits(request, limits)?;
    let prepared =
        prepare(scene, &limits.budget, &mut Timings::default()).map_err(|e| scene_error(&e))?;
    let world = &prepared.assembly.world;
    let b = match &request.body {
        None => 0,
        Some(name) => body_index(world, name)?,
    };
    let body = &world.bodies[b];
    let facets = stops
        .iter()
        .map(|s| Ok(locate(body, s.facet, s.point_m, s.lat_deg, s.lon_deg)?.0 as u32))
        .collect::<ApiResult<Vec<u32>>>()?;
    let first_step = departure_step(request, &prepared.states)?;
    let terrain = match &request.gravity {
        None => Terrain::new(&body.mesh),
        Some(g) => {
            let spin = spin_rad_s(&prepared.states, b, first_step)?;
            Terrain::with_up(&body.mesh, &up_vectors(&body.mesh, g.density_kg_m3, spin))
        }
    };
    let name = body.name.clone();
    if request.to.is_some() {
        check_ends(&terrain, &rover, &facets)?;
    }
    let clock = Instant::now();
    let light = Light::compute(prepared, b, first_step, &limits.budget, progress)
        .map_err(|e| scene_error(&e))?;
    let light_s = clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let model = Model::new(&terrain, &light, rover, weights, request.substeps)
        .map_err(|why| ApiError::bad_request("bad_route", why))?;
    let (route, labels) = match request.to {
        Some(_) => walk_plan(&model, &facets, search)?,
        None => {
            let waypoints = waypoints(&model, &stops, &facets)?;
            let route = evaluate(&model, &waypoints, 0)
                .map_err(|why| ApiError::bad_request("bad_route", why))?;
            (route, 0)
        }
    };
    let times_s = (light_s, clock.elapsed().as_secs_f64());
    Ok(feature(&name, &terrain, &light, (route, labels), times_s))
}

/// Body `b`'s angular velocity (rad/s, body frame) from its poses at `step` and the
/// next: the rotation between them over their interval. Refused when the body turns so
/// far in a step that the turn is ambiguous.
fn spin_rad_s(states: &[EpochState], b: usize, step: usize) -> ApiResult<DVec3> {
    let (s0, s1) = (&states[step], &states[step + 1]);
    let dt = s1.epoch.to_tdb_seconds() - s0.epoch.to_tdb_seconds();
    let q = s0.bodies[b].pose.body_to_scene.transpose() * s1.bodies[b].pose.body_to_scene;
    let cos = ((q.x_axis.x + q.y_axis.y + q.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
    let angle = cos.acos();
    if angle > 150f64.to_radians() || dt.is_nan() || dt <= 0.0 {
        return Err(ApiError::bad_request(
            "bad_route",
            format!(
                "the body turns {:.0}° between steps {step} and {}: too far to tell its spin \
                 for gravity; use a scene with shorter steps",
                angle.to_degrees(),
                step + 1
            ),
        ));
    }
    // The axis from the antisymmetric part: (Q − Qᵀ)/2 = sin θ [axis]×.
    let axis = DVec3::new(
        q.y_axis.z - q.z_axis.y,
        q.z_axis.x - q.x_axis.z,
        q.x_axis.y - q.y_axis.x,
    )
    .normalize_or_zero();
    Ok(axis * (angle / dt))
}

/// The search's limits a request asks for, within the service's; a plan's search is
/// refused here when its labels could outgrow the memory budget.
fn search_limits(request: &RouteRequest, limits: &RouteLimits) -> ApiResult<SearchLimits> {
    let bad = |why: String| ApiError::bad_request("bad_route", why);
    let max_labels = request.max_labels.unwrap_or(limits.max_labels);
    if max_labels > limits.max_labels {
        return Err(bad(format!(
            "max_labels {max_labels}: at most {}",
            limits.max_labels
        )));
    }
    let gap = request.optimality_gap;
    if !(gap.is_finite() && gap >= 0.0) {
        return Err(bad("optimality_gap must be finite and ≥ 0".into()));
    }
    check_search_memory(&limits.budget, max_labels, request.to.is_some())?;
    Ok(SearchLimits { max_labels, gap })
}

/// The cost weights of a request, or a 400.
fn weights(spec: &WeightsSpec) -> ApiResult<Weights> {
    let weights = Weights {
        illumination: spec.illumination,
        slope: spec.slope,
        roughness: spec.roughness,
        waiting: spec.waiting,
    };
    weights
        .check()
        .map_err(|why| ApiError::bad_request("bad_route", why))?;
    Ok(weights)
}

/// The stops of a plan (from, to) or an evaluation (the waypoints), checked for shape.
fn stops(request: &RouteRequest, limits: &RouteLimits) -> ApiResult<Vec<Stop>> {
    let bad = |why: String| ApiError::bad_request("bad_route", why);
    match (&request.from, &request.to, &request.waypoints) {
        (Some(from), Some(to), None) => {
            if from.depart_tdb_s.is_some() || to.depart_tdb_s.is_some() {
                return Err(bad(
                    "depart_tdb_s belongs on waypoints; a plan departs at the request's \
                     depart_tdb_s or depart_step"
                        .into(),
                ));
            }
            Ok(vec![from.clone(), to.clone()])
        }
        (None, None, Some(list)) if (2..=limits.max_waypoints).contains(&list.len()) => {
            Ok(list.clone())
        }
        (None, None, Some(list)) => Err(bad(format!(
            "{} waypoints: give 2 to {}",
            list.len(),
            limits.max_waypoints
        ))),
        _ => Err(bad(
            "give either from and to (to plan a route) or waypoints (to evaluate one)".into(),
        )),
    }
}

/// The scene step the route departs at.
fn departure_step(request: &RouteRequest, states: &[EpochState]) -> ApiResult<usize> {
    let step = match request.depart_tdb_s {
        Some(t) if t.is_finite() => states.partition_point(|s| s.epoch.to_tdb_seconds() < t),
        Some(_) => {
            return Err(ApiError::bad_request(
                "bad_route",
                "depart_tdb_s must be finite",
            ))
        }
        None => request.depart_step,
    };
    if step + 1 >= states.len() {
        return Err(ApiError::bad_request(
            "bad_route",
            format!(
                "the departure (step {step}) leaves no step to drive in: the scene has steps \
                 0 to {}",
                states.len().saturating_sub(1)
            ),
        ));
    }
    Ok(step)
}

/// Refuses a plan whose search could outgrow `budget` at `max_labels` labels.
fn check_search_memory(budget: &Budget, max_labels: usize, planning: bool) -> ApiResult<()> {
    if !planning {
        return Ok(());
    }
    let estimate = Estimate {
        items: vec![Item {
            what: "route search labels".into(),
            bytes: (max_labels as u64).saturating_mul(route::BYTES_PER_LABEL),
            shrink: "give a smaller max_labels".into(),
        }],
    };
    budget
        .check(&estimate)
        .map_err(|e| ApiError::unprocessable("limit_exceeded", e.to_string()))
}

/// The rover of a request, or a 400 naming the bad field.
fn rover(spec: &RoverSpec) -> ApiResult<Rover> {
    let b = &spec.battery;
    let battery = crate::panel::Battery::checked(
        b.capacity_wh,
        b.initial_wh,
        b.charge_efficiency,
        b.discharge_efficiency,
    )
    .map_err(|(field, why)| {
        ApiError::bad_request("bad_route", format!("rover.battery.{field}: {why}"))
    })?;
    let rover = Rover {
        speed_m_s: spec.speed_m_s,
        max_slope_deg: spec.max_slope_deg,
        panel_area_m2: spec.panel.area_m2,
        panel_efficiency: spec.panel.efficiency,
        battery,
        min_charge_wh: b.min_charge_wh,
        idle_load_w: spec.idle_load_w,
        drive_load_w: spec.drive_load_w.unwrap_or(spec.idle_load_w),
    };
    rover
        .check()
        .map_err(|why| ApiError::bad_request("bad_route", format!("rover.{why}")))?;
    Ok(rover)
}

/// A 422 unless the rover may stand on both ends of a plan (`facets`: from, to).
fn check_ends(terrain: &Terrain, rover: &Rover, facets: &[u32]) -> ApiResult<()> {
    for (which, f) in [("from", facets[0]), ("to", facets[1])] {
        if terrain.slope_deg[f as usize] > rover.max_slope_deg {
            return Err(ApiError::unprocessable(
                "no_route",
                format!(
                    "the {which} facet {f} slopes {:.1}°, steeper than the rover's \
                     max_slope_deg {}",
                    terrain.slope_deg[f as usize], rover.max_slope_deg
                ),
            ));
        }
    }
    Ok(())
}

/// The planned route between the two `facets` and the labels the search took.
fn walk_plan(model: &Model, facets: &[u32], limits: SearchLimits) -> ApiResult<(Route, usize)> {
    let (from, to) = (facets[0], facets[1]);
    let found = route::plan(model, from, to, 0, limits)
        .map_err(|why| ApiError::unprocessable("no_route", why))?;
    let route = Route::walk(model, from, 0, found.actions.iter().copied())
        .map_err(|why| ApiError::internal(format!("the planned route does not walk: {why}")))?;
    Ok((route, found.labels))
}

/// The waypoints of an evaluation, with their departure quanta.
fn waypoints(model: &Model, stops: &[Stop], facets: &[u32]) -> ApiResult<Vec<Waypoint>> {
    stops
        .iter()
        .zip(facets)
        .map(|(s, &facet)| {
            let depart_quantum = match s.depart_tdb_s {
                None => None,
                Some(t) if t.is_finite() => {
                    let q = ((t - model.epoch(0)) / model.quantum_s()).ceil();
                    Some(q.clamp(0.0, f64::from(model.quanta())) as u32)
                }
                Some(_) => {
                    return Err(ApiError::bad_request(
                        "bad_route",
                        "waypoints' depart_tdb_s must be finite",
                    ))
                }
            };
            Ok(Waypoint {
                facet,
                depart_quantum,
            })
        })
        .collect()
}

/// The route (with the labels its plan took: at least one; 0 for an evaluation) as a
/// GeoJSON Feature,
/// with the seconds spent on the light and on the search.
fn feature(
    body: &str,
    terrain: &Terrain,
    light: &Light,
    (route, labels): (Route, usize),
    (light_s, search_s): (f64, f64),
) -> RouteAnswer {
    let coordinates = route
        .facets
        .iter()
        .map(|&f| {
            let c = terrain.centroids[f as usize];
            let (lat, lon) = crate::output::read::lat_lon_deg(c);
            [lon, lat, c.length()]
        })
        .collect();
    RouteAnswer {
        kind: "Feature",
        geometry: LineString {
            kind: "LineString",
            coordinates,
        },
        properties: RouteProperties {
            body: body.to_string(),
            mode: if labels > 0 { "plan" } else { "evaluate" },
            arrive_utc: route.arrive_tdb_s.iter().map(|&t| utc_text(t)).collect(),
            cost_total: route.cost.total(),
            route,
            first_step: light.first_step,
            steps: light.steps(),
            labels,
            light_s,
            search_s,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ephemeris::BodyState;
    use crate::world::Pose;
    use glam::DMat3;
    use hifitime::Epoch;

    /// A body turning about an inclined axis at a known rate: the spin read from two of
    /// its poses is that rate about that axis; a turn of more than 150° in a step is
    /// refused.
    #[test]
    fn the_spin_comes_from_two_poses() {
        let axis = DVec3::new(0.3, -0.2, 0.9).normalize();
        let rate = 2.0 * std::f64::consts::PI / (5.27 * 3600.0);
        let state = |t: f64| EpochState {
            step: 0,
            epoch: Epoch::from_tdb_seconds(t),
            bodies: vec![BodyState {
                sun_dir: DVec3::X,
                sun_distance_m: 1e11,
                flux_w_m2: 1000.0,
                pose: Pose {
                    body_to_scene: DMat3::from_rotation_x(0.4)
                        * DMat3::from_axis_angle(axis, rate * t),
                    position_m: DVec3::ZERO,
                },
            }],
        };
        let spin = spin_rad_s(&[state(100.0), state(3894.0)], 0, 0).unwrap();
        assert!(
            (spin - axis * rate).length() < 1e-12 * rate.max(1.0),
            "{spin}"
        );
        let err = spin_rad_s(&[state(0.0), state(2.5 * 3600.0)], 0, 0).unwrap_err();
        assert!(err.message.contains("too far"), "{}", err.message);
    }
}
