//! Sun band: the zone of directions a run's Sun takes in a body's frame, so that a horizon
//! map need only know what can stand in front of that Sun.
//!
//! In: the Sun's unit directions at a run's steps (body frame) and how far to widen them
//! (radians: the disk's largest angular radius, and more where a map's centres are read,
//! [`super::shadows::CENTRES_HEADROOM`]). Out: a [`SunBand`], the directions whose sine of
//! declination about the body's z axis lies in `[sin_lo, sin_hi]`: every step's Sun,
//! widened so and by a margin for rounding, the ends rounded outward to a tenth of a
//! degree so that runs over nearly the same Suns name the same map; or every direction,
//! [`SunBand::WHOLE`].
//!
//! Why a map built for a band is exact for its Suns: a facet's shadow ray toward a Sun of
//! the band, and the sight line toward every point of its disk, run from the centroid `c`
//! inside the cone `{c + t·s : t > 0, s in the band}`. Only facets that meet that cone can
//! block them, so a map's search may leave out every box and triangle that does not
//! (`SunBand::meets_box` for a triangle's box; for the tree's boxes, the range of
//! declinations the search bounds four boxes at a time, `SunBand::meets_range`): its
//! upper bounds still bound whatever can hide a Sun of the band. Where the horizon at a
//! wedge's centre stands within the band, the facet that sets it meets the cone, so the
//! centre is the whole mesh's; above the band a centre may come out lower than the whole
//! mesh's horizon, but not below the band's top there (the
//! surface climbing from the facet to its horizon crosses the band on its way), and below
//! it lower still. A Sun of the band stands on the same side of such a centre either way;
//! between two centres, where the approximate horizon is interpolated, it may not, which
//! the widening for centres keeps to the errors of a map of every direction. The maps of
//! a band are told apart from those of every other band by their cache key.
//!
//! Slim's bodies turn about their frame's z axis (a spin scene's axis; the IAU frames'
//! poles), so a run's Suns keep near one declination: exactly one in a spin scene, about
//! ±1.6° for the Moon over a year, ±25° for Phobos over a Martian year. A thin cone meets
//! little of the mesh: the map of Itokawa's 49,152 facets for a spin's band took 3.0 s on
//! one thread against 17.2 s for every direction, and at 786,432 facets 89 s against 647
//! s on two (docs/performance.md, "Maps for the Sun's band").

use super::geometry::signed_box_bound;
use glam::DVec3;
use std::f64::consts::FRAC_PI_2;

/// Declinations are rounded outward to this grid (radians, a tenth of a degree).
const GRID: f64 = std::f64::consts::PI / 1800.0;

/// Widening of the band beyond its Suns' declinations (radians): far more than the
/// rounding of a unit direction's z and of its arcsine.
const MARGIN: f64 = 1e-6;

/// The zone of directions `s` (unit, body frame) with `sin_lo ≤ s.z ≤ sin_hi`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunBand {
    sin_lo: f64,
    sin_hi: f64,
}

impl SunBand {
    /// Every direction.
    pub const WHOLE: SunBand = SunBand {
        sin_lo: -1.0,
        sin_hi: 1.0,
    };

    /// The band of the unit directions `suns` (body frame), each widened by `radius`
    /// (radians, the disk's); [`SunBand::WHOLE`] when there are none.
    pub fn of_suns(suns: impl IntoIterator<Item = DVec3>, radius: f64) -> SunBand {
        let declination = |s: DVec3| s.z.clamp(-1.0, 1.0).asin();
        let (lo, hi) = suns
            .into_iter()
            .map(declination)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| {
                (lo.min(d), hi.max(d))
            });
        if lo > hi {
            return SunBand::WHOLE;
        }
        let widen = radius + MARGIN;
        let lo = ((lo - widen) / GRID).floor() * GRID;
        let hi = ((hi + widen) / GRID).ceil() * GRID;
        let sine = |d: f64| match d {
            d if d <= -FRAC_PI_2 => -1.0,
            d if d >= FRAC_PI_2 => 1.0,
            d => d.sin(),
        };
        SunBand {
            sin_lo: sine(lo),
            sin_hi: sine(hi),
        }
    }

    /// True for the band of every direction.
    pub fn is_whole(&self) -> bool {
        self.sin_lo <= -1.0 && self.sin_hi >= 1.0
    }

    /// True when the unit direction `s` (body frame) lies in the band.
    pub fn holds(&self, s: DVec3) -> bool {
        (self.sin_lo..=self.sin_hi).contains(&s.z)
    }

    /// The least and greatest declination of the band, degrees (for the plan and
    /// `run.json`), on the band's grid of a tenth of a degree.
    pub fn degrees(&self) -> (f64, f64) {
        let on_grid = |sin: f64| (sin.asin() / GRID).round() / 10.0;
        (on_grid(self.sin_lo), on_grid(self.sin_hi))
    }

    /// The band's bounds, for a cache key.
    pub fn key_bytes(&self) -> [u8; 16] {
        let mut bytes = [0; 16];
        bytes[..8].copy_from_slice(&self.sin_lo.to_le_bytes());
        bytes[8..].copy_from_slice(&self.sin_hi.to_le_bytes());
        bytes
    }

    /// False only when no point of the box `lo..hi` widened by `widening` (metres, body
    /// frame) lies in the cone of the band's directions from `c`: the box's range of
    /// `(q − c)·z / |q − c|` over its points, bounded as elevations above the plane of
    /// normal `z` and of `−z` are, misses `[sin_lo, sin_hi]`.
    #[inline]
    pub(super) fn meets_box(&self, c: DVec3, lo: DVec3, hi: DVec3, widening: f64) -> bool {
        if self.is_whole() {
            return true;
        }
        let highest = signed_box_bound(c, DVec3::Z, lo, hi, widening);
        let lowest = -signed_box_bound(c, DVec3::NEG_Z, lo, hi, widening);
        self.meets_range((lowest, highest))
    }

    /// False only when a range of sines of declination `(lowest, highest)` misses the
    /// band's: a search box's [`crate::trace::bvh::SearchBox::axial`].
    #[inline]
    pub(super) fn meets_range(&self, (lowest, highest): (f64, f64)) -> bool {
        highest >= self.sin_lo && lowest <= self.sin_hi
    }
}

impl std::fmt::Display for SunBand {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.is_whole() {
            return write!(f, "every direction");
        }
        let (lo, hi) = self.degrees();
        write!(
            f,
            "Sun declinations {lo:.1}° to {hi:.1}° about the body's z axis"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestRng;

    fn at_declination(d_deg: f64, h_deg: f64) -> DVec3 {
        let (d, h) = (d_deg.to_radians(), h_deg.to_radians());
        DVec3::new(d.cos() * h.cos(), d.cos() * h.sin(), d.sin())
    }

    #[test]
    fn a_band_holds_its_suns_and_their_disks_and_rounds_outward() {
        let suns: Vec<DVec3> = (0..360)
            .map(|h| at_declination(15.0 + 0.3 * ((h as f64) * 0.1).sin(), h as f64))
            .collect();
        let radius = 0.0047;
        let band = SunBand::of_suns(suns.iter().copied(), radius);
        let (lo, hi) = band.degrees();
        // 14.7° − 0.27° and 15.3° + 0.27°, rounded outward to a tenth of a degree.
        assert!(
            (lo - 14.4).abs() < 1e-9 && (hi - 15.6).abs() < 1e-9,
            "{lo} {hi}"
        );
        for s in &suns {
            for edge in [-1.0, 1.0] {
                // The disk's highest and lowest points.
                let d = s.z.asin() + edge * radius;
                assert!(band.holds(at_declination(d.to_degrees(), 0.0)));
            }
        }
        assert!(!band.holds(at_declination(14.3, 0.0)) && !band.holds(at_declination(15.7, 0.0)));
        assert!(SunBand::of_suns([], 0.0).is_whole());
        assert!(SunBand::of_suns([DVec3::Z, DVec3::NEG_Z], 0.01).is_whole());
        assert!(!band.is_whole());
    }

    #[test]
    fn a_box_that_a_direction_of_the_band_reaches_is_never_left_out() {
        // Rays from random points along directions of a thin band; every box around a
        // point on such a ray must meet the band's cone, and boxes well off it must not.
        let mut rng = TestRng::new(7);
        let mut range = |a: f64, b: f64| a + (b - a) * rng.unit();
        let band = SunBand::of_suns([at_declination(-20.0, 0.0)], 0.0);
        let mut missed = 0;
        for _ in 0..20_000 {
            let c = DVec3::new(range(-50.0, 50.0), range(-50.0, 50.0), range(-50.0, 50.0));
            let s = at_declination(range(-20.1, -19.9), range(0.0, 360.0));
            if !band.holds(s) {
                continue;
            }
            let q = c + s * range(0.001, 100.0);
            let half = DVec3::new(range(0.0, 2.0), range(0.0, 2.0), range(0.0, 2.0));
            let shift = DVec3::new(range(-1.0, 1.0), range(-1.0, 1.0), range(-1.0, 1.0));
            let (lo, hi) = (q - half + half * shift, q + half + half * shift);
            assert!(band.meets_box(c, lo, hi, 0.0), "c {c} s {s} box {lo}..{hi}");
            // The same box moved well above the cone (10° of declination at its distance).
            let up = DVec3::Z * ((q - c).length() * 0.2 + 3.0 * half.max_element() + 1.0);
            missed += usize::from(band.meets_box(c, lo + up, hi + up, 0.0));
        }
        // A box above the cone but for a corner near the apex may still be met; far
        // boxes are not.
        assert!(missed < 200, "{missed} boxes far above the band were kept");
        assert!(SunBand::WHOLE.meets_box(DVec3::ZERO, DVec3::splat(5.0), DVec3::splat(6.0), 0.0));
    }
}
