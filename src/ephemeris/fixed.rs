//! Fixed geometry: a list of Sun directions and fluxes given in the scene, with bodies at
//! fixed poses. For laboratory cases, tests and one-off geometries.
//!
//! In: per step, the unit vector toward the Sun in the scene frame and the flux (W/m²) or
//! Sun distance; per body, a fixed pose. Out: one [`EpochState`] per listed Sun, epochs
//! `start + k · step_s`.

use super::{BodyState, Ephemeris, EpochState};
use crate::error::Result;
use crate::world::Pose;
use glam::DVec3;
use hifitime::{Duration, Epoch};

/// One listed illumination: Sun direction (scene frame), distance and flux.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixedSun {
    /// Unit vector toward the Sun, scene frame.
    pub dir_scene: DVec3,
    /// Sun distance, metres (for outputs only; NaN when the scene gives only the flux).
    pub distance_m: f64,
    /// Irradiance, W/m².
    pub flux_w_m2: f64,
}

/// The fixed-geometry ephemeris.
#[derive(Debug, Clone)]
pub struct FixedGeometry {
    pub start: Epoch,
    /// Time between listed Suns, seconds (each step stands for this long in statistics).
    pub step_s: f64,
    pub suns: Vec<FixedSun>,
    /// One fixed pose per body.
    pub poses: Vec<Pose>,
}

impl Ephemeris for FixedGeometry {
    fn steps(&self) -> usize {
        self.suns.len()
    }

    fn duration_s(&self) -> f64 {
        self.step_s * self.suns.len() as f64
    }

    fn state(&self, step: usize) -> Result<EpochState> {
        let sun = self.suns[step];
        let bodies = self
            .poses
            .iter()
            .map(|pose| BodyState {
                sun_dir: pose.body_to_scene.transpose() * sun.dir_scene,
                sun_distance_m: sun.distance_m,
                flux_w_m2: sun.flux_w_m2,
                pose: *pose,
            })
            .collect();
        Ok(EpochState {
            step,
            epoch: self.start + Duration::from_seconds(self.step_s * step as f64),
            bodies,
        })
    }
}

/// Normalises a direction listed in a scene; `None` unless it is finite and non-zero.
pub fn normalized_direction(v: [f64; 3]) -> Option<DVec3> {
    let d = DVec3::from_array(v);
    let n = d.length();
    (n.is_finite() && n > 0.0).then(|| d / n)
}
