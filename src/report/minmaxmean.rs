//! Minimum, maximum and mean irradiance of every facet (SLIM paper Fig. 16), and the same
//! three quantities as histograms over facet area.
//!
//! In: the run's facets (min/max/mean in W/m², areas in m²). Out: `minmaxmean.png`/`.svg`
//! (W/m² against facet number, bodies one after the other), `histograms.png`/`.svg` (share
//! of the surface area in %, per bin of W/m²), and the numbers drawn: `minmaxmean.csv`
//! (`body`, `facet`, `min_w_m2`, `max_w_m2`, `mean_w_m2`) and `histograms.csv`
//! (`quantity`, `low_w_m2`, `high_w_m2`, `area_percent`).

use super::cdf_plot::csv_field;
use super::colormap::Colormap;
use super::figure::{legend, rgb, text, xy_chart, Axes, DrawResult, Figure};
use crate::atomic::write_atomic;
use crate::error::Result;
use crate::output::read::{Facets, RunData};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Number of histogram bins.
const HISTOGRAM_BINS: usize = 50;

/// The three per-facet quantities, in drawing order: name and accessor.
type Quantity = (&'static str, fn(&Facets) -> &[f64]);

const QUANTITIES: [Quantity; 3] = [
    ("max", |f| &f.max_w_m2),
    ("mean", |f| &f.mean_w_m2),
    ("min", |f| &f.min_w_m2),
];

/// Colour of quantity `q` (0 max, 1 mean, 2 min): light to dark.
fn color(colormap: Colormap, q: usize) -> RGBColor {
    let t = [0.75, 0.45, 0.1][q.min(2)];
    rgb(colormap.color(0.0, 1.0, t).unwrap_or([0, 0, 0]))
}

/// Largest finite maximum over all facets (at least 1 W/m²).
fn largest(run: &RunData) -> f64 {
    run.bodies
        .iter()
        .flat_map(|b| b.facets.max_w_m2.iter())
        .filter(|v| v.is_finite())
        .fold(1.0, |a, &b| a.max(b))
}

/// min/max/mean against facet number.
pub struct MinMaxMeanFigure<'a> {
    pub run: &'a RunData,
    pub colormap: Colormap,
}

impl Figure for MinMaxMeanFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (1100, 600)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult {
        let n = self.run.facet_count().max(2);
        let bodies: Vec<&str> = self.run.bodies.iter().map(|b| b.name.as_str()).collect();
        let x_desc = format!("facet number ({} in order)", bodies.join(", "));
        let axes = Axes {
            x: 0.0..(n - 1) as f64,
            y: 0.0..largest(self.run) * 1.05,
            x_desc: &x_desc,
            y_desc: "irradiance (W/m²)",
        };
        let caption = "Minimum, maximum and mean irradiance of every facet";
        let mut chart = xy_chart(root, Some(caption), axes)?;
        for (q, (name, values)) in QUANTITIES.iter().enumerate() {
            let c = color(self.colormap, q);
            let points = self.run.bodies.iter().scan(0usize, |offset, body| {
                let start = *offset;
                *offset += body.facets.len();
                Some(
                    values(&body.facets)
                        .iter()
                        .enumerate()
                        .map(move |(k, v)| ((start + k) as f64, *v)),
                )
            });
            let finite = points.flatten().filter(|(_, v)| v.is_finite());
            chart
                .draw_series(LineSeries::new(finite, c.stroke_width(1)))?
                .label(*name)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], c.filled()));
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

/// Area-weighted histograms of the three quantities.
pub struct Histograms {
    /// Bin edges, W/m² (bins + 1 values).
    pub edges: Vec<f64>,
    /// Per quantity (max, mean, min): share of the surface area per bin, %.
    pub percent: Vec<(&'static str, Vec<f64>)>,
}

impl Histograms {
    /// Histograms of the run's facets, `HISTOGRAM_BINS` equal bins over 0 … largest max.
    pub fn new(run: &RunData) -> Histograms {
        let top = largest(run);
        let width = top / HISTOGRAM_BINS as f64;
        let edges = (0..=HISTOGRAM_BINS).map(|b| b as f64 * width).collect();
        let total: f64 = run
            .bodies
            .iter()
            .flat_map(|b| b.facets.area_m2.iter())
            .filter(|a| a.is_finite())
            .sum();
        let percent = QUANTITIES
            .iter()
            .map(|(name, values)| {
                let mut bins = vec![0.0; HISTOGRAM_BINS];
                for body in &run.bodies {
                    for (v, a) in values(&body.facets).iter().zip(&body.facets.area_m2) {
                        if v.is_finite() && a.is_finite() && total > 0.0 {
                            let b = ((v / width) as usize).min(HISTOGRAM_BINS - 1);
                            bins[b] += 100.0 * a / total;
                        }
                    }
                }
                (*name, bins)
            })
            .collect();
        Histograms { edges, percent }
    }

    /// Writes `histograms.csv`.
    pub fn write_csv(&self, dir: &Path) -> Result<PathBuf> {
        let path = dir.join("histograms.csv");
        let mut s = String::from("quantity,low_w_m2,high_w_m2,area_percent\n");
        for (name, bins) in &self.percent {
            for (b, p) in bins.iter().enumerate() {
                s.push_str(&format!(
                    "{name},{},{},{p}\n",
                    self.edges[b],
                    self.edges[b + 1]
                ));
            }
        }
        write_atomic(&path, s.as_bytes())?;
        Ok(path)
    }
}

/// The histogram figure: one panel per quantity.
pub struct HistogramFigure<'a> {
    pub histograms: &'a Histograms,
    pub colormap: Colormap,
}

impl Figure for HistogramFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (900, 900)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult {
        let (title, body) = root.split_vertically(40);
        title.titled(
            "Irradiance over the surface: share of facet area per bin",
            text(20.0),
        )?;
        let panels = body.split_evenly((3, 1));
        let h = self.histograms;
        let top = h.edges.last().copied().unwrap_or(1.0);
        for (q, ((name, bins), panel)) in h.percent.iter().zip(&panels).enumerate() {
            let y_max = bins.iter().fold(1.0, |a: f64, &b| a.max(b)) * 1.1;
            let x_desc = format!("{name} irradiance (W/m²)");
            let axes = Axes {
                x: 0.0..top,
                y: 0.0..y_max,
                x_desc: &x_desc,
                y_desc: "area (%)",
            };
            let mut chart = xy_chart(panel, None, axes)?;
            let c = color(self.colormap, q);
            chart.draw_series(bins.iter().enumerate().map(|(b, p)| {
                Rectangle::new([(h.edges[b], 0.0), (h.edges[b + 1], *p)], c.filled())
            }))?;
        }
        Ok(())
    }
}

/// Writes `minmaxmean.csv`.
pub fn write_csv(run: &RunData, dir: &Path) -> Result<PathBuf> {
    let path = dir.join("minmaxmean.csv");
    let mut s = String::from("body,facet,min_w_m2,max_w_m2,mean_w_m2\n");
    for body in &run.bodies {
        let f = &body.facets;
        let name = csv_field(&body.name);
        for k in 0..f.len() {
            s.push_str(&format!(
                "{name},{k},{},{},{}\n",
                f.min_w_m2[k], f.max_w_m2[k], f.mean_w_m2[k]
            ));
        }
    }
    write_atomic(&path, s.as_bytes())?;
    Ok(path)
}
