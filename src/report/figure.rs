//! Drawing a figure once and writing it as PNG and SVG.
//!
//! In: a [`Figure`] (its size in pixels and a drawing routine for any plotters backend).
//! Out: `NAME.png` (8-bit RGB, encoded with `png`) and/or `NAME.svg`, written atomically.
//! Text uses DejaVu Sans, embedded in the binary and registered with plotters' ab_glyph
//! renderer, so no system font or library is needed.

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Once;

/// DejaVu Sans (Bitstream Vera licence, data/fonts/DejaVu-LICENSE.txt).
static FONT: &[u8] = include_bytes!("../../data/fonts/DejaVuSans.ttf");

/// The font family every figure uses.
pub const FAMILY: &str = "sans-serif";

/// Registers the embedded font with plotters (once per process).
pub fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a valid TrueType file built into the binary; a failure would only
        // leave text undrawn, which the PNG tests would catch.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

/// A drawing error, as text.
#[derive(Debug)]
pub struct DrawError(pub String);

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for DrawError {
    fn from(e: DrawingAreaErrorKind<E>) -> DrawError {
        DrawError(e.to_string())
    }
}

/// Result of drawing.
pub type DrawResult = std::result::Result<(), DrawError>;

/// A figure that can be drawn on any backend.
pub trait Figure {
    /// Width and height, pixels.
    fn size(&self) -> (u32, u32);
    /// Draws the figure on `root` (already filled white).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult;
}

/// The figure as RGB pixels, row by row.
pub fn rgb_pixels(figure: &impl Figure) -> std::result::Result<Vec<u8>, DrawError> {
    register_font();
    let (w, h) = figure.size();
    let mut buf = vec![255u8; (w as usize) * (h as usize) * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        figure.draw(&root)?;
        root.present()?;
    }
    Ok(buf)
}

/// The figure as SVG text.
pub fn svg_text(figure: &impl Figure) -> std::result::Result<String, DrawError> {
    register_font();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, figure.size()).into_drawing_area();
        root.fill(&WHITE)?;
        figure.draw(&root)?;
        root.present()?;
    }
    Ok(svg)
}

/// PNG encoding of 8-bit RGB pixels.
pub fn encode_png(rgb: &[u8], width: u32, height: u32) -> std::result::Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::High);
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(rgb).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// Writes `DIR/NAME.png`; returns its path.
pub fn write_png(figure: &impl Figure, dir: &Path, name: &str) -> Result<PathBuf> {
    let path = dir.join(format!("{name}.png"));
    let (w, h) = figure.size();
    let bytes = rgb_pixels(figure)
        .map_err(|e| e.0)
        .and_then(|px| encode_png(&px, w, h))
        .map_err(|e| Error::output(&path, e))?;
    write_atomic(&path, &bytes)?;
    Ok(path)
}

/// Writes `DIR/NAME.svg`; returns its path.
pub fn write_svg(figure: &impl Figure, dir: &Path, name: &str) -> Result<PathBuf> {
    let path = dir.join(format!("{name}.svg"));
    let svg = svg_text(figure).map_err(|e| Error::output(&path, e.0))?;
    write_atomic(&path, svg.as_bytes())?;
    Ok(path)
}

/// Writes `DIR/NAME.png` and `DIR/NAME.svg`.
pub fn write_png_and_svg(figure: &impl Figure, dir: &Path, name: &str) -> Result<Vec<PathBuf>> {
    Ok(vec![
        write_png(figure, dir, name)?,
        write_svg(figure, dir, name)?,
    ])
}

/// A text style of the report font.
pub fn text(size: f64) -> TextStyle<'static> {
    (FAMILY, size).into_font().color(&BLACK)
}

/// An RGB colour for plotters.
pub fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// A short number for axis labels and legends (up to 4 significant digits).
pub fn short_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let digits = (3 - x.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{x:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A chart with linear axes in f64.
pub type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Axis ranges and descriptions of a chart.
pub struct Axes<'t> {
    pub x: std::ops::Range<f64>,
    pub y: std::ops::Range<f64>,
    pub x_desc: &'t str,
    pub y_desc: &'t str,
}

/// A chart on `area` with the report's margins, fonts and number labels.
pub fn xy_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: Option<&str>,
    axes: Axes,
) -> std::result::Result<Chart<'a, DB>, DrawError> {
    let mut builder = ChartBuilder::on(area);
    if let Some(c) = caption {
        builder.caption(c, text(20.0));
    }
    let mut chart = builder
        .margin(14)
        .x_label_area_size(48)
        .y_label_area_size(64)
        .build_cartesian_2d(axes.x, axes.y)?;
    chart
        .configure_mesh()
        .x_desc(axes.x_desc)
        .y_desc(axes.y_desc)
        .x_label_formatter(&|x| short_number(*x))
        .y_label_formatter(&|y| short_number(*y))
        .label_style(text(13.0))
        .axis_desc_style(text(15.0))
        .draw()?;
    Ok(chart)
}

/// Draws the legend of the labelled series at `position`.
pub fn legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut Chart<'a, DB>,
    position: SeriesLabelPosition,
) -> DrawResult {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(text(13.0))
        .draw()?;
    Ok(())
}
