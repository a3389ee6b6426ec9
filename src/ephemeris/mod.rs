//! Ephemeris: the sequence of epochs a run steps through, and at each epoch the Sun's
//! direction and distance in every body's frame and every body's pose.
//!
//! In: a scene's `[ephemeris]` table. Out: an [`Ephemeris`], which the engine asks for one
//! [`EpochState`] per step. This is the seam where geometry sources plug in: the synthetic
//! spin model ([`spin`]) and the listed fixed geometries ([`fixed`]) live here; SPICE-driven
//! geometry implements the same trait.
//!
//! Units: directions are unit vectors, distances metres, flux W/m², epochs hifitime `Epoch`.

pub mod fixed;
pub mod spice;
pub mod spin;
pub mod synthetic;

use crate::error::Result;
use crate::world::Pose;
use glam::DVec3;
use hifitime::Epoch;

/// The Sun and the pose of one body at one epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyState {
    /// Unit vector from the body centre toward the Sun, body-fixed frame.
    pub sun_dir: DVec3,
    /// Distance from the body centre to the Sun, metres.
    pub sun_distance_m: f64,
    /// Solar irradiance at the body, W/m², on a surface facing the Sun.
    pub flux_w_m2: f64,
    /// Pose of the body in the scene frame.
    pub pose: Pose,
}

impl BodyState {
    /// Every number of the state, as bits: equal bits mean the same light, and NaN (a
    /// Sun given by its flux alone has no distance) equals itself.
    fn bits(&self) -> [u64; 17] {
        let m = self.pose.body_to_scene.to_cols_array();
        let v = [self.sun_dir, self.pose.position_m].map(|v| v.to_array());
        let all = [
            v[0][0],
            v[0][1],
            v[0][2],
            self.sun_distance_m,
            self.flux_w_m2,
            m[0],
            m[1],
            m[2],
            m[3],
            m[4],
            m[5],
            m[6],
            m[7],
            m[8],
            v[1][0],
            v[1][1],
            v[1][2],
        ];
        all.map(f64::to_bits)
    }
}

/// The number of steps after which the bodies' geometry repeats: the least `m` such that
/// every step `k ≥ m` has, bit for bit, the Sun and poses of step `k − m` (a spin scene of
/// several periods whose steps divide the period, a fixed geometry listing one Sun);
/// `states.len()` when it never repeats. Only the first step with step 0's geometry is
/// tried as `m`: a geometry that passes through step 0's within a longer cycle counts as
/// not repeating, which loses speed but never changes a result.
pub fn repeat_period(states: &[EpochState]) -> usize {
    let Some(first) = states.first() else {
        return 0;
    };
    let same = |a: &EpochState, b: &EpochState| {
        a.bodies.len() == b.bodies.len()
            && a.bodies
                .iter()
                .zip(&b.bodies)
                .all(|(x, y)| x.bits() == y.bits())
    };
    let m = (states.iter().skip(1))
        .position(|s| same(s, first))
        .map_or(states.len(), |p| p + 1);
    match (m..states.len()).all(|k| same(&states[k], &states[k - m])) {
        true => m,
        false => states.len(),
    }
}

/// The earlier step whose Sun stands nearest a step's own, as a fixed number of steps
/// back: a spin stepped hourly turns the Sun 30° a step but brings it back within a
/// fraction of a degree a spin later, and the shadow rays of a step start from the
/// blockers the rays of that earlier step found ([`crate::illum`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunReturn {
    /// Steps back, at least 1.
    pub lag: usize,
    /// The median angle, degrees, between a step's Sun and the Sun `lag` steps before in
    /// a body's frame, over the bodies weighed and every step: the median, not the mean,
    /// so that a few long gaps (a window's jumps) do not stand for the run. 0 with fewer
    /// than two steps, infinite with no body weighed.
    pub turn_deg: f64,
}

impl SunReturn {
    /// The step before, the Sun's turn unknown: what a run assumes that has not looked
    /// at its steps.
    pub const UNKNOWN: SunReturn = SunReturn {
        lag: 1,
        turn_deg: f64::INFINITY,
    };
}

/// Turns this small count as none: from 0.1° to 1° the walks from a remembered blocker
/// answer as many rays (docs/performance.md), so a longer lag buys nothing below it.
const NEGLIGIBLE_TURN_DEG: f64 = 0.1;

/// A lag counts as good as the best when its turn is within this factor of the best
/// one's; the shortest such lag is taken: it keeps fewer steps' blockers.
const NEARLY_AS_NEAR: f64 = 1.25;

/// Pairs of steps whose angle is measured per lag, spread evenly over the run: enough
/// for a median, and a run of millions of steps is weighed in milliseconds.
const SAMPLED_PAIRS: usize = 20_000;

/// Where the Sun returns ([`SunReturn`]) in the frames of the bodies numbered in `bodies`
/// (those whose rays recall blockers: another body's frame may turn at another pace),
/// looking at most `max_lag` steps back.
pub fn sun_return(states: &[EpochState], bodies: &[usize], max_lag: usize) -> SunReturn {
    let longest = max_lag.max(1).min(states.len().saturating_sub(1));
    let turns: Vec<(usize, f64)> = (1..=longest)
        .map(|lag| (lag, median_turn_deg(states, bodies, lag)))
        .collect();
    let counted = |turn: f64| turn.max(NEGLIGIBLE_TURN_DEG);
    let Some(best) = turns.iter().map(|t| counted(t.1)).min_by(f64::total_cmp) else {
        return SunReturn {
            lag: 1,
            turn_deg: 0.0,
        };
    };
    let (lag, turn_deg) = (turns.into_iter())
        .find(|t| counted(t.1) <= NEARLY_AS_NEAR * best)
        .expect("the best lag is nearly as near as itself");
    SunReturn { lag, turn_deg }
}

/// The median angle (degrees) between the Sun of a step and that of the step `lag`
/// before, in the frame of each body of `bodies` (`lag < states.len()`); infinite when
/// no angle is finite.
fn median_turn_deg(states: &[EpochState], bodies: &[usize], lag: usize) -> f64 {
    let stride = (states.len() - lag).div_ceil(SAMPLED_PAIRS).max(1);
    let mut turns: Vec<f64> = (lag..states.len())
        .step_by(stride)
        .flat_map(|k| {
            let (then, now) = (&states[k - lag], &states[k]);
            let sun = |state: &EpochState, b: usize| state.bodies.get(b).map(|s| s.sun_dir);
            bodies
                .iter()
                .filter_map(move |&b| Some(sun(then, b)?.angle_between(sun(now, b)?)))
        })
        .filter(|t| t.is_finite())
        .collect();
    if turns.is_empty() {
        return f64::INFINITY;
    }
    let mid = turns.len() / 2;
    turns.select_nth_unstable_by(mid, f64::total_cmp);
    turns[mid].to_degrees()
}

/// The geometry of every body at one step.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochState {
    /// Step index, 0-based.
    pub step: usize,
    /// The epoch of this step.
    pub epoch: Epoch,
    /// One state per body, in scene order.
    pub bodies: Vec<BodyState>,
}

/// A source of geometry: a fixed number of steps, each an [`EpochState`].
pub trait Ephemeris: Send + Sync {
    /// Number of steps.
    fn steps(&self) -> usize;
    /// The geometry at `step` (`step < steps()`).
    fn state(&self, step: usize) -> Result<EpochState>;
    /// Total time covered, seconds (each step stands for `duration / steps`).
    fn duration_s(&self) -> f64;
    /// The SPICE kernels this ephemeris reads, if it reads any.
    fn kernels(&self) -> Option<&spice::Kernels> {
        None
    }
}

/// A TDB epoch (seconds past J2000) as UTC text rounded to the millisecond,
/// `YYYY-MM-DDTHH:MM:SS.sssZ`: no rounding noise such as `03:59:59.999999997`.
pub fn utc_text(tdb_s: f64) -> String {
    let utc = Epoch::from_tdb_seconds(tdb_s)
        .to_time_scale(hifitime::TimeScale::UTC)
        .round(hifitime::Unit::Millisecond * 1);
    let (y, mo, d, h, mi, s, ns) = utc.to_gregorian_utc();
    format!(
        "{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}.{:03}Z",
        ns / 1_000_000
    )
}

/// Solar irradiance (W/m²) at `distance_m` from the Sun for a solar constant at 1 AU.
pub fn flux_at(solar_constant_w_m2: f64, distance_m: f64) -> f64 {
    let r_au = distance_m / crate::AU_M;
    solar_constant_w_m2 / (r_au * r_au)
}
