//! The Sun as a disk: the visible fraction of a limb-darkened solar disk above a straight
//! horizon, and where the visible part's light comes from.
//!
//! In: the Sun's angular radius ρ (radians, from its distance at the step) and a linear
//! limb-darkening coefficient `u` (intensity `I(μ) = 1 − u·(1 − μ)`, μ the cosine of the
//! angle from disk centre; `u = 0` a uniform disk). Out: for a horizon line at angular
//! distance `d·ρ` below the disk centre (negative: above it), the share of the disk's
//! flux above the line and the height of that part's flux-weighted centroid above the
//! disk centre (in units of ρ).
//!
//! Both are closed forms. A chord at height `y` (units of ρ) has half-length
//! `a = √(1 − y²)` and carries `(1 − u)·2a + u·(π/2)·a²` of flux; integrating from the
//! line `y = −d` to the top:
//!
//! - flux above: `(1 − u)(π/2 + d√(1 − d²) + asin d) + u(π/2)(2/3 + d − d³/3)`,
//!   divided by the whole disk's `(1 − u)π + 2πu/3`;
//! - first moment: `(1 − u)(2/3)(1 − d²)^{3/2} + u(π/8)(1 − d²)²`.
//!
//! How irradiance is taken over a partly hidden disk: `E = S · f · max(0, sin ē)`, with
//! `f` the visible share and `ē` the elevation (above the facet's plane) of the visible
//! part's centroid. The facet's own plane is a horizon at elevation 0 like any other, so
//! `sin ē · f` is the disk integral of `n·s` to second order in ρ (ρ ≈ 0.0047 rad at
//! 1 AU).

use std::f64::consts::PI;

/// The Sun's radius, metres (IAU 2015 nominal solar radius).
pub const SUN_RADIUS_M: f64 = 6.957e8;

/// A limb-darkened solar disk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolarDisk {
    /// Linear limb-darkening coefficient, 0 (uniform) to 1.
    pub limb_darkening: f64,
}

/// The visible part of the disk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Visible {
    /// Share of the disk's flux above the horizon, 0 to 1.
    pub fraction: f64,
    /// Height of the visible part's flux centroid above the disk centre, units of ρ.
    pub centroid: f64,
}

impl SolarDisk {
    /// The disk's angular radius (radians) seen from `distance_m` from the Sun's centre.
    pub fn angular_radius(distance_m: f64) -> f64 {
        (SUN_RADIUS_M / distance_m).min(1.0).asin()
    }

    /// The part of the disk above a straight horizon `d` radii below its centre.
    pub fn visible(&self, d: f64) -> Visible {
        if d >= 1.0 {
            return Visible {
                fraction: 1.0,
                centroid: 0.0,
            };
        }
        if d <= -1.0 {
            return Visible {
                fraction: 0.0,
                centroid: 0.0,
            };
        }
        let u = self.limb_darkening;
        let s = (1.0 - d * d).sqrt();
        let whole = (1.0 - u) * PI + 2.0 * PI * u / 3.0;
        let flux = (1.0 - u) * (PI / 2.0 + d * s + d.asin())
            + u * (PI / 2.0) * (2.0 / 3.0 + d - d * d * d / 3.0);
        let moment = (1.0 - u) * (2.0 / 3.0) * s * s * s + u * (PI / 8.0) * (s * s) * (s * s);
        Visible {
            fraction: (flux / whole).clamp(0.0, 1.0),
            centroid: if flux > 0.0 { moment / flux } else { 1.0 },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestRng;

    /// The disk sampled on a fine polar grid: flux above the line `y = −d` and its
    /// centroid height, by brute force.
    fn sampled(u: f64, d: f64) -> (f64, f64) {
        let (mut above, mut total, mut moment) = (0.0, 0.0, 0.0);
        let n = 800;
        for i in 0..n {
            let r = (i as f64 + 0.5) / n as f64;
            let intensity = 1.0 - u * (1.0 - (1.0 - r * r).sqrt());
            for j in 0..n {
                let t = (j as f64 + 0.5) / n as f64 * 2.0 * PI;
                let w = intensity * r;
                let y = r * t.sin();
                total += w;
                if y > -d {
                    above += w;
                    moment += w * y;
                }
            }
        }
        (
            above / total,
            if above > 0.0 { moment / above } else { 1.0 },
        )
    }

    #[test]
    fn closed_forms_match_a_brute_force_integration_of_the_disk() {
        let mut rng = TestRng::new(3);
        for _ in 0..12 {
            let u = rng.unit();
            let d = 2.0 * rng.unit() - 1.0;
            let v = SolarDisk { limb_darkening: u }.visible(d);
            let (f, c) = sampled(u, d);
            // The 800 × 800 polar grid cuts a chord with an error of about one cell.
            assert!(
                (v.fraction - f).abs() < 2e-3,
                "u {u} d {d}: {} vs {f}",
                v.fraction
            );
            if f > 0.01 {
                assert!(
                    (v.centroid - c).abs() < 5e-3,
                    "u {u} d {d}: {} vs {c}",
                    v.centroid
                );
            }
        }
    }

    #[test]
    fn half_a_uniform_disk_has_its_centroid_at_four_over_three_pi() {
        let v = SolarDisk {
            limb_darkening: 0.0,
        }
        .visible(0.0);
        assert!((v.fraction - 0.5).abs() < 1e-15);
        assert!((v.centroid - 4.0 / (3.0 * PI)).abs() < 1e-15);
    }

    #[test]
    fn the_sun_at_one_au_is_a_quarter_degree_in_radius() {
        let rho = SolarDisk::angular_radius(1.495_978_707e11);
        // 959.2 arcseconds: the nominal solar radius seen from 1 AU.
        assert!(
            (rho.to_degrees() * 3600.0 - 959.2).abs() < 1.0,
            "{}",
            rho.to_degrees() * 3600.0
        );
    }
}
