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
//!
//! [`solve_lanes`] solves K equations with the same `G` side by side (the first orders of
//! K time steps): every product with `G` then serves all K ([`super::csr`]). Each lane
//! keeps its own scalars and stops on its own; a lane that has met the tolerance keeps
//! its result while the others go on, so each lane's result and report are those it
//! would get alone.

use super::csr::Lanes;
use serde::Serialize;
use std::array::from_fn;

/// Exchange areas as an operator.
pub trait Exchange: Sync {
    /// `y = G x` (m² × the unit of x), every facet, lane by lane.
    fn apply<L: Lanes>(&self, x: &[L], y: &mut [L]);
    /// Facet areas, m².
    fn areas(&self) -> &[f64];
}

/// Which method solves the multiple-scattering equation: the scene's choice.
pub use crate::scene::SolverKind;

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
pub fn solve<E: Exchange>(
    g: &E,
    albedo: &[f64],
    s1: &[f64],
    method: SolverKind,
    stop: Stopping,
    s: &mut [f64],
) -> SolveReport {
    let lanes: Vec<[f64; 1]> = s1.iter().map(|&v| [v]).collect();
    let mut out = vec![[0.0]; s1.len()];
    let [report] = solve_lanes(g, albedo, &lanes, method, stop, &mut out);
    s.iter_mut().zip(&out).for_each(|(s, [v])| *s = *v);
    report
}

/// [`solve`] for K equations side by side: lane k of `s1` gives lane k of `s`, with its
/// own report (module doc).
pub fn solve_lanes<E: Exchange, const K: usize>(
    g: &E,
    albedo: &[f64],
    s1: &[[f64; K]],
    method: SolverKind,
    stop: Stopping,
    s: &mut [[f64; K]],
) -> [SolveReport; K] {
    s.copy_from_slice(s1);
    let reflecting = albedo.iter().any(|&r| r > 0.0);
    let lit = norms(s1).map(|size| reflecting && size > 0.0);
    let mut reports = if !lit.contains(&true) {
        [SolveReport::default(); K]
    } else if method == SolverKind::Cg {
        conjugate_gradients(g, albedo, s1, stop, lit, s)
    } else {
        jacobi(g, albedo, s1, stop, lit, s)
    };
    // A dark lane has nothing to scatter: S = S1 = 0.
    for k in lanes(lit.map(|l| !l)) {
        reports[k] = SolveReport {
            method: if method == SolverKind::Cg {
                "cg"
            } else {
                "jacobi"
            },
            iterations: 1,
            residual: 0.0,
            converged: true,
        };
    }
    reports
}

/// `Auto` resolved for the largest albedo.
pub fn resolve(kind: SolverKind, max_albedo: f64) -> SolverKind {
    match kind {
        SolverKind::Auto if max_albedo <= 0.5 => SolverKind::Jacobi,
        SolverKind::Auto => SolverKind::Cg,
        k => k,
    }
}

fn jacobi<E: Exchange, const K: usize>(
    g: &E,
    albedo: &[f64],
    s1: &[[f64; K]],
    stop: Stopping,
    lit: [bool; K],
    s: &mut [[f64; K]],
) -> [SolveReport; K] {
    let mut next = vec![[0.0; K]; s.len()];
    let mut open = lit;
    let mut orders = [1; K];
    let mut converged = [false; K];
    let mut done = 1;
    while done < stop.max_iterations.max(1) && open.contains(&true) {
        scatter_once(g, albedo, s1, s, &mut next);
        done += 1;
        let change = distances(&next, s);
        for (s, next) in s.iter_mut().zip(&next) {
            lanes(open).for_each(|k| s[k] = next[k]);
        }
        let size = norms(s);
        for k in lanes(open) {
            orders[k] = done;
            if change[k] <= stop.tolerance * size[k] {
                converged[k] = true;
                open[k] = false;
            }
        }
    }
    let residual = residuals(g, albedo, s1, s, &mut next);
    from_fn(|k| SolveReport {
        method: "jacobi",
        iterations: orders[k],
        residual: residual[k],
        converged: converged[k],
    })
}

/// Preconditioned CG on `(A/ρ − G) x = A S1` from `x = 0`, in the variant that applies
/// the operator to the preconditioned residual `z` rather than to the search direction
/// `p` (whose product follows by the recurrence that gives `p`). That product also gives,
/// at no cost, the residual of the `S` that the iterate stands for (module doc), so CG
/// stops on the quantity it reports, with one product per iteration.
fn conjugate_gradients<E: Exchange, const K: usize>(
    g: &E,
    albedo: &[f64],
    s1: &[[f64; K]],
    stop: Stopping,
    lit: [bool; K],
    s: &mut [[f64; K]],
) -> [SolveReport; K] {
    let system = System::new(g.areas(), albedo);
    let n = s1.len();
    let zeros = vec![[0.0; K]; n];
    let mut it = Iterate {
        x: zeros.clone(),
        r: (0..n)
            .map(|i| {
                if system.active[i] {
                    s1[i].map(|v| system.a[i] * v)
                } else {
                    [0.0; K]
                }
            })
            .collect(),
        z: zeros.clone(),
        p: zeros.clone(),
        gx: zeros.clone(),
        gz: zeros.clone(),
        gp: zeros.clone(),
    };
    system.precondition(&it.r, &mut it.z);
    g.apply(&it.z, &mut it.gz);
    it.p.copy_from_slice(&it.z);
    it.gp.copy_from_slice(&it.gz);
    let mut rz = dots(&it.r, &it.z);
    let mut products = 1;
    let mut open = lit;
    let mut iterations = [1; K];
    let mut residual = system.scattered(s1, &it, open, s);
    lanes(open).for_each(|k| open[k] = residual[k] > stop.tolerance);
    let mut q = zeros;
    while open.contains(&true) && products < stop.max_iterations.max(1) {
        system.operator_from(&it.p, &it.gp, &mut q);
        let pq = dots(&it.p, &q);
        // Only rounding can make p·q ≤ 0 (the matrix is positive definite): such a lane
        // stops where it is.
        lanes(open).for_each(|k| open[k] = pq[k] > 0.0);
        let alpha = from_fn(|k| if open[k] { rz[k] / pq[k] } else { 0.0 });
        axpy(alpha, &it.p, &mut it.x);
        axpy(alpha, &it.gp, &mut it.gx);
        axpy(alpha.map(|a| -a), &q, &mut it.r);
        system.precondition(&it.r, &mut it.z);
        g.apply(&it.z, &mut it.gz);
        products += 1;
        let rz_next = dots(&it.r, &it.z);
        let beta: [f64; K] = from_fn(|k| if open[k] { rz_next[k] / rz[k] } else { 0.0 });
        rz = rz_next;
        xpay(&it.z, beta, &mut it.p);
        xpay(&it.gz, beta, &mut it.gp);
        let now = system.scattered(s1, &it, open, s);
        for k in lanes(open) {
            residual[k] = now[k];
            iterations[k] = products;
            open[k] = now[k] > stop.tolerance;
        }
    }
    from_fn(|k| SolveReport {
        method: "cg",
        iterations: iterations[k],
        residual: residual[k],
        converged: residual[k] <= stop.tolerance,
    })
}

/// CG's symmetric system `(A/ρ − G) x = A S1`, on the facets of non-zero albedo and area
/// (the active ones; the others' rows are empty).
struct System<'a> {
    a: &'a [f64],
    albedo: &'a [f64],
    active: Vec<bool>,
    /// `A/ρ` on the active facets.
    diag: Vec<f64>,
}

/// A CG iterate, K lanes: the unknown `x`, the residual `r` of the symmetric system, its
/// preconditioned form `z = r ρ/A`, the search direction `p`, and the products of `G`
/// with `x`, `z` and `p` (every facet).
struct Iterate<const K: usize> {
    x: Vec<[f64; K]>,
    r: Vec<[f64; K]>,
    z: Vec<[f64; K]>,
    p: Vec<[f64; K]>,
    gx: Vec<[f64; K]>,
    gz: Vec<[f64; K]>,
    gp: Vec<[f64; K]>,
}

impl<'a> System<'a> {
    fn new(a: &'a [f64], albedo: &'a [f64]) -> System<'a> {
        let active: Vec<bool> = (0..a.len())
            .map(|i| albedo[i] > 0.0 && a[i] > 0.0)
            .collect();
        let diag = (0..a.len())
            .map(|i| if active[i] { a[i] / albedo[i] } else { 0.0 })
            .collect();
        System {
            a,
            albedo,
            active,
            diag,
        }
    }

    /// `q = (A/ρ − G) p` on the active facets, from `p` and `G p`.
    fn operator_from<const K: usize>(&self, p: &[[f64; K]], gp: &[[f64; K]], q: &mut [[f64; K]]) {
        for (i, q) in q.iter_mut().enumerate() {
            *q = if self.active[i] {
                from_fn(|k| self.diag[i] * p[i][k] - gp[i][k])
            } else {
                [0.0; K]
            };
        }
    }

    /// `z = r / (A/ρ)` on the active facets.
    fn precondition<const K: usize>(&self, r: &[[f64; K]], z: &mut [[f64; K]]) {
        for (i, z) in z.iter_mut().enumerate() {
            *z = if self.active[i] {
                r[i].map(|v| v / self.diag[i])
            } else {
                [0.0; K]
            };
        }
    }

    /// Writes into the `open` lanes of `s` the scattered irradiance that the iterate
    /// stands for and returns each lane's relative residual `‖S1 + FρS − S‖₂ / ‖S‖₂`:
    /// `S = x/ρ + r/A` on the active facets, so that `ρS = x + z` there, and
    /// `S = S1 + A⁻¹ G (x + z)` on those that receive but do not reflect. The residual is
    /// then `A⁻¹ G z` on the active facets and zero elsewhere (module doc).
    fn scattered<const K: usize>(
        &self,
        s1: &[[f64; K]],
        it: &Iterate<K>,
        open: [bool; K],
        s: &mut [[f64; K]],
    ) -> [f64; K] {
        let mut miss = [0.0; K];
        for (i, s) in s.iter_mut().enumerate() {
            for k in lanes(open) {
                s[k] = if self.active[i] {
                    miss[k] += (it.gz[i][k] / self.a[i]).powi(2);
                    it.x[i][k] / self.albedo[i] + it.r[i][k] / self.a[i]
                } else if self.a[i] > 0.0 {
                    s1[i][k] + (it.gx[i][k] + it.gz[i][k]) / self.a[i]
                } else {
                    s1[i][k]
                };
            }
        }
        let size = norms(s);
        from_fn(|k| {
            if size[k] == 0.0 {
                0.0
            } else {
                miss[k].sqrt() / size[k]
            }
        })
    }
}

/// `out = S1 + F ρ s`, lane by lane.
fn scatter_once<E: Exchange, const K: usize>(
    g: &E,
    albedo: &[f64],
    s1: &[[f64; K]],
    s: &[[f64; K]],
    out: &mut [[f64; K]],
) {
    let reflected: Vec<[f64; K]> = s
        .iter()
        .zip(albedo)
        .map(|(s, r)| s.map(|v| v * r))
        .collect();
    g.apply(&reflected, out);
    for ((out, s1), &a) in out.iter_mut().zip(s1).zip(g.areas()) {
        for (o, s1) in out.iter_mut().zip(s1) {
            *o = s1 + if a > 0.0 { *o / a } else { 0.0 };
        }
    }
}

/// Each lane's `‖S1 + FρS − S‖₂ / ‖S‖₂` (0 where `S` is 0), by one product.
fn residuals<E: Exchange, const K: usize>(
    g: &E,
    albedo: &[f64],
    s1: &[[f64; K]],
    s: &[[f64; K]],
    work: &mut [[f64; K]],
) -> [f64; K] {
    scatter_once(g, albedo, s1, s, work);
    let (miss, size) = (distances(work, s), norms(s));
    from_fn(|k| {
        if size[k] == 0.0 {
            0.0
        } else {
            miss[k] / size[k]
        }
    })
}

/// The lanes whose mask is set.
fn lanes<const K: usize>(mask: [bool; K]) -> impl Iterator<Item = usize> {
    (0..K).filter(move |&k| mask[k])
}

/// Each lane's `Σ_i term(a_i, b_i)`.
fn lane_sums<const K: usize>(
    a: &[[f64; K]],
    b: &[[f64; K]],
    term: impl Fn(f64, f64) -> f64,
) -> [f64; K] {
    let mut sum = [0.0; K];
    for (a, b) in a.iter().zip(b) {
        for ((sum, a), b) in sum.iter_mut().zip(a).zip(b) {
            *sum += term(*a, *b);
        }
    }
    sum
}

fn dots<const K: usize>(a: &[[f64; K]], b: &[[f64; K]]) -> [f64; K] {
    lane_sums(a, b, |a, b| a * b)
}

fn norms<const K: usize>(a: &[[f64; K]]) -> [f64; K] {
    dots(a, a).map(f64::sqrt)
}

fn distances<const K: usize>(a: &[[f64; K]], b: &[[f64; K]]) -> [f64; K] {
    lane_sums(a, b, |a, b| (a - b).powi(2)).map(f64::sqrt)
}

/// `y = x + beta y`, lane by lane.
fn xpay<const K: usize>(x: &[[f64; K]], beta: [f64; K], y: &mut [[f64; K]]) {
    for (y, x) in y.iter_mut().zip(x) {
        for ((y, x), b) in y.iter_mut().zip(x).zip(beta) {
            *y = x + b * *y;
        }
    }
}

fn axpy<const K: usize>(alpha: [f64; K], x: &[[f64; K]], y: &mut [[f64; K]]) {
    for (y, x) in y.iter_mut().zip(x) {
        for k in 0..K {
            y[k] += alpha[k] * x[k];
        }
    }
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
        fn apply<L: Lanes>(&self, x: &[L], y: &mut [L]) {
            for (yi, row) in y.iter_mut().zip(&self.g) {
                *yi = L::ZERO;
                row.iter().zip(x).for_each(|(&g, x)| yi.add_scaled(g, x));
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

    fn norm(a: &[f64]) -> f64 {
        a.iter().map(|v| v * v).sum::<f64>().sqrt()
    }

    fn distance(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// `‖S1 + FρS − S‖₂ / ‖S‖₂` from the dense matrix.
    fn independent_residual(d: &Dense, albedo: &[f64], s1: &[f64], s: &[f64]) -> f64 {
        let miss: Vec<f64> = (0..s.len())
            .map(|i| {
                let f = |j: usize| {
                    if d.a[i] > 0.0 {
                        d.g[i][j] / d.a[i]
                    } else {
                        0.0
                    }
                };
                s1[i] + (0..s.len()).map(|j| f(j) * albedo[j] * s[j]).sum::<f64>() - s[i]
            })
            .collect();
        norm(&miss) / norm(s)
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
                let true_residual = independent_residual(&d, &albedo, &s1, &s);
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

    #[test]
    fn lanes_solved_together_match_each_solved_alone() {
        let (d, albedo, s1) = system();
        // Lane 0 the system's first order; lane 1 lit mostly on facets that do not
        // reflect, so that it meets the tolerance in fewer products while lane 0 goes on
        // (and would still change if it went on too); lane 2 dark.
        let n = s1.len();
        let rough: Vec<f64> = (0..n)
            .map(|i| if i >= n - 4 { s1[i] } else { 1e-4 * s1[i] })
            .collect();
        let lanes: Vec<[f64; 3]> = (0..n).map(|i| [s1[i], rough[i], 0.0]).collect();
        for method in [SolverKind::Jacobi, SolverKind::Cg] {
            let stop = Stopping {
                tolerance: 1e-9,
                max_iterations: 1000,
            };
            let mut together = vec![[0.0; 3]; n];
            let reports = solve_lanes(&d, &albedo, &lanes, method, stop, &mut together);
            for (k, alone_s1) in [&s1, &rough, &vec![0.0; n]].into_iter().enumerate() {
                let mut alone = vec![0.0; n];
                let report = solve(&d, &albedo, alone_s1, method, stop, &mut alone);
                assert_eq!(reports[k], report, "{method:?} lane {k}");
                let lane: Vec<f64> = together.iter().map(|l| l[k]).collect();
                assert_eq!(lane, alone, "{method:?} lane {k}");
            }
            // The lanes need different numbers of products, so one went on after the
            // other had stopped.
            assert_ne!(reports[0].iterations, reports[1].iterations, "{reports:?}");
            assert!(reports[2].converged && reports[2].residual == 0.0);
        }
    }
}
