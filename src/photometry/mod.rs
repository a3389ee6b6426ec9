//! Photometry: how bright a surface element looks for a given illumination and view.
//!
//! In: the viewing geometry of a surface element — cosines of the incidence angle i (to
//! the Sun) and emission angle e (to the observer), both from the local normal, and of the
//! phase angle g between the directions to the Sun and to the observer — and a model's
//! parameters. Out: the bidirectional reflectance r(i, e, g) in sr⁻¹ (Hapke 1981's
//! definition): the radiance scattered toward the observer divided by the collimated
//! irradiance J on a plane perpendicular to the Sun, so that
//!
//! ```text
//! L = J · r          radiance, W m⁻² sr⁻¹, for J in W/m²
//! I/F = π · r        radiance factor ("I/F"), dimensionless
//! ```
//!
//! r contains the cos i of the illumination (a Lambert surface has r = A·cos i/π). Every
//! model returns 0 (never NaN or infinity) when the Sun is at or below the local horizon
//! (cos i ≤ 0) or the observer below it (cos e < 0).
//!
//! Models ([`Reflectance`]): [`lambert::Lambert`], [`lommel_seeliger::LommelSeeliger`]
//! and [`hapke::Hapke`]; [`Material`] holds any of them with named, bounded parameters
//! (for scenes, the CLI and the fit).

pub mod hapke;
pub mod lambert;
pub mod lommel_seeliger;

use crate::error::{Error, Result};
use glam::DVec3;
use hapke::{HFunction, Hapke, PhaseFunction};
use lambert::Lambert;
use lommel_seeliger::LommelSeeliger;

/// The viewing geometry of a surface element, as cosines.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Angles {
    /// cos i: incidence angle from the normal to the Sun.
    pub cos_i: f64,
    /// cos e: emission angle from the normal to the observer.
    pub cos_e: f64,
    /// cos g: phase angle between the directions to the Sun and to the observer.
    pub cos_g: f64,
}

/// cos x for x in degrees, as sin(90° − x): exactly 0 at 90° (cos of the rounded π/2 is
/// 6e-17, which would leave a surface lit by light along its horizon) and exactly ±1 at
/// 0° and 180°.
fn cos_deg(x: f64) -> f64 {
    (90.0 - x).to_radians().sin()
}

impl Angles {
    /// The geometry for angles in degrees; the phase angle must be possible for the given
    /// i and e (|i − e| ≤ g ≤ min(i + e, 360° − i − e)).
    pub fn from_degrees(incidence: f64, emission: f64, phase: f64) -> Result<Angles> {
        let all = [incidence, emission, phase];
        if all.iter().any(|x| !x.is_finite() || *x < 0.0 || *x > 180.0) {
            return Err(Error::Usage(format!(
                "angles must be between 0 and 180 degrees, not i={incidence}, e={emission}, \
                 g={phase}"
            )));
        }
        let slack = 1e-9;
        let most = (incidence + emission).min(360.0 - incidence - emission);
        if phase < (incidence - emission).abs() - slack || phase > most + slack {
            return Err(Error::Usage(format!(
                "phase {phase}° is impossible for incidence {incidence}° and emission \
                 {emission}°: it must lie between |i−e| = {}° and {most}°",
                (incidence - emission).abs()
            )));
        }
        Ok(Angles {
            cos_i: cos_deg(incidence),
            cos_e: cos_deg(emission),
            cos_g: cos_deg(phase),
        })
    }

    /// The geometry for a unit normal and unit vectors toward the Sun and the observer.
    pub fn from_vectors(normal: DVec3, to_sun: DVec3, to_observer: DVec3) -> Angles {
        Angles {
            cos_i: normal.dot(to_sun),
            cos_e: normal.dot(to_observer),
            cos_g: to_sun.dot(to_observer).clamp(-1.0, 1.0),
        }
    }

    /// True when the Sun is above and the observer not below the local horizon.
    pub fn is_lit_and_seen(&self) -> bool {
        self.cos_i > 0.0 && self.cos_e >= 0.0
    }

    /// The phase angle, radians.
    pub fn phase(&self) -> f64 {
        self.cos_g.clamp(-1.0, 1.0).acos()
    }
}

/// A reflectance model.
pub trait Reflectance: Send + Sync + std::fmt::Debug {
    /// Bidirectional reflectance r (sr⁻¹); 0 unless `angles.is_lit_and_seen()`.
    fn reflectance(&self, angles: &Angles) -> f64;
}

/// The radiance factor I/F = π·r for a bidirectional reflectance r (sr⁻¹).
pub fn i_over_f(r: f64) -> f64 {
    std::f64::consts::PI * r
}

/// A surface material: any of the models, with parameters addressed by name.
#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    Lambert(Lambert),
    LommelSeeliger(LommelSeeliger),
    Hapke(Hapke),
}

/// A parameter's valid range (inclusive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    pub min: f64,
    pub max: f64,
}

impl Range {
    const fn new(min: f64, max: f64) -> Range {
        Range { min, max }
    }

    /// True when `x` is a finite number in the range.
    pub fn contains(&self, x: f64) -> bool {
        x.is_finite() && x >= self.min && x <= self.max
    }
}

impl Material {
    /// The model names, as written in scenes and on the command line.
    pub const MODELS: [&'static str; 3] = ["lambert", "lommel_seeliger", "hapke"];

    /// The model's default parameters by name (`lambert`, `lommel_seeliger`, `hapke`).
    pub fn default_for(model: &str) -> Result<Material> {
        match model {
            "lambert" => Ok(Material::Lambert(Lambert::default())),
            "lommel_seeliger" | "lommel-seeliger" => {
                Ok(Material::LommelSeeliger(LommelSeeliger::default()))
            }
            "hapke" => Ok(Material::Hapke(Hapke::default())),
            other => Err(Error::Usage(format!(
                "unknown reflectance model '{other}': use one of {}",
                Material::MODELS.join(", ")
            ))),
        }
    }

    /// A material of `model` with the named parameters set (others keep their defaults).
    /// For Hapke, giving `xi` selects the one-lobe Henyey–Greenstein phase function,
    /// giving `b` or `c` the two-lobe one (b defaults to 0.2, c to 0); neither keeps it
    /// isotropic. Errors name the offending parameter.
    pub fn from_params(
        model: &str,
        params: &[(String, f64)],
        h_function: Option<HFunction>,
    ) -> Result<Material> {
        let mut material = Material::default_for(model)?;
        if let Material::Hapke(h) = &mut material {
            let has = |n: &str| params.iter().any(|(k, _)| k == n);
            if has("xi") && (has("b") || has("c")) {
                return Err(Error::Usage(
                    "give either xi (one-lobe Henyey–Greenstein) or b and c (two lobes), \
                     not both"
                        .into(),
                ));
            }
            if has("xi") {
                h.phase = PhaseFunction::HenyeyGreenstein1 { xi: 0.0 };
            } else if has("b") || has("c") {
                h.phase = PhaseFunction::HenyeyGreenstein2 { b: 0.2, c: 0.0 };
            }
            if let Some(f) = h_function {
                h.h_function = f;
            }
        } else if h_function.is_some() {
            return Err(Error::Usage(format!(
                "h_function applies to the hapke model only, not {model}"
            )));
        }
        for (name, value) in params {
            material.set(name, *value)?;
        }
        Ok(material)
    }

    /// The model's name.
    pub fn model(&self) -> &'static str {
        match self {
            Material::Lambert(_) => "lambert",
            Material::LommelSeeliger(_) => "lommel_seeliger",
            Material::Hapke(_) => "hapke",
        }
    }

    /// The names of the parameters this material has (in its current configuration: a
    /// Hapke material has `xi` only with a one-lobe phase function, `b` and `c` only with
    /// two lobes).
    pub fn parameter_names(&self) -> Vec<&'static str> {
        match self {
            Material::Lambert(_) => vec!["albedo"],
            Material::LommelSeeliger(_) => vec!["w"],
            Material::Hapke(h) => h.parameter_names(),
        }
    }

    /// The value of parameter `name`, if the material has it.
    pub fn get(&self, name: &str) -> Option<f64> {
        match (self, name) {
            (Material::Lambert(l), "albedo") => Some(l.albedo),
            (Material::LommelSeeliger(l), "w") => Some(l.w),
            (Material::Hapke(h), _) => h.get(name),
            _ => None,
        }
    }

    /// The valid range of parameter `name` of this material's model.
    pub fn range(&self, name: &str) -> Option<Range> {
        self.get(name)?;
        Some(match name {
            "albedo" | "w" => Range::new(0.0, 1.0),
            _ => Hapke::range(name)?,
        })
    }

    /// Sets parameter `name`, checking that the material has it and that it is in range.
    pub fn set(&mut self, name: &str, value: f64) -> Result<()> {
        let range = self.range(name).ok_or_else(|| {
            Error::Usage(format!(
                "model {} has no parameter '{name}'; its parameters are {}",
                self.model(),
                self.parameter_names().join(", ")
            ))
        })?;
        if !range.contains(value) {
            return Err(Error::Usage(format!(
                "{} parameter {name} = {value} is outside [{}, {}]",
                self.model(),
                range.min,
                range.max
            )));
        }
        match self {
            Material::Lambert(l) => l.albedo = value,
            Material::LommelSeeliger(l) => l.w = value,
            Material::Hapke(h) => h.set(name, value),
        }
        Ok(())
    }

    /// A one-line description with every parameter.
    pub fn describe(&self) -> String {
        let params: Vec<String> = self
            .parameter_names()
            .iter()
            .filter_map(|n| self.get(n).map(|v| format!("{n}={v}")))
            .collect();
        let extra = match self {
            Material::Hapke(h) => format!(" h_function={}", h.h_function.name()),
            _ => String::new(),
        };
        format!("{} {}{extra}", self.model(), params.join(" "))
    }
}

impl Reflectance for Material {
    fn reflectance(&self, angles: &Angles) -> f64 {
        match self {
            Material::Lambert(m) => m.reflectance(angles),
            Material::LommelSeeliger(m) => m.reflectance(angles),
            Material::Hapke(m) => m.reflectance(angles),
        }
    }
}
