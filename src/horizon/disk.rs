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

use super::sky::LocalHorizon;
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
        let whole = self.whole_flux();
        let flux = (1.0 - u) * (PI / 2.0 + d * s + d.asin())
            + u * (PI / 2.0) * (2.0 / 3.0 + d - d * d * d / 3.0);
        let moment = (1.0 - u) * (2.0 / 3.0) * s * s * s + u * (PI / 8.0) * (s * s) * (s * s);
        Visible {
            fraction: (flux / whole).clamp(0.0, 1.0),
            centroid: if flux > 0.0 { moment / flux } else { 1.0 },
        }
    }

    /// The part of a disk of angular radius `radius` whose centre stands at elevation
    /// `elevation` (radians) seen above `horizon`, taken as a straight line across the
    /// disk tilted by its slope: the share of the flux, and the elevation (radians) of
    /// that part's flux centroid.
    pub fn above(&self, elevation: f64, horizon: LocalHorizon, radius: f64) -> (f64, f64) {
        self.cut_by(elevation, horizon, radius)
            .unwrap_or((1.0, elevation))
    }

    /// [`SolarDisk::above`] where the horizon cuts the disk; `None` where the whole disk
    /// stands above it (all of the flux, its centroid at the disk's centre).
    pub fn cut_by(&self, elevation: f64, horizon: LocalHorizon, radius: f64) -> Option<(f64, f64)> {
        let tilt = horizon.slope / elevation.cos().max(1e-6);
        let across = (1.0 + tilt * tilt).sqrt();
        let d = (elevation - horizon.elevation) / (radius * across);
        (d < 1.0).then(|| {
            let seen = self.visible(d);
            (seen.fraction, elevation + radius * seen.centroid / across)
        })
    }

    /// The share of the disk's flux inside a circle of `radius` whose centre lies
    /// `distance` from the disk's centre (both in units of ρ): what a round occluder
    /// hides. Rings of the disk are integrated in closed form around (the arc of each
    /// ring inside the circle) and by Gauss–Legendre quadrature across, piece by piece
    /// between the radii where a ring enters or leaves the circle.
    pub fn hidden_by_circle(&self, distance: f64, radius: f64) -> f64 {
        if distance >= radius + 1.0 {
            return 0.0;
        }
        if radius >= distance + 1.0 {
            return 1.0;
        }
        let arc_inside = |s: f64| {
            if s + distance <= radius {
                2.0 * PI
            } else if (s - distance).abs() >= radius {
                0.0
            } else {
                let cos =
                    (s * s + (distance - radius) * (distance + radius)) / (2.0 * s * distance);
                2.0 * cos.clamp(-1.0, 1.0).acos()
            }
        };
        let mut cuts = [
            0.0,
            (distance - radius).abs().min(1.0),
            (distance + radius).min(1.0),
            1.0,
        ];
        cuts.sort_by(f64::total_cmp);
        let hidden: f64 = cuts
            .windows(2)
            .filter(|w| w[1] > w[0])
            .map(|w| smooth_quadrature(w[0], w[1], |s| s * self.intensity(s) * arc_inside(s)))
            .sum();
        (hidden / self.whole_flux()).clamp(0.0, 1.0)
    }

    /// `n` points on the unit disk (units of ρ) that each carry an equal share of its
    /// flux: radii at the flux quantiles `(j + ½)/n`, angles stepped by the golden angle
    /// (a sunflower pattern, even in every direction).
    pub fn samples(&self, n: usize) -> Vec<(f64, f64)> {
        let golden = PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|j| {
                let share = (j as f64 + 0.5) / n as f64;
                let (mut lo, mut hi) = (0.0, 1.0);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if self.flux_within(mid) < share {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let r = 0.5 * (lo + hi);
                let angle = golden * j as f64;
                (r * angle.cos(), r * angle.sin())
            })
            .collect()
    }

    /// Intensity at `s` radii from the centre, relative to the centre's.
    fn intensity(&self, s: f64) -> f64 {
        let mu = (1.0 - s * s).max(0.0).sqrt();
        1.0 - self.limb_darkening * (1.0 - mu)
    }

    /// The whole disk's flux, `∫ I(s) 2πs ds` over the unit disk.
    fn whole_flux(&self) -> f64 {
        let u = self.limb_darkening;
        (1.0 - u) * PI + 2.0 * PI * u / 3.0
    }

    /// The share of the flux within `s` radii of the centre.
    fn flux_within(&self, s: f64) -> f64 {
        let u = self.limb_darkening;
        let rim = (1.0 - s * s).max(0.0).powf(1.5);
        2.0 * PI * ((1.0 - u) * s * s / 2.0 + u * (1.0 - rim) / 3.0) / self.whole_flux()
    }
}

/// `∫ f` over `[lo, hi]` by 24-point Gauss–Legendre after `s = lo + (hi − lo)(1 − cos t)/2`,
/// which takes out the square-root behaviour of `f` at both ends (a ring entering a
/// circle, the disk's limb).
fn smooth_quadrature(lo: f64, hi: f64, f: impl Fn(f64) -> f64) -> f64 {
    gauss_legendre()
        .iter()
        .map(|&(x, w)| {
            let t = PI * (x + 1.0) / 2.0;
            let s = lo + (hi - lo) * (1.0 - t.cos()) / 2.0;
            let ds_dt = (hi - lo) * t.sin() / 2.0;
            w * (PI / 2.0) * ds_dt * f(s)
        })
        .sum()
}

/// The 24-point Gauss–Legendre rule, computed once.
fn gauss_legendre() -> &'static [(f64, f64)] {
    static NODES: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    NODES.get_or_init(|| crate::quadrature::gauss_legendre(24))
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

    /// The lens two circles share (radii 1 and `big`, centres `d` apart), over π: what a
    /// round occluder hides of a uniform disk, in closed form.
    fn lens_share(d: f64, big: f64) -> f64 {
        let a = ((d * d + 1.0 - big * big) / (2.0 * d))
            .clamp(-1.0, 1.0)
            .acos();
        let b = ((d * d + big * big - 1.0) / (2.0 * d * big))
            .clamp(-1.0, 1.0)
            .acos();
        let k = (-d + 1.0 + big) * (d + 1.0 - big) * (d - 1.0 + big) * (d + 1.0 + big);
        (a + big * big * b - 0.5 * k.max(0.0).sqrt()) / PI
    }

    #[test]
    fn a_circle_hides_of_a_uniform_disk_the_lens_they_share() {
        let uniform = SolarDisk {
            limb_darkening: 0.0,
        };
        let mut rng = TestRng::new(11);
        for _ in 0..200 {
            let big = 0.2 + 5.0 * rng.unit();
            let d = (big - 1.0).abs() + (2.0 * big.min(1.0)) * rng.unit();
            let h = uniform.hidden_by_circle(d, big);
            assert!((h - lens_share(d, big)).abs() < 1e-9, "d {d} R {big}: {h}");
        }
        assert_eq!(uniform.hidden_by_circle(3.0, 1.9), 0.0);
        assert_eq!(uniform.hidden_by_circle(0.5, 1.6), 1.0);
        // An annular transit: a small circle well inside hides its area.
        assert!((uniform.hidden_by_circle(0.3, 0.2) - 0.04).abs() < 1e-12);
    }

    #[test]
    fn a_huge_circle_hides_what_a_straight_horizon_does_of_a_darkened_disk() {
        let mut rng = TestRng::new(12);
        for _ in 0..50 {
            let disk = SolarDisk {
                limb_darkening: rng.unit(),
            };
            let d = 2.0 * rng.unit() - 1.0;
            let big = 1e7;
            let hidden = disk.hidden_by_circle(big + d, big);
            let below = 1.0 - disk.visible(d).fraction;
            assert!((hidden - below).abs() < 1e-6, "d {d}: {hidden} vs {below}");
        }
    }

    #[test]
    fn equal_flux_samples_split_the_disk_as_a_horizon_does() {
        let disk = SolarDisk {
            limb_darkening: 0.6,
        };
        let samples = disk.samples(2000);
        for d in [-0.8, -0.3, 0.0, 0.45, 0.9] {
            let above = samples.iter().filter(|p| p.1 > -d).count() as f64 / 2000.0;
            let exact = disk.visible(d).fraction;
            assert!((above - exact).abs() < 5e-3, "d {d}: {above} vs {exact}");
        }
        assert!(samples.iter().all(|p| p.0.hypot(p.1) < 1.0));
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
