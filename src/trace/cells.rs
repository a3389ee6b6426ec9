//! Compressed cell lists (CSR), shared by the 3-D reference grid and the Sun-view grid.
//!
//! In: a number of cells (cells are indices `0..n_cells`) and items `0..n_items`. For each
//! item the caller gives a [`Cover`] (which cells it lies in, each once) and the value to
//! store: a facet id for the grid, a depth (metres) and a caster index for the Sun view.
//! Out: [`CellLists`], where [`CellLists::cell`]`(c)` holds the value of every item that
//! covers cell `c`, in item order. Building counts the entries of each cell, turns the
//! counts into offsets with a prefix sum and fills the entries, reusing the allocations of
//! the previous build (the Sun view rebuilds its lists every step).
//!
//! Offsets are `u32`. The offset array has one entry per cell, about one per two facets,
//! and `usize` would double it for nothing a real mesh needs: 2³² entries are already
//! 16 GB of grid facet ids (64 GB of Sun-view entries). Instead the total number of
//! (item, cell) entries is summed first from each cover's cell count, in `u64` with
//! checked arithmetic, before anything is counted or allocated. If it exceeds
//! `u32::MAX`, building returns [`TooManyEntries`] and leaves valid, empty lists; the
//! tracers then retry with a coarser grid, which lists a large facet in fewer cells (with
//! one cell, each facet is one entry, and facet ids are `u32`). Once the total fits, no
//! count or offset can exceed it.

/// The cells one item lies in.
pub(crate) trait Cover {
    /// How many cells [`Cover::cells`] yields.
    fn cell_count(&self) -> u64;
    /// The cells' indices, each once; their order is the order the item is filled in.
    fn cells(&self) -> impl Iterator<Item = usize>;
}

/// The total number of entries exceeds what `u32` offsets can address.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct TooManyEntries;

/// Per cell, the values of the items covering it: those of cell `c` are
/// `values[start[c]..start[c + 1]]`.
#[derive(Default)]
pub(crate) struct CellLists<T> {
    start: Vec<u32>,
    values: Vec<T>,
}

impl<T: Copy + Default> CellLists<T> {
    /// Lists item `k`, as `value(k)`, in every cell of `cover(k)`, for `k` in `0..n_items`.
    pub(crate) fn build<C: Cover>(
        &mut self,
        n_cells: usize,
        n_items: usize,
        cover: impl Fn(usize) -> C,
        value: impl Fn(usize) -> T,
    ) -> Result<(), TooManyEntries> {
        self.start.clear();
        self.start.resize(n_cells + 1, 0);
        self.values.clear();
        let total = entry_total((0..n_items).map(|k| cover(k).cell_count()))?;
        for k in 0..n_items {
            cover(k).cells().for_each(|c| self.start[c + 1] += 1);
        }
        for c in 1..=n_cells {
            self.start[c] += self.start[c - 1];
        }
        self.values.resize(total as usize, T::default());
        for k in 0..n_items {
            let v = value(k);
            cover(k).cells().for_each(|c| {
                self.values[self.start[c] as usize] = v;
                self.start[c] += 1;
            });
        }
        // Filling used each cell's offset as its cursor, which ends at the next cell's
        // offset; shifting by one restores the offsets without a second array.
        self.start.copy_within(0..n_cells, 1);
        self.start[0] = 0;
        Ok(())
    }

    /// The values listed in cell `c`.
    pub(crate) fn cell(&self, c: usize) -> &[T] {
        &self.values[self.start[c] as usize..self.start[c + 1] as usize]
    }
}

/// The sum of the items' cell counts, if every offset up to it fits in `u32`.
fn entry_total(counts: impl IntoIterator<Item = u64>) -> Result<u32, TooManyEntries> {
    let total = counts
        .into_iter()
        .try_fold(0u64, u64::checked_add)
        .ok_or(TooManyEntries)?;
    u32::try_from(total).map_err(|_| TooManyEntries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestRng;

    /// An inclusive rectangle of cells in a row-major grid `width` cells wide.
    #[derive(Clone, Copy)]
    struct Rect {
        lo: [usize; 2],
        hi: [usize; 2],
        width: usize,
    }

    impl Cover for Rect {
        fn cell_count(&self) -> u64 {
            let side = |k: usize| (self.hi[k] + 1).saturating_sub(self.lo[k]) as u64;
            side(0) * side(1)
        }

        fn cells(&self) -> impl Iterator<Item = usize> {
            let Rect { lo, hi, width } = *self;
            (lo[1]..=hi[1]).flat_map(move |y| (lo[0]..=hi[0]).map(move |x| y * width + x))
        }
    }

    fn below(rng: &mut TestRng, n: usize) -> usize {
        (rng.next_u64() % n as u64) as usize
    }

    fn random_rects(rng: &mut TestRng, dims: [usize; 2], n: usize) -> Vec<Rect> {
        (0..n)
            .map(|_| {
                let (a, b) = (
                    [0, 1].map(|k| below(rng, dims[k])),
                    [0, 1].map(|k| below(rng, dims[k])),
                );
                Rect {
                    lo: [a[0].min(b[0]), a[1].min(b[1])],
                    hi: [a[0].max(b[0]), a[1].max(b[1])],
                    width: dims[0],
                }
            })
            .collect()
    }

    #[test]
    fn lists_match_naive_per_cell_vectors() {
        let mut rng = TestRng::new(7);
        let mut lists = CellLists::default();
        // One set of lists rebuilt at several sizes, as the Sun view reuses its buffers.
        for _ in 0..20 {
            let dims = [1 + below(&mut rng, 12), 1 + below(&mut rng, 12)];
            let n_items = below(&mut rng, 40);
            let rects = random_rects(&mut rng, dims, n_items);
            let n_cells = dims[0] * dims[1];
            let value = |k: usize| (k as f64 * 0.5, k as u32);
            lists
                .build(n_cells, rects.len(), |k| rects[k], value)
                .expect("a small grid fits");
            let mut naive = vec![Vec::new(); n_cells];
            for (k, r) in rects.iter().enumerate() {
                assert_eq!(r.cell_count(), r.cells().count() as u64);
                r.cells().for_each(|c| naive[c].push(value(k)));
            }
            for (c, expected) in naive.iter().enumerate() {
                assert_eq!(lists.cell(c), expected.as_slice(), "cell {c}");
            }
        }
    }

    #[test]
    fn entry_total_refuses_what_u32_offsets_cannot_hold() {
        let max = u64::from(u32::MAX);
        assert_eq!(entry_total([]), Ok(0));
        assert_eq!(entry_total([max - 1, 1]), Ok(u32::MAX));
        assert_eq!(entry_total([max, 1]), Err(TooManyEntries));
        assert_eq!(entry_total([max + 1]), Err(TooManyEntries));
        // The u64 sum itself must not wrap back into range.
        assert_eq!(entry_total([u64::MAX, 2]), Err(TooManyEntries));
    }

    #[test]
    fn too_many_entries_leave_empty_lists_without_counting() {
        // 65 537 items covering all 65 536 cells: 2³² + 2¹⁶ entries. The guard answers
        // before enumerating or allocating them.
        let width = 1 << 8;
        let all = Rect {
            lo: [0, 0],
            hi: [width - 1, width - 1],
            width,
        };
        let n_cells = width * width;
        let mut lists = CellLists::default();
        lists
            .build(
                4,
                2,
                |_| Rect {
                    lo: [0, 0],
                    hi: [1, 1],
                    width: 2,
                },
                |k| k as u32,
            )
            .expect("four entries fit");
        let result = lists.build(n_cells, n_cells + 1, |_| all, |k| k as u32);
        assert_eq!(result, Err(TooManyEntries));
        assert!((0..n_cells).all(|c| lists.cell(c).is_empty()));
    }
}
