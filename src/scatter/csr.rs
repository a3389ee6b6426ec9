//! Compressed sparse rows: the storage of exchange areas.
//!
//! In: per-row lists of (column, value) pairs — for a body's own block only the strict
//! upper triangle of the symmetric matrix. Out: [`Csr`] with column indices in 16 bits
//! (plus a second 16-bit array only when there are more than 65,536 columns) and `f32`
//! values — 6 bytes per stored entry up to 65,536 facets, 8 beyond — and a product
//! `y += M x`, whose time is set by the bytes it reads. A symmetric block
//! stores each pair once, so reciprocity `A_i F_ij = A_j F_ji` holds exactly and memory
//! and the bytes read per product are halved. `f32` keeps 7 significant digits, well
//! inside the accuracy of any form factor; products are accumulated in `f64`.
//!
//! The symmetric product splits the rows into a fixed number of parts (not one per
//! thread), each adding into its own vector, summed in part order: results do not depend
//! on the number of threads.
//!
//! Products take one number per column ([`f64`]) or several side by side (`[f64; K]`, the
//! [`Lanes`] of K time steps solved together): each stored entry is then read once for K
//! products, which on Itokawa makes a product per vector about 40 % cheaper at K = 8.

use rayon::prelude::*;

/// Row parts of the symmetric product.
const PARTS: usize = 8;

/// The value a product gives each row: one number, or K numbers side by side.
pub trait Lanes: Copy + Send + Sync + 'static {
    const ZERO: Self;
    /// `self += v · x`, lane by lane.
    fn add_scaled(&mut self, v: f64, x: &Self);
    /// `self += x`, lane by lane.
    fn add(&mut self, x: &Self);
}

impl Lanes for f64 {
    const ZERO: f64 = 0.0;
    #[inline]
    fn add_scaled(&mut self, v: f64, x: &f64) {
        *self += v * x;
    }
    #[inline]
    fn add(&mut self, x: &f64) {
        *self += x;
    }
}

impl<const K: usize> Lanes for [f64; K] {
    const ZERO: [f64; K] = [0.0; K];
    #[inline]
    fn add_scaled(&mut self, v: f64, x: &[f64; K]) {
        self.iter_mut().zip(x).for_each(|(s, x)| *s += v * x);
    }
    #[inline]
    fn add(&mut self, x: &[f64; K]) {
        self.iter_mut().zip(x).for_each(|(s, x)| *s += x);
    }
}

/// A sparse matrix in compressed rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Csr {
    /// Number of columns.
    pub cols: usize,
    /// Only the strict upper triangle of a symmetric matrix is stored.
    pub symmetric: bool,
    /// Row r's entries are `start[r]..start[r + 1]`.
    start: Vec<u64>,
    /// Low 16 bits of each entry's column.
    index_lo: Vec<u16>,
    /// High 16 bits, empty when every column fits in the low ones.
    index_hi: Vec<u16>,
    value: Vec<f32>,
}

impl Csr {
    /// The symmetric matrix whose strict upper triangle is given row by row
    /// (`upper[i]` holds (j, value) with j > i); the diagonal is zero.
    pub fn symmetric_from_upper(upper: &[Vec<(u32, f32)>]) -> Csr {
        Csr {
            symmetric: true,
            ..Csr::from_rows(upper, upper.len())
        }
    }

    /// A rectangular matrix from its rows (columns increasing within each row).
    pub fn from_rows(rows: &[Vec<(u32, f32)>], cols: usize) -> Csr {
        let start = prefix_sums(
            std::iter::once(0)
                .chain(rows.iter().map(|r| r.len() as u64))
                .collect(),
        );
        let entries = || rows.iter().flatten();
        Csr {
            cols,
            symmetric: false,
            index_lo: exact(entries().map(|&(j, _)| j as u16), start[rows.len()]),
            index_hi: if cols > 1 << 16 {
                exact(entries().map(|&(j, _)| (j >> 16) as u16), start[rows.len()])
            } else {
                Vec::new()
            },
            value: exact(entries().map(|&(_, v)| v), start[rows.len()]),
            start,
        }
    }

    /// The transpose.
    pub fn transpose(&self) -> Csr {
        if self.symmetric {
            return self.clone();
        }
        let mut rows: Vec<Vec<(u32, f32)>> = vec![Vec::new(); self.cols];
        for r in 0..self.rows() {
            for (j, v) in self.row(r) {
                rows[j as usize].push((r as u32, v));
            }
        }
        Csr::from_rows(&rows, self.rows())
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// Number of stored entries.
    pub fn nnz(&self) -> usize {
        self.value.len()
    }

    /// Bytes held by the matrix.
    pub fn bytes(&self) -> usize {
        self.start.len() * 8
            + (self.index_lo.len() + self.index_hi.len()) * 2
            + self.value.len() * 4
    }

    /// Appends the matrix to `out` (little-endian): columns u64, symmetric u8, rows u64,
    /// entries u64, whether high column bits follow u8, row starts ((rows + 1) × u64),
    /// low column bits (u16 each), high ones if any, values (f32 each).
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&(self.cols as u64).to_le_bytes());
        out.push(self.symmetric as u8);
        out.extend_from_slice(&(self.rows() as u64).to_le_bytes());
        out.extend_from_slice(&(self.nnz() as u64).to_le_bytes());
        out.push(!self.index_hi.is_empty() as u8);
        self.start
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
        self.index_lo
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
        self.index_hi
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
        self.value
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
    }

    /// Reads what [`Csr::encode`] wrote, checking that it is a well-formed matrix of
    /// `rows` × `cols` (row starts increasing, columns in range and, for a symmetric one,
    /// right of the diagonal; values finite).
    pub fn decode(r: &mut crate::cache::Reader, rows: usize, cols: usize) -> Result<Csr, String> {
        let stored_cols = r.u64("the column count")?;
        let symmetric = r.take(1, "the symmetry flag")?[0] == 1;
        let stored_rows = r.u64("the row count")?;
        if (stored_rows, stored_cols) != (rows as u64, cols as u64) {
            return Err(format!(
                "a {stored_rows} × {stored_cols} matrix, expected {rows} × {cols}"
            ));
        }
        let nnz = usize::try_from(r.u64("the entry count")?).map_err(|_| "absurd size")?;
        let wide = r.take(1, "the column width")?[0] == 1;
        if wide != (cols > 1 << 16) {
            return Err("column width does not fit the column count".into());
        }
        let start: Vec<u64> = r
            .items(rows + 1, 8, "the row starts")?
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        let mut halves = |n: usize, what: &str| -> Result<Vec<u16>, String> {
            Ok(r.items(n, 2, what)?
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect())
        };
        let index_lo = halves(nnz, "the columns")?;
        let index_hi = halves(if wide { nnz } else { 0 }, "the high column bits")?;
        let value: Vec<f32> = r
            .items(nnz, 4, "the values")?
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        let csr = Csr {
            cols,
            symmetric,
            start,
            index_lo,
            index_hi,
            value,
        };
        csr.check()?;
        Ok(csr)
    }

    /// Whether the parts fit together (see [`Csr::decode`]).
    fn check(&self) -> Result<(), String> {
        let ends_right = self.start.first() == Some(&0)
            && self.start.last() == Some(&(self.nnz() as u64))
            && self.start.windows(2).all(|w| w[0] <= w[1]);
        if !ends_right {
            return Err("row starts out of order".into());
        }
        for r in 0..self.rows() {
            for (j, v) in self.row(r) {
                let j = j as usize;
                if j >= self.cols || (self.symmetric && j <= r) || !v.is_finite() {
                    return Err(format!("row {r}: entry ({j}, {v}) out of place"));
                }
            }
        }
        Ok(())
    }

    /// The column of stored entry `k`.
    #[inline]
    fn column(&self, k: usize) -> usize {
        let lo = self.index_lo[k] as usize;
        if self.index_hi.is_empty() {
            lo
        } else {
            lo | (self.index_hi[k] as usize) << 16
        }
    }

    /// The stored entries of row `r` as (column, value) (for a symmetric matrix, those
    /// right of the diagonal).
    pub fn row(&self, r: usize) -> impl Iterator<Item = (u32, f32)> + '_ {
        (self.start[r] as usize..self.start[r + 1] as usize)
            .map(|k| (self.column(k) as u32, self.value[k]))
    }

    /// Calls `f(column, value)` for the stored entries of row `r`, on plain slices so
    /// that the products' inner loops carry no per-entry branch or bounds check.
    #[inline]
    fn for_each_entry(&self, r: usize, mut f: impl FnMut(usize, f32)) {
        let range = self.start[r] as usize..self.start[r + 1] as usize;
        let (lo, value) = (&self.index_lo[range.clone()], &self.value[range.clone()]);
        if self.index_hi.is_empty() {
            lo.iter().zip(value).for_each(|(&j, &v)| f(j as usize, v));
        } else {
            let hi = &self.index_hi[range];
            lo.iter()
                .zip(hi)
                .zip(value)
                .for_each(|((&j, &h), &v)| f(j as usize | (h as usize) << 16, v));
        }
    }

    /// The sum of each row (of the whole matrix).
    pub fn row_sums(&self) -> Vec<f64> {
        let mut sums = vec![0.0; self.rows()];
        self.mul_add(&vec![1.0; self.cols], &mut sums);
        sums
    }

    /// Multiplies every entry (i, j) by `scale(i, j)`.
    pub fn scale_entries(&mut self, scale: impl Fn(usize, usize) -> f64 + Sync) {
        let start = &self.start;
        let column = |k: usize| {
            let lo = self.index_lo[k] as usize;
            self.index_hi
                .get(k)
                .map_or(lo, |&hi| lo | (hi as usize) << 16)
        };
        self.value
            .par_chunks_mut(1 << 12)
            .enumerate()
            .for_each(|(chunk, values)| {
                let first = chunk << 12;
                let mut r = start.partition_point(|&s| s as usize <= first) - 1;
                for (k, v) in values.iter_mut().enumerate() {
                    while start[r + 1] as usize <= first + k {
                        r += 1;
                    }
                    *v = (*v as f64 * scale(r, column(first + k))) as f32;
                }
            });
    }

    /// `y[r] += Σ_j M[r][j] · x[j]` for every row (lane by lane).
    pub fn mul_add<L: Lanes>(&self, x: &[L], y: &mut [L]) {
        if self.symmetric {
            return self.symmetric_mul_add(x, y);
        }
        y.par_chunks_mut(256).enumerate().for_each(|(chunk, ys)| {
            for (k, yr) in ys.iter_mut().enumerate() {
                let mut sum = L::ZERO;
                self.for_each_entry(chunk * 256 + k, |j, v| sum.add_scaled(v as f64, &x[j]));
                yr.add(&sum);
            }
        });
    }
}

impl Csr {
    /// The symmetric product from the upper triangle: every stored (i, j) adds to row i
    /// and to row j. Rows are split into [`PARTS`] runs of about equal entry counts.
    fn symmetric_mul_add<L: Lanes>(&self, x: &[L], y: &mut [L]) {
        let n = self.rows();
        let nnz = self.nnz() as u64;
        let bounds: Vec<usize> = (0..=PARTS)
            .map(|p| {
                self.start
                    .partition_point(|&s| s < nnz * p as u64 / PARTS as u64)
                    .min(n)
            })
            .collect();
        // Part p adds only into rows from its first one on (the upper triangle's columns
        // lie right of its rows), so its vector starts there, which saves zeroing and
        // summing the parts' untouched heads.
        let partials: Vec<Vec<L>> = (0..PARTS)
            .into_par_iter()
            .map(|p| {
                let from = bounds[p];
                let mut acc = vec![L::ZERO; n - from];
                for r in from..bounds[p + 1] {
                    let mut own = L::ZERO;
                    let xr = x[r];
                    self.for_each_entry(r, |j, v| {
                        own.add_scaled(v as f64, &x[j]);
                        acc[j - from].add_scaled(v as f64, &xr);
                    });
                    acc[r - from].add(&own);
                }
                acc
            })
            .collect();
        y.par_iter_mut().enumerate().for_each(|(i, yi)| {
            (0..PARTS)
                .filter(|&p| bounds[p] <= i)
                .for_each(|p| yi.add(&partials[p][i - bounds[p]]));
        });
    }
}

/// The items collected into a vector of exactly `len` (a flattened iterator does not
/// know its length, and collecting would leave up to half the capacity unused).
fn exact<T>(items: impl Iterator<Item = T>, len: u64) -> Vec<T> {
    let mut v = Vec::with_capacity(len as usize);
    v.extend(items);
    v
}

fn prefix_sums(mut v: Vec<u64>) -> Vec<u64> {
    for i in 1..v.len() {
        v[i] += v[i - 1];
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirrored_upper_triangle_and_products() {
        let upper = vec![vec![(1, 2.0), (3, 1.0)], vec![(2, 5.0)], vec![], vec![]];
        let m = Csr::symmetric_from_upper(&upper);
        assert_eq!(m.nnz(), 3);
        let mut y = vec![1.0; 4];
        m.mul_add(&[1.0, 10.0, 100.0, 1000.0], &mut y);
        assert_eq!(y, vec![1021.0, 503.0, 51.0, 2.0]);
        assert_eq!(m.row_sums(), vec![3.0, 7.0, 5.0, 1.0]);
        let mut s = m.clone();
        s.scale_entries(|i, j| (i + j) as f64);
        assert_eq!(s.row(0).collect::<Vec<_>>(), vec![(1, 2.0), (3, 3.0)]);
        // The rectangular transpose.
        let r = Csr::from_rows(&[vec![(2, 1.0)], vec![(0, 4.0)]], 3);
        let t = r.transpose();
        assert_eq!((t.rows(), t.cols), (3, 2));
        assert_eq!(t.row(0).collect::<Vec<_>>(), vec![(1, 4.0)]);
        assert_eq!(t.row(2).collect::<Vec<_>>(), vec![(0, 1.0)]);
    }

    #[test]
    fn symmetric_product_equals_the_dense_one() {
        // Enough rows and uneven row lengths that every part starts at a different row.
        let n = 300;
        let mut rng = crate::TestRng::new(0x9e37_79b9_7f4a_7c15);
        let upper: Vec<Vec<(u32, f32)>> = (0..n)
            .map(|i| {
                ((i + 1)..n)
                    .filter_map(|j| {
                        let r = rng.next_u64();
                        r.is_multiple_of(5)
                            .then(|| (j as u32, (r >> 8) as f32 % 1000.0 / 7.0))
                    })
                    .collect()
            })
            .collect();
        let mut dense = vec![vec![0.0; n]; n];
        for (i, row) in upper.iter().enumerate() {
            for &(j, v) in row {
                dense[i][j as usize] = v as f64;
                dense[j as usize][i] = v as f64;
            }
        }
        let x: Vec<f64> = (0..n).map(|k| 1.0 + (k % 17) as f64).collect();
        let mut y = vec![0.5; n];
        Csr::symmetric_from_upper(&upper).mul_add(&x, &mut y);
        for i in 0..n {
            let expected = 0.5 + (0..n).map(|j| dense[i][j] * x[j]).sum::<f64>();
            assert!(
                (y[i] - expected).abs() <= 1e-12 * expected,
                "row {i}: {} vs {expected}",
                y[i]
            );
        }
    }

    #[test]
    fn columns_beyond_sixteen_bits() {
        let wide = Csr::from_rows(
            &[vec![(3, 1.0), (70_000, 2.0)], vec![(65_536, 4.0)]],
            70_001,
        );
        assert_eq!(wide.bytes(), 3 * 8 + 3 * 4 + 3 * 4);
        assert_eq!(
            wide.row(0).collect::<Vec<_>>(),
            vec![(3, 1.0), (70_000, 2.0)]
        );
        let mut x = vec![0.0; 70_001];
        x[70_000] = 10.0;
        x[65_536] = 100.0;
        let mut y = vec![0.0; 2];
        wide.mul_add(&x, &mut y);
        assert_eq!(y, vec![20.0, 400.0]);
        let mut scaled = wide.clone();
        scaled.scale_entries(|i, j| if (i, j) == (1, 65_536) { 0.5 } else { 1.0 });
        assert_eq!(scaled.row(1).collect::<Vec<_>>(), vec![(65_536, 2.0)]);
        let narrow = Csr::from_rows(&[vec![(65_535, 1.0)]], 65_536);
        assert_eq!(narrow.bytes(), 2 * 8 + 2 + 4);
        assert_eq!(narrow.row(0).collect::<Vec<_>>(), vec![(65_535, 1.0)]);
    }
}
