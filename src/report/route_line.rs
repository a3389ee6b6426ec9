//! Routes on the maps: a rover route written by `slim route` (or the service's `/route`),
//! drawn over its body's map.
//!
//! In: a route file (the GeoJSON Feature `slim route` writes: `properties.body` and
//! `properties.facets`) and the run it is drawn on. Out: a [`RouteLine`] — the body's
//! index in the run and the facets visited — and, on a map raster, the polyline through
//! the pixel centres of those facets (pixels, the raster's own coordinates), broken
//! where it wraps around the map's edge.

use super::raster::IdRaster;
use crate::error::{Error, Result};
use crate::output::read::RunData;
use std::collections::HashMap;
use std::path::Path;

/// A route to draw: which body, which facets in order.
#[derive(Debug, Clone, PartialEq)]
pub struct RouteLine {
    pub body: usize,
    pub facets: Vec<usize>,
}

impl RouteLine {
    /// The route in file `path`, on a body of `run`; errors name the file and what is
    /// wrong (not a route, a body the run does not have, a facet it does not have).
    pub fn read(path: &Path, run: &RunData) -> Result<RouteLine> {
        let bad = |msg: String| Error::file(path, msg);
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let json: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| bad(format!("not JSON: {e} (a route from `slim route` is)")))?;
        let props = &json["properties"];
        let name = props["body"]
            .as_str()
            .ok_or_else(|| bad("no properties.body: not a route from `slim route`".into()))?;
        let body = run
            .bodies
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| bad(format!("body '{name}' is not in this run")))?;
        let count = run.bodies[body].facets.area_m2.len();
        let facets = props["facets"]
            .as_array()
            .ok_or_else(|| bad("no properties.facets: not a route from `slim route`".into()))?
            .iter()
            .map(|f| match f.as_u64() {
                Some(i) if (i as usize) < count => Ok(i as usize),
                _ => Err(bad(format!(
                    "facet {f} is not one of the {count} of '{name}'"
                ))),
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(RouteLine { body, facets })
    }

    /// The route's polylines on `raster` (pixel coordinates): through the mean pixel of
    /// each facet the raster shows — of its pixels within half the raster's width of the
    /// previous point, where it has any, so a facet cut by the longitude seam is drawn
    /// on the side the route comes from — with a new piece wherever a step still spans
    /// more than half the width.
    pub fn pieces(&self, raster: &IdRaster) -> Vec<Vec<(f64, f64)>> {
        let mut pixels: HashMap<usize, Vec<(f64, f64)>> =
            self.facets.iter().map(|&f| (f, Vec::new())).collect();
        for y in 0..raster.height {
            for x in 0..raster.width {
                if let Some(list) = raster.facet(x, y).and_then(|f| pixels.get_mut(&f)) {
                    list.push((x as f64 + 0.5, y as f64 + 0.5));
                }
            }
        }
        let half = raster.width as f64 / 2.0;
        let mut pieces: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
        let mut last: Option<(f64, f64)> = None;
        for f in &self.facets {
            let all = &pixels[f];
            let near: Vec<(f64, f64)> = match last {
                Some(p) => all
                    .iter()
                    .copied()
                    .filter(|q| (q.0 - p.0).abs() <= half)
                    .collect(),
                None => Vec::new(),
            };
            let chosen = if near.is_empty() {
                all.as_slice()
            } else {
                &near
            };
            let Some(point) = mean(chosen) else { continue };
            if last.is_some_and(|p| (point.0 - p.0).abs() > half) {
                pieces.push(Vec::new());
            }
            pieces.last_mut().expect("one piece at least").push(point);
            last = Some(point);
        }
        pieces.retain(|p| !p.is_empty());
        pieces
    }
}

/// The mean of `points`, if any.
fn mean(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    let (x, y) = points
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p.0, y + p.1));
    (n > 0.0).then(|| (x / n, y / n))
}
