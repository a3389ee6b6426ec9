//! Quadrature: Gauss–Legendre nodes and weights, for the stages that integrate over the
//! solar disk or a planet's visible cap.
//!
//! In: a number of nodes `n ≥ 1`. Out: `n` pairs (node, weight) on [−1, 1] that integrate
//! polynomials of degree `2n − 1` exactly.

use std::f64::consts::PI;

/// Nodes and weights of `n`-point Gauss–Legendre quadrature on [−1, 1], by Newton's
/// method on the Legendre polynomial `P_n` from the usual cosine first guesses.
pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut slope = 1.0;
            for _ in 0..50 {
                let (value, derivative) = legendre(n, x);
                slope = derivative;
                let step = value / derivative;
                x -= step;
                if step.abs() < 1e-15 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * slope * slope))
        })
        .collect()
}

/// `P_n(x)` and its derivative, by the three-term recurrence.
fn legendre(n: usize, x: f64) -> (f64, f64) {
    let (mut previous, mut value) = (1.0, x);
    for k in 2..=n {
        let k = k as f64;
        let next = ((2.0 * k - 1.0) * x * value - (k - 1.0) * previous) / k;
        previous = value;
        value = next;
    }
    (value, n as f64 * (x * value - previous) / (x * x - 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn n_nodes_integrate_polynomials_to_degree_2n_minus_1_exactly() {
        for n in [1, 2, 5, 24] {
            let nodes = gauss_legendre(n);
            let weights: f64 = nodes.iter().map(|p| p.1).sum();
            assert!((weights - 2.0).abs() < 1e-13, "n {n}: {weights}");
            let degree = 2 * n as i32 - 2;
            let even: f64 = nodes.iter().map(|&(x, w)| w * x.powi(degree)).sum();
            let exact = 2.0 / (degree as f64 + 1.0);
            assert!((even - exact).abs() < 1e-13, "n {n}: {even} vs {exact}");
        }
    }
}
