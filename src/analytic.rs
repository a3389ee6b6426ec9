//! Closed-form illumination of a rotating sphere without shadows, for validation and for
//! reports.
//!
//! A surface element at latitude φ whose normal is radial, under a Sun at sub-solar
//! latitude δ, receives E(h) = S · max(0, a + b cos h) with a = sin φ sin δ,
//! b = cos φ cos δ and h the hour angle. Averaged over a uniform hour angle (one spin):
//! - lit half-arc h₀ = arccos(−a/b) (0 in polar night, π in polar day);
//! - mean E = S (a h₀ + b sin h₀) / π;  max E = S · max(0, a + b);
//! - lit fraction h₀ / π;
//! - F(x) = P(E ≤ x) = 1 − arccos(clamp((x/S − a)/b, −1, 1)) / π for x ≥ 0.
//!
//! Units: angles in radians, S and E in W/m².

use std::f64::consts::PI;

/// Spin-averaged illumination of a radial surface element at one latitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereLatitude {
    a: f64,
    b: f64,
    flux_w_m2: f64,
}

impl SphereLatitude {
    /// The element at `latitude` (rad) under sub-solar latitude `subsolar` (rad) and
    /// flux `flux_w_m2`.
    pub fn new(latitude: f64, subsolar: f64, flux_w_m2: f64) -> SphereLatitude {
        SphereLatitude {
            a: latitude.sin() * subsolar.sin(),
            b: latitude.cos() * subsolar.cos(),
            flux_w_m2,
        }
    }

    /// The element whose unit normal has z-component `normal_z` (sin of its latitude).
    pub fn from_normal_z(normal_z: f64, subsolar: f64, flux_w_m2: f64) -> SphereLatitude {
        SphereLatitude::new(normal_z.clamp(-1.0, 1.0).asin(), subsolar, flux_w_m2)
    }

    /// Half-length of the lit arc of hour angle, radians (0 … π).
    pub fn half_day(&self) -> f64 {
        if self.b <= 0.0 {
            return if self.a > 0.0 { PI } else { 0.0 };
        }
        (-self.a / self.b).clamp(-1.0, 1.0).acos()
    }

    /// Mean irradiance over one spin, W/m².
    pub fn mean(&self) -> f64 {
        let h0 = self.half_day();
        self.flux_w_m2 * (self.a * h0 + self.b.max(0.0) * h0.sin()) / PI
    }

    /// Maximum irradiance over one spin, W/m².
    pub fn max(&self) -> f64 {
        self.flux_w_m2 * (self.a + self.b.max(0.0)).max(0.0)
    }

    /// Share of the spin with E > 0.
    pub fn lit_fraction(&self) -> f64 {
        self.half_day() / PI
    }

    /// F(x): share of the spin with E ≤ x (x in W/m², ≥ 0).
    pub fn cdf(&self, x: f64) -> f64 {
        if self.b <= 0.0 {
            return if self.flux_w_m2 * self.a.max(0.0) <= x {
                1.0
            } else {
                0.0
            };
        }
        let c = ((x / self.flux_w_m2 - self.a) / self.b).clamp(-1.0, 1.0);
        1.0 - c.acos() / PI
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force average over a fine hour-angle grid: an independent check of the algebra.
    fn brute(lat: f64, dec: f64) -> (f64, f64, f64) {
        let n = 200_000;
        let (mut sum, mut lit, mut below) = (0.0, 0, 0);
        for k in 0..n {
            let h = 2.0 * PI * (k as f64 + 0.5) / n as f64;
            let e = (lat.sin() * dec.sin() + lat.cos() * dec.cos() * h.cos()).max(0.0);
            sum += e;
            lit += (e > 0.0) as usize;
            below += (e <= 0.3) as usize;
        }
        (
            sum / n as f64,
            lit as f64 / n as f64,
            below as f64 / n as f64,
        )
    }

    #[test]
    fn closed_form_matches_brute_force() {
        for (lat, dec) in [
            (0.0, 0.0),
            (0.7, 0.3),
            (-1.2, 0.4),
            (1.4, 0.4),
            (-1.4, 0.4),
            (0.3, -0.2),
        ] {
            let s = SphereLatitude::new(lat, dec, 1.0);
            let (mean, lit, below) = brute(lat, dec);
            assert!((s.mean() - mean).abs() < 1e-6, "{lat} {dec}");
            assert!((s.lit_fraction() - lit).abs() < 1e-4, "{lat} {dec}");
            assert!((s.cdf(0.3) - below).abs() < 1e-4, "{lat} {dec}");
        }
    }
}
