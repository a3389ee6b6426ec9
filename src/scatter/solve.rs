//! Solvers of the multiple-scattering equation.
//!
//! In: the first-order scattered irradiance `S1` (W/m²) of every facet, the albedo `ρ`,
//! the facet areas `A` (m²) and the exchange areas `G` (m², symmetric, `G_ij = A_i F_ij`)
//! as an [`Exchange`] operator. Out: the scattered irradiance `S` (W/m²) solving
//!
//! ```text
//! S = S1 + F ρ S,   F = A⁻¹ G,
//! ```
//!
//! and a [`SolveReport`]. Two methods:
//! - **Jacobi** (the SLIM paper, section 6.2): `S⁽¹⁾ = S1`, `S⁽ᵏ⁺¹⁾ = S1 + F ρ S⁽ᵏ⁾`, so
//!   iterate k holds exactly the scattering orders 1…k. It stops at `max_orders` or when
//!   an iteration changes `S` by less than the tolerance (relative, 2-norm). Its error
//!   falls like (ρ·λ)ᵏ, λ ≤ 1 the spectral radius of F: slow when ρ is near 1.
//! - **Conjugate gradients** on the symmetric form given by reciprocity: with `x = ρ S`
//!   on the facets of non-zero albedo, `(A/ρ − G) x = A S1`. Each row of `G` sums to at
//!   most `A_i` (the caller guarantees it), so for ρ < 1 the matrix is strictly diagonally
//!   dominant, hence symmetric positive definite, and CG (preconditioned with its
//!   diagonal A/ρ) converges monotonically in the energy norm; it needs far fewer products
//!   than Jacobi when ρ is near 1. `S = S1 + A⁻¹ G x` then also covers facets of zero
//!   albedo, which receive but do not reflect (on the others it follows from CG's own
//!   residual, without a product).
//!
//! Neither can diverge: both stop at an iteration cap, and the report states the residual
//! `‖S1 + FρS − S‖₂ / ‖S‖₂` of the returned `S` either way.

use serde::{Deserialize, Serialize};

/// Exchange areas as an operator.
pub trait Exchange: Sync {
    /// `y = G x` (m² × the unit of x), every facet.
    fn apply(&self, x: &[f64], y: &mut [f64]);
    /// Facet areas, m².
    fn areas(&self) -> &[f64];
}

/// Which method solves the multiple-scattering equation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SolverKind {
    /// Jacobi when every albedo is at most 0.5, conjugate gradients otherwise.
    #[default]
    Auto,
    /// The paper's iteration: iterate k holds scattering orders ≤ k.
    Jacobi,
    /// Conjugate gradients on the symmetric form (fast when albedo is near 1).
    Cg,
}

/// Stopping rules.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stopping {
    /// Relative tolerance (2-norm).
    pub tolerance: f64,
    /// Jacobi: most scattering orders; CG: most iterations.
    pub max_iterations: u32,
}

/// What a solve did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct SolveReport {
    /// "jacobi" or "cg".
    pub method: &'static str,
    /// Operator products spent (Jacobi: the scattering orders included).
    pub iterations: u32,
    /// ‖S1 + FρS − S‖₂ / ‖S‖₂ of the result (0 when nothing is lit).
    pub residual: f64,
    /// The tolerance was met before the iteration cap.
    pub converged: bool,
}

/// Solves `S = S1 + F ρ S` into `s` with `method` (never `Auto`: resolve it first).
pub fn solve(
    g: &dyn Exchange,
    albedo: &[f64],
    s1: &[f64],
    method: SolverKind,
    stop: Stopping,
    s: &mut [f64],
) -> SolveReport {
    s.copy_from_slice(s1);
    if norm(s1) == 0.0 || albedo.iter().all(|&r| r == 0.0) {
        let method = if method == SolverKind::Cg {
            "cg"
        } else {
            "jacobi"
        };
        return SolveReport {
            method,
            iterations: 1,
            residual: 0.0,
            converged: true,
        };
    }
    match method {
        SolverKind::Cg => conjugate_gradients(g, albedo, s1, stop, s),
        _ => jacobi(g, albedo, s1, stop, s),
    }
}

/// `Auto` resolved for the largest albedo.
pub fn resolve(kind: SolverKind, max_albedo: f64) -> SolverKind {
    match kind {
        SolverKind::Auto if max_albedo <= 0.5 => SolverKind::Jacobi,
        SolverKind::Auto => SolverKind::Cg,
        k => k,
    }
}

fn jacobi(
    g: &dyn Exchange,
    albedo: &[f64],
    s1: &[f64],
    stop: Stopping,
    s: &mut [f64],
) -> SolveReport {
    let mut next = vec![0.0; s.len()];
    let mut orders = 1;
    let mut converged = false;
    while orders < stop.max_iterations.max(1) {
        scatter_once(g, albedo, s1, s, &mut next);
        let change = distance(&next, s);
        s.copy_from_slice(&next);
        orders += 1;
        if change <= stop.tolerance * norm(s) {
            converged = true;
            break;
        }
    }
    SolveReport {
        method: "jacobi",
        iterations: orders,
        residual: residual(g, albedo, s1, s, &mut next),
        converged,
    }
}

fn conjugate_gradients(
    g: &dyn Exchange,
    albedo: &[f64],
    s1: &[f64],
    stop: Stopping,
    s: &mut [f64],
) -> SolveReport {
    let a = g.areas();
    // Facets of zero albedo or zero area take no part: their row of the system is empty.
    let active: Vec<bool> = (0..a.len())
        .map(|i| albedo[i] > 0.0 && a[i] > 0.0)
        .collect();
    let diag: Vec<f64> = (0..a.len())
        .map(|i| if active[i] { a[i] / albedo[i] } else { 0.0 })
        .collect();
    let matvec = |x: &[f64], y: &mut [f64]| {
        g.apply(x, y);
        for i in 0..y.len() {
            y[i] = if active[i] {
                diag[i] * x[i] - y[i]
            } else {
                0.0
            };
        }
    };
    let precondition = |r: &[f64], z: &mut [f64]| {
        for i in 0..r.len() {
            z[i] = if active[i] { r[i] / diag[i] } else { 0.0 };
        }
    };
    let b: Vec<f64> = (0..a.len())
        .map(|i| if active[i] { a[i] * s1[i] } else { 0.0 })
        .collect();
    let b_norm = norm(&b);
    // Start from first order only: x = ρ S1.
    let mut x: Vec<f64> = (0..a.len())
        .map(|i| if active[i] { albedo[i] * s1[i] } else { 0.0 })
        .collect();
    let mut r = vec![0.0; a.len()];
    matvec(&x, &mut r);
    r.iter_mut().zip(&b).for_each(|(r, b)| *r = b - *r);
    let mut z = vec![0.0; a.len()];
    precondition(&r, &mut z);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let mut q = vec![0.0; a.len()];
    let mut iterations = 1;
    let mut converged = norm(&r) <= stop.tolerance * b_norm;
    while !converged && iterations < stop.max_iterations.max(1) {
        matvec(&p, &mut q);
        let pq = dot(&p, &q);
        if pq <= 0.0 {
            break; // only rounding can get here: the matrix is positive definite
        }
        let alpha = rz / pq;
        axpy(alpha, &p, &mut x);
        axpy(-alpha, &q, &mut r);
        iterations += 1;
        converged = norm(&r) <= stop.tolerance * b_norm;
        precondition(&r, &mut z);
        let rz_next = dot(&r, &z);
        let beta = rz_next / rz;
        rz = rz_next;
        p.iter_mut().zip(&z).for_each(|(p, z)| *p = z + beta * *p);
    }
    // S = S1 + A⁻¹ G x. On active facets G x = (A/ρ) x − (b − r) with r = b − (A/ρ − G) x
    // the residual CG carries, so S = x/ρ + r/A there without another product; only
    // facets that receive but do not reflect need G x itself.
    let passive = (0..a.len()).any(|i| !active[i] && a[i] > 0.0);
    if passive {
        g.apply(&x, &mut q);
    }
    for i in 0..s.len() {
        s[i] = if active[i] {
            x[i] / albedo[i] + r[i] / a[i]
        } else if passive && a[i] > 0.0 {
            s1[i] + q[i] / a[i]
        } else {
            s1[i]
        };
    }
    SolveReport {
        method: "cg",
        iterations,
        residual: residual(g, albedo, s1, s, &mut q),
        converged,
    }
}

/// `out = S1 + F ρ s`.
fn scatter_once(g: &dyn Exchange, albedo: &[f64], s1: &[f64], s: &[f64], out: &mut [f64]) {
    let a = g.areas();
    let reflected: Vec<f64> = s.iter().zip(albedo).map(|(s, r)| s * r).collect();
    g.apply(&reflected, out);
    for i in 0..out.len() {
        out[i] = s1[i] + if a[i] > 0.0 { out[i] / a[i] } else { 0.0 };
    }
}

fn residual(g: &dyn Exchange, albedo: &[f64], s1: &[f64], s: &[f64], work: &mut [f64]) -> f64 {
    scatter_once(g, albedo, s1, s, work);
    let n = norm(s);
    if n == 0.0 {
        0.0
    } else {
        distance(work, s) / n
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt()
}

fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += alpha * x);
}
