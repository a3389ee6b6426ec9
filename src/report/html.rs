//! `index.html`: one self-contained page a run can be mailed or archived with.
//!
//! In: the run (run.json fields), the geometry summary and accuracy estimates, and the
//! figures written (PNG, with SVG and data files beside them). Out: an HTML page with no
//! network references — no external CSS, script or font; PNGs embedded as base64 data URIs,
//! SVGs and the numbers behind each figure linked by relative file name.

use super::figure::short_number;
use super::summary::{Accuracy, GeometrySummary};
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::output::read::RunData;
use base64::Engine;
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// A figure on the page: its PNG and what else belongs to it.
#[derive(Debug, Clone)]
pub struct FigureEntry {
    pub title: String,
    pub caption: String,
    /// The PNG, embedded.
    pub png: PathBuf,
    /// Files linked beside it (SVG, CSV, JSON), by file name.
    pub links: Vec<String>,
}

/// Escapes text for HTML.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:2px 8px;text-align:left}\
th{background:#eee}img{max-width:100%;border:1px solid #ddd}figure{margin:1.5em 0}\
figcaption{font-size:90%;color:#444}.skip{color:#a33}.run{color:#262}";

/// Writes `DIR/index.html`.
pub fn write_index(
    dir: &Path,
    run: &RunData,
    figures: &[FigureEntry],
    notes: &[String],
) -> Result<PathBuf> {
    let geometry = GeometrySummary::new(run);
    let accuracy = Accuracy::new(run.record.plan.steps, &geometry);
    let mut h = String::new();
    let name = escape(&run.record.name);
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>slim report: {name}</title><style>{STYLE}</style></head><body>\n\
         <h1>slim report: {name}</h1>\n"
    );
    run_section(&mut h, run);
    plan_section(&mut h, run);
    geometry_section(&mut h, &geometry);
    accuracy_section(&mut h, &accuracy);
    counts_section(&mut h, run);
    mesh_section(&mut h, run);
    list_section(&mut h, "Warnings", &run.record.warnings);
    list_section(&mut h, "Report notes", notes);
    figure_section(&mut h, figures)?;
    h.push_str("</body></html>\n");
    let path = dir.join("index.html");
    write_atomic(&path, h.as_bytes())?;
    Ok(path)
}

/// Appends a two-column table of (label, value) rows; values are escaped.
fn key_values(h: &mut String, rows: &[(&str, String)]) {
    h.push_str("<table>\n");
    for (k, v) in rows {
        let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", escape(k), escape(v));
    }
    h.push_str("</table>\n");
}

fn run_section(h: &mut String, run: &RunData) {
    let i = &run.record;
    h.push_str("<h2>Run</h2>\n");
    key_values(
        h,
        &[
            ("program", format!("{} {}", i.program, i.version)),
            (
                "scene",
                format!("{} (SHA-256 {})", i.scene.path.display(), i.scene.sha256),
            ),
            ("run folder", run.dir.display().to_string()),
            (
                "simulated time",
                format!(
                    "{} s ({} h)",
                    short_number(i.duration_s),
                    short_number(i.duration_s / 3600.0)
                ),
            ),
            ("threads", i.threads.to_string()),
            (
                "CDF thresholds",
                format!(
                    "{} from 0 W/m² every {} W/m²",
                    i.bins_w_m2.count,
                    short_number(i.bins_w_m2.width_w_m2)
                ),
            ),
        ],
    );
    h.push_str("<h3>Timings</h3>\n");
    let timings: Vec<(&str, String)> = i
        .timings_s
        .iter()
        .map(|(s, t)| (s.as_str(), format!("{t:.3} s")))
        .collect();
    key_values(h, &timings);
}

fn plan_section(h: &mut String, run: &RunData) {
    let p = &run.record.plan;
    let _ = writeln!(
        h,
        "<h2>Plan</h2>\n<p>bodies: {}, facets: {}, steps: {}, tracer: {}.</p>\n<table><tr><th>stage</th><th></th><th>why</th></tr>",
        p.bodies,
        p.facets,
        p.steps,
        escape(&p.tracer)
    );
    for d in &p.decisions {
        let (class, word) = if d.runs {
            ("run", "run")
        } else {
            ("skip", "skipped")
        };
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"{class}\">{word}</td><td>{}</td></tr>",
            escape(&d.stage),
            escape(&d.reason)
        );
    }
    h.push_str("</table>\n");
}

fn geometry_section(h: &mut String, g: &GeometrySummary) {
    let _ = writeln!(
        h,
        "<h2>Geometry</h2>\n<p>{} steps from {} to {} (UTC).</p>\n<table><tr><th>body</th><th>Sun distance (km)</th>\
         <th>Sun distance (AU)</th><th>flux (W/m²)</th><th>Sun longitude change per step</th></tr>",
        g.steps,
        escape(&g.first_utc),
        escape(&g.last_utc)
    );
    let pair = |(a, b): (f64, f64), scale: f64| {
        if a == b {
            short_number(a * scale)
        } else {
            format!("{} – {}", short_number(a * scale), short_number(b * scale))
        }
    };
    for b in &g.bodies {
        let step = b
            .sun_step_deg
            .map_or_else(|| "—".to_string(), |d| format!("{}°", short_number(d)));
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(&b.name),
            pair(b.distance_km, 1.0),
            pair(b.distance_km, 1000.0 / crate::AU_M),
            pair(b.flux_w_m2, 1.0),
            step
        );
    }
    h.push_str("</table>\n");
}

fn accuracy_section(h: &mut String, a: &Accuracy) {
    let n = match a.steps_per_turn {
        Some(n) => format!(
            "The Sun turns once around the first body's sky every {} steps (n), over {} steps in all.",
            short_number(n),
            a.steps
        ),
        None => format!("The Sun does not turn in the body frame; n is the run's {} steps.", a.steps),
    };
    let _ = writeln!(
        h,
        "<h2>Accuracy from the step count</h2>\n<p>{n} Following the error table of docs/accuracy.md: F(x) is a share of \
         steps, so its error is about 1/n = {:.2} %; the mean converges as 1/n², about 0.92·S/n² = {} W/m² on \
         a smooth body (several times more on rough terrain: Phobos has 0.75 W/m² at 360 steps); the maximum \
         converges slowly where brief glints can fall between steps. More steps per turn reduce all three.</p>",
        100.0 * a.cdf_error,
        short_number(a.mean_error_w_m2)
    );
}

fn counts_section(h: &mut String, run: &RunData) {
    h.push_str("<h2>Counts</h2>\n");
    key_values_of(h, &run.record.counts);
}

fn mesh_section(h: &mut String, run: &RunData) {
    h.push_str("<h2>Meshes</h2>\n");
    for b in &run.record.bodies {
        let source = match &b.mesh {
            Some(file) => format!(
                "{} (SHA-256 {})",
                escape(&file.path.display().to_string()),
                escape(&file.sha256)
            ),
            None => escape(&b.shape),
        };
        let _ = writeln!(h, "<h3>{}</h3><p>{source}</p>", escape(&b.name));
        key_values_of(h, &b.report);
    }
}

/// The fields of a recorded struct as key–value rows, keys in alphabetical order and
/// values as JSON writes them.
fn key_values_of(h: &mut String, value: &impl serde::Serialize) {
    let fields = match serde_json::to_value(value) {
        Ok(serde_json::Value::Object(map)) => map,
        _ => serde_json::Map::new(),
    };
    let rows: Vec<(&str, String)> = fields
        .iter()
        .map(|(k, v)| (k.as_str(), v.to_string()))
        .collect();
    key_values(h, &rows);
}

fn list_section(h: &mut String, title: &str, items: &[String]) {
    let _ = writeln!(h, "<h2>{}</h2>", escape(title));
    if items.is_empty() {
        h.push_str("<p>none</p>\n");
        return;
    }
    h.push_str("<ul>\n");
    for item in items {
        let _ = writeln!(h, "<li>{}</li>", escape(item));
    }
    h.push_str("</ul>\n");
}

fn figure_section(h: &mut String, figures: &[FigureEntry]) -> Result<()> {
    h.push_str("<h2>Figures</h2>\n");
    for f in figures {
        let bytes = std::fs::read(&f.png).map_err(|e| Error::io(&f.png, e))?;
        let data = base64::engine::general_purpose::STANDARD.encode(bytes);
        let file = f
            .png
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        let links: Vec<String> = std::iter::once(&file)
            .chain(&f.links)
            .map(|l| format!("<a href=\"{0}\">{0}</a>", escape(l)))
            .collect();
        let _ = writeln!(
            h,
            "<figure><h3>{}</h3><img alt=\"{}\" src=\"data:image/png;base64,{data}\">\
             <figcaption>{} Files: {}</figcaption></figure>",
            escape(&f.title),
            escape(&f.title),
            escape(&f.caption),
            links.join(", ")
        );
    }
    Ok(())
}
