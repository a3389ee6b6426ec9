//! The Lambert model: a perfectly diffuse surface.
//!
//! r(i, e, g) = A · cos i / π (sr⁻¹), with A the Lambert (hemispherical) albedo: the
//! surface scatters the fraction A of the light it receives, with the same radiance in
//! every direction. Its directional-hemispherical reflectance is exactly A for every i.
//! Reference: J. H. Lambert, Photometria (1760); Hapke (2012), "Theory of Reflectance and
//! Emittance Spectroscopy", 2nd ed., section 8.2.

use super::{Angles, Reflectance};

/// A Lambert surface of albedo `albedo` (0 … 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lambert {
    pub albedo: f64,
}

impl Default for Lambert {
    fn default() -> Self {
        Lambert { albedo: 1.0 }
    }
}

impl Reflectance for Lambert {
    fn reflectance(&self, a: &Angles) -> f64 {
        if !a.is_lit_and_seen() {
            return 0.0;
        }
        self.albedo * a.cos_i / std::f64::consts::PI
    }
}
