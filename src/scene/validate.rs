//! Scene validation: the checks a parsed scene passes before anything is built.
//!
//! In: a [`Scene`] as parsed. Out: `Ok`, or the first problem as an error naming the
//! scene file, the key path (`body[1].orbit.radius_km`) and what is wrong.

use super::schema::*;
use super::Scene;
use crate::error::Result;
use crate::horizon::SunShape;

/// The most steps a scene may ask for: a century of one-minute steps fits, a run that
/// could not finish in a lifetime does not.
pub const MAX_STEPS: usize = 100_000_000;

/// The most bodies a scene may have: every step checks each pair for shadows.
pub const MAX_BODIES: usize = 64;

/// The longest time a run may span, seconds: far beyond any ephemeris, well inside what
/// an epoch can hold.
pub const MAX_SPAN_S: f64 = 1e12;

impl Scene {
    pub(super) fn validate(&self) -> Result<()> {
        positive(self, "run.bin_width_w_m2", self.run.bin_width_w_m2)?;
        self.shadows().check().map_err(|msg| self.err("run", msg))?;
        check_name(self, "run.name", &self.name)?;
        if self.bodies.is_empty() {
            return Err(self.err("body", "a scene needs at least one [[body]]"));
        }
        if self.bodies.len() > MAX_BODIES {
            return Err(self.err(
                "body",
                format!(
                    "{} bodies; at most {MAX_BODIES} (pairs of bodies are checked at every step)",
                    self.bodies.len()
                ),
            ));
        }
        for (i, b) in self.bodies.iter().enumerate() {
            let key = |k: &str| format!("body[{i}].{k}");
            check_name(self, &key("name"), &b.name)?;
            if self.bodies[..i]
                .iter()
                .any(|o| o.name.eq_ignore_ascii_case(&b.name))
            {
                return Err(self.err(key("name"), format!("'{}' is used twice", b.name)));
            }
            if b.position_km.iter().any(|x| !x.is_finite()) {
                return Err(self.err(key("position_km"), "must be finite numbers"));
            }
            if let Some(p) = b.spin_period_h {
                positive(self, &key("spin_period_h"), p)?;
            }
            finite(self, &key("initial_rotation_deg"), b.initial_rotation_deg)?;
            let spice = matches!(self.ephemeris, EphemerisSection::Spice(_));
            for (given, what) in [(b.frame.is_some(), "frame"), (b.orbit.is_some(), "orbit")] {
                if given && !spice {
                    return Err(self.err(key(what), "only in spice mode"));
                }
            }
        }
        self.validate_outputs()?;
        for (i, b) in self.bodies.iter().enumerate() {
            self.validate_shape(i, b)?;
            if b.material.is_some() {
                self.material(i, None)?;
                for band in &self.bands {
                    self.material(i, Some(&band.name))?;
                }
            }
        }
        self.validate_bands()?;
        if let Some(c) = &self.camera {
            self.validate_camera(c)?;
        }
        self.validate_scatter()?;
        match &self.ephemeris {
            EphemerisSection::Spin(s) => self.validate_spin(s),
            EphemerisSection::Fixed(f) => self.validate_fixed(f),
            EphemerisSection::Spice(s) => self.validate_spice(s),
        }?;
        self.validate_step_count()
    }

    /// A run that cannot finish, or whose epochs lie beyond any calendar, is refused
    /// before anything is allocated.
    fn validate_step_count(&self) -> Result<()> {
        if let Some((span_s, key)) = self.span_s() {
            if span_s.is_nan() || span_s > MAX_SPAN_S {
                return Err(self.err(
                    key,
                    format!(
                        "makes the run span {span_s:e} s; at most {MAX_SPAN_S:e} s (about \
                         31,700 years)"
                    ),
                ));
            }
        }
        let steps = self.step_count();
        if steps.is_nan() || steps > MAX_STEPS as f64 {
            return Err(self.err(
                self.step_key(),
                format!(
                    "asks for {steps:e} steps; at most {MAX_STEPS} (a century of minute steps \
                     is 5.3e7): use fewer or longer steps"
                ),
            ));
        }
        Ok(())
    }

    fn validate_bands(&self) -> Result<()> {
        for (i, band) in self.bands.iter().enumerate() {
            check_name(self, &format!("band[{i}].name"), &band.name)?;
            if self.bands[..i].iter().any(|o| o.name == band.name) {
                return Err(self.err(
                    format!("band[{i}].name"),
                    format!("'{}' is used twice", band.name),
                ));
            }
            positive(
                self,
                &format!("band[{i}].solar_constant_w_m2"),
                band.solar_constant_w_m2,
            )?;
        }
        Ok(())
    }

    fn validate_camera(&self, c: &CameraSection) -> Result<()> {
        match (&c.preset, c.width, c.height, c.fov_deg) {
            (Some(p), None, None, None) if p == "dawn_fc" => {}
            (Some(p), None, None, None) => {
                return Err(self.err(
                    "camera.preset",
                    format!("unknown preset '{p}': the presets are \"dawn_fc\""),
                ))
            }
            (None, Some(w), Some(h), Some(fov)) => {
                if let Some(problem) = camera_size_problem(w, h, fov) {
                    return Err(self.err("camera", problem));
                }
            }
            _ => {
                return Err(self.err(
                    "camera",
                    "give either preset = \"dawn_fc\", or width, height and fov_deg",
                ))
            }
        }
        match (c.position_km, c.observer_naif_id) {
            (Some(_), Some(_)) => {
                return Err(self.err(
                    "camera",
                    "give either position_km or observer_naif_id, not both",
                ))
            }
            (None, None) => {
                return Err(self.err(
                    "camera.position_km",
                    "missing: give the camera's position, or observer_naif_id in spice mode",
                ))
            }
            (None, Some(_)) if !matches!(self.ephemeris, EphemerisSection::Spice(_)) => {
                return Err(self.err("camera.observer_naif_id", "only in spice mode"))
            }
            _ => {}
        }
        let vectors = [("position_km", c.position_km), ("up", Some(c.up))];
        for (k, v) in vectors.into_iter().chain([("look_at_km", c.look_at_km)]) {
            if v.is_some_and(|v| v.iter().any(|x| !x.is_finite())) {
                return Err(self.err(format!("camera.{k}"), "must be finite numbers"));
            }
        }
        if let Some(t) = &c.target {
            if c.look_at_km.is_some() {
                return Err(self.err("camera", "give either target or look_at_km, not both"));
            }
            if !self.bodies.iter().any(|b| &b.name == t) {
                return Err(self.err("camera.target", format!("no body is named '{t}'")));
            }
        }
        if !matches!(c.png_bits, 8 | 16) {
            return Err(self.err("camera.png_bits", "must be 8 or 16"));
        }
        if let Some(w) = c.png_white_i_over_f {
            positive(self, "camera.png_white_i_over_f", w)?;
        }
        if c.steps.as_ref().is_some_and(|s| s.is_empty()) {
            return Err(self.err("camera.steps", "list at least one step (or leave it out)"));
        }
        Ok(())
    }

    /// At least one body must get outputs, or the run would write nothing.
    fn validate_outputs(&self) -> Result<()> {
        if self.bodies.iter().any(|b| b.outputs) {
            return Ok(());
        }
        Err(self.err(
            "body",
            "every body has outputs = false: the run would write no statistics; set \
             outputs = true (the default) on the bodies to report",
        ))
    }

    fn validate_shape(&self, i: usize, b: &BodySection) -> Result<()> {
        let key = |k: &str| format!("body[{i}].{k}");
        match (&b.mesh, &b.ellipsoid, b.units) {
            (Some(_), None, Some(_)) => match &b.stereographic {
                Some(p) => positive(self, &key("stereographic.radius_km"), p.radius_km),
                None => Ok(()),
            },
            (Some(_), None, None) => Err(self.err(
                key("units"),
                "missing field `units`: the mesh file's length unit, \"km\" or \"m\"",
            )),
            (Some(_), Some(_), _) => Err(self.err(
                format!("body[{i}]"),
                "give either mesh or ellipsoid, not both",
            )),
            (None, None, _) => Err(self.err(
                format!("body[{i}]"),
                "give a mesh file (mesh = ..., units = ...) or ellipsoid = { ... }",
            )),
            (None, Some(_), _) if b.stereographic.is_some() => Err(self.err(
                key("stereographic"),
                "applies to mesh files only, not to a generated ellipsoid",
            )),
            (None, Some(_), _) if b.surroundings.is_some() => Err(self.err(
                key("surroundings"),
                "surround a terrain patch (a mesh file), not a generated ellipsoid",
            )),
            (None, Some(e), _) => {
                if let Some(r) = e.radii_km {
                    if r.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
                        return Err(
                            self.err(key("ellipsoid.radii_km"), "must be three positive numbers")
                        );
                    }
                } else if b.naif_id.is_none()
                    || !matches!(self.ephemeris, EphemerisSection::Spice(_))
                {
                    return Err(self.err(key("ellipsoid.radii_km"), "missing: give the radii, or a naif_id in spice mode to take them from the PCK"));
                }
                if e.levels > 8 {
                    return Err(self.err(key("ellipsoid.levels"), "at most 8 (1,310,720 facets)"));
                }
                Ok(())
            }
        }
    }

    /// A SPICE body is placed by the kernels (`naif_id`), or, after the first, by a
    /// synthetic `orbit` or a fixed `position_km`.
    fn validate_spice_placement(&self, i: usize, b: &BodySection) -> Result<()> {
        let key = |k: &str| format!("body[{i}].{k}");
        let fixed = b.position_km != [0.0; 3];
        match (b.naif_id, &b.orbit) {
            (Some(_), Some(_)) => {
                Err(self.err(key("orbit"), "give either naif_id or orbit, not both"))
            }
            (Some(_), None) if fixed => Err(self.err(
                key("position_km"),
                "a body with a naif_id is placed by the kernels; drop position_km",
            )),
            (Some(_), None) => Ok(()),
            (None, _) if i == 0 => Err(self.err(
                key("naif_id"),
                "missing: the first body needs a NAIF id the kernels cover (e.g. 401 for Phobos)",
            )),
            (None, _) if b.frame.is_some() => Err(self.err(
                key("frame"),
                "only bodies with a naif_id have a kernel frame",
            )),
            (None, Some(_)) if fixed => Err(self.err(
                key("position_km"),
                "give either orbit or position_km, not both",
            )),
            (None, Some(o)) => {
                positive(self, &key("orbit.radius_km"), o.radius_km)?;
                finite(self, &key("orbit.period_h"), o.period_h)?;
                if o.period_h == 0.0 {
                    return Err(self.err(key("orbit.period_h"), "must not be zero"));
                }
                finite(self, &key("orbit.pole_ra_deg"), o.pole_ra_deg)?;
                finite(self, &key("orbit.pole_dec_deg"), o.pole_dec_deg)?;
                finite(self, &key("orbit.phase_deg"), o.phase_deg)
            }
            (None, None) if fixed => Ok(()),
            (None, None) => Err(self.err(
                key("naif_id"),
                "missing: give a naif_id the kernels cover, a synthetic orbit = { radius_km, \
                 period_h, ... }, or a fixed position_km relative to the first body",
            )),
        }
    }

    fn validate_scatter(&self) -> Result<()> {
        let albedo = |key: &str, a: Option<f64>| {
            match a {
            Some(a) if !(a.is_finite() && (0.0..1.0).contains(&a)) => Err(self.err(
                key,
                format!("must be at least 0 and below 1 (1 reflects everything and never converges), not {a}"),
            )),
            _ => Ok(()),
        }
        };
        for (i, b) in self.bodies.iter().enumerate() {
            albedo(&format!("body[{i}].albedo"), b.albedo)?;
            for (name, value) in &b.albedo_bands {
                let key = format!("body[{i}].albedo_bands.{name}");
                if !self.bands.iter().any(|band| &band.name == name) {
                    return Err(self.err(key, "no [[band]] has this name"));
                }
                albedo(&key, Some(*value))?;
            }
            if b.albedo.is_some() && b.albedo_file.is_some() {
                return Err(self.err(
                    format!("body[{i}]"),
                    "give either albedo or albedo_file, not both",
                ));
            }
        }
        let Some(s) = self.scatter.as_ref().filter(|s| s.enabled) else {
            return Ok(());
        };
        albedo("scatter.albedo", s.albedo)?;
        positive(self, "scatter.tolerance", s.tolerance)?;
        positive(self, "scatter.near_field_ratio", s.near_field_ratio)?;
        if !(s.inter_body_tolerance.is_finite() && s.inter_body_tolerance >= 0.0) {
            return Err(self.err(
                "scatter.inter_body_tolerance",
                "must be a finite number ≥ 0",
            ));
        }
        if !(0.0..=0.1).contains(&s.inter_body_reuse) {
            return Err(self.err(
                "scatter.inter_body_reuse",
                "must be 0 to 0.1 (a share of the solar flux)",
            ));
        }
        if s.max_orders == 0 {
            return Err(self.err("scatter.max_orders", "must be at least 1"));
        }
        if !(2..=64).contains(&s.planet_order) {
            return Err(self.err("scatter.planet_order", "must be 2 to 64"));
        }
        if !(0.0..=0.1).contains(&s.planet_reuse) {
            return Err(self.err("scatter.planet_reuse", "must be 0 to 0.1"));
        }
        if let Some(i) = self
            .bodies
            .iter()
            .position(|b| b.albedo.is_none() && b.albedo_file.is_none() && s.albedo.is_none())
        {
            return Err(self.err(
                format!("body[{i}].albedo"),
                "missing: scattering needs an albedo for every body (here, in albedo_file, or in [scatter])",
            ));
        }
        Ok(())
    }

    fn validate_spice(&self, s: &SpiceSection) -> Result<()> {
        if s.kernels.is_empty() {
            return Err(self.err("ephemeris.kernels", "list at least one kernel"));
        }
        positive(self, "ephemeris.solar_constant_w_m2", s.solar_constant_w_m2)?;
        if crate::ephemeris::spice::parse_aberration(&s.aberration).is_none() {
            return Err(self.err(
                "ephemeris.aberration",
                format!("'{}' is not one of NONE, LT, LT+S, CN, CN+S", s.aberration),
            ));
        }
        for (i, b) in self.bodies.iter().enumerate() {
            self.validate_spice_placement(i, b)?;
        }
        match s.steps {
            SpiceSteps::Window { stop, step_s } => {
                positive(self, "ephemeris.step_s", step_s)?;
                if stop <= self.start {
                    return Err(self.err("ephemeris.stop", "must be after start"));
                }
                Ok(())
            }
            SpiceSteps::Spins {
                spins,
                steps_per_spin,
            } => {
                positive(self, "ephemeris.spins", spins)?;
                if steps_per_spin == 0 {
                    return Err(self.err("ephemeris.steps_per_spin", "must be at least 1"));
                }
                Ok(())
            }
        }
    }

    fn validate_spin(&self, s: &SpinSection) -> Result<()> {
        positive(self, "ephemeris.distance_au", s.distance_au)?;
        positive(self, "ephemeris.solar_constant_w_m2", s.solar_constant_w_m2)?;
        positive(self, "ephemeris.periods", s.periods)?;
        if s.steps_per_period == 0 {
            return Err(self.err("ephemeris.steps_per_period", "must be at least 1"));
        }
        if self.bodies[0].spin_period_h.is_none() {
            return Err(self.err(
                "body[0].spin_period_h",
                "spin mode needs the first body's spin period (hours)",
            ));
        }
        match (
            s.subsolar_latitude_deg,
            s.obliquity_deg,
            s.solar_longitude_deg,
        ) {
            (Some(lat), None, None) if (-90.0..=90.0).contains(&lat) => Ok(()),
            (Some(_), None, None) => Err(self.err(
                "ephemeris.subsolar_latitude_deg",
                "must be between -90 and 90 degrees",
            )),
            (None, Some(o), Some(l)) if o.is_finite() && l.is_finite() => Ok(()),
            (None, None, None) => Ok(()),
            _ => Err(self.err(
                "ephemeris",
                "give either subsolar_latitude_deg, or both obliquity_deg and solar_longitude_deg \
                 (finite numbers)",
            )),
        }
    }

    fn validate_fixed(&self, f: &FixedSection) -> Result<()> {
        positive(self, "ephemeris.step_s", f.step_s)?;
        positive(self, "ephemeris.solar_constant_w_m2", f.solar_constant_w_m2)?;
        if f.sun.is_empty() {
            return Err(self.err(
                "ephemeris.sun",
                "fixed mode needs at least one [[ephemeris.sun]]",
            ));
        }
        for (i, s) in f.sun.iter().enumerate() {
            let key = |k: &str| format!("ephemeris.sun[{i}].{k}");
            if crate::ephemeris::fixed::normalized_direction(s.direction).is_none() {
                return Err(self.err(key("direction"), "must be a finite, non-zero vector"));
            }
            match (s.distance_au, s.flux_w_m2) {
                (Some(d), None) => positive(self, &key("distance_au"), d)?,
                (None, Some(_)) if self.run.sun == Some(SunShape::Disk) => {
                    return Err(self.err(
                        key("flux_w_m2"),
                        "a disk Sun's size comes from its distance: give distance_au instead \
                         (or sun = \"point\" in [run])",
                    ))
                }
                (None, Some(w)) if w.is_finite() && w >= 0.0 => {}
                (None, Some(_)) => {
                    return Err(self.err(key("flux_w_m2"), "must be a finite number ≥ 0"))
                }
                _ => {
                    return Err(self.err(
                        format!("ephemeris.sun[{i}]"),
                        "give exactly one of distance_au and flux_w_m2",
                    ))
                }
            }
        }
        Ok(())
    }
}

fn positive(scene: &Scene, key: &str, x: f64) -> Result<()> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(scene.err(key, format!("must be a positive number, not {x}")))
    }
}

fn finite(scene: &Scene, key: &str, x: f64) -> Result<()> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(scene.err(key, format!("must be a finite number, not {x}")))
    }
}

/// Names become file names (`BODY.ply`, `results/NAME`): keep them to letters, digits,
/// `-`, `_` and `.`, not starting with a dot, so no name can reach outside a folder.
fn check_name(scene: &Scene, key: &str, name: &str) -> Result<()> {
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    if name.is_empty() || name.len() > 100 || name.starts_with('.') || !name.chars().all(allowed) {
        return Err(scene.err(
            key,
            format!(
                "'{name}' is not a usable name: use 1 to 100 letters, digits, '-', '_' or '.', \
                 not starting with '.'"
            ),
        ));
    }
    Ok(())
}

/// What is wrong with a camera of `width` × `height` pixels and a field of view of
/// `fov_deg` degrees across the width, if anything: the size must be 1 to 2^26 pixels,
/// the field of view strictly between 0 and 180 degrees.
pub fn camera_size_problem(width: usize, height: usize, fov_deg: f64) -> Option<String> {
    if width == 0 || height == 0 || width.saturating_mul(height) > 1 << 26 {
        return Some(format!(
            "camera size {width} × {height} must be between 1 and 2^26 pixels"
        ));
    }
    if !(fov_deg > 0.0 && fov_deg < 180.0) {
        return Some(format!(
            "field of view {fov_deg}° must be between 0 and 180 degrees"
        ));
    }
    None
}
