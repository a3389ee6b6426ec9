//! Colour maps for report figures: perceptually uniform and readable in grey.
//!
//! In: a value and the scale `[lo, hi]` it is drawn on (physical units). Out: one of the
//! 256 8-bit sRGB entries of viridis (default) or cividis. The mapping is exact and
//! invertible up to the quantisation (hi − lo)/255: entry `round((v − lo)/(hi − lo)·255)`,
//! clamped to the table. [`Colormap::nearest_index`] inverts a colour read from a PNG.

use super::colormap_tables::{CIVIDIS, VIRIDIS};
use std::str::FromStr;

/// A 256-entry colour map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Colormap {
    /// matplotlib's viridis: dark blue → green → yellow.
    #[default]
    Viridis,
    /// cividis: dark blue → grey → yellow, also for red–green colour-vision deficiency.
    Cividis,
}

/// Number of colour entries in a map.
pub const ENTRIES: usize = 256;

impl Colormap {
    /// The map's name as written in reports and accepted by `--colormap`.
    pub fn name(self) -> &'static str {
        match self {
            Colormap::Viridis => "viridis",
            Colormap::Cividis => "cividis",
        }
    }

    /// The 256 sRGB entries, low to high.
    pub fn table(self) -> &'static [[u8; 3]; ENTRIES] {
        match self {
            Colormap::Viridis => &VIRIDIS,
            Colormap::Cividis => &CIVIDIS,
        }
    }

    /// The entry index of `value` on the scale `[lo, hi]` (clamped; NaN has none).
    pub fn index(lo: f64, hi: f64, value: f64) -> Option<usize> {
        if !value.is_finite() {
            return None;
        }
        let t = if hi > lo {
            (value - lo) / (hi - lo)
        } else {
            0.0
        };
        Some((t.clamp(0.0, 1.0) * (ENTRIES - 1) as f64).round() as usize)
    }

    /// The colour of `value` on the scale `[lo, hi]`, or `None` for a non-finite value.
    pub fn color(self, lo: f64, hi: f64, value: f64) -> Option<[u8; 3]> {
        Colormap::index(lo, hi, value).map(|i| self.table()[i])
    }

    /// The value at the centre of entry `index` on the scale `[lo, hi]`.
    pub fn value_of_index(lo: f64, hi: f64, index: usize) -> f64 {
        lo + (hi - lo) * index as f64 / (ENTRIES - 1) as f64
    }

    /// The index of the table entry nearest to `rgb` (squared sRGB distance).
    pub fn nearest_index(self, rgb: [u8; 3]) -> usize {
        let distance =
            |c: &[u8; 3]| -> i32 { (0..3).map(|k| (c[k] as i32 - rgb[k] as i32).pow(2)).sum() };
        (0..ENTRIES)
            .min_by_key(|&i| distance(&self.table()[i]))
            .unwrap_or(0)
    }
}

impl FromStr for Colormap {
    type Err = String;

    fn from_str(s: &str) -> Result<Colormap, String> {
        match s.to_ascii_lowercase().as_str() {
            "viridis" => Ok(Colormap::Viridis),
            "cividis" => Ok(Colormap::Cividis),
            other => Err(format!(
                "unknown colour map '{other}': use viridis or cividis"
            )),
        }
    }
}
