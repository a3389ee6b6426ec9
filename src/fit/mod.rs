//! Fit: reflectance parameters of one body from observed images with known geometry.
//!
//! In: per image, the rendered per-pixel geometry ([`GeometryImage`]), the observed image
//! (radiance W m⁻² sr⁻¹, or I/F when its `BUNIT` is "I/F") and the band's flux share; the
//! body's starting [`Material`] and the names of the parameters to fit (any subset of the
//! model's, each kept inside its valid range). Out: [`FitResult`] — fitted values, 1-σ
//! uncertainties and correlations from the covariance, the residual RMS, and one residual
//! image (observed − model) per input image.
//!
//! Method: damped least squares (Levenberg–Marquardt with Marquardt's diagonal scaling;
//! Press et al., Numerical Recipes, 3rd ed., section 15.5) on the pixels where the body
//! is seen in sunlight; Jacobian by central differences (one-sided at a bound); steps
//! projected onto the bounds. Covariance C = s²·(JᵀJ)⁻¹ with s² = RSS/(n − k), the pixel
//! noise estimated from the residuals (all pixels weighted equally).
//!
//! Identifiability is checked before and after fitting: a parameter that changes no pixel,
//! or a combination of parameters that the data cannot separate (the correlation matrix
//! of JᵀJ has an eigenvalue below 1e-7, i.e. correlations within ~1e-7 of ±1), is an
//! error that names the parameters, instead of a fit with meaningless uncertainties.

pub mod job;

use crate::error::{Error, Result};
use crate::image::Image;
use crate::photometry::{i_over_f, Material, Reflectance};
use crate::render::GeometryImage;

/// One observed image and what is needed to model it.
pub struct Observation<'a> {
    pub geometry: &'a GeometryImage,
    pub observed: &'a Image,
    /// Share of the solar flux in the image's band (1: whole spectrum).
    pub flux_scale: f64,
    /// Materials of the other bodies (the fitted body's entry is replaced).
    pub materials: &'a [Material],
}

/// The outcome of a fit.
#[derive(Debug, Clone)]
pub struct FitResult {
    pub names: Vec<String>,
    pub values: Vec<f64>,
    /// 1-σ uncertainties.
    pub sigmas: Vec<f64>,
    /// Correlation matrix, row-major k × k.
    pub correlation: Vec<Vec<f64>>,
    /// Parameters that ended on a bound (their uncertainty is not meaningful).
    pub at_bound: Vec<bool>,
    /// The fitted material.
    pub material: Material,
    /// Root-mean-square residual over the fitted pixels (image unit).
    pub rms: f64,
    /// Pixels used and iterations taken.
    pub pixels: usize,
    pub iterations: usize,
    /// Observed − model, one image per observation.
    pub residuals: Vec<Image>,
}

/// A pixel the fit uses: which observation, which pixel, and its value unit factor.
struct Pixel {
    obs: usize,
    index: usize,
    /// Model value = factor · r.
    factor: f64,
    observed: f64,
}

/// Fits `names` of body `body`'s `start` material to `observations`.
pub fn fit(
    observations: &[Observation<'_>],
    body: usize,
    start: &Material,
    names: &[String],
) -> Result<FitResult> {
    if names.is_empty() {
        return Err(Error::Usage("name at least one parameter to fit".into()));
    }
    let ranges = names
        .iter()
        .map(|n| {
            start.range(n).ok_or_else(|| {
                Error::Usage(format!(
                    "model {} has no parameter '{n}'; its parameters are {}",
                    start.model(),
                    start.parameter_names().join(", ")
                ))
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let pixels = fitted_pixels(observations, body)?;
    if pixels.len() <= names.len() {
        return Err(Error::Usage(format!(
            "only {} sunlit pixels of the body are seen: too few to fit {} parameters",
            pixels.len(),
            names.len()
        )));
    }
    let model = Model {
        observations,
        body,
        start,
        names,
        pixels: &pixels,
    };
    let mut theta: Vec<f64> = names
        .iter()
        .map(|n| start.get(n).expect("checked"))
        .collect();
    let mut residual = model.residuals(&theta)?;
    let mut cost = sum_sq(&residual);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut jac = model.jacobian(&theta, &ranges)?;
    check_identifiable(&jac, names)?;
    while iterations < 200 {
        iterations += 1;
        let (jtj, jte) = normal_equations(&jac, &residual);
        let mut damped = jtj.clone();
        for j in 0..names.len() {
            damped[j][j] += lambda * jtj[j][j];
        }
        let Some(step) = solve(&damped, &jte) else {
            lambda *= 10.0;
            continue;
        };
        let trial: Vec<f64> = theta
            .iter()
            .zip(&step)
            .zip(&ranges)
            .map(|((t, d), r)| (t + d).clamp(r.min, r.max))
            .collect();
        let trial_residual = model.residuals(&trial)?;
        let trial_cost = sum_sq(&trial_residual);
        if trial_cost < cost {
            let gain = (cost - trial_cost) / cost.max(f64::MIN_POSITIVE);
            let moved = trial.iter().zip(&theta).any(|(a, b)| a != b);
            theta = trial;
            residual = trial_residual;
            cost = trial_cost;
            lambda = (lambda / 10.0).max(1e-12);
            jac = model.jacobian(&theta, &ranges)?;
            if gain < 1e-12 || !moved {
                break;
            }
        } else {
            lambda *= 10.0;
            if lambda > 1e12 {
                break; // no step reduces the cost: a minimum within the bounds
            }
        }
    }
    check_identifiable(&jac, names)?;
    let k = names.len();
    let n = pixels.len();
    let (jtj, _) = normal_equations(&jac, &residual);
    let inverse = invert(&jtj).ok_or_else(|| {
        Error::Usage(
            "the fitted parameters are not constrained by the data (JᵀJ is singular)".into(),
        )
    })?;
    let s2 = cost / (n - k) as f64;
    let sigmas: Vec<f64> = (0..k).map(|j| (s2 * inverse[j][j]).sqrt()).collect();
    let correlation = (0..k)
        .map(|i| {
            (0..k)
                .map(|j| inverse[i][j] / (inverse[i][i] * inverse[j][j]).sqrt())
                .collect()
        })
        .collect();
    let at_bound = theta
        .iter()
        .zip(&ranges)
        .map(|(t, r)| *t <= r.min || *t >= r.max)
        .collect();
    let material = model.material(&theta)?;
    let residuals = model.residual_images(&material);
    Ok(FitResult {
        names: names.to_vec(),
        values: theta,
        sigmas,
        correlation,
        at_bound,
        material,
        rms: (cost / n as f64).sqrt(),
        pixels: n,
        iterations,
        residuals,
    })
}

/// The pixels that constrain body `body`: seen, sunlit, with a finite observed value.
fn fitted_pixels(observations: &[Observation<'_>], body: usize) -> Result<Vec<Pixel>> {
    let mut pixels = Vec::new();
    for (o, obs) in observations.iter().enumerate() {
        let g = obs.geometry;
        if (obs.observed.width, obs.observed.height) != (g.width, g.height) {
            return Err(Error::Usage(format!(
                "observed image {o} is {} × {} pixels, the camera {} × {}",
                obs.observed.width, obs.observed.height, g.width, g.height
            )));
        }
        let iof = obs.observed.text("BUNIT") == Some("I/F");
        for (index, s) in g.samples.iter().enumerate() {
            let observed = obs.observed.pixels[index];
            let fitted = s.is_some_and(|s| s.lit && s.body as usize == body);
            if fitted && observed.is_finite() {
                let factor = if iof {
                    i_over_f(1.0)
                } else {
                    g.flux_w_m2[body] * obs.flux_scale
                };
                pixels.push(Pixel {
                    obs: o,
                    index,
                    factor,
                    observed,
                });
            }
        }
    }
    Ok(pixels)
}

/// The forward model as a function of the fitted parameters.
struct Model<'a> {
    observations: &'a [Observation<'a>],
    body: usize,
    start: &'a Material,
    names: &'a [String],
    pixels: &'a [Pixel],
}

impl Model<'_> {
    fn material(&self, theta: &[f64]) -> Result<Material> {
        let mut m = self.start.clone();
        for (n, &v) in self.names.iter().zip(theta) {
            m.set(n, v)?;
        }
        Ok(m)
    }

    /// observed − model at every fitted pixel.
    fn residuals(&self, theta: &[f64]) -> Result<Vec<f64>> {
        let m = self.material(theta)?;
        Ok(self
            .pixels
            .iter()
            .map(|p| {
                let s = self.observations[p.obs].geometry.samples[p.index].expect("fitted pixel");
                p.observed - p.factor * m.reflectance(&s.angles)
            })
            .collect())
    }

    /// d(residual)/dθ by central differences, one-sided at a bound.
    fn jacobian(
        &self,
        theta: &[f64],
        ranges: &[crate::photometry::Range],
    ) -> Result<Vec<Vec<f64>>> {
        let mut columns = Vec::with_capacity(theta.len());
        for (j, r) in ranges.iter().enumerate() {
            let h = 1e-6 * (r.max - r.min).min(10.0).max(theta[j].abs());
            let up = (theta[j] + h).min(r.max);
            let down = (theta[j] - h).max(r.min);
            let at = |x: f64| {
                let mut t = theta.to_vec();
                t[j] = x;
                self.residuals(&t)
            };
            let (a, b) = (at(up)?, at(down)?);
            columns.push(
                a.iter()
                    .zip(&b)
                    .map(|(a, b)| (a - b) / (up - down))
                    .collect(),
            );
        }
        Ok(columns)
    }

    fn residual_images(&self, material: &Material) -> Vec<Image> {
        self.observations
            .iter()
            .map(|obs| {
                let mut materials = obs.materials.to_vec();
                materials[self.body] = material.clone();
                let refs: Vec<&dyn Reflectance> =
                    materials.iter().map(|m| m as &dyn Reflectance).collect();
                let mut model = if obs.observed.text("BUNIT") == Some("I/F") {
                    obs.geometry.i_over_f(&refs)
                } else {
                    obs.geometry.radiance(&refs, obs.flux_scale)
                };
                for (m, o) in model.pixels.iter_mut().zip(&obs.observed.pixels) {
                    *m = o - *m;
                }
                model.header = obs.observed.header.clone();
                model
            })
            .collect()
    }
}

fn sum_sq(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

/// JᵀJ and Jᵀe for the residual e = observed − model (J = d e/dθ, so the step is −).
fn normal_equations(jac: &[Vec<f64>], residual: &[f64]) -> (Vec<Vec<f64>>, Vec<f64>) {
    let k = jac.len();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let jtj = (0..k)
        .map(|i| (0..k).map(|j| dot(&jac[i], &jac[j])).collect())
        .collect();
    let jte = (0..k).map(|i| -dot(&jac[i], residual)).collect();
    (jtj, jte)
}

/// Solves a small dense system by Gaussian elimination with partial pivoting.
fn solve(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let mut m: Vec<Vec<f64>> = a
        .iter()
        .zip(b)
        .map(|(row, &bi)| row.iter().copied().chain([bi]).collect())
        .collect();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| m[i][c].abs().total_cmp(&m[j][c].abs()))?;
        if m[p][c].abs() < f64::MIN_POSITIVE || !m[p][c].is_finite() {
            return None;
        }
        m.swap(c, p);
        let pivot = m[c].clone();
        for (r, row) in m.iter_mut().enumerate() {
            if r != c {
                let f = row[c] / pivot[c];
                for (x, pv) in row[c..].iter_mut().zip(&pivot[c..]) {
                    *x -= f * pv;
                }
            }
        }
    }
    Some((0..n).map(|i| m[i][n] / m[i][i]).collect())
}

/// Inverse of a small symmetric matrix, column by column.
fn invert(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = a.len();
    let columns: Option<Vec<Vec<f64>>> = (0..n)
        .map(|j| {
            solve(
                a,
                &(0..n).map(|i| (i == j) as u8 as f64).collect::<Vec<_>>(),
            )
        })
        .collect();
    let c = columns?;
    Some((0..n).map(|i| (0..n).map(|j| c[j][i]).collect()).collect())
}

/// Smallest eigenvalue of the correlation matrix of JᵀJ accepted: 1e-7 means pairwise
/// correlations up to 1 − 1e-7, uncertainties inflated by up to ~3000 × over independent
/// parameters; beyond it the data constrain only a combination.
const MIN_EIGENVALUE: f64 = 1e-7;

/// Errors when a parameter changes no pixel or the data cannot separate a combination.
fn check_identifiable(jac: &[Vec<f64>], names: &[String]) -> Result<()> {
    let (jtj, _) = normal_equations(jac, &vec![0.0; jac[0].len()]);
    let k = names.len();
    for j in 0..k {
        if jtj[j][j].is_nan() || jtj[j][j] <= 0.0 {
            return Err(Error::Usage(format!(
                "parameter {} is not constrained by the data: changing it changes no \
                 fitted pixel (e.g. the opposition width h while b0 = 0)",
                names[j]
            )));
        }
    }
    let scaled: Vec<Vec<f64>> = (0..k)
        .map(|i| {
            (0..k)
                .map(|j| jtj[i][j] / (jtj[i][i] * jtj[j][j]).sqrt())
                .collect()
        })
        .collect();
    let (values, vectors) = symmetric_eigen(scaled);
    let (low, &smallest) = values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .expect("k ≥ 1");
    if smallest < MIN_EIGENVALUE {
        let involved: Vec<String> = (0..k)
            .filter(|&i| vectors[i][low].abs() > 0.2)
            .map(|i| format!("{} ({:+.3})", names[i], vectors[i][low]))
            .collect();
        return Err(Error::Usage(format!(
            "parameters {} are not constrained separately by the data: only combinations \
             of them change the fitted pixels (smallest eigenvalue of their correlation \
             matrix {smallest:.1e}); fix some of them or add images at other geometries",
            involved.join(", ")
        )));
    }
    Ok(())
}

/// Eigenvalues and eigenvectors (columns) of a small symmetric matrix, Jacobi rotations.
fn symmetric_eigen(mut a: Vec<Vec<f64>>) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut v: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| (i == j) as u8 as f64).collect())
        .collect();
    for _ in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                let t = sign / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                let rotate = |x: f64, y: f64| (c * x - s * y, s * x + c * y);
                for row in a.iter_mut() {
                    (row[p], row[q]) = rotate(row[p], row[q]);
                }
                let rotated: Vec<(f64, f64)> = a[p]
                    .iter()
                    .zip(&a[q])
                    .map(|(&x, &y)| rotate(x, y))
                    .collect();
                for (k, (x, y)) in rotated.into_iter().enumerate() {
                    (a[p][k], a[q][k]) = (x, y);
                }
                for row in v.iter_mut() {
                    (row[p], row[q]) = rotate(row[p], row[q]);
                }
            }
        }
    }
    ((0..n).map(|i| a[i][i]).collect(), v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_eigen_of_a_known_matrix() {
        // [[2, 1], [1, 2]] has eigenvalues 1 and 3 with vectors (1, −1)/√2 and (1, 1)/√2.
        let (values, vectors) = symmetric_eigen(vec![vec![2.0, 1.0], vec![1.0, 2.0]]);
        let mut sorted = values.clone();
        sorted.sort_by(f64::total_cmp);
        assert!((sorted[0] - 1.0).abs() < 1e-12 && (sorted[1] - 3.0).abs() < 1e-12);
        for j in 0..2 {
            let (x, y) = (vectors[0][j], vectors[1][j]);
            let lam = values[j];
            assert!((2.0 * x + y - lam * x).abs() < 1e-12 && (x + 2.0 * y - lam * y).abs() < 1e-12);
        }
    }

    #[test]
    fn small_solver_and_inverse() {
        let a = vec![
            vec![4.0, 1.0, 0.0],
            vec![1.0, 3.0, 1.0],
            vec![0.0, 1.0, 2.0],
        ];
        let x = solve(&a, &[1.0, 2.0, 3.0]).unwrap();
        for i in 0..3 {
            let bi: f64 = (0..3).map(|j| a[i][j] * x[j]).sum();
            assert!((bi - [1.0, 2.0, 3.0][i]).abs() < 1e-12);
        }
        let inv = invert(&a).unwrap();
        let product: Vec<f64> = (0..9)
            .map(|ij| (0..3).map(|k| a[ij / 3][k] * inv[k][ij % 3]).sum())
            .collect();
        for (ij, e) in product.iter().enumerate() {
            assert!((e - (ij / 3 == ij % 3) as u8 as f64).abs() < 1e-12);
        }
        assert!(solve(&[vec![1.0, 1.0], vec![1.0, 1.0]], &[1.0, 2.0]).is_none());
    }
}
