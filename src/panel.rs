//! Panels: sunlight on a solar panel standing at a place above a body's surface.
//!
//! In: the body's mesh (metres, body frame, centre at the origin) and its [`Bvh`], a
//! point on the surface and a height above it, a [`Panel`] (orientation, area,
//! efficiency); per step the Sun's unit direction in the body frame, the solar flux
//! (W/m²) and, for a disk Sun, its angular radius. Out: the irradiance on the panel
//! (W/m²), its electrical power (W) and the visible share of the Sun; and a [`Battery`]'s
//! charge (Wh) along a power series and a load.
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
//! `s̄ = s`. `n` is the panel's normal; tracking panels turn toward `s̄`. Light scattered
//! by the terrain onto the panel is added by the point queries when the scene scatters
//! light ([`crate::scatter::to_panel`]), and other bodies' shadows by
//! [`PanelLight::dimmed`] with the share they leave ([`crate::illum::Direct::share_past_others`]).
//! Left out: the panel's own plane cutting the disk (second order in the disk's radius,
//! 0.27° at 1 AU).

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
    /// The panel's unit normal at this step (body frame).
    pub normal: DVec3,
}

impl PanelLight {
    /// The light with only `share` (0 to 1) of the Sun left, e.g. past other bodies:
    /// irradiance, power and visible share scale with it (the two causes are taken as
    /// independent, which is exact for a point Sun).
    pub fn dimmed(self, share: f64) -> PanelLight {
        PanelLight {
            irradiance_w_m2: self.irradiance_w_m2 * share,
            power_w: self.power_w * share,
            sun_visible: self.sun_visible * share,
            ..self
        }
    }
}

/// A place above the surface with its horizon.
pub struct Site<'a> {
    bvh: &'a Bvh<'a>,
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
        bvh: &'a Bvh<'a>,
        surface_m: DVec3,
        height_m: f64,
    ) -> Result<Site<'a>, String> {
        Site::with_horizon(mesh, bvh, surface_m, height_m, None)
    }

    /// [`Site::new`] with the horizon already built for this place and height (kept by a
    /// caller that answers many queries), or `None` to build it.
    pub fn with_horizon(
        mesh: &Mesh,
        bvh: &'a Bvh<'a>,
        surface_m: DVec3,
        height_m: f64,
        horizon: Option<PointHorizon>,
    ) -> Result<Site<'a>, String> {
        if !(height_m.is_finite() && height_m > 0.0) {
            return Err(format!("height {height_m} m: give a height above 0"));
        }
        let up = surface_m.normalize_or_zero();
        if up == DVec3::ZERO || !surface_m.is_finite() {
            return Err("the place is the body's centre: give a point on its surface".into());
        }
        let point = surface_m + up * height_m;
        let north = match level(up, DVec3::Z) {
            n if n != DVec3::ZERO => n,
            _ => level(up, DVec3::X),
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
            horizon: horizon
                .unwrap_or_else(|| PointHorizon::build(mesh, bvh, point, up, PANEL_AZIMUTHS)),
            reach_m,
        })
    }

    /// The horizon seen from the panel.
    pub fn horizon(&self) -> &PointHorizon {
        &self.horizon
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
            Orientation::AzimuthTracking { tilt_deg } => facing(tilt_deg, level(self.up, toward)),
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
                let (share, e) = disk.above(at.elevation(), self.horizon.horizon(&at), radius);
                (share, level(self.up, sun) * e.cos() + self.up * e.sin())
            }
            None => (if self.sees(sun) { 1.0 } else { 0.0 }, sun),
        };
        let n = self.normal(panel.orientation, centroid);
        let irradiance = flux_w_m2 * visible * n.dot(centroid).max(0.0);
        PanelLight {
            irradiance_w_m2: irradiance,
            power_w: irradiance * panel.area_m2 * panel.efficiency,
            sun_visible: visible,
            normal: n,
        }
    }
}

/// The horizontal (normal to `up`) unit direction of `dir`; zero straight up or down.
fn level(up: DVec3, dir: DVec3) -> DVec3 {
    (dir - up * up.dot(dir)).normalize_or_zero()
}

/// A battery charged by a panel and drained by a load.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Battery {
    /// Most energy it holds, Wh.
    pub capacity_wh: f64,
    /// Energy held at the first step, Wh.
    pub initial_wh: f64,
    /// Share of surplus power stored, 0 to 1.
    pub charge_efficiency: f64,
    /// Share of stored energy delivered to the load, 0 to 1 (above 0).
    pub discharge_efficiency: f64,
}

/// What a battery went through over a series of steps.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Charge {
    /// Energy held at the end of each step, Wh.
    pub charge_wh: Vec<f64>,
    /// The least energy held, Wh.
    pub min_wh: f64,
    /// Time spent below the low mark, s.
    pub below_low_s: f64,
    /// Load the empty battery could not serve, Wh.
    pub unmet_wh: f64,
}

impl Battery {
    /// A battery of `capacity_wh` holding `initial_wh` (default: full) with the given
    /// efficiencies, or the name of the first bad field and why.
    pub fn checked(
        capacity_wh: f64,
        initial_wh: Option<f64>,
        charge_efficiency: f64,
        discharge_efficiency: f64,
    ) -> Result<Battery, (&'static str, &'static str)> {
        if !(capacity_wh.is_finite() && capacity_wh > 0.0) {
            return Err(("capacity_wh", "must be above 0"));
        }
        let initial_wh = initial_wh.unwrap_or(capacity_wh);
        if !(0.0..=capacity_wh).contains(&initial_wh) {
            return Err(("initial_wh", "must be 0 to capacity_wh"));
        }
        for (field, eta) in [
            ("charge_efficiency", charge_efficiency),
            ("discharge_efficiency", discharge_efficiency),
        ] {
            if !(eta > 0.0 && eta <= 1.0) {
                return Err((field, "must be above 0 and at most 1"));
            }
        }
        Ok(Battery {
            capacity_wh,
            initial_wh,
            charge_efficiency,
            discharge_efficiency,
        })
    }

    /// Runs the battery through steps of `duration_s[k]` seconds in which the panel gives
    /// `power_w[k]` and the load takes `load_w[k]` (both held over the step). Surplus is
    /// stored at the charge efficiency up to the capacity, deficit drawn at the
    /// discharge efficiency down to empty; within a step the energy changes linearly
    /// until it meets a bound, so the time below `low_wh` is exact for that model.
    pub fn run(&self, power_w: &[f64], load_w: &[f64], duration_s: &[f64], low_wh: f64) -> Charge {
        let mut held = self.initial_wh.clamp(0.0, self.capacity_wh);
        let mut out = Charge {
            charge_wh: Vec::with_capacity(power_w.len()),
            min_wh: held,
            below_low_s: 0.0,
            unmet_wh: 0.0,
        };
        for ((&p, &load), &dt) in power_w.iter().zip(load_w).zip(duration_s) {
            out.below_low_s += time_below(held, self.rate_wh_s(p, load), dt, low_wh);
            let (free, kept) = self.after(held, p, load, dt);
            if free < 0.0 {
                out.unmet_wh += -free * self.discharge_efficiency;
            }
            held = kept;
            out.min_wh = out.min_wh.min(held);
            out.charge_wh.push(held);
        }
        out
    }

    /// The energy held after `dt` seconds that start with `held_wh` while the panel gives
    /// `power_w` and the load takes `load_w`: (unbounded, kept). The unbounded value may
    /// fall below 0 (load the battery could not serve) or rise past the capacity; the
    /// kept one is clamped to 0..capacity.
    pub fn after(&self, held_wh: f64, power_w: f64, load_w: f64, dt: f64) -> (f64, f64) {
        let free = held_wh + self.rate_wh_s(power_w, load_w) * dt;
        (free, free.clamp(0.0, self.capacity_wh))
    }

    /// Rate of change of the stored energy, Wh per second: surplus stored at the charge
    /// efficiency, deficit drawn at the discharge efficiency.
    fn rate_wh_s(&self, power_w: f64, load_w: f64) -> f64 {
        let net = power_w - load_w;
        if net >= 0.0 {
            net * self.charge_efficiency / 3600.0
        } else {
            net / self.discharge_efficiency / 3600.0
        }
    }
}

/// Seconds within a step of `dt` seconds that a store starting at `start` Wh and changing
/// at `rate` Wh/s (clamped to its bounds, which does not change which side of a mark
/// between them it is on) spends below `low` Wh.
fn time_below(start: f64, rate: f64, dt: f64, low: f64) -> f64 {
    if rate == 0.0 {
        return if start < low { dt } else { 0.0 };
    }
    // The time at which it passes the mark, if within the step.
    let cross = ((low - start) / rate).clamp(0.0, dt);
    if rate > 0.0 {
        cross // below until it rises past the mark
    } else {
        dt - cross // below once it falls past the mark
    }
}
