//! Query: facet statistics, CDFs and nearest facets of a finished job, from its files.
//!
//! In: a succeeded job's result folder (read once through [`crate::output::read`] and kept
//! in memory) and a body with facet ids, a body-fixed point (metres) or a planetocentric
//! latitude/east longitude (degrees). Out: per facet its area (m²), centroid (m, body
//! frame), normal, latitude/longitude (degrees), min/max/mean irradiance (W/m²), lit
//! fraction and optionally F(x) at the run's thresholds (W/m²); or the nearest facet.

use super::lru::Lru;
use super::reply::{ApiError, ApiResult};
use super::AppState;
use crate::output::read::{BodyData, RunData};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// Finished runs held in memory, by job id, within a byte budget.
pub struct ResultCache {
    runs: Mutex<Lru<Arc<RunData>>>,
}

impl ResultCache {
    /// An empty cache of at most `budget_bytes`.
    pub fn new(budget_bytes: u64) -> ResultCache {
        ResultCache {
            runs: Mutex::new(Lru::new(budget_bytes)),
        }
    }

    /// The finished run of job `id`, read on first use.
    pub async fn get(app: &AppState, id: &str) -> ApiResult<Arc<RunData>> {
        let dir = app.jobs.result_dir(id)?;
        if let Some(run) = app.results.lock().get(id) {
            return Ok(run);
        }
        let run = tokio::task::spawn_blocking(move || RunData::read(&dir))
            .await
            .map_err(|e| ApiError::internal(e.to_string()))?
            .map_err(|e| ApiError::internal(format!("reading the job's results: {e}")))?;
        let run = Arc::new(run);
        let bytes = run.bytes();
        app.results
            .lock()
            .insert(id.to_string(), Arc::clone(&run), bytes);
        Ok(run)
    }

    /// Drops a job's run (it was deleted).
    pub fn forget(&self, id: &str) {
        self.lock().remove(id);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Lru<Arc<RunData>>> {
        self.runs.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// `?body=NAME&ids=1,2,3&cdf=true`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FacetsQuery {
    /// Body name (default: the first body).
    pub body: Option<String>,
    /// Comma-separated facet ids.
    pub ids: String,
    /// Also return F(x) per facet.
    #[serde(default)]
    pub cdf: bool,
}

/// One facet's row of a facets answer: its geometry and statistics.
#[derive(Debug, Serialize)]
pub struct FacetRow {
    pub facet: usize,
    pub area_m2: f64,
    pub centroid_m: [f64; 3],
    pub normal: [f64; 3],
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub min_w_m2: f64,
    pub max_w_m2: f64,
    pub mean_w_m2: f64,
    pub lit_fraction: f64,
    /// F(x) at `cdf_thresholds_w_m2`, when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cdf: Option<Vec<f64>>,
}

/// The answer to a facets query.
#[derive(Debug, Serialize)]
pub struct FacetsAnswer {
    pub body: String,
    pub facets: Vec<FacetRow>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cdf_thresholds_w_m2: Option<Vec<f64>>,
}

/// Statistics (and CDFs) of the asked facets.
pub fn facets(run: &RunData, q: &FacetsQuery, max_targets: usize) -> ApiResult<FacetsAnswer> {
    let body = find_body(run, q.body.as_deref())?;
    let ids = parse_ids(&q.ids, max_targets)?;
    let facets = ids
        .into_iter()
        .map(|k| {
            check_facet(&body.name, body.facets.len(), k)?;
            let f = &body.facets;
            let (lat_deg, lon_deg) = f.lat_lon_deg(k);
            Ok(FacetRow {
                facet: k,
                area_m2: f.area_m2[k],
                centroid_m: f.centroid_m[k].to_array(),
                normal: f.normal[k].to_array(),
                lat_deg,
                lon_deg,
                min_w_m2: f.min_w_m2[k],
                max_w_m2: f.max_w_m2[k],
                mean_w_m2: f.mean_w_m2[k],
                lit_fraction: f.lit_fraction[k],
                cdf: q.cdf.then(|| body.cdf.facet(k).to_vec()),
            })
        })
        .collect::<ApiResult<Vec<_>>>()?;
    Ok(FacetsAnswer {
        body: body.name.clone(),
        facets,
        cdf_thresholds_w_m2: q.cdf.then(|| body.cdf.thresholds_w_m2.clone()),
    })
}

/// A body of the run by name (none: the first).
pub fn find_body<'r>(run: &'r RunData, name: Option<&str>) -> ApiResult<&'r BodyData> {
    match name {
        None => run.bodies.first(),
        Some(n) => run.bodies.iter().find(|b| b.name == n),
    }
    .ok_or_else(|| {
        let names: Vec<&str> = run.bodies.iter().map(|b| b.name.as_str()).collect();
        unknown_body(name.unwrap_or(""), &names)
    })
}

/// 404 for a body name that is not in the scene.
pub fn unknown_body(name: &str, names: &[&str]) -> ApiError {
    ApiError::not_found(
        "unknown_body",
        format!("no body '{name}' (bodies: {})", names.join(", ")),
    )
}

/// 404 unless `facet` is an id of a body with `count` facets.
pub fn check_facet(body: &str, count: usize, facet: usize) -> ApiResult<()> {
    if facet < count {
        return Ok(());
    }
    Err(ApiError::not_found(
        "unknown_facet",
        format!(
            "body '{body}' has {count} facets (ids 0 to {}); there is no facet {facet}",
            count.saturating_sub(1)
        ),
    ))
}

fn parse_ids(text: &str, max: usize) -> ApiResult<Vec<usize>> {
    let ids = text
        .split(',')
        .map(|t| {
            t.trim().parse::<usize>().map_err(|_| {
                ApiError::bad_request(
                    "bad_facet_id",
                    format!("'{t}' is not a facet id (a whole number ≥ 0)"),
                )
            })
        })
        .collect::<ApiResult<Vec<_>>>()?;
    if ids.len() > max {
        return Err(ApiError::unprocessable(
            "limit_exceeded",
            format!("{} facets asked; at most {max} per query", ids.len()),
        ));
    }
    Ok(ids)
}

/// Where on a body: a body-fixed point or a latitude/longitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Place {
    /// Body-fixed point, metres.
    Point(DVec3),
    /// Planetocentric latitude and east-positive longitude, degrees.
    LatLon { lat_deg: f64, lon_deg: f64 },
}

impl Place {
    /// The unit direction of the place from the body's centre (body frame).
    pub fn direction(self) -> DVec3 {
        match self {
            Place::Point(p) => p.normalize_or_zero(),
            Place::LatLon { lat_deg, lon_deg } => {
                let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
                DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin())
            }
        }
    }

    /// From optional query fields: exactly a full point or a full lat/lon, finite.
    pub fn from_parts(
        point: Option<[f64; 3]>,
        lat: Option<f64>,
        lon: Option<f64>,
    ) -> ApiResult<Place> {
        let place =
            match (point, lat, lon) {
                (Some(p), None, None) if p.iter().all(|x| x.is_finite()) => {
                    Place::Point(DVec3::from_array(p))
                }
                (None, Some(lat), Some(lon))
                    if lat.is_finite() && lon.is_finite() && lat.abs() <= 90.0 =>
                {
                    Place::LatLon {
                        lat_deg: lat,
                        lon_deg: lon,
                    }
                }
                _ => return Err(ApiError::bad_request(
                    "bad_place",
                    "give either a point (x_m, y_m, z_m) or lat_deg (within ±90) and lon_deg, as \
                     finite numbers",
                )),
            };
        Ok(place)
    }
}

/// The facet whose centroid is nearest to `place`: by distance for a point, by angle
/// between centroid directions for a latitude/longitude. None for an empty body.
pub fn nearest_facet(centroids: &[DVec3], place: Place) -> Option<usize> {
    let dir = place.direction();
    let score = |c: DVec3| match place {
        Place::Point(p) => c.distance_squared(p),
        Place::LatLon { .. } => -c.normalize_or_zero().dot(dir),
    };
    centroids
        .iter()
        .enumerate()
        .filter(|(_, c)| c.is_finite())
        .min_by(|a, b| score(*a.1).total_cmp(&score(*b.1)))
        .map(|(k, _)| k)
}

/// `?body=NAME&lat_deg=..&lon_deg=..` or `?body=NAME&x_m=..&y_m=..&z_m=..`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NearestQuery {
    pub body: Option<String>,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    pub x_m: Option<f64>,
    pub y_m: Option<f64>,
    pub z_m: Option<f64>,
}

impl NearestQuery {
    /// The place asked for.
    pub fn place(&self) -> ApiResult<Place> {
        let point = match (self.x_m, self.y_m, self.z_m) {
            (None, None, None) => None,
            (Some(x), Some(y), Some(z)) => Some([x, y, z]),
            _ => {
                return Err(ApiError::bad_request(
                    "bad_place",
                    "a point needs all of x_m, y_m and z_m",
                ))
            }
        };
        Place::from_parts(point, self.lat_deg, self.lon_deg)
    }
}

/// The facet and surface point (m, body frame) of a place on `body` given as a facet id
/// (its centroid), a body-fixed point or a latitude and longitude (the nearest facet,
/// [`on_mesh`]); exactly one of the three.
pub fn locate(
    body: &crate::world::Body,
    facet: Option<usize>,
    point_m: Option<[f64; 3]>,
    lat_deg: Option<f64>,
    lon_deg: Option<f64>,
) -> ApiResult<(usize, DVec3)> {
    let has_place = point_m.is_some() || lat_deg.is_some() || lon_deg.is_some();
    match (facet, has_place) {
        (Some(i), false) => {
            check_facet(&body.name, body.mesh.len(), i)?;
            Ok((i, body.mesh.centroids[i]))
        }
        (None, true) => {
            let place = Place::from_parts(point_m, lat_deg, lon_deg)?;
            let i = nearest_facet(&body.mesh.centroids, place).ok_or_else(|| {
                ApiError::unprocessable("empty_body", format!("body '{}' has no facets", body.name))
            })?;
            let c = body.mesh.centroids[i];
            Ok((i, on_mesh(&body.name, i, c, body.mesh.areas[i], place)?))
        }
        _ => Err(ApiError::bad_request(
            "bad_target",
            "each target gives either facet, or point_m, or lat_deg and lon_deg",
        )),
    }
}

/// The surface point of a place whose nearest facet (on body `body`) is `facet`, with
/// centroid `c` (m) and area `area_m2`: the point itself, or the centroid for a latitude
/// and longitude. A place farther from that centroid than three facet sizes (2√area;
/// along the surface for a latitude and longitude) is refused, with how far it is.
pub fn on_mesh(body: &str, facet: usize, c: DVec3, area_m2: f64, place: Place) -> ApiResult<DVec3> {
    let size = 2.0 * area_m2.max(0.0).sqrt();
    let dir = place.direction();
    let (apart_m, how_far) = match place {
        Place::Point(p) => {
            let d = p.distance(c);
            (d, format!("{d:.1} m"))
        }
        Place::LatLon { .. } => {
            let angle = dir.cross(c).length().atan2(dir.dot(c));
            (angle * c.length(), format!("{:.2}°", angle.to_degrees()))
        }
    };
    if apart_m > 3.0 * size {
        let (lat, lon) = crate::output::read::lat_lon_deg(c);
        return Err(ApiError::unprocessable(
            "off_mesh",
            format!(
                "the place is {how_far} from the nearest facet of body '{body}' (facet {facet} \
                 at lat {lat:.2}°, lon {lon:.2}°, about {size:.1} m across): give a place on the mesh"
            ),
        ));
    }
    Ok(match place {
        Place::Point(p) => p,
        Place::LatLon { .. } => c,
    })
}

/// The nearest facet.
#[derive(Debug, Serialize)]
pub struct NearestAnswer {
    pub body: String,
    pub facet: usize,
    pub centroid_m: [f64; 3],
    pub lat_deg: f64,
    pub lon_deg: f64,
}

/// The facet of the asked body nearest to the asked place.
pub fn nearest(run: &RunData, q: &NearestQuery) -> ApiResult<NearestAnswer> {
    let body = find_body(run, q.body.as_deref())?;
    let place = q.place()?;
    let facet = nearest_facet(&body.facets.centroid_m, place).ok_or_else(|| {
        ApiError::unprocessable("empty_body", format!("body '{}' has no facets", body.name))
    })?;
    on_mesh(
        &body.name,
        facet,
        body.facets.centroid_m[facet],
        body.facets.area_m2[facet],
        place,
    )?;
    let (lat_deg, lon_deg) = body.facets.lat_lon_deg(facet);
    Ok(NearestAnswer {
        body: body.name.clone(),
        facet,
        centroid_m: body.facets.centroid_m[facet].to_array(),
        lat_deg,
        lon_deg,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_by_point_and_by_direction() {
        let c = [
            DVec3::new(1000.0, 0.0, 0.0),
            DVec3::new(0.0, 2000.0, 0.0),
            DVec3::new(0.0, 0.0, -500.0),
        ];
        assert_eq!(
            nearest_facet(&c, Place::Point(DVec3::new(0.0, 1500.0, 0.0))),
            Some(1)
        );
        let south = Place::LatLon {
            lat_deg: -80.0,
            lon_deg: 10.0,
        };
        assert_eq!(nearest_facet(&c, south), Some(2));
        let east = Place::LatLon {
            lat_deg: 0.0,
            lon_deg: 80.0,
        };
        assert_eq!(nearest_facet(&c, east), Some(1));
        assert_eq!(nearest_facet(&[], east), None);
    }

    #[test]
    fn ids_are_checked() {
        assert_eq!(parse_ids("1, 2,3", 8).unwrap(), vec![1, 2, 3]);
        assert_eq!(parse_ids("1,x", 8).unwrap_err().code, "bad_facet_id");
        assert_eq!(parse_ids("-1", 8).unwrap_err().code, "bad_facet_id");
        assert_eq!(parse_ids("1,2,3", 2).unwrap_err().code, "limit_exceeded");
        assert_eq!(check_facet("a", 3, 3).unwrap_err().code, "unknown_facet");
    }
}
