//! Synthetic spin model: bodies rotating uniformly about the scene z axis under a Sun that
//! stays fixed in the scene frame (no orbital motion within the run).
//!
//! In: the Sun's distance (AU) and sub-solar latitude δ, each body's spin period and
//! initial rotation, the number of steps. Out: per step, the Sun direction in each body
//! frame, s = Rz(−θ(t)) · (cos δ, 0, sin δ) with θ(t) = θ₀ + 2π t / P, and the flux
//! S₀ / r². Steps sample t = k·Δt, k = 0 … n−1, Δt = duration / n, so a whole number of
//! periods is sampled uniformly in hour angle.

use super::{flux_at, BodyState, Ephemeris, EpochState};
use crate::error::Result;
use crate::world::Pose;
use glam::{DMat3, DVec3};
use hifitime::{Duration, Epoch};

/// Rotation of one body in the spin model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spin {
    /// Sidereal rotation period, seconds; `None` for a body that does not rotate.
    pub period_s: Option<f64>,
    /// Rotation angle about z at the first step, radians.
    pub initial_angle_rad: f64,
    /// Body centre in the scene frame, metres.
    pub position_m: DVec3,
}

/// The spin-model ephemeris.
#[derive(Debug, Clone)]
pub struct SpinModel {
    /// Epoch of step 0.
    pub start: Epoch,
    /// Time covered, seconds.
    pub duration_s: f64,
    /// Number of steps.
    pub steps: usize,
    /// Unit vector toward the Sun in the scene frame.
    pub sun_dir_scene: DVec3,
    /// Sun distance, metres.
    pub sun_distance_m: f64,
    /// Irradiance at 1 AU, W/m².
    pub solar_constant_w_m2: f64,
    /// One entry per body.
    pub bodies: Vec<Spin>,
}

impl SpinModel {
    /// Sun direction in the scene frame for a sub-solar latitude (radians).
    pub fn sun_dir_for_subsolar_latitude(latitude_rad: f64) -> DVec3 {
        DVec3::new(latitude_rad.cos(), 0.0, latitude_rad.sin())
    }

    fn time_s(&self, step: usize) -> f64 {
        self.duration_s * step as f64 / self.steps as f64
    }

    /// Turns a body of period `period_s` has made at `step`, from the step's place within
    /// the period when a whole number of steps fills it: every period's steps then repeat
    /// the first's bit for bit, and a run computes the light of one period only
    /// ([`crate::ephemeris::repeat_period`]).
    fn turns(&self, step: usize, period_s: f64) -> f64 {
        let per_turn = period_s * self.steps as f64 / self.duration_s;
        let whole = per_turn.round();
        match whole >= 1.0 && whole < u32::MAX as f64 && (per_turn - whole).abs() < 1e-9 * whole {
            true => (step % whole as usize) as f64 / whole,
            false => self.time_s(step) / period_s,
        }
    }
}

impl Ephemeris for SpinModel {
    fn steps(&self) -> usize {
        self.steps
    }

    fn duration_s(&self) -> f64 {
        self.duration_s
    }

    fn state(&self, step: usize) -> Result<EpochState> {
        let t = self.time_s(step);
        let flux = flux_at(self.solar_constant_w_m2, self.sun_distance_m);
        let bodies = self
            .bodies
            .iter()
            .map(|spin| {
                let angle = spin.initial_angle_rad
                    + spin
                        .period_s
                        .map_or(0.0, |p| std::f64::consts::TAU * self.turns(step, p));
                let body_to_scene = DMat3::from_rotation_z(angle);
                BodyState {
                    sun_dir: body_to_scene.transpose() * self.sun_dir_scene,
                    sun_distance_m: self.sun_distance_m,
                    flux_w_m2: flux,
                    pose: Pose {
                        body_to_scene,
                        position_m: spin.position_m,
                    },
                }
            })
            .collect();
        Ok(EpochState {
            step,
            epoch: self.start + Duration::from_seconds(t),
            bodies,
        })
    }
}
