//! What the report says in words and numbers: the geometry covered and the accuracy the
//! run's step count gives.
//!
//! In: the `geometry` rows (Sun unit vectors in each body frame, distances in km, flux in
//! W/m²) and the plan's step count. Out: [`GeometrySummary`] (epochs, per body the Sun
//! distance and flux ranges and how far the Sun moves in body longitude per step) and
//! [`Accuracy`]: the error rule of docs/accuracy.md — F(x) error ≈ 1/n (one step's share
//! of time) and mean error ≈ 0.92·S/n² on a smooth body (its sphere table: 0.55 W/m² at
//! n = 48, S = 1361 W/m²), several times more on rough terrain — with n the steps per turn
//! of the Sun in the body's sky (or the run's steps when the Sun does not turn).

use crate::output::read::{GeometryRow, RunData};

/// The Sun as seen from one body over the run.
#[derive(Debug, Clone)]
pub struct BodyGeometry {
    pub name: String,
    pub distance_km: (f64, f64),
    pub flux_w_m2: (f64, f64),
    /// Median change of the Sun's body-frame longitude per step, degrees (absolute).
    pub sun_step_deg: Option<f64>,
}

/// Epochs covered and per-body Sun geometry.
#[derive(Debug, Clone)]
pub struct GeometrySummary {
    pub first_utc: String,
    pub last_utc: String,
    pub steps: usize,
    pub bodies: Vec<BodyGeometry>,
}

/// (min, max) of the finite values (NaN, NaN when there are none).
fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.is_finite())
        .fold((f64::NAN, f64::NAN), |(lo, hi), v| (lo.min(v), hi.max(v)))
}

/// Median longitude change of the Sun per step, degrees.
fn sun_step_deg(rows: &[&GeometryRow]) -> Option<f64> {
    let lon = |r: &GeometryRow| r.sun.y.atan2(r.sun.x).to_degrees();
    let mut steps: Vec<f64> = rows
        .windows(2)
        .filter(|w| w[0].sun.truncate().length() > 1e-9 && w[1].sun.truncate().length() > 1e-9)
        .map(|w| ((lon(w[1]) - lon(w[0]) + 180.0).rem_euclid(360.0) - 180.0).abs())
        .filter(|d| d.is_finite())
        .collect();
    steps.sort_by(f64::total_cmp);
    steps.get(steps.len() / 2).copied()
}

impl GeometrySummary {
    /// Summarises the run's geometry rows.
    pub fn new(run: &RunData) -> GeometrySummary {
        let mut rows: Vec<&GeometryRow> = run.geometry.iter().collect();
        rows.sort_by_key(|r| r.step);
        let mut steps: Vec<u64> = rows.iter().map(|r| r.step).collect();
        steps.dedup();
        let bodies = run
            .bodies
            .iter()
            .map(|b| {
                let mine: Vec<&GeometryRow> =
                    rows.iter().copied().filter(|r| r.body == b.name).collect();
                BodyGeometry {
                    name: b.name.clone(),
                    distance_km: range(mine.iter().map(|r| r.sun_distance_km)),
                    flux_w_m2: range(mine.iter().map(|r| r.flux_w_m2)),
                    sun_step_deg: sun_step_deg(&mine),
                }
            })
            .collect();
        GeometrySummary {
            first_utc: rows.first().map_or_else(String::new, |r| r.utc.clone()),
            last_utc: rows.last().map_or_else(String::new, |r| r.utc.clone()),
            steps: steps.len(),
            bodies,
        }
    }
}

/// Error estimates from the step count.
#[derive(Debug, Clone, Copy)]
pub struct Accuracy {
    /// Steps of the run.
    pub steps: usize,
    /// Steps per turn of the Sun in the first body's sky, when it turns.
    pub steps_per_turn: Option<f64>,
    /// Estimated error of F(x), a share (≈ 1/n).
    pub cdf_error: f64,
    /// Estimated error of the mean on a smooth body, W/m² (≈ 0.92·S/n²).
    pub mean_error_w_m2: f64,
}

/// The smooth-sphere constant of docs/accuracy.md: mean error · n² / S.
const MEAN_ERROR_CONSTANT: f64 = 0.92;

impl Accuracy {
    /// Estimates from the plan's steps and the geometry summary.
    pub fn new(steps: usize, geometry: &GeometrySummary) -> Accuracy {
        let steps_per_turn = geometry
            .bodies
            .first()
            .and_then(|b| b.sun_step_deg)
            .filter(|d| *d > 1e-9)
            .map(|d| 360.0 / d);
        let n = steps_per_turn.unwrap_or(steps.max(1) as f64).max(1.0);
        let flux = geometry
            .bodies
            .iter()
            .map(|b| b.flux_w_m2.1)
            .filter(|f| f.is_finite())
            .fold(0.0, f64::max);
        Accuracy {
            steps,
            steps_per_turn,
            cdf_error: 1.0 / n,
            mean_error_w_m2: MEAN_ERROR_CONSTANT * flux / (n * n),
        }
    }
}
