//! The F_k(x) plot (SLIM paper Fig. 15): the cumulative distribution of irradiance for a
//! few chosen facets.
//!
//! In: the chosen facets and their CDF rows (thresholds x in W/m², F(x) as a share).
//! Out: `cdf.png` and `cdf.svg` (x in W/m², F in %, a legend naming body, facet, reason and
//! centroid latitude/longitude) and `cdf_plot.csv` with the plotted numbers: `body`,
//! `facet`, `role`, `latitude_deg`, `longitude_deg`, `irradiance_w_m2`, `cdf` (a share,
//! exactly as in the run's cdf table).

use super::colormap::Colormap;
use super::figure::{legend, rgb, xy_chart, Axes, DrawResult, Figure};
use super::select::Chosen;
use crate::atomic::write_atomic;
use crate::error::Result;
use crate::output::read::RunData;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// One plotted curve.
#[derive(Debug, Clone)]
pub struct Curve {
    pub body: String,
    pub facet: usize,
    pub role: String,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// (x in W/m², F(x) as a share 0…1).
    pub points: Vec<(f64, f64)>,
}

impl Curve {
    fn label(&self) -> String {
        format!(
            "{} #{} ({}): lat {:.1}°, lon {:.1}°",
            self.body, self.facet, self.role, self.lat_deg, self.lon_deg
        )
    }
}

/// The curves of the chosen facets (points with a missing F are left out).
pub fn curves(run: &RunData, chosen: &[Chosen]) -> Vec<Curve> {
    chosen
        .iter()
        .map(|c| {
            let body = &run.bodies[c.body];
            let points = body
                .cdf
                .thresholds_w_m2
                .iter()
                .zip(body.cdf.facet(c.facet))
                .filter(|(_, f)| f.is_finite())
                .map(|(x, f)| (*x, *f))
                .collect();
            Curve {
                body: body.name.clone(),
                facet: c.facet,
                role: c.why.clone(),
                lat_deg: c.lat_deg,
                lon_deg: c.lon_deg,
                points,
            }
        })
        .collect()
}

/// The CDF figure.
pub struct CdfFigure<'a> {
    pub curves: &'a [Curve],
    pub colormap: Colormap,
    pub title: String,
}

impl CdfFigure<'_> {
    fn x_max(&self) -> f64 {
        self.curves
            .iter()
            .flat_map(|c| c.points.iter().map(|p| p.0))
            .fold(0.0, f64::max)
            .max(1.0)
    }

    /// Curve colours spread over the darker 85 % of the colour map (yellow is hard to see).
    fn color(&self, i: usize) -> RGBColor {
        let n = self.curves.len().max(2) - 1;
        let t = 0.85 * i as f64 / n as f64;
        rgb(self.colormap.color(0.0, 1.0, t).unwrap_or([0, 0, 0]))
    }
}

impl Figure for CdfFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (960, 640)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult {
        let axes = Axes {
            x: 0.0..self.x_max(),
            y: 0.0..100.0,
            x_desc: "irradiance x (W/m²)",
            y_desc: "F(x): share of time with E ≤ x (%)",
        };
        let mut chart = xy_chart(root, Some(&self.title), axes)?;
        for (i, curve) in self.curves.iter().enumerate() {
            let color = self.color(i);
            let points = curve.points.iter().map(|&(x, f)| (x, 100.0 * f));
            chart
                .draw_series(LineSeries::new(points, color.stroke_width(2)))?
                .label(curve.label())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3))
                });
        }
        if !self.curves.is_empty() {
            legend(&mut chart, SeriesLabelPosition::LowerRight)?;
        }
        Ok(())
    }
}

/// Writes `cdf_plot.csv`: the numbers the CDF figure was drawn from.
pub fn write_csv(curves: &[Curve], dir: &Path) -> Result<PathBuf> {
    let path = dir.join("cdf_plot.csv");
    let mut s = String::from("body,facet,role,latitude_deg,longitude_deg,irradiance_w_m2,cdf\n");
    for c in curves {
        for (x, f) in &c.points {
            s.push_str(&format!(
                "{},{},\"{}\",{},{},{x},{f}\n",
                csv_field(&c.body),
                c.facet,
                c.role.replace('"', "\"\""),
                c.lat_deg,
                c.lon_deg
            ));
        }
    }
    write_atomic(&path, s.as_bytes())?;
    Ok(path)
}

/// A CSV field, quoted when it holds a separator or quote.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
