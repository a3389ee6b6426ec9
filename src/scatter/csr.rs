//! Compressed sparse rows: the storage of exchange areas.
//!
//! In: per-row lists of (column, value) pairs — for a body's own block only the upper
//! triangle, mirrored here. Out: [`Csr`] with `u32` column indices and `f32` values (8
//! bytes per stored entry) and a parallel product `y += M x`. `f32` keeps 7 significant
//! digits, well inside the accuracy of any form factor, and halves the memory of the
//! largest structure of a run; products are accumulated in `f64`. A mirrored entry is the
//! same `f32` in both places, so reciprocity `A_i F_ij = A_j F_ji` holds exactly.

use rayon::prelude::*;

/// A sparse matrix in compressed rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Csr {
    /// Number of columns.
    pub cols: usize,
    /// Row r's entries are `start[r]..start[r + 1]`.
    start: Vec<u64>,
    index: Vec<u32>,
    value: Vec<f32>,
}

impl Csr {
    /// The symmetric matrix whose strict upper triangle is given row by row
    /// (`upper[i]` holds (j, value) with j > i, increasing j); the diagonal is zero.
    pub fn symmetric_from_upper(upper: &[Vec<(u32, f32)>]) -> Csr {
        let n = upper.len();
        let mut count = vec![0u64; n + 1];
        for (i, row) in upper.iter().enumerate() {
            count[i + 1] += row.len() as u64;
            for &(j, _) in row {
                count[j as usize + 1] += 1;
            }
        }
        let start = prefix_sums(count);
        let nnz = start[n] as usize;
        let mut fill: Vec<u64> = start[..n].to_vec();
        let mut index = vec![0u32; nnz];
        let mut value = vec![0f32; nnz];
        // Row j receives its lower entries (from rows i < j) in increasing i before its
        // own upper entries, so every row ends up sorted by column.
        for (i, row) in upper.iter().enumerate() {
            for &(j, v) in row {
                let at = fill[j as usize] as usize;
                index[at] = i as u32;
                value[at] = v;
                fill[j as usize] += 1;
            }
            let at = fill[i] as usize;
            for (k, &(j, v)) in row.iter().enumerate() {
                index[at + k] = j;
                value[at + k] = v;
            }
            fill[i] += row.len() as u64;
        }
        Csr {
            cols: n,
            start,
            index,
            value,
        }
    }

    /// A rectangular matrix from its rows (columns increasing within each row).
    pub fn from_rows(rows: &[Vec<(u32, f32)>], cols: usize) -> Csr {
        let start = prefix_sums(
            std::iter::once(0)
                .chain(rows.iter().map(|r| r.len() as u64))
                .collect(),
        );
        Csr {
            cols,
            start,
            index: rows.iter().flatten().map(|&(j, _)| j).collect(),
            value: rows.iter().flatten().map(|&(_, v)| v).collect(),
        }
    }

    /// The transpose.
    pub fn transpose(&self) -> Csr {
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
        self.index.len()
    }

    /// Bytes held by the matrix.
    pub fn bytes(&self) -> usize {
        self.start.len() * 8 + self.index.len() * 4 + self.value.len() * 4
    }

    /// The entries of row `r` as (column, value).
    pub fn row(&self, r: usize) -> impl Iterator<Item = (u32, f32)> + '_ {
        let range = self.start[r] as usize..self.start[r + 1] as usize;
        self.index[range.clone()]
            .iter()
            .copied()
            .zip(self.value[range].iter().copied())
    }

    /// The sum of each row.
    pub fn row_sums(&self) -> Vec<f64> {
        (0..self.rows())
            .into_par_iter()
            .map(|r| self.row(r).map(|(_, v)| v as f64).sum())
            .collect()
    }

    /// Multiplies every entry (i, j) by `scale(i, j)`.
    pub fn scale_entries(&mut self, scale: impl Fn(usize, usize) -> f64 + Sync) {
        let start = &self.start;
        let index = &self.index;
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
                    *v = (*v as f64 * scale(r, index[first + k] as usize)) as f32;
                }
            });
    }

    /// `y[r] += Σ_j M[r][j] · x[j]` for every row.
    pub fn mul_add(&self, x: &[f64], y: &mut [f64]) {
        y.par_chunks_mut(256).enumerate().for_each(|(chunk, ys)| {
            for (k, yr) in ys.iter_mut().enumerate() {
                *yr += self
                    .row(chunk * 256 + k)
                    .map(|(j, v)| v as f64 * x[j as usize])
                    .sum::<f64>();
            }
        });
    }
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
        assert_eq!(m.nnz(), 6);
        let rows: Vec<Vec<(u32, f32)>> = (0..4).map(|r| m.row(r).collect()).collect();
        assert_eq!(rows[0], vec![(1, 2.0), (3, 1.0)]);
        assert_eq!(rows[1], vec![(0, 2.0), (2, 5.0)]);
        assert_eq!(rows[2], vec![(1, 5.0)]);
        assert_eq!(rows[3], vec![(0, 1.0)]);
        let mut y = vec![1.0; 4];
        m.mul_add(&[1.0, 10.0, 100.0, 1000.0], &mut y);
        assert_eq!(y, vec![1021.0, 503.0, 51.0, 2.0]);
        assert_eq!(m.transpose(), m);
        let mut s = m.clone();
        s.scale_entries(|i, j| (i + j) as f64);
        assert_eq!(s.row(3).collect::<Vec<_>>(), vec![(0, 3.0)]);
    }
}
