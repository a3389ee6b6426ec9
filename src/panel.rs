//! Panels: sunlight on a solar panel standing at a place above a body's surface.
//!
//! In: the body's mesh (metres, body frame, centre at the origin) and its [`Bvh`], a
//! point on the surface and a height above it, a [`Panel`] (orientation, area,
//! efficiency); per step the Sun's unit direction in the body frame, the solar flux
//! (W/m²) and, for a disk Sun, its angular radius. Out: the irradiance on the panel
//! (W/m²), its electrical power (W) and the visible share of the Sun.
//!
//! The place's frame: *up* is the radial direction of the surface point, *north* the
//! body's +z axis projected on the horizontal plane (+x where that vanishes, at the
//! poles), *east* = north × up; azimuths run from north toward east.
//!
//! Sunlight, `E = F · f · max(0, n·s̄)`: `f` is the share of the Sun seen above the
//! horizon from the panel's height ([`PointHorizon`]); for a disk Sun the part of the
//! disk above a straight horizon line ([`SolarDisk::above`]) and `s̄` the direction of
//! that part's flux centroid, for a point Sun 1 or 0 decided exactly (above the wedge's
//! upper bound: lit; otherwise a ray from the panel through the body's own mesh) and
//! `s̄ = s`. `n` is the panel's normal; tracking panels turn toward `s̄`. Left out: light
//! scattered by the terrain onto the panel, other bodies' shadows, and the panel's own
//! plane cutting the disk (second order in the disk's radius, 0.27° at 1 AU).

use crate::horizon::disk::SolarDisk;
use crate::horizon::map::PointHorizon;
use crate::mesh::Mesh;
use crate::trace::bvh::Bvh;
use glam::DVec3;

/// Azimuth wedges of a panel's horizon: 0.35° each.
pub const PANEL_AZIMUTHS: u32 = 1024;

/// How a panel faces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Orientation {
    /// Fixed: facing `azimuth_deg` (from north toward east), tilted `tilt_deg` from
    /// horizontal (0 faces straight up, 90 is a vertical panel).
    Fixed { tilt_deg: f64, azimuth_deg: f64 },
    /// Turning about the vertical to face the Sun's azimuth, at a fixed tilt (one axis).
    AzimuthTracking { tilt_deg: f64 },
    /// Always facing the Sun (two axes).
    SunTracking,
}

/// A solar panel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Panel {
    pub orientation: Orientation,
    /// Area, m².
    pub area_m2: f64,
    /// Share of the irradiance turned into electrical power, 0 to 1.
    pub efficiency: f64,
}

/// What a panel receives at one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PanelLight {
    /// Irradiance on the panel, W/m².
    pub irradiance_w_m2: f64,
    /// Electrical power, W.
    pub power_w: f64,
    /// Share of the Sun's flux seen above the horizon, 0 to 1.
    pub sun_visible: f64,
}

/// A place above the surface with its horizon.
pub struct Site<'a> {
    bvh: &'a Bvh,
    point: DVec3,
    up: DVec3,
    north: DVec3,
    east: DVec3,
    horizon: PointHorizon,
    /// Farther than any facet from the point, metres: the length of its shadow rays.
    reach_m: f64,
}

impl<'a> Site<'a> {
    /// The place `height_m` above `surface_m` (body frame, metres) on `mesh`, whose tree
    /// is `bvh`. Errors when the height is not positive or the point is the origin.
    pub fn new(
        mesh: &Mesh,
        bvh: &'a Bvh,
        surface_m: DVec3,
        height_m: f64,
    ) -> Result<Site<'a>, String> {
        if !(height_m.is_finite() && height_m > 0.0) {
            return Err(format!("height {height_m} m: give a height above 0"));
        }
        let up = surface_m.normalize_or_zero();
        if up == DVec3::ZERO || !surface_m.is_finite() {
            return Err("the place is the body's centre: give a point on its surface".into());
        }
        let point = surface_m + up * height_m;
        let level = |axis: DVec3| (axis - up * up.dot(axis)).normalize_or_zero();
        let north = match level(DVec3::Z) {
            n if n != DVec3::ZERO => n,
            _ => level(DVec3::X),
        };
        let reach_m = 2.0
            * mesh
                .vertices
                .iter()
                .fold(0.0f64, |m, v| m.max(v.distance(point)))
            + 1.0;
        Ok(Site {
            bvh,
            point,
            up,
            north,
            east: north.cross(up),
            horizon: PointHorizon::build(mesh, bvh, point, up, PANEL_AZIMUTHS),
            reach_m,
        })
    }

    /// The panel's position, body frame, metres.
    pub fn point(&self) -> DVec3 {
        self.point
    }

    /// Elevation of the unit direction `dir` above the local horizontal, radians.
    pub fn elevation(&self, dir: DVec3) -> f64 {
        self.up.dot(dir).clamp(-1.0, 1.0).asin()
    }

    /// Elevation of the horizon (radians) toward the unit direction `dir`'s azimuth.
    pub fn horizon_toward(&self, dir: DVec3) -> f64 {
        self.horizon.horizon(&self.horizon.position(dir)).elevation
    }

    /// True when a point Sun in direction `sun` is seen from the panel.
    pub fn sees(&self, sun: DVec3) -> bool {
        let at = self.horizon.position(sun);
        self.horizon.clears(&at)
            || !self.bvh.segment_blocked(
                self.point,
                self.point + sun * self.reach_m,
                [u32::MAX; 2],
                0.0,
            )
    }

    /// The panel's unit normal when it faces the direction `toward` (for tracking).
    pub fn normal(&self, orientation: Orientation, toward: DVec3) -> DVec3 {
        let facing = |tilt_deg: f64, horizontal: DVec3| {
            let t = tilt_deg.to_radians();
            self.up * t.cos() + horizontal * t.sin()
        };
        match orientation {
            Orientation::Fixed {
                tilt_deg,
                azimuth_deg,
            } => {
                let a = azimuth_deg.to_radians();
                facing(tilt_deg, self.north * a.cos() + self.east * a.sin())
            }
            Orientation::AzimuthTracking { tilt_deg } => {
                let level = (toward - self.up * self.up.dot(toward)).normalize_or_zero();
                facing(tilt_deg, level)
            }
            Orientation::SunTracking => toward,
        }
    }

    /// What `panel` receives from a Sun in unit direction `sun` (body frame) with flux
    /// `flux_w_m2`; `disk` with the Sun's angular radius (radians) for a disk Sun.
    pub fn sunlight(
        &self,
        panel: &Panel,
        sun: DVec3,
        flux_w_m2: f64,
        disk: Option<(&SolarDisk, f64)>,
    ) -> PanelLight {
        let (visible, centroid) = match disk {
            Some((disk, radius)) => {
                let at = self.horizon.position(sun);
                let (share, e) = disk.above(at.elevation, self.horizon.horizon(&at), radius);
                let level = (sun - self.up * self.up.dot(sun)).normalize_or_zero();
                (share, level * e.cos() + self.up * e.sin())
            }
            None => (if self.sees(sun) { 1.0 } else { 0.0 }, sun),
        };
        let n = self.normal(panel.orientation, centroid);
        let irradiance = flux_w_m2 * visible * n.dot(centroid).max(0.0);
        PanelLight {
            irradiance_w_m2: irradiance,
            power_w: irradiance * panel.area_m2 * panel.efficiency,
            sun_visible: visible,
        }
    }
}
