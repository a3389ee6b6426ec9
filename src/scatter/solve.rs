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
//!   than Jacobi when ρ is near 1. An iterate `x` with residual `r` stands for
//!   `S = x/ρ + r/A` on the reflecting facets, so that `ρS = x + z` with `z = ρ r/A` the
//!   preconditioned residual, and for `S = S1 + A⁻¹ G (x + z)` on facets of zero albedo,
//!   which receive but do not reflect. Substituting `G x = (A/ρ) x − A S1 + r` shows that
//!   this `S` leaves the residual `S1 + FρS − S = A⁻¹ G z` on the reflecting facets and
//!   none elsewhere; CG computes `G z` anyway (it needs the operator applied to `z`), so
//!   it stops on this residual, one product per iteration.
//!
//! Neither can diverge: both stop at an iteration cap, and the report states the residual
//! `‖S1 + FρS − S‖₂ / ‖S‖₂` of the returned `S` either way (CG's from its recurrences,
//! which rounding moves by far less than any tolerance: tested against an independent
//! evaluation).

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

/// Preconditioned CG on `(A/ρ − G) x = A S1` from `x = 0`, in the variant that applies
/// the operator to the preconditioned residual `z` rather than to the search direction
/// `p` (whose product follows by the recurrence that gives `p`). That product also gives,
/// at no cost, the residual of the `S` that the iterate stands for (module doc), so CG
/// stops on the quantity it reports, with one product per iteration.
fn conjugate_gradients(
    g: &dyn Exchange,
    albedo: &[f64],
    s1: &[f64],
    stop: Stopping,
    s: &mut [f64],
) -> SolveReport {
    let system = System::new(g.areas(), albedo, s1);
    let n = s1.len();
    let mut it = Iterate {
        x: vec![0.0; n],
        r: (0..n)
            .map(|i| {
                if system.active[i] {
                    system.a[i] * s1[i]
                } else {
                    0.0
                }
            })
            .collect(),
        z: vec![0.0; n],
        p: vec![0.0; n],
        gx: vec![0.0; n],
        gz: vec![0.0; n],
        gp: vec![0.0; n],
    };
    system.precondition(&it.r, &mut it.z);
    g.apply(&it.z, &mut it.gz);
    it.p.copy_from_slice(&it.z);
    it.gp.copy_from_slice(&it.gz);
    let mut rz = dot(&it.r, &it.z);
    let mut iterations = 1;
    let mut residual = system.scattered(&it, s);
    let mut q = vec![0.0; n];
    while residual > stop.tolerance && iterations < stop.max_iterations.max(1) {
        system.operator_from(&it.p, &it.gp, &mut q);
        let pq = dot(&it.p, &q);
        if pq <= 0.0 {
            break; // only rounding can get here: the matrix is positive definite
        }
        let alpha = rz / pq;
        axpy(alpha, &it.p, &mut it.x);
        axpy(alpha, &it.gp, &mut it.gx);
        axpy(-alpha, &q, &mut it.r);
        system.precondition(&it.r, &mut it.z);
        g.apply(&it.z, &mut it.gz);
        iterations += 1;
        let rz_next = dot(&it.r, &it.z);
        let beta = rz_next / rz;
        rz = rz_next;
        for i in 0..n {
            it.p[i] = it.z[i] + beta * it.p[i];
            it.gp[i] = it.gz[i] + beta * it.gp[i];
        }
        residual = system.scattered(&it, s);
    }
    SolveReport {
        method: "cg",
        iterations,
        residual,
        converged: residual <= stop.tolerance,
    }
}

/// CG's symmetric system `(A/ρ − G) x = A S1`, on the facets of non-zero albedo and area
/// (the active ones; the others' rows are empty).
struct System<'a> {
    a: &'a [f64],
    albedo: &'a [f64],
    s1: &'a [f64],
    active: Vec<bool>,
    /// `A/ρ` on the active facets.
    diag: Vec<f64>,
}

/// A CG iterate: the unknown `x`, the residual `r` of the symmetric system, its
/// preconditioned form `z = r ρ/A`, the search direction `p`, and the products of `G`
/// with `x`, `z` and `p` (every facet).
struct Iterate {
    x: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    gx: Vec<f64>,
    gz: Vec<f64>,
    gp: Vec<f64>,
}

impl<'a> System<'a> {
    fn new(a: &'a [f64], albedo: &'a [f64], s1: &'a [f64]) -> System<'a> {
        let active: Vec<bool> = (0..a.len())
            .map(|i| albedo[i] > 0.0 && a[i] > 0.0)
            .collect();
        let diag = (0..a.len())
            .map(|i| if active[i] { a[i] / albedo[i] } else { 0.0 })
            .collect();
        System {
            a,
            albedo,
            s1,
            active,
            diag,
        }
    }

    /// `q = (A/ρ − G) p` on the active facets, from `p` and `G p`.
    fn operator_from(&self, p: &[f64], gp: &[f64], q: &mut [f64]) {
        for (i, q) in q.iter_mut().enumerate() {
            *q = if self.active[i] {
                self.diag[i] * p[i] - gp[i]
            } else {
                0.0
            };
        }
    }

    /// `z = r / (A/ρ)` on the active facets.
    fn precondition(&self, r: &[f64], z: &mut [f64]) {
        for i in 0..r.len() {
            z[i] = if self.active[i] {
                r[i] / self.diag[i]
            } else {
                0.0
            };
        }
    }

    /// Writes into `s` the scattered irradiance that the iterate stands for and returns
    /// its relative residual `‖S1 + FρS − S‖₂ / ‖S‖₂`: `S = x/ρ + r/A` on the active
    /// facets, so that `ρS = x + z` there, and `S = S1 + A⁻¹ G (x + z)` on those that
    /// receive but do not reflect. The residual is then `A⁻¹ G z` on the active facets
    /// and zero elsewhere (module doc).
    fn scattered(&self, it: &Iterate, s: &mut [f64]) -> f64 {
        let mut miss = 0.0;
        for (i, s) in s.iter_mut().enumerate() {
            *s = if self.active[i] {
                miss += (it.gz[i] / self.a[i]).powi(2);
                it.x[i] / self.albedo[i] + it.r[i] / self.a[i]
            } else if self.a[i] > 0.0 {
                self.s1[i] + (it.gx[i] + it.gz[i]) / self.a[i]
            } else {
                self.s1[i]
            };
        }
        let size = norm(s);
        if size == 0.0 {
            0.0
        } else {
            miss.sqrt() / size
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense exchange matrix.
    struct Dense {
        g: Vec<Vec<f64>>,
        a: Vec<f64>,
    }

    impl Exchange for Dense {
        fn apply(&self, x: &[f64], y: &mut [f64]) {
            for (yi, row) in y.iter_mut().zip(&self.g) {
                *yi = row.iter().zip(x).map(|(g, x)| g * x).sum();
            }
        }
        fn areas(&self) -> &[f64] {
            &self.a
        }
    }

    /// 40 facets of unequal areas exchanging with each other (symmetric `G`, rows of
    /// `F` summing to at most 0.95), the last three of zero albedo and one of zero area.
    fn system() -> (Dense, Vec<f64>, Vec<f64>) {
        let n = 40;
        let mut rng = crate::TestRng::new(0x2545_f491_4f6c_dd1d);
        let mut next = || rng.unit();
        let mut a: Vec<f64> = (0..n).map(|_| 0.5 + next()).collect();
        a[n - 1] = 0.0;
        let mut g = vec![vec![0.0; n]; n];
        let pairs = (0..n - 1).flat_map(|i| (i + 1..n - 1).map(move |j| (i, j)));
        for (i, j) in pairs {
            if next() < 0.5 {
                let v = next();
                (g[i][j], g[j][i]) = (v, v);
            }
        }
        // Scale so that the fullest row of F = A⁻¹G sums to 0.95.
        let fullest = (0..n - 1)
            .map(|i| g[i].iter().sum::<f64>() / a[i])
            .fold(0.0, f64::max);
        g.iter_mut().flatten().for_each(|v| *v *= 0.95 / fullest);
        let mut albedo: Vec<f64> = (0..n).map(|_| 0.8 + 0.2 * next()).collect();
        albedo[n - 4..n - 1].fill(0.0);
        let s1 = (0..n).map(|_| 10.0 * next()).collect();
        (Dense { g, a }, albedo, s1)
    }

    /// `S = S1 + F ρ S` by Gaussian elimination with partial pivoting.
    fn direct(d: &Dense, albedo: &[f64], s1: &[f64]) -> Vec<f64> {
        let n = s1.len();
        let mut m: Vec<Vec<f64>> = (0..n)
            .map(|i| {
                let mut row: Vec<f64> = (0..n)
                    .map(|j| {
                        let f = if d.a[i] > 0.0 {
                            d.g[i][j] / d.a[i]
                        } else {
                            0.0
                        };
                        f64::from(i == j) - f * albedo[j]
                    })
                    .collect();
                row.push(s1[i]);
                row
            })
            .collect();
        for c in 0..n {
            let pivot = (c..n)
                .max_by(|&x, &y| m[x][c].abs().total_cmp(&m[y][c].abs()))
                .unwrap();
            m.swap(c, pivot);
            let pivot_row = m[c].clone();
            for (_, row) in m.iter_mut().enumerate().filter(|&(r, _)| r != c) {
                let k = row[c] / pivot_row[c];
                row[c..]
                    .iter_mut()
                    .zip(&pivot_row[c..])
                    .for_each(|(x, p)| *x -= k * p);
            }
        }
        (0..n).map(|i| m[i][n] / m[i][i]).collect()
    }

    #[test]
    fn both_methods_match_a_direct_solve_and_report_their_true_residual() {
        let (d, albedo, s1) = system();
        let exact = direct(&d, &albedo, &s1);
        let size = norm(&exact);
        for method in [SolverKind::Jacobi, SolverKind::Cg] {
            for tolerance in [1e-4, 1e-8, 1e-12] {
                let stop = Stopping {
                    tolerance,
                    max_iterations: 1000,
                };
                let mut s = vec![0.0; s1.len()];
                let report = solve(&d, &albedo, &s1, method, stop, &mut s);
                let mut work = vec![0.0; s.len()];
                let true_residual = residual(&d, &albedo, &s1, &s, &mut work);
                assert!(report.converged, "{method:?} {tolerance}: {report:?}");
                assert!(report.residual <= tolerance, "{report:?}");
                // The reported residual is the returned S's, evaluated independently.
                assert!(
                    (report.residual - true_residual).abs() <= 1e-3 * true_residual + 1e-15,
                    "{method:?} {tolerance}: reported {} vs {true_residual}",
                    report.residual
                );
                // The error is about the residual times ‖(I − Fρ)⁻¹‖, at most 1/(1 − 0.95)
                // = 20 in the ∞-norm.
                let error = distance(&s, &exact) / size;
                assert!(error <= 20.0 * tolerance, "{method:?} {tolerance}: {error}");
            }
        }
    }
}
