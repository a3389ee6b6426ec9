//! Windows: charging windows of one facet from a finished job's irradiance history — the
//! intervals in which the irradiance stays at or above a threshold for at least a given
//! duration, the question a rover planner asks before parking.
//!
//! In: `history.parquet` (step, TDB seconds, body, facet, W/m²) of a job run with
//! `[output] history = true`, the run's step length (duration / steps, seconds), a
//! threshold (W/m²) and a least duration (s). Out: windows with start and end (TDB seconds
//! past J2000, and UTC), duration (s), energy (J/m²) and least sampled irradiance (W/m²).
//!
//! Edges are refined inside their step by linear interpolation of the irradiance: an edge
//! between a sample below the threshold and one at or above it lies where the straight
//! line through the two equals the threshold ([`crate::sight::stretches`], shared with the
//! sight windows). Where E varies smoothly (the Sun's elevation over the facet's plane) the
//! error is at most Δt²·max|Ë|/(8·|Ė|). Beside a dark sample (E = 0, which says nothing of
//! how far the light is off) the edge comes instead from the line through the window's
//! two samples next to it, extended back to the threshold within the step: a sunrise over
//! the facet's plane then errs by at most Δt²·max|Ë|/|Ė| (over the two steps), not by up
//! to a step. Where the Sun crosses the terrain's horizon with a point Sun, E jumps within
//! the step, and the edge is only known to lie in that step. The energy is ∫ E dt over the
//! same straight lines (trapezoids), from edge to edge. A window that holds the first or last sample asked for (or one beside a missing
//! step) is flagged as cut and is not refined past it: it starts at the first sample's
//! epoch, or ends at the end of the last sample's step (each sample stands for the step
//! that starts at its epoch), holding that sample's irradiance. Times print in UTC to the
//! millisecond.

use super::reply::{ApiError, ApiResult};
use crate::output::read::column;
use crate::sight::{stretches, Stretch};
use arrow_array::{Float64Array, StringArray, UInt32Array};
use parquet::arrow::arrow_reader::{
    ArrowReaderOptions, ParquetRecordBatchReaderBuilder, RowSelection, RowSelector,
};
use parquet::arrow::ProjectionMask;
use parquet::file::metadata::PageIndexPolicy;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// `?body=NAME&facet=ID&threshold_w_m2=X&min_duration_s=Y[&from_tdb_s=..&to_tdb_s=..]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowsQuery {
    pub body: Option<String>,
    pub facet: usize,
    pub threshold_w_m2: f64,
    #[serde(default)]
    pub min_duration_s: f64,
    /// Only samples at or after this epoch (TDB seconds past J2000).
    pub from_tdb_s: Option<f64>,
    /// Only samples before this epoch.
    pub to_tdb_s: Option<f64>,
}

impl WindowsQuery {
    /// Checks the numbers.
    pub fn check(&self) -> ApiResult<()> {
        let finite = [self.threshold_w_m2, self.min_duration_s]
            .into_iter()
            .chain(self.from_tdb_s)
            .chain(self.to_tdb_s)
            .all(f64::is_finite);
        if !finite || self.min_duration_s < 0.0 {
            return Err(ApiError::bad_request(
                "bad_query",
                "threshold_w_m2, min_duration_s (≥ 0), from_tdb_s and to_tdb_s must be finite",
            ));
        }
        Ok(())
    }
}

/// One charging window: its span (edges, duration, cut flags) and what it brings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Window {
    #[serde(flatten)]
    pub span: crate::sight::Window,
    /// ∫ E dt over the window, J/m².
    pub energy_j_m2: f64,
    /// Least irradiance in the window, W/m².
    pub min_w_m2: f64,
}

/// The windows of `samples` (epoch in TDB seconds, irradiance W/m², in time order), each
/// sample standing for `step_s` seconds, edges and energy as the module doc says.
pub fn charging_windows(
    samples: &[(f64, f64)],
    step_s: f64,
    threshold_w_m2: f64,
    min_duration_s: f64,
) -> Vec<Window> {
    contiguous_parts(samples, step_s)
        .flat_map(|part| windows_of_part(part, step_s, threshold_w_m2))
        .filter(|w| w.span.duration_s >= min_duration_s)
        .collect()
}

/// The runs of samples with no step missing between them: a gap (a filtered step) cuts a
/// window as the ends of the range do, since what happened in it is not known.
fn contiguous_parts(
    samples: &[(f64, f64)],
    step_s: f64,
) -> impl Iterator<Item = &[(f64, f64)]> + '_ {
    samples.chunk_by(move |a, b| b.0 - a.0 <= 1.5 * step_s)
}

/// The windows of one contiguous run of samples.
fn windows_of_part(part: &[(f64, f64)], step_s: f64, threshold_w_m2: f64) -> Vec<Window> {
    let (t, e): (Vec<f64>, Vec<f64>) = part.iter().copied().unzip();
    let margin: Vec<f64> = e.iter().map(|e| e - threshold_w_m2).collect();
    stretches(&t, &margin, |m| m >= 0.0)
        .into_iter()
        .map(|mut s| {
            (s.start, s.end) = edges_beside_darkness(&t, &e, &s, threshold_w_m2);
            // The last sample stands for its whole step, which the range still holds.
            let end = if s.cut_at_end {
                t[s.last] + step_s
            } else {
                s.end
            };
            let inner = s.first..=s.last;
            Window {
                span: crate::sight::Window::new(s.start, end, s.cut_at_start, s.cut_at_end),
                energy_j_m2: energy_over(&t, &e, &s, end, threshold_w_m2),
                min_w_m2: e[inner].iter().copied().fold(f64::INFINITY, f64::min),
            }
        })
        .collect()
}

/// The edges of stretch `s`, those beside a dark sample (E = 0) taken from the window's
/// own side. A dark sample says only that the light is off, not how far below it is (the
/// cosine is clamped at 0, or the Sun is behind terrain), so the line from it to the first
/// lit sample puts a sunrise over the facet up to a step early. The line through the two
/// lit samples next to the edge, extended back to the threshold, follows the rising cosine
/// instead; it is kept inside the edge's step, and used only where it rises toward the
/// window (else, as at a shadow's sharp edge, the line from the dark sample stays).
fn edges_beside_darkness(t: &[f64], e: &[f64], s: &Stretch, threshold_w_m2: f64) -> (f64, f64) {
    let (mut start, mut end) = (s.start, s.end);
    if s.last == s.first {
        return (start, end);
    }
    // Where the line through samples i and j equals the threshold, if it lies in [lo, hi].
    let extended = |i: usize, j: usize, lo: f64, hi: f64| {
        let slope = (e[j] - e[i]) / (t[j] - t[i]);
        let at = t[i] + (threshold_w_m2 - e[i]) / slope;
        (slope.is_finite() && slope != 0.0).then_some(at.clamp(lo, hi))
    };
    let (a, b) = (s.first, s.first + 1);
    if !s.cut_at_start && e[a - 1] == 0.0 && e[b] > e[a] {
        start = extended(a, b, t[a - 1], t[a]).unwrap_or(start);
    }
    let (y, z) = (s.last - 1, s.last);
    if !s.cut_at_end && e[z + 1] == 0.0 && e[y] > e[z] {
        end = extended(y, z, t[z], t[z + 1]).unwrap_or(end);
    }
    (start, end)
}

/// ∫ E dt over a stretch from its start to `end`, J/m²: the trapezoids of the straight
/// lines between its samples (the model its refined edges come from, where E equals the
/// threshold), and a cut end's last sample held for its step.
fn energy_over(t: &[f64], e: &[f64], s: &Stretch, end: f64, threshold_w_m2: f64) -> f64 {
    let trapezoid = |t0: f64, e0: f64, t1: f64, e1: f64| 0.5 * (e0 + e1) * (t1 - t0);
    let inner: f64 = (s.first..s.last)
        .map(|k| trapezoid(t[k], e[k], t[k + 1], e[k + 1]))
        .sum();
    let lead = if s.cut_at_start {
        0.0
    } else {
        trapezoid(s.start, threshold_w_m2, t[s.first], e[s.first])
    };
    let tail = if s.cut_at_end {
        e[s.last] * (end - t[s.last])
    } else {
        trapezoid(t[s.last], e[s.last], end, threshold_w_m2)
    };
    lead + inner + tail
}

/// Where one facet's rows lie in `history.parquet`: each step writes every facet of every
/// body in global order, so facet `global` of `total` is row `step × total + global`.
#[derive(Debug, Clone, Copy)]
pub struct HistoryRows {
    /// The facet's index over all bodies (body offset + facet id).
    pub global: usize,
    /// Facets of all bodies: the rows of one step.
    pub total: usize,
    pub steps: usize,
}

impl HistoryRows {
    /// The selection of the facet's rows, one per step: the reader then decodes only the
    /// pages that hold them (the file's offset index locates the pages).
    fn selection(&self) -> RowSelection {
        let mut rows = Vec::with_capacity(3 * self.steps);
        for _ in 0..self.steps {
            rows.push(RowSelector::skip(self.global));
            rows.push(RowSelector::select(1));
            rows.push(RowSelector::skip(self.total - self.global - 1));
        }
        rows.into()
    }
}

/// The (TDB seconds, W/m²) samples of facet `facet` of `body` from `history.parquet`, in
/// time order, reading only the facet's rows. Every row read is checked to be the facet's,
/// so a file of another layout is an error, not a wrong answer.
pub fn facet_history(
    dir: &Path,
    body: &str,
    facet: u32,
    rows: HistoryRows,
) -> crate::Result<Vec<(f64, f64)>> {
    let path = dir.join("history.parquet");
    let fail = |e: &dyn std::fmt::Display| crate::Error::file(&path, e.to_string());
    let file = std::fs::File::open(&path).map_err(|e| crate::Error::io(&path, e))?;
    let options = ArrowReaderOptions::new().with_page_index_policy(PageIndexPolicy::Optional);
    let builder = ParquetRecordBatchReaderBuilder::try_new_with_options(file, options)
        .map_err(|e| fail(&e))?;
    let wanted = ["et_tdb_s", "body", "facet", "irradiance_w_m2"];
    let mask = ProjectionMask::columns(builder.parquet_schema(), wanted);
    let reader = builder
        .with_projection(mask)
        .with_row_selection(rows.selection())
        .build()
        .map_err(|e| fail(&e))?;
    let mut samples = Vec::with_capacity(rows.steps);
    for batch in reader {
        let batch = batch.map_err(|e| fail(&e))?;
        let bodies = column::<StringArray>(&batch, "body", &path)?;
        let facets = column::<UInt32Array>(&batch, "facet", &path)?;
        let epochs = column::<Float64Array>(&batch, "et_tdb_s", &path)?;
        let values = column::<Float64Array>(&batch, "irradiance_w_m2", &path)?;
        for r in 0..batch.num_rows() {
            if facets.value(r) != facet || bodies.value(r) != body {
                return Err(fail(&format!(
                    "row {} of step {} is not facet {facet} of '{body}': the history is not in \
                     the layout slim writes",
                    rows.global,
                    samples.len()
                )));
            }
            samples.push((epochs.value(r), values.value(r)));
        }
    }
    if samples.len() != rows.steps {
        return Err(fail(&format!(
            "{} rows of facet {facet} of '{body}' for {} steps",
            samples.len(),
            rows.steps
        )));
    }
    samples.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(samples)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{PI, TAU};

    /// E(t) = max(0, S·sin ωt), sampled every `dt` from `t0` for `n` samples.
    fn sine(s: f64, omega: f64, t0: f64, dt: f64, n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|k| {
                let t = t0 + k as f64 * dt;
                (t, (s * (omega * t).sin()).max(0.0))
            })
            .collect()
    }

    /// Over E(t) = max(0, S·sin ωt) the threshold τ is reached at t = asin(τ/S)/ω and left
    /// at (π − asin(τ/S))/ω each period, with ∫ E dt = 2·√(S² − τ²)/ω in between. Linear
    /// interpolation misses each edge by at most Δt²·max|Ë|/(8|Ė|) = Δt²·ω/(8·cos(asin(τ/S)))
    /// (31 s at half-hour steps), where the step-quantised edges were up to 30 min off.
    #[test]
    fn refined_edges_and_energy_match_the_closed_form_of_a_sine() {
        let (s, tau, period) = (1000.0, 300.0, 86_400.0);
        let omega = TAU / period;
        let dt = period / 48.0;
        // Two days from 0.3 of a period, in daylight, so that the first window is cut by
        // the range's start and the last (begun at 2P + rise) by its end at 2.28 P.
        let samples = sine(s, omega, 0.3 * period, dt, 2 * 48);
        let w = charging_windows(&samples, dt, tau, 0.0);
        assert_eq!(w.len(), 3, "{w:?}");
        let rise = (tau / s).asin() / omega;
        let set = (PI - (tau / s).asin()) / omega;
        let bound = dt * dt * omega / (8.0 * (tau / s).asin().cos());
        assert!(bound < dt / 20.0);
        // The first starts at the first sample (cut), then ends at the first set.
        assert!(w[0].span.cut_at_start && !w[0].span.cut_at_end);
        assert_eq!(w[0].span.start_tdb_s, samples[0].0);
        assert!((w[0].span.end_tdb_s - set).abs() <= bound, "{:?}", w[0]);
        // The second is whole: both edges and the energy to the closed form.
        let whole = &w[1].span;
        assert!(!whole.cut_at_start && !whole.cut_at_end);
        assert!(
            (whole.start_tdb_s - (period + rise)).abs() <= bound,
            "{whole:?}"
        );
        assert!(
            (whole.end_tdb_s - (period + set)).abs() <= bound,
            "{whole:?}"
        );
        assert_eq!(whole.duration_s, whole.end_tdb_s - whole.start_tdb_s);
        let energy = 2.0 * (s * s - tau * tau).sqrt() / omega;
        // Trapezoids of a function with |Ë| ≤ Sω² err by at most (b − a)·Δt²·Sω²/12 over
        // the window and its edge steps; each edge, off by at most `bound` where E ≈ τ,
        // adds or drops about τ·bound more.
        let trapezoid_bound = (set - rise + 2.0 * dt) * dt * dt * s * omega * omega / 12.0;
        let edge_bound = 2.0 * tau * bound;
        let error = (w[1].energy_j_m2 - energy).abs();
        assert!(
            error <= trapezoid_bound + edge_bound,
            "{error} J/m² of {energy}"
        );
        assert!(w[1].min_w_m2 >= tau);
        // The last begins at a rise and is cut by the range's end: it ends with the last
        // sample's step, not past it.
        let last = &w[2].span;
        assert!(!last.cut_at_start && last.cut_at_end);
        assert!((last.start_tdb_s - (2.0 * period + rise)).abs() <= bound);
        assert_eq!(last.end_tdb_s, samples.last().unwrap().0 + dt);
        // Every refined edge lies within the step of its crossing.
        for win in &w[1..] {
            let k = samples
                .iter()
                .position(|x| x.0 >= win.span.start_tdb_s)
                .unwrap();
            assert!(samples[k - 1].1 < tau && samples[k].1 >= tau);
        }
        // A least duration above a day's window leaves none of the whole ones.
        assert!(charging_windows(&samples, dt, tau, set - rise + 2.0 * bound).is_empty());
    }

    /// A threshold of ~0 over max(0, S·sin ωt): the dark samples before sunrise hold 0,
    /// not the negative sine, so the edges come from the lit side's line, which misses
    /// the true sunrise (t = 0) and sunset (P/2) by at most Δt²·max|Ë|/|Ė| over the two
    /// steps, Δt²·ω·tan(2ωΔt) = 63 s at half-hour steps. The line from the dark sample
    /// would put the edge anywhere in the step, up to 30 min early.
    #[test]
    fn edges_beside_dark_samples_follow_the_lit_side() {
        let period = 86_400.0;
        let omega = TAU / period;
        let dt = period / 48.0;
        let bound = dt * dt * omega * (2.0 * omega * dt).tan();
        for offset in [0.1, 0.5, 0.9] {
            let samples = sine(1000.0, omega, -period / 4.0 + offset * dt, dt, 48);
            let w = charging_windows(&samples, dt, 1e-9, 0.0);
            assert_eq!(w.len(), 1, "{w:?}");
            let span = &w[0].span;
            assert!(span.start_tdb_s.abs() <= bound, "offset {offset}: {span:?}");
            assert!((span.end_tdb_s - period / 2.0).abs() <= bound, "{span:?}");
            let energy = 2.0 * 1000.0 / omega;
            // Trapezoids of a sine arch at steps of h = ωΔt err by about h²/12 = 1.4e-3.
            assert!((w[0].energy_j_m2 - energy).abs() < 2e-3 * energy);
        }
    }

    #[test]
    fn dark_steps_and_gaps_split_windows() {
        let samples = [
            (0.0, 10.0),
            (1.0, 10.0),
            (2.0, 0.0),
            (3.0, 10.0),
            (4.0, 10.0),
            (6.0, 10.0),
        ];
        let w = charging_windows(&samples, 1.0, 5.0, 0.0);
        let spans: Vec<(f64, f64, f64)> = w
            .iter()
            .map(|w| (w.span.start_tdb_s, w.span.end_tdb_s, w.energy_j_m2))
            .collect();
        // Edges half-way through the dark step (the line from 10 to 0 meets 5 there), with
        // the triangle above 5 W/m² of each half step; the missing step at 5 s cuts the
        // second window at its last sample's step and the third at its own.
        assert_eq!(
            spans,
            [(0.0, 1.5, 13.75), (2.5, 5.0, 23.75), (6.0, 7.0, 10.0)]
        );
        let cuts: Vec<(bool, bool)> = w
            .iter()
            .map(|w| (w.span.cut_at_start, w.span.cut_at_end))
            .collect();
        assert_eq!(cuts, [(true, false), (false, true), (true, true)]);
        assert_eq!(charging_windows(&samples, 1.0, 5.0, 2.0).len(), 1);
        assert!(charging_windows(&[], 1.0, 5.0, 0.0).is_empty());
    }
}
