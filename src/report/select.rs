//! Choosing the facets whose F_k(x) curves are plotted.
//!
//! In: the run's facets (centroids in metres, means in W/m², lit fractions) and the user's
//! requests: `BODY:ID` references and `LAT,LON` points (degrees, planetocentric latitude,
//! east-positive longitude). Out: the chosen facets with the reason each was chosen and
//! their centroid latitude/longitude. Without requests, a spread: brightest, darkest lit,
//! median mean, most polar, most equatorial (a facet chosen twice is listed once).

use crate::error::{Error, Result};
use crate::output::read::{BodyData, RunData};
use std::str::FromStr;

/// A facet named by body and id: `BODY:ID`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FacetRef {
    pub body: String,
    pub facet: usize,
}

impl FromStr for FacetRef {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<FacetRef, String> {
        let (body, id) = s
            .rsplit_once(':')
            .ok_or_else(|| format!("'{s}': expected BODY:ID, e.g. phobos:1000"))?;
        let facet = id
            .trim()
            .parse()
            .map_err(|_| format!("'{s}': the facet id '{id}' is not a whole number"))?;
        Ok(FacetRef {
            body: body.trim().to_string(),
            facet,
        })
    }
}

/// A point on the body: planetocentric latitude and east-positive longitude, degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatLon {
    pub lat_deg: f64,
    pub lon_deg: f64,
}

impl FromStr for LatLon {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<LatLon, String> {
        let parse = |t: &str| t.trim().parse::<f64>().ok().filter(|x| x.is_finite());
        let (lat, lon) = s
            .split_once(',')
            .and_then(|(a, b)| Some((parse(a)?, parse(b)?)))
            .ok_or_else(|| format!("'{s}': expected LAT,LON in degrees, e.g. 30,-45"))?;
        if lat.abs() > 90.0 {
            return Err(format!("'{s}': latitude must be within ±90°"));
        }
        Ok(LatLon {
            lat_deg: lat,
            lon_deg: lon,
        })
    }
}

/// A facet chosen for the CDF plot.
#[derive(Debug, Clone, PartialEq)]
pub struct Chosen {
    /// Index into [`RunData::bodies`].
    pub body: usize,
    pub facet: usize,
    /// Why it was chosen (e.g. "brightest").
    pub why: String,
    pub lat_deg: f64,
    pub lon_deg: f64,
}

/// The facets to plot: the requested ones, or the default spread.
pub fn choose(run: &RunData, facets: &[FacetRef], near: &[LatLon]) -> Result<Vec<Chosen>> {
    let mut chosen = Vec::new();
    for r in facets {
        let (body, facet) = find_ref(run, r)?;
        push_unique(
            &mut chosen,
            run,
            body,
            facet,
            format!("--facet {}:{}", r.body, r.facet),
        );
    }
    for p in near {
        if let Some((body, facet)) = nearest(run, *p) {
            let why = format!("nearest to {}°, {}°", p.lat_deg, p.lon_deg);
            push_unique(&mut chosen, run, body, facet, why);
        }
    }
    if facets.is_empty() && near.is_empty() {
        for (why, pick) in default_spread(run) {
            if let Some((body, facet)) = pick {
                push_unique(&mut chosen, run, body, facet, why.to_string());
            }
        }
    }
    Ok(chosen)
}

fn find_ref(run: &RunData, r: &FacetRef) -> Result<(usize, usize)> {
    let body = run
        .bodies
        .iter()
        .position(|b| b.name == r.body)
        .ok_or_else(|| {
            let names: Vec<&str> = run.bodies.iter().map(|b| b.name.as_str()).collect();
            Error::Usage(format!(
                "--facet {}:{}: no body '{}' in this run (bodies: {})",
                r.body,
                r.facet,
                r.body,
                names.join(", ")
            ))
        })?;
    let n = run.bodies[body].facets.len();
    if r.facet >= n {
        return Err(Error::Usage(format!(
            "--facet {}:{}: body '{}' has {n} facets (ids 0 to {})",
            r.body,
            r.facet,
            r.body,
            n.saturating_sub(1)
        )));
    }
    Ok((body, r.facet))
}

/// Adds a facet, or appends the reason to the entry that already holds it.
fn push_unique(chosen: &mut Vec<Chosen>, run: &RunData, body: usize, facet: usize, why: String) {
    if let Some(c) = chosen
        .iter_mut()
        .find(|c| c.body == body && c.facet == facet)
    {
        c.why = format!("{}, {why}", c.why);
        return;
    }
    let (lat_deg, lon_deg) = run.bodies[body].facets.lat_lon_deg(facet);
    chosen.push(Chosen {
        body,
        facet,
        why,
        lat_deg,
        lon_deg,
    });
}

/// Every facet of the first body (the body of interest; later bodies are usually
/// occluders such as a planet) with a finite value of `key`, as (body, facet).
fn scored(run: &RunData, key: impl Fn(&BodyData, usize) -> f64) -> Vec<((usize, usize), f64)> {
    let Some(body) = run.bodies.first() else {
        return Vec::new();
    };
    (0..body.facets.len())
        .filter_map(|k| {
            let v = key(body, k);
            v.is_finite().then_some(((0, k), v))
        })
        .collect()
}

/// The (body, facet) minimising `key`.
fn argmin(run: &RunData, key: impl Fn(&BodyData, usize) -> f64) -> Option<(usize, usize)> {
    scored(run, key)
        .into_iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(id, _)| id)
}

/// The facet nearest to `p` by angle between centroid directions.
pub fn nearest(run: &RunData, p: LatLon) -> Option<(usize, usize)> {
    let (lat, lon) = (p.lat_deg.to_radians(), p.lon_deg.to_radians());
    let target = glam::DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
    argmin(run, |b, k| {
        -b.facets.centroid_m[k].normalize_or_zero().dot(target)
    })
}

/// The default spread of facets, with the reason for each.
fn default_spread(run: &RunData) -> Vec<(&'static str, Option<(usize, usize)>)> {
    let mean = |b: &BodyData, k: usize| b.facets.mean_w_m2[k];
    let lat = |b: &BodyData, k: usize| b.facets.lat_lon_deg(k).0.abs();
    let darkest_lit = |b: &BodyData, k: usize| {
        if b.facets.lit_fraction[k] > 0.0 {
            b.facets.mean_w_m2[k]
        } else {
            f64::NAN
        }
    };
    vec![
        ("brightest", argmin(run, |b, k| -mean(b, k))),
        ("darkest lit", argmin(run, darkest_lit)),
        ("median mean", median(run)),
        ("most polar", argmin(run, |b, k| -lat(b, k))),
        ("most equatorial", argmin(run, lat)),
    ]
}

/// The facet whose mean irradiance is the median over all facets.
fn median(run: &RunData) -> Option<(usize, usize)> {
    let mut all = scored(run, |b, k| b.facets.mean_w_m2[k]);
    all.sort_by(|a, b| a.1.total_cmp(&b.1));
    all.get(all.len() / 2).map(|(id, _)| *id)
}
