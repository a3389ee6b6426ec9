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
