//! Reports people look at: figures and one HTML page drawn from a finished run's files.
//!
//! In: a run folder holding `run.json`, `summary.parquet`, `cdf.parquet`,
//! `geometry.parquet` and (for maps) `BODY.ply`; nothing is recomputed. Out, in the report
//! folder (default `RUN_DIR/report`):
//! - `cdf.png`/`.svg` and `cdf_plot.csv`: F_k(x) (%) against x (W/m²) for chosen facets;
//! - `minmaxmean.png`/`.svg` and `minmaxmean.csv`: min, max and mean (W/m²) per facet;
//! - `histograms.png`/`.svg` and `histograms.csv`: the same over facet area (%);
//! - `map_<quantity>.png` and `.json` for mean, max (W/m²), lit fraction and time above a
//!   threshold (%), and with scattered light the mean direct, scattered and planet light
//!   (W/m²): latitude–longitude maps and views from ±x, ±y, ±z, bodies side by side;
//! - `index.html`: the run, plan, geometry, accuracy, counts, meshes, warnings and every
//!   figure, self-contained.

pub mod cdf_plot;
pub mod colormap;
mod colormap_tables;
pub mod figure;
pub mod html;
pub mod maps;
pub mod minmaxmean;
pub mod raster;
pub mod route_line;
pub mod select;
pub mod summary;

use crate::error::{Error, Result};
use crate::output::read::RunData;
use colormap::Colormap;
use figure::{write_png_and_svg, Figure};
use html::FigureEntry;
use select::{FacetRef, LatLon};
use std::path::{Path, PathBuf};

/// What to draw.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Facets whose CDF is plotted (`BODY:ID`).
    pub facets: Vec<FacetRef>,
    /// Points whose nearest facet's CDF is plotted.
    pub near: Vec<LatLon>,
    /// Threshold of the "time above" map, W/m².
    pub threshold_w_m2: f64,
    pub colormap: Colormap,
    /// Route files (from `slim route`) drawn on their bodies' maps.
    pub routes: Vec<PathBuf>,
}

impl Default for ReportOptions {
    fn default() -> ReportOptions {
        ReportOptions {
            facets: Vec::new(),
            near: Vec::new(),
            threshold_w_m2: 100.0,
            colormap: Colormap::Viridis,
            routes: Vec::new(),
        }
    }
}

/// A written report.
#[derive(Debug, Clone)]
pub struct Report {
    pub dir: PathBuf,
    pub index: PathBuf,
    /// Every file written, `index.html` last.
    pub files: Vec<PathBuf>,
}

/// The default report folder of a run: `RUN_DIR/report`.
pub fn default_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("report")
}

/// Reads the finished run in `run_dir` and writes its report into `out_dir` (default
/// `RUN_DIR/report`).
pub fn write_report(
    run_dir: &Path,
    out_dir: Option<&Path>,
    options: &ReportOptions,
) -> Result<Report> {
    if !(options.threshold_w_m2.is_finite() && options.threshold_w_m2 >= 0.0) {
        return Err(Error::Usage(
            "--threshold must be a number ≥ 0 (W/m²)".into(),
        ));
    }
    let run = RunData::read(run_dir)?;
    let dir = out_dir.map_or_else(|| default_dir(run_dir), Path::to_path_buf);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut out = Written {
        dir,
        files: Vec::new(),
        figures: Vec::new(),
        notes: Vec::new(),
    };
    cdf_figure(&run, options, &mut out)?;
    spread_figures(&run, options.colormap, &mut out)?;
    map_figures(&run, options, &mut out)?;
    let index = html::write_index(&out.dir, &run, &out.figures, &out.notes)?;
    out.files.push(index.clone());
    Ok(Report {
        dir: out.dir,
        index,
        files: out.files,
    })
}

/// What a report has written so far.
struct Written {
    dir: PathBuf,
    files: Vec<PathBuf>,
    figures: Vec<FigureEntry>,
    /// Notes for the page (e.g. bodies without maps).
    notes: Vec<String>,
}

impl Written {
    /// Lists figure `name` (its PNG, linking the other files of `beside`).
    fn list(&mut self, name: &str, title: &str, caption: String, beside: Vec<PathBuf>) {
        let links = beside
            .iter()
            .filter(|p| p.extension().is_some_and(|e| e != "png"))
            .filter_map(|p| Some(p.file_name()?.to_string_lossy().into_owned()))
            .collect();
        self.figures.push(FigureEntry {
            title: title.to_string(),
            caption,
            png: self.dir.join(format!("{name}.png")),
            links,
        });
        self.files.extend(beside);
    }

    /// Writes the figure as PNG and SVG beside its data file, and lists it.
    fn add(
        &mut self,
        fig: &impl Figure,
        name: &str,
        data: PathBuf,
        title: &str,
        caption: &str,
    ) -> Result<()> {
        let mut written = write_png_and_svg(fig, &self.dir, name)?;
        written.push(data);
        self.list(name, title, caption.to_string(), written);
        Ok(())
    }
}

fn cdf_figure(run: &RunData, options: &ReportOptions, out: &mut Written) -> Result<()> {
    let chosen = select::choose(run, &options.facets, &options.near)?;
    let curves = cdf_plot::curves(run, &chosen);
    let fig = cdf_plot::CdfFigure {
        curves: &curves,
        colormap: options.colormap,
        title: format!(
            "F(x): share of time a facet receives at most x ({})",
            run.record.name
        ),
    };
    let data = cdf_plot::write_csv(&curves, &out.dir)?;
    let caption = "F_k(x), the share of time facet k receives at most x W/m², for the facets \
                   named in the legend (latitude and longitude of the centroid, planetocentric, \
                   east-positive).";
    out.add(&fig, "cdf", data, "Cumulative distribution F_k(x)", caption)
}

fn spread_figures(run: &RunData, colormap: Colormap, out: &mut Written) -> Result<()> {
    let fig = minmaxmean::MinMaxMeanFigure { run, colormap };
    let data = minmaxmean::write_csv(run, &out.dir)?;
    let caption =
        "Minimum, maximum and mean irradiance over time of every facet (SLIM paper Fig. 16).";
    out.add(
        &fig,
        "minmaxmean",
        data,
        "Min, max and mean per facet",
        caption,
    )?;
    let histograms = minmaxmean::Histograms::new(run);
    let fig = minmaxmean::HistogramFigure {
        histograms: &histograms,
        colormap,
    };
    let data = histograms.write_csv(&out.dir)?;
    let caption =
        "Share of the surface area (%) whose max, mean or min irradiance falls in each bin.";
    out.add(
        &fig,
        "histograms",
        data,
        "Histograms over facet area",
        caption,
    )
}

fn map_figures(run: &RunData, options: &ReportOptions, out: &mut Written) -> Result<()> {
    for body in &run.bodies {
        if let Err(why) = &body.mesh {
            out.notes
                .push(format!("body '{}' is not mapped: {why}", body.name));
        }
    }
    let routes = options
        .routes
        .iter()
        .map(|path| route_line::RouteLine::read(path, run))
        .collect::<Result<Vec<_>>>()?;
    let written = maps::write_maps(
        run,
        &out.dir,
        options.colormap,
        options.threshold_w_m2,
        &routes,
    )?;
    let mut caption = format!(
        "Per-facet values on a latitude–longitude map (unshaded, exact colours) and seen from \
         ±x, ±y, ±z (shaded for relief); colour map {}.",
        options.colormap.name()
    );
    if !routes.is_empty() {
        caption.push_str(" White lines: rover routes, from the green dot to the red one.");
    }
    for png in written
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
    {
        let stem = png
            .file_stem()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        let title = format!("Map: {}", stem.trim_start_matches("map_").replace('_', " "));
        out.list(
            &stem,
            &title,
            caption.clone(),
            vec![png.clone(), png.with_extension("json")],
        );
    }
    Ok(())
}
