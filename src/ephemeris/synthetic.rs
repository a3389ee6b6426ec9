//! Synthetic poses for bodies no kernel covers — a moonlet such as Dimorphos beside a
//! primary that the SPKs do have — placed relative to the scene's first body.
//!
//! In: a fixed offset (km, J2000 axes) or a circular orbit (radius km, period s, pole as
//! right ascension and declination in J2000, phase at the first epoch). Out, at a time
//! `t` seconds after the first epoch: the body's offset from the first body (km, J2000) and
//! its orientation (body → J2000). A fixed body keeps J2000-aligned axes; an orbiting body
//! is tidally locked: +x points at the primary, +z along the orbit pole.

use glam::{DMat3, DVec3};
use std::f64::consts::TAU;

/// How a synthetic body moves relative to the first body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SyntheticMotion {
    /// A constant offset, km (J2000 axes); the body's axes are J2000's.
    Fixed { offset_km: DVec3 },
    /// A circular, synchronously rotating orbit.
    Orbit(CircularOrbit),
}

/// A circular orbit about the first body's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircularOrbit {
    /// Orbit radius, km.
    pub radius_km: f64,
    /// Orbital period, s (negative: retrograde about the pole).
    pub period_s: f64,
    /// Unit orbit pole, J2000.
    pub pole: DVec3,
    /// Angle from the ascending node on the J2000 equator at the first epoch, radians.
    pub phase_rad: f64,
}

impl CircularOrbit {
    /// An orbit whose pole has right ascension `ra_deg` and declination `dec_deg` (J2000).
    pub fn new(radius_km: f64, period_s: f64, ra_deg: f64, dec_deg: f64, phase_deg: f64) -> Self {
        let (ra, dec) = (ra_deg.to_radians(), dec_deg.to_radians());
        CircularOrbit {
            radius_km,
            period_s,
            pole: DVec3::new(dec.cos() * ra.cos(), dec.cos() * ra.sin(), dec.sin()),
            phase_rad: phase_deg.to_radians(),
        }
    }

    /// The in-plane axes: toward the ascending node, and 90° ahead of it.
    fn plane_axes(&self) -> (DVec3, DVec3) {
        let node = DVec3::Z.cross(self.pole);
        // A pole along J2000 z has no node; J2000 x then stands in for it.
        let node = if node.length() < 1e-12 {
            DVec3::X
        } else {
            node.normalize()
        };
        (node, self.pole.cross(node))
    }
}

impl SyntheticMotion {
    /// Offset from the first body (km, J2000) and body → J2000 rotation, `t_s` seconds
    /// after the first epoch.
    pub fn pose_at(&self, t_s: f64) -> (DVec3, DMat3) {
        match self {
            SyntheticMotion::Fixed { offset_km } => (*offset_km, DMat3::IDENTITY),
            SyntheticMotion::Orbit(orbit) => {
                let (u, v) = orbit.plane_axes();
                let angle = orbit.phase_rad + TAU * t_s / orbit.period_s;
                let radial = u * angle.cos() + v * angle.sin();
                let to_primary = -radial;
                let body_to_j2000 =
                    DMat3::from_cols(to_primary, orbit.pole.cross(to_primary), orbit.pole);
                (radial * orbit.radius_km, body_to_j2000)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_orbit_returns_after_one_period_and_faces_its_primary() {
        let orbit = CircularOrbit::new(1.2, 11.92 * 3600.0, 310.0, -81.0, 30.0);
        let motion = SyntheticMotion::Orbit(orbit);
        let (p0, r0) = motion.pose_at(0.0);
        let (p1, r1) = motion.pose_at(orbit.period_s);
        assert!((p0 - p1).length() < 1e-12);
        assert!((r0 - r1).abs_diff_eq(DMat3::ZERO, 1e-12));
        assert!((p0.length() - 1.2).abs() < 1e-12);
        assert!(p0.dot(orbit.pole).abs() < 1e-12);
        // +x of the body points at the primary, and the frame is a rotation.
        assert!((r0 * DVec3::X + p0.normalize()).length() < 1e-12);
        assert!((r0.determinant() - 1.0).abs() < 1e-12);
        // A quarter period later the body has moved 90° about the pole.
        let (pq, _) = motion.pose_at(orbit.period_s / 4.0);
        assert!((p0.cross(pq).normalize() - orbit.pole).length() < 1e-12);
    }
}
