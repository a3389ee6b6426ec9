//! Maps of per-facet quantities: equirectangular latitude–longitude maps and shaded
//! orthographic views from ±x, ±y, ±z, bodies side by side, with a colour bar.
//!
//! In: the run's facets and meshes, a quantity per facet (mean or max irradiance in W/m²,
//! lit fraction or time above a threshold in %), a colour map. Out: `map_<quantity>.png`
//! and `map_<quantity>.json` with the numbers drawn: the quantity, unit, colour map, scale
//! `[scale_min, scale_max]` (physical units), per body the values per facet and the pixel
//! rectangles of the equirectangular map (longitude −180…180°, latitude 90…−90°, pixel
//! centres as in [`super::raster`]) and of each view, and the colour bar's rectangle.
//! Map pixels carry the exact colour-map entry of their facet's value (no shading), so a
//! pixel can be inverted to a value within (scale_max − scale_min)/255; only the
//! orthographic views are modulated by a relief factor (0.75 … 1).

use super::colormap::Colormap;
use super::figure::{rgb, short_number, text, write_png, DrawResult, Figure};
use super::raster::{
    equirectangular, is_patch, orthographic, overhead_view, Framing, IdRaster, VIEWS,
};
use super::route_line::RouteLine;
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::output::read::{Facets, RunData};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use serde_json::json;
use std::path::{Path, PathBuf};

// Layout of a map figure, pixels: a title, then per body a column with the map above six
// views, then the colour bar.
const MARGIN_LEFT: i32 = 60;
const COLUMN_W: i32 = 680;
const TITLE_H: i32 = 60;
const NAME_H: i32 = 30;
const MAP_W: i32 = 600;
const MAP_H: i32 = 300;
const LON_LABEL_H: i32 = 34;
const VIEW: i32 = 190;
const VIEW_GAP: i32 = 15;
const VIEW_LABEL_H: i32 = 22;
const BAR_AREA_W: i32 = 170;
const BAR_W: i32 = 28;
/// Colour of pixels no facet covers.
const BACKGROUND: [u8; 3] = [235, 235, 235];

/// A per-facet quantity to map.
#[derive(Debug, Clone)]
pub struct Quantity {
    /// File-name key: `map_<key>.png`.
    pub key: &'static str,
    pub title: String,
    pub unit: &'static str,
    /// Values per body and facet, in `unit`.
    pub values: Vec<Vec<f64>>,
    pub scale_min: f64,
    pub scale_max: f64,
}

impl Quantity {
    fn new(
        key: &'static str,
        title: String,
        unit: &'static str,
        values: Vec<Vec<f64>>,
    ) -> Quantity {
        let top = values
            .iter()
            .flatten()
            .filter(|v| v.is_finite())
            .fold(0.0, |a: f64, &b| a.max(b));
        let scale_max = if unit == "%" {
            100.0
        } else if top > 0.0 {
            top
        } else {
            1.0
        };
        Quantity {
            key,
            title,
            unit,
            values,
            scale_min: 0.0,
            scale_max,
        }
    }

    fn from_facets(
        run: &RunData,
        key: &'static str,
        title: &str,
        unit: &'static str,
        f: impl Fn(&Facets, usize) -> f64,
    ) -> Quantity {
        let values = run
            .bodies
            .iter()
            .map(|b| (0..b.facets.len()).map(|k| f(&b.facets, k)).collect())
            .collect();
        Quantity::new(key, title.to_string(), unit, values)
    }
}

/// The threshold of the cdf table used for "time above x": the smallest at or above x
/// (the largest if x is beyond them all), W/m².
pub fn threshold_used(thresholds: &[f64], x: f64) -> Option<(usize, f64)> {
    thresholds
        .iter()
        .position(|&t| t >= x)
        .or_else(|| thresholds.len().checked_sub(1))
        .map(|b| (b, thresholds[b]))
}

/// The mapped quantities: mean, max, lit fraction and time above `threshold_w_m2`; with
/// scattered light, the mean of each part (direct, scattered, and light from planets as
/// it arrives).
pub fn quantities(run: &RunData, threshold_w_m2: f64) -> Vec<Quantity> {
    let mut list = vec![
        Quantity::from_facets(run, "mean", "Mean irradiance", "W/m²", |f, k| {
            f.mean_w_m2[k]
        }),
        Quantity::from_facets(run, "max", "Maximum irradiance", "W/m²", |f, k| {
            f.max_w_m2[k]
        }),
        Quantity::from_facets(
            run,
            "lit_fraction",
            "Lit fraction (share of time with E > 0)",
            "%",
            |f, k| 100.0 * f.lit_fraction[k],
        ),
    ];
    let thresholds = run
        .bodies
        .first()
        .map(|b| b.cdf.thresholds_w_m2.as_slice())
        .unwrap_or(&[]);
    if let Some((b, used)) = threshold_used(thresholds, threshold_w_m2) {
        let values = run
            .bodies
            .iter()
            .map(|body| {
                (0..body.facets.len())
                    .map(|k| 100.0 * (1.0 - body.cdf.facet(k).get(b).copied().unwrap_or(f64::NAN)))
                    .collect()
            })
            .collect();
        let title = format!(
            "Time with E > {} W/m² (asked {} W/m²; cdf threshold used: {} W/m², the nearest at or above)",
            short_number(used),
            short_number(threshold_w_m2),
            short_number(used)
        );
        list.push(Quantity::new("time_above", title, "%", values));
    }
    let parts: Vec<&str> = run
        .bodies
        .first()
        .map(|b| b.facets.part_means_w_m2.iter().map(|(p, _)| *p).collect())
        .unwrap_or_default();
    for (n, part) in parts.into_iter().enumerate() {
        let (key, title) = match part {
            "direct" => ("direct_mean", "Mean direct sunlight"),
            "scattered" => (
                "scattered_mean",
                "Mean scattered light (all orders, planets' light included)",
            ),
            _ => ("planet_mean", "Mean light from planets, as it arrives"),
        };
        list.push(Quantity::from_facets(run, key, title, "W/m²", |f, k| {
            f.part_means_w_m2.get(n).map_or(f64::NAN, |(_, v)| v[k])
        }));
    }
    list
}

/// A body's rasters, computed once and coloured per quantity.
pub struct BodyRasters {
    pub name: String,
    /// The map and the six views, or why there are none.
    pub rasters: std::result::Result<Rasters, String>,
}

/// A body's pictures: its map and the six views.
pub struct Rasters {
    /// The equirectangular map of a whole body, or the view from above of a terrain patch.
    pub map: IdRaster,
    /// For a patch, how its view from above is framed (for the scale bar).
    pub overhead: Option<Framing>,
    pub views: Vec<IdRaster>,
}

/// Rasterises every body (needs its mesh from BODY.ply).
pub fn rasterise(run: &RunData) -> Vec<BodyRasters> {
    run.bodies
        .iter()
        .map(|b| BodyRasters {
            name: b.name.clone(),
            rasters: b.mesh.clone().map(|mesh| body_rasters(&mesh)),
        })
        .collect()
}

fn body_rasters(mesh: &Mesh) -> Rasters {
    let (w, h) = (MAP_W as usize, MAP_H as usize);
    let (map, overhead) = if is_patch(mesh) {
        let above = orthographic(mesh, &overhead_view(mesh), w, h);
        (above, Framing::fit(mesh, w, h))
    } else {
        let corners = (0..mesh.len()).map(|k| mesh.corners(k));
        (equirectangular(corners, w, h), None)
    };
    let views = VIEWS
        .iter()
        .map(|v| orthographic(mesh, v, VIEW as usize, VIEW as usize))
        .collect();
    Rasters {
        map,
        overhead,
        views,
    }
}

/// A pixel rectangle in the figure.
#[derive(Debug, Clone, Copy)]
struct Rect {
    left: i32,
    top: i32,
    width: i32,
    height: i32,
}

impl Rect {
    fn json(&self) -> serde_json::Value {
        json!({"left": self.left, "top": self.top, "width": self.width, "height": self.height})
    }
}

/// Where body column `b` draws its map and views.
fn map_rect(b: usize) -> Rect {
    Rect {
        left: MARGIN_LEFT + b as i32 * COLUMN_W,
        top: TITLE_H + NAME_H,
        width: MAP_W,
        height: MAP_H,
    }
}

fn view_rect(b: usize, v: usize) -> Rect {
    let top = TITLE_H + NAME_H + MAP_H + LON_LABEL_H + VIEW_LABEL_H;
    Rect {
        left: MARGIN_LEFT + b as i32 * COLUMN_W + (v as i32 % 3) * (VIEW + VIEW_GAP),
        top: top + (v as i32 / 3) * (VIEW + VIEW_LABEL_H),
        width: VIEW,
        height: VIEW,
    }
}

fn bar_rect(bodies: usize) -> Rect {
    Rect {
        left: MARGIN_LEFT + bodies as i32 * COLUMN_W + 10,
        top: TITLE_H + NAME_H,
        width: BAR_W,
        height: MAP_H,
    }
}

/// One quantity's map figure.
pub struct MapFigure<'a> {
    pub quantity: &'a Quantity,
    pub bodies: &'a [BodyRasters],
    pub colormap: Colormap,
    /// Rover routes drawn over their bodies' maps.
    pub routes: &'a [RouteLine],
}

impl MapFigure<'_> {
    fn color(&self, value: f64, relief: f32) -> RGBColor {
        let q = self.quantity;
        let c = self
            .colormap
            .color(q.scale_min, q.scale_max, value)
            .unwrap_or(BACKGROUND);
        rgb(c.map(|x| (x as f32 * relief).round() as u8))
    }

    /// Paints `raster` into `rect` with the colours of `values`.
    fn paint<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        raster: &IdRaster,
        rect: Rect,
        values: &[f64],
    ) -> DrawResult {
        for y in 0..raster.height {
            for x in 0..raster.width {
                let value = raster
                    .facet(x, y)
                    .and_then(|k| values.get(k))
                    .copied()
                    .unwrap_or(f64::NAN);
                let color = self.color(value, raster.relief(x, y));
                root.draw_pixel((rect.left + x as i32, rect.top + y as i32), &color)?;
            }
        }
        frame(root, rect)
    }

    fn draw_body<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, b: usize) -> DrawResult {
        let body = &self.bodies[b];
        let m = map_rect(b);
        let centre = text(16.0).pos(Pos::new(HPos::Center, VPos::Bottom));
        let rasters = match &body.rasters {
            Ok(r) => r,
            Err(why) => {
                root.draw(&Text::new(
                    format!("no map: {why}"),
                    (m.left, m.top + 20),
                    text(14.0),
                ))?;
                return Ok(());
            }
        };
        let values = self
            .quantity
            .values
            .get(b)
            .map(Vec::as_slice)
            .unwrap_or(&[]);
        let title = match rasters.overhead {
            Some(_) => "terrain patch seen from above, north up",
            None => "latitude–longitude map",
        };
        root.draw(&Text::new(
            format!("{}: {title}", body.name),
            (m.left + m.width / 2, m.top - 6),
            centre,
        ))?;
        self.paint(root, &rasters.map, m, values)?;
        for route in self.routes.iter().filter(|r| r.body == b) {
            draw_route(root, route, &rasters.map, m)?;
        }
        match rasters.overhead {
            Some(framing) => scale_bar(root, m, framing)?,
            None => map_axes(root, m)?,
        }
        for (v, raster) in rasters.views.iter().enumerate() {
            let r = view_rect(b, v);
            self.paint(root, raster, r, values)?;
            let label = format!("{} (shaded)", VIEWS[v].label);
            root.draw(&Text::new(
                label,
                (r.left + r.width / 2, r.top - 4),
                text(13.0).pos(Pos::new(HPos::Center, VPos::Bottom)),
            ))?;
        }
        Ok(())
    }

    fn draw_colour_bar<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult {
        let q = self.quantity;
        let r = bar_rect(self.bodies.len());
        for y in 0..r.height {
            let value =
                q.scale_max - (y as f64 + 0.5) / r.height as f64 * (q.scale_max - q.scale_min);
            let c = self.color(value, 1.0);
            root.draw(&PathElement::new(
                vec![(r.left, r.top + y), (r.left + r.width - 1, r.top + y)],
                c,
            ))?;
        }
        frame(root, r)?;
        for k in 0..=4 {
            let value = q.scale_min + (q.scale_max - q.scale_min) * k as f64 / 4.0;
            let y = r.top + r.height - 1 - ((r.height - 1) as f64 * k as f64 / 4.0).round() as i32;
            let x = r.left + r.width;
            root.draw(&PathElement::new(vec![(x, y), (x + 5, y)], BLACK))?;
            let style = text(13.0).pos(Pos::new(HPos::Left, VPos::Center));
            root.draw(&Text::new(
                format!("{} {}", short_number(value), q.unit),
                (x + 8, y),
                style,
            ))?;
        }
        let caption = format!("{} ({})", self.colormap.name(), q.unit);
        root.draw(&Text::new(
            caption,
            (r.left, r.top - 6),
            text(13.0).pos(Pos::new(HPos::Left, VPos::Bottom)),
        ))?;
        Ok(())
    }
}

/// A one-pixel black frame just outside `r`.
fn frame<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, r: Rect) -> DrawResult {
    let corners = [
        (r.left - 1, r.top - 1),
        (r.left + r.width, r.top + r.height),
    ];
    root.draw(&Rectangle::new(corners, BLACK.stroke_width(1)))?;
    Ok(())
}

/// `route` over the map raster `raster` drawn in `m`: a white line with a dark edge, the
/// start a green dot, the end a red one.
fn draw_route<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    route: &RouteLine,
    raster: &IdRaster,
    m: Rect,
) -> DrawResult {
    let pieces = route.pieces(raster);
    let at = |(x, y): (f64, f64)| (m.left + x.round() as i32, m.top + y.round() as i32);
    for piece in &pieces {
        let points: Vec<(i32, i32)> = piece.iter().map(|&p| at(p)).collect();
        root.draw(&PathElement::new(points.clone(), BLACK.stroke_width(4)))?;
        root.draw(&PathElement::new(points, WHITE.stroke_width(2)))?;
    }
    let ends = [
        pieces.first().and_then(|p| p.first()),
        pieces.last().and_then(|p| p.last()),
    ];
    for (end, colour) in ends.into_iter().zip([GREEN, RED]) {
        if let Some(&p) = end {
            root.draw(&Circle::new(at(p), 4, colour.filled()))?;
        }
    }
    Ok(())
}

/// Longitude and latitude ticks and labels around the map in `m`.
fn map_axes<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, m: Rect) -> DrawResult {
    for lon in [-180, -90, 0, 90, 180] {
        let x = m.left + ((lon + 180) as f64 / 360.0 * m.width as f64).round() as i32;
        let y = m.top + m.height;
        root.draw(&PathElement::new(vec![(x, y), (x, y + 5)], BLACK))?;
        let style = text(12.0).pos(Pos::new(HPos::Center, VPos::Top));
        root.draw(&Text::new(format!("{lon}°"), (x, y + 7), style))?;
    }
    for lat in [-90, -45, 0, 45, 90] {
        let y = m.top + ((90 - lat) as f64 / 180.0 * m.height as f64).round() as i32;
        root.draw(&PathElement::new(
            vec![(m.left - 6, y), (m.left - 1, y)],
            BLACK,
        ))?;
        let style = text(12.0).pos(Pos::new(HPos::Right, VPos::Center));
        root.draw(&Text::new(format!("{lat}°"), (m.left - 8, y), style))?;
    }
    let style = text(12.0).pos(Pos::new(HPos::Center, VPos::Top));
    root.draw(&Text::new(
        "east longitude",
        (m.left + m.width / 2, m.top + m.height + 20),
        style,
    ))?;
    Ok(())
}

/// A scale bar under the view from above in `m`: a round length near a fifth of the width.
fn scale_bar<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    m: Rect,
    framing: Framing,
) -> DrawResult {
    let target_m = 0.2 * m.width as f64 / framing.px_per_m;
    let decade = 10f64.powf(target_m.log10().floor());
    let length_m = [5.0, 2.0, 1.0]
        .into_iter()
        .map(|f| f * decade)
        .find(|l| *l <= target_m)
        .unwrap_or(decade);
    let px = (length_m * framing.px_per_m).round() as i32;
    let y = m.top + m.height + 10;
    root.draw(&PathElement::new(
        vec![(m.left, y), (m.left + px, y)],
        BLACK.stroke_width(3),
    ))?;
    let label = if length_m >= 1000.0 {
        format!("{} km", short_number(length_m / 1000.0))
    } else {
        format!("{} m", short_number(length_m))
    };
    let style = text(12.0).pos(Pos::new(HPos::Left, VPos::Center));
    root.draw(&Text::new(label, (m.left + px + 8, y), style))?;
    Ok(())
}

impl Figure for MapFigure<'_> {
    fn size(&self) -> (u32, u32) {
        let bodies = self.bodies.len().max(1) as i32;
        let width = MARGIN_LEFT + bodies * COLUMN_W + BAR_AREA_W;
        let height = view_rect(0, 5).top + VIEW + 20;
        (width as u32, height as u32)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult {
        let q = self.quantity;
        root.draw(&Text::new(q.title.clone(), (MARGIN_LEFT, 10), text(17.0)))?;
        let scale = format!(
            "colour: {} from {} to {} {}; maps unshaded, views shaded for relief",
            self.colormap.name(),
            short_number(q.scale_min),
            short_number(q.scale_max),
            q.unit
        );
        root.draw(&Text::new(scale, (MARGIN_LEFT, 34), text(13.0)))?;
        for b in 0..self.bodies.len() {
            self.draw_body(root, b)?;
        }
        self.draw_colour_bar(root)
    }
}

/// What the map panel of body `b` shows, as JSON.
fn map_description(b: usize, body: &BodyRasters) -> serde_json::Value {
    match body.rasters.as_ref().ok().and_then(|r| r.overhead) {
        Some(f) => json!({
            "kind": "overhead",
            "rect": map_rect(b).json(),
            "centre_m": f.centre.to_array(),
            "metres_per_pixel": 1.0 / f.px_per_m,
        }),
        None => json!({
            "kind": "equirectangular",
            "rect": map_rect(b).json(),
            "lon_min_deg": -180.0, "lon_max_deg": 180.0,
            "lat_top_deg": 90.0, "lat_bottom_deg": -90.0,
        }),
    }
}

/// The numbers a map figure was drawn from, as JSON.
fn map_json(fig: &MapFigure, image: &str, threshold: Option<f64>) -> serde_json::Value {
    let q = fig.quantity;
    let (width, height) = fig.size();
    let bodies: Vec<_> = fig
        .bodies
        .iter()
        .enumerate()
        .map(|(b, body)| {
            let values: Vec<Option<f32>> = q.values.get(b).map_or_else(Vec::new, |v| {
                v.iter()
                    .map(|x| x.is_finite().then_some(*x as f32))
                    .collect()
            });
            json!({
                "name": body.name,
                "mapped": body.rasters.is_ok(),
                "note": body.rasters.as_ref().err(),
                "map": map_description(b, body),
                "views": VIEWS.iter().enumerate().map(|(v, view)| json!({
                    "label": view.label,
                    "rect": view_rect(b, v).json(),
                })).collect::<Vec<_>>(),
                "values": values,
            })
        })
        .collect();
    json!({
        "quantity": q.key,
        "title": q.title,
        "unit": q.unit,
        "colormap": fig.colormap.name(),
        "scale_min": q.scale_min,
        "scale_max": q.scale_max,
        "threshold_used_w_m2": threshold,
        "image": image,
        "width": width,
        "height": height,
        "colorbar": bar_rect(fig.bodies.len()).json(),
        "bodies": bodies,
    })
}

/// Writes `map_<key>.png` and `map_<key>.json` for each quantity.
pub fn write_maps(
    run: &RunData,
    dir: &Path,
    colormap: Colormap,
    threshold_w_m2: f64,
    routes: &[RouteLine],
) -> Result<Vec<PathBuf>> {
    let bodies = rasterise(run);
    let thresholds = run
        .bodies
        .first()
        .map(|b| b.cdf.thresholds_w_m2.as_slice())
        .unwrap_or(&[]);
    let used = threshold_used(thresholds, threshold_w_m2).map(|(_, t)| t);
    let mut files = Vec::new();
    for q in quantities(run, threshold_w_m2) {
        let fig = MapFigure {
            quantity: &q,
            bodies: &bodies,
            colormap,
            routes,
        };
        let name = format!("map_{}", q.key);
        files.push(write_png(&fig, dir, &name)?);
        let threshold = (q.key == "time_above").then_some(used).flatten();
        let json_path = dir.join(format!("{name}.json"));
        let text = serde_json::to_vec_pretty(&map_json(&fig, &format!("{name}.png"), threshold))
            .map_err(|e| Error::output(&json_path, e))?;
        write_atomic(&json_path, &text)?;
        files.push(json_path);
    }
    Ok(files)
}
