//! Compare: two images judged by their value distributions (SLIM paper, section 9.1).
//!
//! In: two images of the same quantity (radiance W m⁻² sr⁻¹, irradiance W/m² or I/F) and
//! bins (start, width; the paper uses 10 W/m² bins). Out: each image's histogram — the
//! paper's "irradiance probability density function" (IPDF) — and Pearson's two-sample χ²
//! test of homogeneity between them, with its degrees of freedom and p-value.
//!
//! The test (Press et al., Numerical Recipes, 3rd ed., section 14.3.2, "chstwo"): with
//! counts Rᵢ and Sᵢ in bin i and totals R = ΣRᵢ, S = ΣSᵢ,
//!
//! ```text
//! χ² = Σᵢ (√(S/R)·Rᵢ − √(R/S)·Sᵢ)² / (Rᵢ + Sᵢ)      over bins with Rᵢ + Sᵢ > 0
//! ν  = (number of such bins) − 1
//! p  = Q(ν/2, χ²/2)                                 (upper regularised incomplete gamma)
//! ```
//!
//! What it shows, and what it does not. The null hypothesis is that both histograms are
//! samples of the same distribution. A small p (say < 0.05) rejects it: the distributions
//! differ beyond what counting noise explains. A large p does not show that they are the
//! same; it shows only that this test with these bins cannot tell them apart. (The paper
//! words the null hypothesis the other way round, "the IPDFs are different", and takes
//! the number of pixels as the degrees of freedom; both are wrong: ν counts bins, and
//! rejecting means "different".) Pixels are not independent draws: neighbouring pixels
//! are correlated and the histogram ignores where the pixels are, so two images with the
//! same histogram but different pictures pass, and with 10⁶ pixels any small systematic
//! difference (calibration, a slightly different phase angle) gives p ≈ 0. Use p to
//! rank or flag, together with the histograms and a residual image, not as a verdict.

use crate::error::{Error, Result};
use crate::image::Image;

/// Histogram bins over image values, of equal width from `start`; values beyond the last bin go into the last one,
/// values below `start` into the first, non-finite values are left out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValueBins {
    pub start: f64,
    pub width: f64,
    pub count: usize,
}

impl ValueBins {
    /// Bins of `width` from `start` up to and including `end`.
    pub fn covering(start: f64, end: f64, width: f64) -> Result<ValueBins> {
        if !(width.is_finite() && width > 0.0 && start.is_finite() && end.is_finite()) {
            return Err(Error::Usage(format!(
                "bins need a finite start, end and positive width, not {start}, {end}, {width}"
            )));
        }
        let count = (((end - start) / width).floor() as usize + 1).min(1_000_000);
        Ok(ValueBins {
            start,
            width,
            count,
        })
    }

    /// Histogram of `values`.
    pub fn histogram(&self, values: impl Iterator<Item = f64>) -> Vec<u64> {
        let mut counts = vec![0u64; self.count];
        for x in values.filter(|x| x.is_finite()) {
            let k = ((x - self.start) / self.width).floor().max(0.0) as usize;
            counts[k.min(self.count - 1)] += 1;
        }
        counts
    }
}

/// Result of a two-sample χ² test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChiSquare {
    /// The statistic χ².
    pub statistic: f64,
    /// Degrees of freedom ν.
    pub dof: usize,
    /// P(χ²_ν ≥ statistic) under the null hypothesis (same distribution).
    pub p_value: f64,
}

/// Pearson's two-sample χ² test of homogeneity between histograms `r` and `s` (same bins).
pub fn chi_square_two_sample(r: &[u64], s: &[u64]) -> Result<ChiSquare> {
    if r.len() != s.len() {
        return Err(Error::Usage(format!(
            "histograms have {} and {} bins",
            r.len(),
            s.len()
        )));
    }
    let (tr, ts) = (r.iter().sum::<u64>() as f64, s.iter().sum::<u64>() as f64);
    if tr == 0.0 || ts == 0.0 {
        return Err(Error::Usage(
            "a histogram is empty: no pixel value falls into the bins".into(),
        ));
    }
    let (kr, ks) = ((ts / tr).sqrt(), (tr / ts).sqrt());
    let mut statistic = 0.0;
    let mut used = 0usize;
    for (&a, &b) in r.iter().zip(s) {
        if a + b > 0 {
            let (a, b) = (a as f64, b as f64);
            statistic += (kr * a - ks * b).powi(2) / (a + b);
            used += 1;
        }
    }
    let dof = used.saturating_sub(1);
    let p_value = if dof == 0 {
        1.0
    } else {
        gamma_q(dof as f64 / 2.0, statistic / 2.0)
    };
    Ok(ChiSquare {
        statistic,
        dof,
        p_value,
    })
}

/// A comparison of two images.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub bins: ValueBins,
    pub counts_a: Vec<u64>,
    pub counts_b: Vec<u64>,
    pub chi_square: ChiSquare,
}

/// Histograms of two images' pixels (optionally only pixels above `floor`, e.g. to leave
/// out the black sky) and the χ² test between them.
pub fn compare_images(
    a: &Image,
    b: &Image,
    bins: ValueBins,
    floor: Option<f64>,
) -> Result<Comparison> {
    let keep = |x: &f64| floor.is_none_or(|f| *x > f);
    let counts_a = bins.histogram(a.pixels.iter().copied().filter(keep));
    let counts_b = bins.histogram(b.pixels.iter().copied().filter(keep));
    let chi_square = chi_square_two_sample(&counts_a, &counts_b)?;
    Ok(Comparison {
        bins,
        counts_a,
        counts_b,
        chi_square,
    })
}

/// ln Γ(x) for x > 0 (Lanczos approximation, g = 7, 9 terms; relative error < 1e-15).
pub fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x)Γ(1 − x) = π / sin(πx).
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + G + 0.5;
    let series = C[1..]
        .iter()
        .enumerate()
        .fold(C[0], |acc, (k, c)| acc + c / (x + k as f64 + 1.0));
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + series.ln()
}

/// Lower regularised incomplete gamma P(a, x) = γ(a, x)/Γ(a), a > 0, x ≥ 0.
pub fn gamma_p(a: f64, x: f64) -> f64 {
    1.0 - gamma_q(a, x)
}

/// Upper regularised incomplete gamma Q(a, x) = Γ(a, x)/Γ(a), a > 0, x ≥ 0: the series
/// for x < a + 1, Lentz's continued fraction otherwise (Numerical Recipes, section 6.2).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let log_prefactor = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        // P = e^{−x} x^a / Γ(a+1) · Σ xⁿ / ((a+1)…(a+n)).
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * log_prefactor.exp()).max(0.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            d = if d.abs() < tiny { tiny } else { d };
            c = b + an / c;
            c = if c.abs() < tiny { tiny } else { c };
            d = 1.0 / d;
            let step = d * c;
            h *= step;
            if (step - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (log_prefactor.exp() * h).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn incomplete_gamma_against_known_values() {
        // Q(1, x) = e^{−x}; Q(1/2, x) = erfc(√x); erfc(1) = 0.157299207050285.
        for x in [0.01, 0.5, 1.0, 3.0, 20.0] {
            assert!((gamma_q(1.0, x) - (-x).exp()).abs() < 1e-14);
        }
        assert!((gamma_q(0.5, 1.0) - 0.157_299_207_050_285_1).abs() < 1e-13);
        // χ² critical values (Abramowitz & Stegun, Table 26.8): P(χ²_ν ≥ x) = 0.05 at
        // x = 3.841459 (ν = 1), 18.307038 (ν = 10); 0.01 at 23.209251 (ν = 10);
        // 0.05 at 124.342113 (ν = 100).
        let p = |x: f64, nu: f64| gamma_q(nu / 2.0, x / 2.0);
        assert!((p(3.841_459, 1.0) - 0.05).abs() < 1e-6);
        assert!((p(18.307_038, 10.0) - 0.05).abs() < 1e-6);
        assert!((p(23.209_251, 10.0) - 0.01).abs() < 1e-6);
        assert!((p(124.342_113, 100.0) - 0.05).abs() < 1e-6);
        // Γ(5) = 24, Γ(1/2) = √π.
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-13);
        assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-13);
        assert!((gamma_p(2.0, 1e-3) + gamma_q(2.0, 1e-3) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn self_comparison_and_clear_difference() {
        let a = vec![5, 40, 100, 30, 0, 2];
        let same = chi_square_two_sample(&a, &a).unwrap();
        assert_eq!(same.statistic, 0.0);
        assert_eq!(same.p_value, 1.0);
        assert_eq!(same.dof, 4);
        // Twice the counts: the same distribution.
        let twice: Vec<u64> = a.iter().map(|x| 2 * x).collect();
        let scaled = chi_square_two_sample(&a, &twice).unwrap();
        assert!(scaled.statistic < 1e-12 && scaled.p_value > 0.999_999);
        let b = vec![100, 40, 5, 0, 30, 2];
        let diff = chi_square_two_sample(&a, &b).unwrap();
        assert!(diff.p_value < 1e-20, "{diff:?}");
        assert!(chi_square_two_sample(&[0, 0], &[1, 2]).is_err());
        assert!(chi_square_two_sample(&[1], &[1, 2]).is_err());
    }

    #[test]
    fn bins_clamp_and_skip() {
        let bins = ValueBins::covering(0.0, 30.0, 10.0).unwrap();
        assert_eq!(bins.count, 4);
        let h = bins.histogram([-5.0, 0.0, 9.99, 10.0, 35.0, 1e9, f64::NAN].into_iter());
        assert_eq!(h, vec![3, 1, 0, 2]);
        assert!(ValueBins::covering(0.0, 1.0, 0.0).is_err());
    }
}
