//! Sight: what a place on a body sees of another body (the Earth from a lunar site, for
//! direct-to-Earth links, or any body of the scene), and the windows in which it is seen.
//!
//! In: each step's [`EpochState`] (every body's pose), the observing body, a point in its
//! frame (metres) and the target body; for terrain, the [`Site`] at that point. Out: per
//! step the elevation of the target's centre above the local horizontal and the horizon's
//! elevation toward it (radians), and the windows in which the first is above the second.
//!
//! Directions are geometric: both bodies' positions at the same epoch, no light time or
//! stellar aberration (for the Earth seen from the Moon they move it by under 0.01°).
//! The target counts as seen when its centre is above the horizon.
//!
//! Windows ([`windows_above`]): from a quantity sampled at the steps (here the elevation
//! minus the horizon), the intervals where it is above zero. Each edge is refined inside
//! its step to where the straight line between the two samples around it crosses zero
//! (error at most Δt²·max|m̈|/(8·|ṁ|) for a margin m sampled Δt apart). An interval that
//! begins at the first sample or ends at the last is flagged as cut by the range: its true
//! edge lies outside it.

use crate::ephemeris::{utc_text, EpochState};
use crate::panel::Site;
use glam::DVec3;
use serde::Serialize;

/// The unit direction (observer's body frame) from `point_m` (observer's frame, metres)
/// on body `observer` to the centre of body `target` at `state`.
pub fn direction_to(state: &EpochState, observer: usize, point_m: DVec3, target: usize) -> DVec3 {
    let from = &state.bodies[observer].pose;
    let to = &state.bodies[target].pose;
    // Difference of positions first: both may be huge, their difference is not.
    let apart = (to.position_m - from.position_m) - from.body_to_scene * point_m;
    (from.body_to_scene.transpose() * apart).normalize()
}

/// Where a target stands in a site's sky at one step, radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    /// Elevation of the target's centre above the local horizontal.
    pub elevation: f64,
    /// Elevation of the terrain's horizon toward it.
    pub horizon: f64,
}

impl Sighting {
    /// The target `target` from `site` on body `observer` at `state`.
    pub fn of(site: &Site, state: &EpochState, observer: usize, target: usize) -> Sighting {
        let dir = direction_to(state, observer, site.point(), target);
        Sighting {
            elevation: site.elevation(dir),
            horizon: site.horizon_toward(dir),
        }
    }

    /// True when the target's centre is above the horizon.
    pub fn seen(&self) -> bool {
        self.elevation > self.horizon
    }
}

/// An interval of time (in which a sampled quantity stays above zero), with its edges
/// in TDB seconds and UTC and whether the sampled range cut it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Window {
    pub start_tdb_s: f64,
    pub end_tdb_s: f64,
    pub start_utc: String,
    pub end_utc: String,
    pub duration_s: f64,
    /// It begins at the first sample: it may have begun earlier.
    pub cut_at_start: bool,
    /// It ends at the last sample: it may go on later.
    pub cut_at_end: bool,
}

/// The windows in which `margin` (sampled at the increasing epochs `t`, TDB seconds) is
/// above zero, edges refined as the module doc says.
pub fn windows_above(t: &[f64], margin: &[f64]) -> Vec<Window> {
    stretches(t, margin, |m| m > 0.0)
        .into_iter()
        .map(|s| Window::new(s.start, s.end, s.cut_at_start, s.cut_at_end))
        .collect()
}

/// A run of consecutive samples inside a set (above zero, at or above a threshold), with
/// its edges in time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stretch {
    /// Its first and last sample.
    pub first: usize,
    pub last: usize,
    /// Its edges, TDB seconds: refined between samples, or the first or last sample's
    /// epoch where it is cut.
    pub start: f64,
    pub end: f64,
    /// It holds the first sample: its true start is not known.
    pub cut_at_start: bool,
    /// It holds the last sample: its true end is not known.
    pub cut_at_end: bool,
}

/// The stretches of samples whose `margin` (at the increasing epochs `t`) is `inside`,
/// where the margin's zero is the set's border. Each edge between a sample outside and one
/// inside is refined to where the straight line through the two crosses zero (so it lies
/// in that step, at the inside sample at the latest); a stretch holding the first or last
/// sample starts or ends at its epoch and is flagged as cut, never extended past it.
pub fn stretches(t: &[f64], margin: &[f64], inside: impl Fn(f64) -> bool) -> Vec<Stretch> {
    assert_eq!(t.len(), margin.len(), "one margin per epoch");
    let crossing = |k: usize| {
        // Between samples k and k + 1, one on each side: a and b differ in sign (or b is
        // zero), so the division is safe and the result lies in [t[k], t[k + 1]].
        let (a, b) = (margin[k], margin[k + 1]);
        t[k] + (t[k + 1] - t[k]) * (a / (a - b))
    };
    let mut found = Vec::new();
    let mut open: Option<(usize, f64)> = None;
    for (k, &m) in margin.iter().enumerate() {
        match (inside(m), open) {
            (true, None) => {
                open = Some((k, if k == 0 { t[0] } else { crossing(k - 1) }));
            }
            (false, Some((first, start))) => {
                found.push(Stretch {
                    first,
                    last: k - 1,
                    start,
                    end: crossing(k - 1),
                    cut_at_start: first == 0,
                    cut_at_end: false,
                });
                open = None;
            }
            _ => {}
        }
    }
    if let Some((first, start)) = open {
        let last = t.len() - 1;
        found.push(Stretch {
            first,
            last,
            start,
            end: t[last],
            cut_at_start: first == 0,
            cut_at_end: true,
        });
    }
    found
}

impl Window {
    /// The window from `start` to `end` (TDB seconds), with its cut flags.
    pub fn new(start: f64, end: f64, cut_at_start: bool, cut_at_end: bool) -> Window {
        Window {
            start_tdb_s: start,
            end_tdb_s: end,
            start_utc: utc_text(start),
            end_utc: utc_text(end),
            duration_s: end - start,
            cut_at_start,
            cut_at_end,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_of_a_sine_have_their_edges_at_its_zeros_and_flag_the_cut_ones() {
        // sin(2π t / 100) sampled every 7 s from 0.5 s: above zero on (0, 50), (100, 150),
        // (200, 250). The first starts at the first sample (cut). The line between samples
        // misses a zero by at most Δt²·max|m̈|/(8|ṁ|) = 49·(2π/100)²/(8·2π/100) = 0.38 s.
        let t: Vec<f64> = (0..=42).map(|k| 7.0 * k as f64 + 0.5).collect();
        let m: Vec<f64> = t
            .iter()
            .map(|&x| (std::f64::consts::TAU * x / 100.0).sin())
            .collect();
        let w = windows_above(&t, &m);
        let bound = 49.0 * (std::f64::consts::TAU / 100.0) / 8.0;
        assert_eq!(w.len(), 3, "{w:?}");
        assert!(w[0].cut_at_start && !w[0].cut_at_end);
        assert_eq!(w[0].start_tdb_s, 0.5);
        for (k, win) in w.iter().enumerate() {
            let (zero_up, zero_down) = (100.0 * k as f64, 100.0 * k as f64 + 50.0);
            if k > 0 {
                assert!((win.start_tdb_s - zero_up).abs() <= bound, "{win:?}");
            }
            assert!((win.end_tdb_s - zero_down).abs() <= bound, "{win:?}");
        }
        // Ending above zero: the last window is cut at the end.
        let w = windows_above(&t[..30], &m[..30]);
        assert!(w.last().unwrap().cut_at_end);
        assert_eq!(w.last().unwrap().end_tdb_s, t[29]);
        assert!(windows_above(&[], &[]).is_empty());
    }

    #[test]
    fn utc_text_is_rounded_to_the_millisecond() {
        let noon = hifitime::Epoch::from_gregorian_utc_hms(2024, 9, 1, 4, 0, 0).to_tdb_seconds();
        assert_eq!(utc_text(noon - 3e-9), "2024-09-01T04:00:00.000Z");
        assert_eq!(utc_text(noon + 0.0126), "2024-09-01T04:00:00.013Z");
    }
}
