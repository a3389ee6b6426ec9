//! Hapke's bidirectional reflectance model for particulate (regolith) surfaces.
//!
//! ```text
//! r(i, e, g) = (w / 4π) · μ₀ₑ / (μ₀ₑ + μₑ) · { [1 + B(g)] p(g) + H(μ₀ₑ) H(μₑ) − 1 } · S(i, e, g)
//! ```
//!
//! in sr⁻¹ (Hapke 1981, J. Geophys. Res. 86, 3039, eq. 37; roughness Hapke 1984, Icarus 59,
//! 41, eqs. 46–51). Without roughness (θ̄ = 0) μ₀ₑ = μ₀ = cos i, μₑ = μ = cos e and S = 1:
//! this is the SLIM paper's eq. 11 (the paper drops the factor μ₀/π that makes r a
//! reflectance per steradian; slim keeps it).
//!
//! - w: single scattering albedo (0 … 1).
//! - Opposition surge (shadow hiding): B(g) = B₀ / (1 + tan(g/2) / h) (paper eq. 13), with
//!   amplitude B₀ ≥ 0 and angular width h > 0.
//! - Particle phase function p(g), normalised so its mean over the sphere is 1:
//!   isotropic p = 1; one-lobe Henyey–Greenstein p = (1 − ξ²)/(1 + 2ξ cos g + ξ²)^{3/2}
//!   (ξ < 0 back-scattering, the usual sign for regolith); two-lobe Henyey–Greenstein
//!   p = (1 + c)/2 · (1 − b²)/(1 − 2b cos g + b²)^{3/2} + (1 − c)/2 · (1 − b²)/(1 + 2b cos g + b²)^{3/2}
//!   (0 ≤ b < 1 lobe width, −1 ≤ c ≤ 1, c > 0 back-scattering; Hapke 2012 eq. 6.7).
//! - Chandrasekhar's H function for isotropic scatterers, either Hapke's 1981
//!   approximation H(x) = (1 + 2x)/(1 + 2γx), γ = √(1 − w) (paper eq. 12; errors up to
//!   ~4 %), or the 2002 one (Icarus 157, 523, eq. 13), accurate to ~1 %:
//!   H(x) = [1 − w x (r₀ + (1 − 2 r₀ x)/2 · ln((1 + x)/x))]⁻¹, r₀ = (1 − γ)/(1 + γ).
//! - Macroscopic roughness θ̄ (mean slope angle, Hapke 1984): effective cosines μ₀ₑ, μₑ and
//!   the shadowing function S(i, e, ψ), ψ the azimuth between the incidence and emission
//!   planes, cos ψ = (cos g − cos i cos e)/(sin i sin e). Hapke writes two cases (i ≤ e and
//!   e ≤ i); both are implemented, and the resulting BRDF r/μ₀ is reciprocal (tested).
//!
//! Limits: the limb and terminator (μ, μ₀ → 0) are evaluated without division by zero:
//! x·ln((1+x)/x) is written x·(ln(1+x) − ln x), which is 0 at x = 0; cot of an angle is
//! cos/sin with sin floored at the smallest normal number; tan(g/2) → ∞ at g → 180° gives
//! B = 0. Nothing returns NaN or infinity for valid parameters.

use super::{Angles, Range, Reflectance};
use std::f64::consts::PI;

/// Which approximation of Chandrasekhar's H function to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
pub enum HFunction {
    /// Hapke (1981): (1 + 2x)/(1 + 2γx).
    #[serde(rename = "1981")]
    Hapke1981,
    /// Hapke (2002): the more accurate logarithmic form (default).
    #[default]
    #[serde(rename = "2002")]
    Hapke2002,
}

impl HFunction {
    /// The name used in scenes and on the command line ("1981" or "2002").
    pub fn name(&self) -> &'static str {
        match self {
            HFunction::Hapke1981 => "1981",
            HFunction::Hapke2002 => "2002",
        }
    }

    /// H(x) for single scattering albedo w, x = cos of an angle in [0, 1].
    pub fn eval(&self, x: f64, w: f64) -> f64 {
        let gamma = (1.0 - w).max(0.0).sqrt();
        match self {
            HFunction::Hapke1981 => (1.0 + 2.0 * x) / (1.0 + 2.0 * gamma * x),
            HFunction::Hapke2002 => {
                let r0 = (1.0 - gamma) / (1.0 + gamma);
                let x_log = if x > 0.0 {
                    x * (x.ln_1p() - x.ln())
                } else {
                    0.0
                };
                1.0 / (1.0 - w * (x * r0 + (1.0 - 2.0 * r0 * x) / 2.0 * x_log))
            }
        }
    }
}

/// The single-particle phase function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PhaseFunction {
    /// p(g) = 1.
    Isotropic,
    /// One-lobe Henyey–Greenstein with asymmetry ξ (−1 < ξ < 1; ξ < 0 back-scattering).
    HenyeyGreenstein1 { xi: f64 },
    /// Two-lobe Henyey–Greenstein with lobe width b (0 ≤ b < 1) and weight c (−1 … 1).
    HenyeyGreenstein2 { b: f64, c: f64 },
}

impl PhaseFunction {
    /// p(g) for cos g.
    pub fn eval(&self, cos_g: f64) -> f64 {
        let lobe = |xi: f64| (1.0 - xi * xi) / (1.0 + 2.0 * xi * cos_g + xi * xi).powf(1.5);
        match *self {
            PhaseFunction::Isotropic => 1.0,
            PhaseFunction::HenyeyGreenstein1 { xi } => lobe(xi),
            PhaseFunction::HenyeyGreenstein2 { b, c } => {
                0.5 * (1.0 + c) * lobe(-b) + 0.5 * (1.0 - c) * lobe(b)
            }
        }
    }
}

/// Hapke's model with its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hapke {
    /// Single scattering albedo w.
    pub w: f64,
    /// Opposition surge amplitude B₀.
    pub b0: f64,
    /// Opposition surge width h.
    pub h: f64,
    /// Particle phase function.
    pub phase: PhaseFunction,
    /// Mean slope angle θ̄, radians (0: smooth).
    pub theta_bar: f64,
    /// H-function approximation.
    pub h_function: HFunction,
}

impl Default for Hapke {
    /// Isotropic, smooth, no opposition surge, w = 0.5, 2002 H function.
    fn default() -> Self {
        Hapke {
            w: 0.5,
            b0: 0.0,
            h: 0.05,
            phase: PhaseFunction::Isotropic,
            theta_bar: 0.0,
            h_function: HFunction::default(),
        }
    }
}

/// Roughness geometry: effective cosines and the shadowing factor.
struct Rough {
    mu0: f64,
    mu: f64,
    shadowing: f64,
}

impl Hapke {
    /// Parameter names of this configuration (θ̄ is given and fitted in degrees).
    pub(crate) fn parameter_names(&self) -> Vec<&'static str> {
        let mut names = vec!["w", "b0", "h"];
        match self.phase {
            PhaseFunction::Isotropic => {}
            PhaseFunction::HenyeyGreenstein1 { .. } => names.push("xi"),
            PhaseFunction::HenyeyGreenstein2 { .. } => names.extend(["b", "c"]),
        }
        names.push("theta_bar_deg");
        names
    }

    pub(crate) fn get(&self, name: &str) -> Option<f64> {
        match (name, self.phase) {
            ("w", _) => Some(self.w),
            ("b0", _) => Some(self.b0),
            ("h", _) => Some(self.h),
            ("theta_bar_deg", _) => Some(self.theta_bar.to_degrees()),
            ("xi", PhaseFunction::HenyeyGreenstein1 { xi }) => Some(xi),
            ("b", PhaseFunction::HenyeyGreenstein2 { b, .. }) => Some(b),
            ("c", PhaseFunction::HenyeyGreenstein2 { c, .. }) => Some(c),
            _ => None,
        }
    }

    /// Valid range of a parameter. ξ and b stop short of ±1, where the lobes become delta
    /// functions; θ̄ stops at 60°, beyond the range Hapke's derivation assumes.
    pub(crate) fn range(name: &str) -> Option<Range> {
        Some(match name {
            "w" => Range::new(0.0, 1.0),
            "b0" => Range::new(0.0, 10.0),
            "h" => Range::new(1e-6, 10.0),
            "xi" => Range::new(-0.99, 0.99),
            "b" => Range::new(0.0, 0.99),
            "c" => Range::new(-1.0, 1.0),
            "theta_bar_deg" => Range::new(0.0, 60.0),
            _ => return None,
        })
    }

    /// Sets a parameter known to exist and to be in range.
    pub(crate) fn set(&mut self, name: &str, value: f64) {
        match (name, &mut self.phase) {
            ("w", _) => self.w = value,
            ("b0", _) => self.b0 = value,
            ("h", _) => self.h = value,
            ("theta_bar_deg", _) => self.theta_bar = value.to_radians(),
            ("xi", PhaseFunction::HenyeyGreenstein1 { xi }) => *xi = value,
            ("b", PhaseFunction::HenyeyGreenstein2 { b, .. }) => *b = value,
            ("c", PhaseFunction::HenyeyGreenstein2 { c, .. }) => *c = value,
            _ => unreachable!("Material::set checks the name first"),
        }
    }

    /// Shadow-hiding opposition surge B(g) for cos g.
    pub fn surge(&self, cos_g: f64) -> f64 {
        // tan(g/2) = √((1 − cos g)/(1 + cos g)); infinite at g = 180°, where B = 0.
        let tan_half = ((1.0 - cos_g).max(0.0) / (1.0 + cos_g).max(0.0)).sqrt();
        self.b0 / (1.0 + tan_half / self.h)
    }

    /// Hapke (1984) effective cosines and shadowing for the mean slope θ̄ > 0.
    fn roughness(&self, a: &Angles) -> Rough {
        let tan_t = self.theta_bar.tan();
        let chi = 1.0 / (1.0 + PI * tan_t * tan_t).sqrt();
        let (ci, ce) = (a.cos_i.clamp(0.0, 1.0), a.cos_e.clamp(0.0, 1.0));
        let (si, se) = ((1.0 - ci * ci).sqrt(), (1.0 - ce * ce).sqrt());
        let cot = |c: f64, s: f64| c / s.max(f64::MIN_POSITIVE);
        let cot_t = 1.0 / tan_t;
        let e1 = |c: f64, s: f64| (-2.0 / PI * cot_t * cot(c, s)).exp();
        let e2 = |c: f64, s: f64| (-1.0 / PI * (cot_t * cot(c, s)).powi(2)).exp();
        let (e1i, e1e, e2i, e2e) = (e1(ci, si), e1(ce, se), e2(ci, si), e2(ce, se));
        let eta = |c: f64, s: f64, e1x: f64, e2x: f64| chi * (c + s * tan_t * e2x / (2.0 - e1x));
        let eta_i = eta(ci, si, e1i, e2i);
        let eta_e = eta(ce, se, e1e, e2e);
        let cos_psi = if si * se > 0.0 {
            ((a.cos_g - ci * ce) / (si * se)).clamp(-1.0, 1.0)
        } else {
            1.0
        };
        let psi = cos_psi.acos();
        let sin2_half = ((1.0 - cos_psi) / 2.0).max(0.0);
        // f = exp(−2 tan(ψ/2)); tan(ψ/2) = sin ψ / (1 + cos ψ), infinite at ψ = π (f = 0).
        let f = if cos_psi > -1.0 {
            (-2.0 * (1.0 - cos_psi * cos_psi).sqrt() / (1.0 + cos_psi)).exp()
        } else {
            0.0
        };
        // The two cases of Hapke (1984) differ by exchanging the roles of i and e.
        let (near, far) = if si <= se { (e1e, e1i) } else { (e1i, e1e) };
        let denom = 2.0 - near - psi / PI * far;
        // denom → 0 only with both angles at 90° and ψ = π, where the numerators vanish
        // too and the factor cos i / η(i) makes r = 0 whatever the ratio.
        let ratio = |num: f64| if denom > 0.0 { num / denom } else { 0.0 };
        let (mu0, mu, tail) = if si <= se {
            (
                chi * (ci + si * tan_t * ratio(cos_psi * e2e + sin2_half * e2i)),
                chi * (ce + se * tan_t * ratio(e2e - sin2_half * e2i)),
                ci / eta_i,
            )
        } else {
            (
                chi * (ci + si * tan_t * ratio(e2i - sin2_half * e2e)),
                chi * (ce + se * tan_t * ratio(cos_psi * e2i + sin2_half * e2e)),
                ce / eta_e,
            )
        };
        let shadowing = mu / eta_e * ci / eta_i * chi / (1.0 - f + f * chi * tail);
        Rough { mu0, mu, shadowing }
    }
}

impl Reflectance for Hapke {
    fn reflectance(&self, a: &Angles) -> f64 {
        if !a.is_lit_and_seen() {
            return 0.0;
        }
        let rough = if self.theta_bar > 0.0 {
            self.roughness(a)
        } else {
            Rough {
                mu0: a.cos_i,
                mu: a.cos_e,
                shadowing: 1.0,
            }
        };
        let p = self.phase.eval(a.cos_g);
        let h = |x: f64| self.h_function.eval(x, self.w);
        let bracket = (1.0 + self.surge(a.cos_g)) * p + h(rough.mu0) * h(rough.mu) - 1.0;
        self.w / (4.0 * PI) * rough.mu0 / (rough.mu0 + rough.mu) * bracket * rough.shadowing
    }
}
