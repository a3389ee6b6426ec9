//! Body-fixed frames from text PCKs: the IAU rotation model and the body's radii.
//!
//! In: the `BODYnnn_POLE_RA`, `_POLE_DEC`, `_PM`, `_NUT_PREC_*` and `_RADII` variables
//! of a text PCK, and the `BODYbbb_NUT_PREC_ANGLES` of the body's system barycentre.
//! Out: the rotation from J2000 to the body-fixed frame at a TDB epoch, the sidereal
//! rotation period, and the radii (km).
//!
//! The model is SPICE's (NAIF PCK Required Reading): with d days and T Julian centuries of
//! TDB past J2000, and system angles θ_k = Σ_j J_kj T^j,
//!   α = α₀ + α₁T + α₂T² + Σ a_k sin θ_k,   δ = δ₀ + δ₁T + δ₂T² + Σ b_k cos θ_k,
//!   W = W₀ + W₁d + W₂d² + Σ c_k sin θ_k   (degrees),
//! and J2000 → body = \[W\]₃ \[90° − δ\]₁ \[90° + α\]₃, \[θ\]ᵢ the frame rotation about axis i.
//! It is evaluated here rather than through anise's PCK conversion, which keeps only two
//! coefficients per system angle (pck00011 gives Mars's angles three) and so misplaces
//! Phobos's prime meridian by about 1e-4 rad.

use super::text_kernel::TextKernel;
use crate::error::{Error, Result};
use glam::{DMat3, DVec3};
use std::path::Path;

const SECONDS_PER_DAY: f64 = 86_400.0;
const DAYS_PER_CENTURY: f64 = 36_525.0;

/// The IAU rotation model of one body.
#[derive(Debug, Clone, PartialEq)]
pub struct RotationModel {
    pole_ra_deg: Vec<f64>,
    pole_dec_deg: Vec<f64>,
    prime_meridian_deg: Vec<f64>,
    nut_ra: Vec<f64>,
    nut_dec: Vec<f64>,
    nut_pm: Vec<f64>,
    /// System angles, one polynomial in T (degrees) each.
    angles: Vec<Vec<f64>>,
}

/// The highest degree of the nutation–precession angle polynomials slim reads. The IAU
/// models use 1 (linear angles); higher values only come from a damaged or crafted file.
pub const MAX_PHASE_DEGREE: usize = 20;

/// Every `BODYnnn_MAX_PHASE_DEGREE` in `kernel` must be a whole number from 0 to
/// [`MAX_PHASE_DEGREE`]; `path` is the file just read, named in the error.
pub fn check_phase_degrees(kernel: &TextKernel, path: &Path) -> Result<()> {
    for name in kernel.names().filter(|n| n.ends_with("_MAX_PHASE_DEGREE")) {
        let degree = kernel.numbers(name).and_then(|d| d.first().copied());
        let whole =
            degree.filter(|d| d.fract() == 0.0 && (0.0..=MAX_PHASE_DEGREE as f64).contains(d));
        if whole.is_none() {
            // The name is the file's: escaped and shortened like any quoted content.
            let name = crate::error::printable(name, 80);
            return Err(Error::file(
                path,
                format!("{name} = {degree:?}: must be a whole number from 0 to {MAX_PHASE_DEGREE}"),
            ));
        }
    }
    Ok(())
}

impl RotationModel {
    /// The model of body `id` in `kernel`, if the kernel defines one.
    pub fn from_kernel(kernel: &TextKernel, id: i32) -> Option<RotationModel> {
        let var = |name: &str| kernel.numbers(&format!("BODY{id}_{name}"));
        let pole_ra_deg = var("POLE_RA")?;
        let pole_dec_deg = var("POLE_DEC")?;
        let prime_meridian_deg = var("PM")?;
        let system = system_of(id);
        let degree = kernel
            .numbers(&format!("BODY{system}_MAX_PHASE_DEGREE"))
            .and_then(|d| d.first().copied())
            .map_or(1, |d| d as usize);
        let angles = kernel
            .numbers(&format!("BODY{system}_NUT_PREC_ANGLES"))
            .map(|a| a.chunks(degree + 1).map(<[f64]>::to_vec).collect())
            .unwrap_or_default();
        Some(RotationModel {
            pole_ra_deg,
            pole_dec_deg,
            prime_meridian_deg,
            nut_ra: var("NUT_PREC_RA").unwrap_or_default(),
            nut_dec: var("NUT_PREC_DEC").unwrap_or_default(),
            nut_pm: var("NUT_PREC_PM").unwrap_or_default(),
            angles,
        })
    }

    /// Rotation taking J2000 vectors to the body-fixed frame at `et_tdb_s`.
    pub fn j2000_to_body(&self, et_tdb_s: f64) -> DMat3 {
        let d = et_tdb_s / SECONDS_PER_DAY;
        let t = d / DAYS_PER_CENTURY;
        let theta: Vec<f64> = self
            .angles
            .iter()
            .map(|c| polynomial(c, t).to_radians())
            .collect();
        let sum = |coefs: &[f64], f: fn(f64) -> f64| -> f64 {
            coefs.iter().zip(&theta).map(|(c, th)| c * f(*th)).sum()
        };
        let ra = (polynomial(&self.pole_ra_deg, t) + sum(&self.nut_ra, f64::sin)).to_radians();
        let dec = (polynomial(&self.pole_dec_deg, t) + sum(&self.nut_dec, f64::cos)).to_radians();
        let w =
            (polynomial(&self.prime_meridian_deg, d) + sum(&self.nut_pm, f64::sin)).to_radians();
        let half_pi = std::f64::consts::FRAC_PI_2;
        frame_rotation_z(w) * frame_rotation_x(half_pi - dec) * frame_rotation_z(half_pi + ra)
    }

    /// Sidereal rotation period from the prime meridian's rate, seconds (None if it is 0).
    pub fn rotation_period_s(&self) -> Option<f64> {
        let rate_deg_per_day = *self.prime_meridian_deg.get(1)?;
        (rate_deg_per_day != 0.0).then(|| 360.0 / rate_deg_per_day.abs() * SECONDS_PER_DAY)
    }
}

/// Radii (km) of body `id` in `kernel`: (a, b, c), a sphere and a spheroid expanded.
pub fn radii_km(kernel: &TextKernel, id: i32) -> Option<DVec3> {
    let r = kernel.numbers(&format!("BODY{id}_RADII"))?;
    match r.as_slice() {
        [a] => Some(DVec3::splat(*a)),
        [a, c] => Some(DVec3::new(*a, *a, *c)),
        [a, b, c, ..] => Some(DVec3::new(*a, *b, *c)),
        [] => None,
    }
}

/// The barycentre whose system angles a body's nutation–precession terms use.
fn system_of(id: i32) -> i32 {
    if (100..1000).contains(&id) {
        id / 100
    } else {
        id
    }
}

fn polynomial(coefs: &[f64], x: f64) -> f64 {
    coefs.iter().rev().fold(0.0, |acc, c| acc * x + c)
}

/// [θ]₃: the rotation of coordinates when the frame turns by θ about z.
fn frame_rotation_z(theta: f64) -> DMat3 {
    DMat3::from_rotation_z(-theta)
}

/// [θ]₁: the rotation of coordinates when the frame turns by θ about x.
fn frame_rotation_x(theta: f64) -> DMat3 {
    DMat3::from_rotation_x(-theta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn pole_and_meridian_follow_the_definition() {
        // A body with pole at RA 90°, Dec 0° and W = 0 at J2000: its z axis is J2000 +y.
        let mut k = TextKernel::default();
        let text = "\\begindata\nBODY9_POLE_RA = (90 0 0)\nBODY9_POLE_DEC = (0 0 0)\nBODY9_PM = (0 36 0)\n";
        k.parse_into(Path::new("t"), text).unwrap();
        let m = RotationModel::from_kernel(&k, 9).unwrap();
        let r = m.j2000_to_body(0.0);
        // The pole (J2000 +y) is the body +z.
        assert!((r * DVec3::Y - DVec3::Z).length() < 1e-15);
        // W = 0: the body x axis is the ascending node of the equator on the ICRF equator,
        // at RA α + 90° = 180°, i.e. J2000 −x.
        assert!((r * -DVec3::X - DVec3::X).length() < 1e-15);
        assert!((m.rotation_period_s().unwrap() - 10.0 * 86_400.0).abs() < 1e-9);
    }
}
