//! Windows: charging windows of one facet from a finished job's irradiance history — the
//! intervals in which the irradiance stays at or above a threshold for at least a given
//! duration, the question a rover planner asks before parking.
//!
//! In: `history.parquet` (step, TDB seconds, body, facet, W/m²) of a job run with
//! `[output] history = true`, the run's step length (duration / steps, seconds), a
//! threshold (W/m²) and a least duration (s). Out: windows with start and end (TDB seconds
//! past J2000, and UTC), duration (s) and energy (J/m²). Each sample stands for the step
//! that starts at its epoch, so a window runs from its first sample's epoch to the end of
//! its last sample's step and its energy is Σ E·Δt; its edges are those of the steps (not
//! refined inside them), and it is flagged when it touches the first or last sample asked
//! for. Times print in UTC to the millisecond.

use super::reply::{ApiError, ApiResult};
use crate::output::read::column;
use arrow::array::{Float64Array, StringArray, UInt32Array};
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
/// sample standing for `step_s` seconds.
pub fn charging_windows(
    samples: &[(f64, f64)],
    step_s: f64,
    threshold_w_m2: f64,
    min_duration_s: f64,
) -> Vec<Window> {
    let mut windows = Vec::new();
    let (first, final_sample) = match (samples.first(), samples.last()) {
        (Some(a), Some(b)) => (a.0, b.0),
        _ => return windows,
    };
    let mut run: Option<(f64, f64, f64, f64)> = None; // start, last epoch, energy, min
    let mut close = |run: Option<(f64, f64, f64, f64)>| {
        if let Some((start, last, energy, min)) = run {
            let end = last + step_s;
            if end - start >= min_duration_s {
                windows.push(Window {
                    span: crate::sight::Window::new(
                        start,
                        end,
                        start == first,
                        last == final_sample,
                    ),
                    energy_j_m2: energy,
                    min_w_m2: min,
                });
            }
        }
    };
    for &(t, e) in samples {
        // A gap in the samples (a filtered step) ends a window like a dark step does.
        let contiguous = run.is_some_and(|(_, last, _, _)| t - last <= 1.5 * step_s);
        if e >= threshold_w_m2 {
            run = match run {
                Some((start, _, energy, min)) if contiguous => {
                    Some((start, t, energy + e * step_s, min.min(e)))
                }
                other => {
                    close(other);
                    Some((t, t, e * step_s, e))
                }
            };
        } else {
            close(run.take());
        }
    }
    close(run);
    windows
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

    /// E(t) = S·max(0, cos ωt) sampled every step over one period, centred on noon:
    /// E ≥ S/2 exactly while |ωt| ≤ π/3, a window of P/3 with energy 2·S·sin(π/3)/ω.
    #[test]
    fn one_window_per_day_matches_the_closed_form() {
        let (s, period, n) = (1000.0, 86_400.0, 3600);
        let dt = period / n as f64;
        let omega = std::f64::consts::TAU / period;
        let samples: Vec<(f64, f64)> = (0..n)
            .map(|k| {
                let t = -period / 2.0 + k as f64 * dt;
                (t, s * (omega * t).cos().max(0.0))
            })
            .collect();
        let w = charging_windows(&samples, dt, s / 2.0, 0.0);
        assert_eq!(w.len(), 1);
        assert!(
            (w[0].span.duration_s - period / 3.0).abs() <= 2.0 * dt,
            "{:?}",
            w[0]
        );
        let energy = 2.0 * s * (std::f64::consts::PI / 3.0).sin() / omega;
        // Riemann sum of a smooth function, plus at most one partial step at each end.
        assert!(
            (w[0].energy_j_m2 - energy).abs() <= 2.0 * s * dt,
            "{} vs {energy}",
            w[0].energy_j_m2
        );
        assert!(w[0].min_w_m2 >= s / 2.0);
        // The same day asked for windows of at least half a day: none.
        assert!(charging_windows(&samples, dt, s / 2.0, period / 2.0).is_empty());
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
        assert_eq!(
            spans,
            [(0.0, 2.0, 20.0), (3.0, 5.0, 20.0), (6.0, 7.0, 10.0)]
        );
        let cuts: Vec<(bool, bool)> = w
            .iter()
            .map(|w| (w.span.cut_at_start, w.span.cut_at_end))
            .collect();
        assert_eq!(cuts, [(true, false), (false, false), (false, true)]);
        assert_eq!(charging_windows(&samples, 1.0, 5.0, 2.0).len(), 2);
        assert!(charging_windows(&[], 1.0, 5.0, 0.0).is_empty());
    }
}
