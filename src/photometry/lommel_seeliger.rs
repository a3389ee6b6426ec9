//! The Lommel–Seeliger model: single isotropic scattering in a semi-infinite medium.
//!
//! r(i, e, g) = (w / 4π) · μ₀ / (μ₀ + μ) (sr⁻¹), μ₀ = cos i, μ = cos e, w the single
//! scattering albedo. It is the w → 0 limit of Hapke's model with an isotropic phase
//! function and no opposition surge, and describes dark regolith surfaces well.
//! Directional-hemispherical reflectance: (w/2)·[1 − μ₀ ln((1 + μ₀)/μ₀)].
//! Reference: H. Seeliger (1888), Abh. Bayer. Akad. Wiss. 16; Hapke (2012), "Theory of
//! Reflectance and Emittance Spectroscopy", 2nd ed., section 8.3.

use super::{Angles, Reflectance};

/// A Lommel–Seeliger surface of single scattering albedo `w` (0 … 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LommelSeeliger {
    pub w: f64,
}

impl Default for LommelSeeliger {
    fn default() -> Self {
        LommelSeeliger { w: 1.0 }
    }
}

impl Reflectance for LommelSeeliger {
    fn reflectance(&self, a: &Angles) -> f64 {
        if !a.is_lit_and_seen() {
            return 0.0;
        }
        // cos i > 0 here, so the denominator is positive.
        self.w / (4.0 * std::f64::consts::PI) * a.cos_i / (a.cos_i + a.cos_e)
    }
}
