//! Stats: streaming, mergeable per-facet statistics of irradiance over time.
//!
//! In: one irradiance value (W/m²) per facet per step, all steps of equal weight. Out, per
//! facet: minimum, maximum, mean, standard deviation (population, over time), lit fraction
//! (share of steps with E > 0) and the cumulative distribution F_k(x_b) = share of steps
//! with E ≤ x_b at thresholds x_b = b·w, b = 0 … B (SLIM paper eq. 14).
//!
//! Memory is O(facets × bins), never O(facets × steps).
//!
//! **Exact merging.** Every statistic is kept as something whose merge is exact and
//! associative, so that a run split into parts in time or by facet and merged in any
//! order gives bit-identical results to one run (the shards of issue 20 rely on it):
//! - min and max are f64 (min and max round nothing);
//! - counts (lit steps, CDF counts, darkness runs) are integers;
//! - mean and variance come from **exact integer sums** Σq and Σq² of each value in fixed
//!   point, q = ⌊E / u⌋ (truncated toward zero) with the unit u = 2^k chosen from the
//!   bins (the run's largest flux): values up to 256 times the last threshold fit in 63
//!   bits, and u is about 10⁻¹⁶ of that flux (2⁻⁴³ W/m² at 1,361 W/m²). Σq is an `i128`
//!   and Σq² a 192-bit integer, which cannot overflow before 2⁶⁴ steps. Mean and variance
//!   are then computed once, from n, Σq and the exact integer n·Σq² − (Σq)². Their only
//!   errors are the truncation (below u per value, far below any f64 rounding of a
//!   running mean) and one final rounding, so they are more accurate than Welford's
//!   running update, not less. Values beyond 256 times the last threshold saturate.
//!
//! Each facet is updated in step order by one thread, so results do not depend on the
//! number of threads.

use rayon::prelude::*;

/// CDF thresholds x_b = b·width, b = 0 … count−1, in W/m².
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Bins {
    /// Bin width, W/m².
    pub width_w_m2: f64,
    /// Number of thresholds (the first is 0 W/m²).
    pub count: usize,
}

impl Bins {
    /// Thresholds of `width_w_m2` covering 0 … `max_w_m2`.
    pub fn covering(width_w_m2: f64, max_w_m2: f64) -> Bins {
        Bins {
            width_w_m2,
            count: ((max_w_m2.max(0.0) / width_w_m2).ceil() as usize).saturating_add(1),
        }
    }

    /// Threshold b, W/m².
    pub fn threshold(&self, b: usize) -> f64 {
        b as f64 * self.width_w_m2
    }

    /// Index of the smallest threshold ≥ `e` (values above the last go to the last).
    fn index(&self, e: f64) -> usize {
        if e <= 0.0 {
            0
        } else {
            // ⌈t⌉ without `f64::ceil`, a libm call on baseline x86-64 in the hottest loop
            // of a run; the same integer for every t (`as` truncates and saturates).
            // Through i64: baseline x86-64 converts between f64 and i64 in one
            // instruction, and between f64 and u64 in a dozen.
            let t = e / self.width_w_m2;
            let floor = t as i64;
            let ceil = floor.saturating_add(i64::from((floor as f64) < t));
            (ceil as usize).min(self.count - 1)
        }
    }
}

/// Running statistics of one facet.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Moments {
    min: f64,
    max: f64,
    /// Σq and Σq² of the values in fixed point (see the module doc).
    sum: i128,
    squares: Wide,
    lit: u64,
    /// Runs of dark steps (E ≤ 0): from the first step on, up to the last step, and the
    /// longest anywhere. Consecutive time ranges merge exactly: the longest run is the
    /// longest of either or the first's trailing run joined to the second's leading run.
    dark_leading: u32,
    dark_trailing: u32,
    dark_longest: u32,
}

/// Facets per parallel task when adding steps: enough to amortise the task, few enough
/// to share the facets out evenly over the threads.
const FACETS_PER_TASK: usize = 2048;

impl Moments {
    /// Adds the value `e` (W/m²) of the step numbered `step` (from 0), with `per_unit`
    /// the inverse of the fixed-point unit.
    fn add(&mut self, e: f64, step: u64, per_unit: f64) {
        // Comparisons, not `f64::min`/`max`, whose care for NaN costs instructions in the
        // hottest loop of a run; a NaN is passed over either way.
        self.min = if e < self.min { e } else { self.min };
        self.max = if e > self.max { e } else { self.max };
        // Truncation toward zero (and saturation) by `as`: a unit is ~1e-16 of the flux,
        // so rounding to nearest would buy nothing but a libm call.
        let q = (e * per_unit) as i64;
        self.sum += q as i128;
        let magnitude = q.unsigned_abs() as u128;
        self.squares.add(magnitude * magnitude, 0);
        if e > 0.0 {
            self.lit += 1;
            self.dark_trailing = 0;
        } else {
            if self.dark_leading as u64 == step {
                self.dark_leading = self.dark_leading.saturating_add(1);
            }
            self.dark_trailing = self.dark_trailing.saturating_add(1);
            self.dark_longest = self.dark_longest.max(self.dark_trailing);
        }
    }

    /// Merges `later`'s moments (`later_steps` steps) into these (`steps` steps), which
    /// come first in time.
    fn merge_later(&mut self, later: &Moments, steps: u64, later_steps: u64) {
        let (a, b) = (self, later);
        a.min = a.min.min(b.min);
        a.max = a.max.max(b.max);
        a.sum += b.sum;
        a.squares.add(b.squares.low, b.squares.high);
        a.lit += b.lit;
        let a_dark_throughout = a.dark_leading as u64 == steps;
        let b_dark_throughout = b.dark_leading as u64 == later_steps;
        a.dark_longest = a
            .dark_longest
            .max(b.dark_longest)
            .max(a.dark_trailing.saturating_add(b.dark_leading));
        if a_dark_throughout {
            a.dark_leading = a.dark_leading.saturating_add(b.dark_leading);
        }
        a.dark_trailing = if b_dark_throughout {
            a.dark_trailing.saturating_add(b.dark_trailing)
        } else {
            b.dark_trailing
        };
    }
}

const EMPTY: Moments = Moments {
    min: f64::INFINITY,
    max: f64::NEG_INFINITY,
    sum: 0,
    squares: Wide { low: 0, high: 0 },
    lit: 0,
    dark_leading: 0,
    dark_trailing: 0,
    dark_longest: 0,
};

/// Bytes of one facet's statistics besides its CDF counts (for memory estimates).
pub const MOMENT_BYTES: usize = std::mem::size_of::<Moments>();

/// Bytes of one facet's moments in [`FacetStats::write_to`].
const ENCODED_MOMENT_BYTES: usize = 8 + 8 + 16 + 16 + 8 + 8 + 3 * 4;

/// Reads `facets` facets' moments as [`FacetStats::write_to`] wrote them.
/// Splits the moments of `facets` facets off the front of `input` (fixed-size records).
fn take_moment_records<'a>(input: &mut &'a [u8], facets: usize) -> std::io::Result<&'a [u8]> {
    let bytes = facets * ENCODED_MOMENT_BYTES;
    if input.len() < bytes {
        return Err(std::io::ErrorKind::UnexpectedEof.into());
    }
    let (records, rest) = input.split_at(bytes);
    *input = rest;
    Ok(records)
}

/// One facet's moments from its record, as [`FacetStats::write_to`] wrote them.
fn decode_moments(record: &[u8]) -> Moments {
    let mut at = 0;
    let mut take = |n: usize| {
        at += n;
        &record[at - n..at]
    };
    let u32_at = |b: &[u8]| u32::from_le_bytes(b.try_into().expect("4 bytes"));
    Moments {
        min: f64::from_le_bytes(take(8).try_into().expect("8 bytes")),
        max: f64::from_le_bytes(take(8).try_into().expect("8 bytes")),
        sum: i128::from_le_bytes(take(16).try_into().expect("16 bytes")),
        squares: Wide {
            low: u128::from_le_bytes(take(16).try_into().expect("16 bytes")),
            high: u64::from_le_bytes(take(8).try_into().expect("8 bytes")),
        },
        lit: u64::from_le_bytes(take(8).try_into().expect("8 bytes")),
        dark_leading: u32_at(take(4)),
        dark_trailing: u32_at(take(4)),
        dark_longest: u32_at(take(4)),
    }
}

/// Appends `counts` to `out` as LEB128 varints, each run of zeros as 0 and its length.
fn encode_counts(counts: &[u32], out: &mut Vec<u8>) {
    let varint = |mut v: u64, out: &mut Vec<u8>| loop {
        let byte = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            out.push(byte);
            break;
        }
        out.push(byte | 0x80);
    };
    let mut i = 0;
    while i < counts.len() {
        if counts[i] == 0 {
            let run = counts[i..].iter().take_while(|&&c| c == 0).count();
            varint(0, out);
            varint(run as u64, out);
            i += run;
        } else {
            varint(counts[i] as u64, out);
            i += 1;
        }
    }
}

/// Adds the `counts.len()` counts written by [`encode_counts`] at the start of `input`
/// to `counts`, and moves `input` past them. Only the counts that are not 0 are touched.
fn add_counts(input: &mut &[u8], counts: &mut [u32]) -> std::io::Result<()> {
    let damaged = || std::io::Error::new(std::io::ErrorKind::InvalidData, "damaged CDF counts");
    let mut varint = || -> std::io::Result<u64> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let (&byte, rest) = input
                .split_first()
                .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::UnexpectedEof))?;
            *input = rest;
            v |= u64::from(byte & 0x7f) << shift;
            if byte & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(damaged())
    };
    let mut b = 0;
    while b < counts.len() {
        match varint()? {
            0 => {
                let run = varint()?;
                if run == 0 || run > (counts.len() - b) as u64 {
                    return Err(damaged());
                }
                b += run as usize;
            }
            v => {
                let v = u32::try_from(v).map_err(|_| damaged())?;
                counts[b] = counts[b].checked_add(v).ok_or_else(damaged)?;
                b += 1;
            }
        }
    }
    Ok(())
}

/// A 192-bit unsigned integer, `high·2¹²⁸ + low`: a sum of squares of 63-bit values.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Wide {
    low: u128,
    high: u64,
}

impl Wide {
    fn add(&mut self, low: u128, high: u64) {
        let (sum, carry) = self.low.overflowing_add(low);
        self.low = sum;
        self.high = self.high.wrapping_add(high).wrapping_add(carry as u64);
    }

    /// `self · n` as four 64-bit limbs, least significant first.
    fn times(&self, n: u64) -> [u64; 4] {
        let limbs = [self.low as u64, (self.low >> 64) as u64, self.high];
        let mut out = [0u64; 4];
        let mut carry = 0u128;
        for (o, &l) in out.iter_mut().zip(&limbs) {
            let p = l as u128 * n as u128 + carry;
            *o = p as u64;
            carry = p >> 64;
        }
        out[3] = carry as u64;
        out
    }
}

/// `a²` of a 128-bit magnitude as four 64-bit limbs, least significant first.
fn square(a: u128) -> [u64; 4] {
    let (lo, hi) = (a as u64 as u128, a >> 64);
    let (ll, lh, hh) = (lo * lo, lo * hi, hi * hi);
    // a² = hh·2¹²⁸ + 2·lh·2⁶⁴ + ll, added limb by limb with carries.
    let mut out = [0u64; 4];
    let terms: [(u128, usize); 4] = [(ll, 0), (lh, 1), (lh, 1), (hh, 2)];
    for (value, at) in terms {
        let mut carry = 0u128;
        for (k, part) in [value as u64, (value >> 64) as u64, 0, 0]
            .into_iter()
            .enumerate()
        {
            let Some(o) = out.get_mut(at + k) else { break };
            let s = *o as u128 + part as u128 + carry;
            *o = s as u64;
            carry = s >> 64;
        }
    }
    out
}

/// `a − b` of two four-limb integers with `a ≥ b`, as an f64 (rounded).
fn difference_as_f64(a: [u64; 4], b: [u64; 4]) -> f64 {
    let mut borrow = 0u128;
    let mut limbs = [0u64; 4];
    for k in 0..4 {
        let d = (a[k] as u128).wrapping_sub(b[k] as u128 + borrow);
        limbs[k] = d as u64;
        borrow = (d >> 127) & 1;
    }
    limbs
        .iter()
        .rev()
        .fold(0.0, |acc, &l| acc * 18_446_744_073_709_551_616.0 + l as f64)
}

/// The facets whose statistics a run keeps (those of the bodies that get outputs, or a
/// shard's part of them), as ranges of global facet ids in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// `None`: every facet.
    ranges: Option<Vec<std::ops::Range<usize>>>,
    count: usize,
    /// Facets in all.
    facets: usize,
}

impl Selection {
    /// The facets in `ranges` out of `facets` in all.
    pub fn new(ranges: Vec<std::ops::Range<usize>>, facets: usize) -> Selection {
        let count = ranges.iter().map(|r| r.len()).sum();
        Selection {
            ranges: (count < facets).then_some(ranges),
            count,
            facets,
        }
    }

    /// Every one of `facets` facets.
    pub fn all(facets: usize) -> Selection {
        Selection {
            ranges: None,
            count: facets,
            facets,
        }
    }

    /// The selected facets numbered `range` among the selected (all for `None`).
    pub fn within(self, range: Option<std::ops::Range<usize>>) -> Selection {
        let Some(range) = range else { return self };
        let ranges = self
            .ranges
            .unwrap_or_else(|| std::iter::once(0..self.facets).collect());
        let mut before = 0;
        let mut picked = Vec::new();
        for r in ranges {
            let from = range.start.saturating_sub(before).min(r.len());
            let to = range.end.saturating_sub(before).min(r.len());
            if from < to {
                picked.push(r.start + from..r.start + to);
            }
            before += r.len();
        }
        Selection::new(picked, self.facets)
    }

    /// The selected facets as runs of consecutive global ids.
    fn runs(&self) -> Runs {
        let mut runs = Vec::new();
        let mut local = 0;
        match &self.ranges {
            None => runs.push((0, 0..self.facets)),
            Some(ranges) => {
                for r in ranges.iter().filter(|r| !r.is_empty()) {
                    runs.push((local, r.clone()));
                    local += r.len();
                }
            }
        }
        Runs(runs)
    }

    /// Number of selected facets.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The selected values of `values` (one per facet, global order): `values` itself
    /// when every facet is selected, else gathered into `buffer`.
    pub fn pick<'a>(&self, values: &'a [f64], buffer: &'a mut Vec<f64>) -> &'a [f64] {
        let Some(ranges) = &self.ranges else {
            return values;
        };
        buffer.clear();
        for r in ranges {
            buffer.extend_from_slice(&values[r.clone()]);
        }
        buffer
    }
}

/// A [`Selection`] as runs of consecutive global ids: (the first's number among the
/// selected, its global ids).
struct Runs(Vec<(usize, std::ops::Range<usize>)>);

impl Runs {
    /// The global ids of the selected facets numbered `locals` among the selected, in
    /// order.
    fn globals(&self, locals: std::ops::Range<usize>) -> impl Iterator<Item = usize> + '_ {
        self.0.iter().flat_map(move |(first, ids)| {
            let from = locals.start.max(*first);
            let to = locals.end.min(first + ids.len());
            (from..to.max(from)).map(move |local| ids.start + (local - first))
        })
    }
}

/// Statistics of every facet over the steps seen so far.
#[derive(Debug, Clone, PartialEq)]
pub struct FacetStats {
    bins: Bins,
    /// The fixed-point unit u of the exact sums, W/m² (a power of two; module doc).
    unit: f64,
    steps: u64,
    moments: Vec<Moments>,
    /// `hist[i·bins + b]`: steps with x_{b−1} < E ≤ x_b (b = 0: E ≤ 0).
    hist: Vec<u32>,
}

/// The statistics of a run of consecutive facets ([`FacetStats::facet_runs`]), to which
/// one task adds every step of the run.
pub struct FacetRun<'a> {
    moments: &'a mut [Moments],
    hist: &'a mut [u32],
    bins: Bins,
    per_unit: f64,
    first_step: u64,
    steps: usize,
}

impl FacetRun<'_> {
    /// Facets in the run.
    pub fn len(&self) -> usize {
        self.moments.len()
    }

    /// Whether the run holds no facet.
    pub fn is_empty(&self) -> bool {
        self.moments.is_empty()
    }

    /// Adds every step: `values[k · len + j]` is the value (W/m²) of the run's facet `j`
    /// at step `k`, the steps in time order. Bit-identical to adding them step by step.
    pub fn add_steps(&mut self, values: &[f64]) {
        let len = self.moments.len().max(1);
        self.add_each(values, |j| values.iter().skip(j).step_by(len).copied());
    }

    /// [`FacetRun::add_steps`] with the values facet by facet: `values[j · steps + k]` is
    /// the value (W/m²) of the run's facet `j` at step `k`.
    pub fn add_series(&mut self, values: &[f64]) {
        let steps = self.steps;
        self.add_each(values, |j| {
            values[j * steps..(j + 1) * steps].iter().copied()
        });
    }

    /// Adds to each facet `j` of the run its steps in time order, `series(j)`, taken
    /// from `values` (one per facet and step).
    fn add_each<I: Iterator<Item = f64>>(&mut self, values: &[f64], series: impl Fn(usize) -> I) {
        assert_eq!(
            values.len(),
            self.steps * self.moments.len(),
            "one value per facet and step"
        );
        let bins = self.bins;
        let facets = self
            .moments
            .iter_mut()
            .zip(self.hist.chunks_mut(bins.count));
        for (j, facet) in facets.enumerate() {
            add_facet_steps(facet, series(j), self.first_step, (bins, self.per_unit));
        }
    }
}

/// Adds one facet's `values` (W/m², consecutive steps from step `first_step`) to its
/// moments and CDF counts `h`, the moments kept in registers over the steps.
#[inline]
fn add_facet_steps(
    (m, h): (&mut Moments, &mut [u32]),
    values: impl Iterator<Item = f64>,
    first_step: u64,
    (bins, per_unit): (Bins, f64),
) {
    let mut running = *m;
    for (k, e) in values.enumerate() {
        running.add(e, first_step + k as u64, per_unit);
        h[bins.index(e)] += 1;
    }
    *m = running;
}

/// The fixed-point unit for `bins`: the power of two with which 256 times the last
/// threshold (or the width, when there is one threshold) fits in 63 bits.
fn unit_for(bins: Bins) -> f64 {
    let top = bins
        .threshold(bins.count.saturating_sub(1))
        .max(bins.width_w_m2);
    let top = if top.is_finite() && top > 0.0 {
        top
    } else {
        1.0
    };
    2f64.powi((256.0 * top).log2().ceil() as i32 - 63)
}

impl FacetStats {
    /// Empty statistics for `facets` facets.
    pub fn new(facets: usize, bins: Bins) -> FacetStats {
        FacetStats {
            bins,
            unit: unit_for(bins),
            steps: 0,
            moments: vec![EMPTY; facets],
            hist: vec![0; facets * bins.count],
        }
    }

    /// Adds one step: `irradiance[i]` is facet i's value in W/m².
    pub fn add_step(&mut self, irradiance: &[f64]) {
        self.add_steps(&[irradiance]);
    }

    /// Adds consecutive steps: `steps[k][i]` is facet i's value in W/m² at the k-th of
    /// them.
    pub fn add_steps(&mut self, steps: &[&[f64]]) {
        self.add_steps_of(steps, &Selection::all(self.moments.len()));
    }

    /// Adds consecutive steps of values given for more facets than these statistics keep:
    /// `steps[k][g]` is the value in W/m² of facet g (global ids) at the k-th step, and
    /// these statistics keep the facets of `kept`, in its order. Each facet takes its
    /// steps in order while its moments sit in registers and its CDF counts in cache, so
    /// a block of steps moves a fraction of the memory that as many single steps move (at
    /// 786k facets the counts alone are hundreds of MB); the result is bit-identical to
    /// adding the steps one by one.
    pub fn add_steps_of(&mut self, steps: &[&[f64]], kept: &Selection) {
        assert_eq!(
            kept.count(),
            self.moments.len(),
            "statistics of the kept facets"
        );
        assert!(
            steps.iter().all(|s| s.len() == kept.facets),
            "one value per facet"
        );
        let runs = kept.runs();
        let first_step = self.steps;
        self.steps += steps.len() as u64;
        let (bins, per_unit) = (self.bins, 1.0 / self.unit);
        self.moments
            .par_chunks_mut(FACETS_PER_TASK)
            .zip(self.hist.par_chunks_mut(FACETS_PER_TASK * bins.count))
            .enumerate()
            .for_each(|(task, (moments, hist))| {
                let first = task * FACETS_PER_TASK;
                let globals = runs.globals(first..first + moments.len());
                let facets = moments.iter_mut().zip(hist.chunks_mut(bins.count));
                for ((m, h), g) in facets.zip(globals) {
                    let values = steps.iter().map(|step| step[g]);
                    add_facet_steps((m, h), values, first_step, (bins, per_unit));
                }
            });
    }

    /// Views of `size` consecutive facets each (the last may hold fewer), to each of which
    /// one task then adds the same `steps` steps ([`FacetRun::add_steps`]): a run that
    /// computes facet by facet instead of step by step. These statistics count the steps
    /// at once; every view must take them all.
    pub fn facet_runs(&mut self, size: usize, steps: usize) -> Vec<FacetRun<'_>> {
        let (bins, per_unit, first_step) = (self.bins, 1.0 / self.unit, self.steps);
        self.steps += steps as u64;
        (self.moments.chunks_mut(size.max(1)))
            .zip(self.hist.chunks_mut(size.max(1) * bins.count))
            .map(|(moments, hist)| FacetRun {
                moments,
                hist,
                bins,
                per_unit,
                first_step,
                steps,
            })
            .collect()
    }

    /// Merges statistics of the same facets and bins over the time range that follows
    /// this one's (darkness runs need the order; every other statistic does not). Exact:
    /// the result is bit-identical to one pass over both ranges.
    pub fn merge(&mut self, other: &FacetStats) {
        assert_eq!(self.bins, other.bins, "merging needs equal bins");
        assert_eq!(
            self.moments.len(),
            other.moments.len(),
            "merging needs equal facets"
        );
        if other.steps == 0 {
            return;
        }
        let (a_steps, b_steps) = (self.steps, other.steps);
        self.moments
            .par_iter_mut()
            .zip(other.moments.par_iter())
            .for_each(|(a, b)| a.merge_later(b, a_steps, b_steps));
        self.hist
            .par_chunks_mut(1 << 16)
            .zip(other.hist.par_chunks(1 << 16))
            .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(a, b)| *a += b));
        self.steps += other.steps;
    }

    /// Appends the facets of `other`, statistics over the same steps and bins of the
    /// facets that follow this one's (a run split by facet).
    pub fn append(&mut self, other: FacetStats) -> Result<(), String> {
        if self.bins != other.bins || self.steps != other.steps {
            return Err(format!(
                "facet parts differ: {} steps and {:?} against {} steps and {:?}",
                self.steps, self.bins, other.steps, other.bins
            ));
        }
        self.moments.extend(other.moments);
        self.hist.extend(other.hist);
        Ok(())
    }

    /// Writes the exact state, little-endian: per facet its moments (min, max: f64; Σq:
    /// i128; Σq²: u128 low, u64 high; lit: u64; darkness leading, trailing, longest: u32),
    /// then per facet its CDF counts as LEB128 varints, a run of zero counts written as
    /// a 0 followed by the run's length (a part of a run has few steps per facet, so most
    /// counts are 0 or small). Steps, bins and facets are the caller's to record
    /// ([`FacetStats::read_from`] needs them).
    pub fn write_to(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        for m in &self.moments {
            out.write_all(&m.min.to_le_bytes())?;
            out.write_all(&m.max.to_le_bytes())?;
            out.write_all(&m.sum.to_le_bytes())?;
            out.write_all(&m.squares.low.to_le_bytes())?;
            out.write_all(&m.squares.high.to_le_bytes())?;
            out.write_all(&m.lit.to_le_bytes())?;
            for run in [m.dark_leading, m.dark_trailing, m.dark_longest] {
                out.write_all(&run.to_le_bytes())?;
            }
        }
        let mut buffer = Vec::new();
        for counts in self.hist.chunks(self.bins.count.max(1)) {
            buffer.clear();
            encode_counts(counts, &mut buffer);
            out.write_all(&buffer)?;
        }
        Ok(())
    }

    /// Reads what [`FacetStats::write_to`] wrote for `facets` facets over `steps` steps.
    pub fn read_from(
        input: &mut &[u8],
        facets: usize,
        steps: u64,
        bins: Bins,
    ) -> std::io::Result<FacetStats> {
        let mut stats = FacetStats::new(0, bins);
        stats.steps = steps;
        stats.moments = take_moment_records(input, facets)?
            .chunks_exact(ENCODED_MOMENT_BYTES)
            .map(decode_moments)
            .collect();
        stats.hist = vec![0; facets * bins.count];
        for counts in stats.hist.chunks_mut(bins.count.max(1)) {
            add_counts(input, counts)?;
        }
        Ok(stats)
    }

    /// Merges what [`FacetStats::write_to`] wrote for these facets over the `steps` steps
    /// that follow this one's, reading it straight into these counts (no second set of
    /// CDF counts is held): the same result as [`FacetStats::read_from`] then
    /// [`FacetStats::merge`].
    pub fn merge_from(&mut self, input: &mut &[u8], steps: u64) -> std::io::Result<()> {
        let records = take_moment_records(input, self.moments.len())?;
        let before = self.steps;
        let hist = &mut self.hist;
        let per_facet = self.bins.count.max(1);
        // The counts are varints, read in order on one thread; the fixed-size moments
        // merge beside them on the others.
        let (counts, ()) = rayon::join(
            || {
                hist.chunks_mut(per_facet)
                    .try_for_each(|into| add_counts(input, into))
            },
            || {
                self.moments
                    .par_iter_mut()
                    .zip(records.par_chunks_exact(ENCODED_MOMENT_BYTES))
                    .for_each(|(a, r)| a.merge_later(&decode_moments(r), before, steps))
            },
        );
        counts?;
        self.steps += steps;
        Ok(())
    }

    /// Number of facets.
    pub fn facets(&self) -> usize {
        self.moments.len()
    }

    /// Number of steps accumulated.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The CDF thresholds.
    pub fn bins(&self) -> Bins {
        self.bins
    }

    /// Minimum irradiance of facet i, W/m².
    pub fn min(&self, i: usize) -> f64 {
        self.moments[i].min
    }

    /// Maximum irradiance of facet i, W/m².
    pub fn max(&self, i: usize) -> f64 {
        self.moments[i].max
    }

    /// Time-mean irradiance of facet i, W/m².
    pub fn mean(&self, i: usize) -> f64 {
        self.moments[i].sum as f64 / self.steps as f64 * self.unit
    }

    /// Standard deviation over time of facet i's irradiance, W/m²: from the exact
    /// integer n·Σq² − (Σq)² (module doc), rounded once.
    pub fn std(&self, i: usize) -> f64 {
        let m = &self.moments[i];
        let n = self.steps as f64;
        let spread = difference_as_f64(m.squares.times(self.steps), square(m.sum.unsigned_abs()));
        (spread / (n * n)).sqrt() * self.unit
    }

    /// Share of steps in which facet i was lit (E > 0).
    pub fn lit_fraction(&self, i: usize) -> f64 {
        self.moments[i].lit as f64 / self.steps as f64
    }

    /// The longest run of consecutive steps in which facet i was dark (E ≤ 0).
    pub fn longest_dark_steps(&self, i: usize) -> u32 {
        self.moments[i].dark_longest
    }

    /// F_i(x_b) for every threshold b: share of steps with E ≤ x_b.
    pub fn cdf(&self, i: usize) -> Vec<f64> {
        let h = &self.hist[i * self.bins.count..(i + 1) * self.bins.count];
        let mut acc = 0u64;
        h.iter()
            .map(|&c| {
                acc += c as u64;
                acc as f64 / self.steps as f64
            })
            .collect()
    }

    /// Raw histogram counts of facet i (see the field doc).
    pub fn histogram(&self, i: usize) -> &[u32] {
        &self.hist[i * self.bins.count..(i + 1) * self.bins.count]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestRng;

    fn series(facets: usize, steps: usize) -> Vec<Vec<f64>> {
        (0..steps)
            .map(|t| {
                (0..facets)
                    .map(|i| ((t * 7 + i * 13) % 23) as f64 * 9.7 - 40.0)
                    .map(|e| e.max(0.0))
                    .collect()
            })
            .collect()
    }

    #[test]
    fn merged_halves_equal_one_run() {
        let bins = Bins::covering(10.0, 200.0);
        let data = series(17, 101);
        let mut whole = FacetStats::new(17, bins);
        data.iter().for_each(|e| whole.add_step(e));
        let mut first = FacetStats::new(17, bins);
        let mut second = FacetStats::new(17, bins);
        data[..40].iter().for_each(|e| first.add_step(e));
        data[40..].iter().for_each(|e| second.add_step(e));
        first.merge(&second);
        assert_eq!(first, whole);
    }

    #[test]
    fn blocks_of_steps_equal_steps_one_by_one() {
        // More facets than one parallel task takes, with dark runs across blocks.
        let facets = 2 * FACETS_PER_TASK + 5;
        let bins = Bins::covering(10.0, 200.0);
        let data = series(facets, 61);
        let mut single = FacetStats::new(facets, bins);
        data.iter().for_each(|e| single.add_step(e));
        let mut rng = TestRng::new(0x2545_f491_4f6c_dd1d);
        let mut blocked = FacetStats::new(facets, bins);
        let mut k = 0;
        while k < data.len() {
            let len = (1 + rng.next_u64() as usize % 17).min(data.len() - k);
            let block: Vec<&[f64]> = data[k..k + len].iter().map(Vec::as_slice).collect();
            blocked.add_steps(&block);
            k += len;
        }
        assert_eq!(blocked, single);
        assert_eq!(
            blocked.longest_dark_steps(facets - 1),
            longest_dark_by_scan(&data.iter().map(|s| s[facets - 1]).collect::<Vec<_>>())
        );
    }

    /// Runs of facets each taking every step of a range at once, after steps added the
    /// usual way, equal the steps added one by one (the last run shorter, dark runs
    /// across the two ranges), the values given step by step or facet by facet.
    #[test]
    fn runs_of_facets_over_every_step_equal_steps_one_by_one() {
        let (facets, size) = (37, 8);
        let bins = Bins::covering(10.0, 200.0);
        let data = series(facets, 45);
        let mut single = FacetStats::new(facets, bins);
        data.iter().for_each(|e| single.add_step(e));
        for by_facet in [false, true] {
            let mut by_runs = FacetStats::new(facets, bins);
            data[..9].iter().for_each(|e| by_runs.add_step(e));
            let later = &data[9..];
            for (r, mut run) in by_runs
                .facet_runs(size, later.len())
                .into_iter()
                .enumerate()
            {
                let facets = r * size..r * size + run.len();
                if by_facet {
                    let values: Vec<f64> = (facets.clone())
                        .flat_map(|i| later.iter().map(move |step| step[i]))
                        .collect();
                    run.add_series(&values);
                } else {
                    let values: Vec<f64> = (later.iter())
                        .flat_map(|step| step[facets.clone()].iter().copied())
                        .collect();
                    run.add_steps(&values);
                }
            }
            assert_eq!(by_runs, single, "facet by facet: {by_facet}");
        }
    }

    #[test]
    fn kept_facets_of_global_steps_equal_their_values_gathered() {
        // Two runs of kept facets across a task boundary, out of more in all.
        let facets = 2 * FACETS_PER_TASK + 40;
        let ranges = vec![
            3..FACETS_PER_TASK + 7,
            FACETS_PER_TASK + 20..2 * FACETS_PER_TASK + 31,
        ];
        let kept = Selection::new(ranges.clone(), facets);
        let bins = Bins::covering(10.0, 200.0);
        let data = series(facets, 23);
        let mut of_global = FacetStats::new(kept.count(), bins);
        for block in data.chunks(6) {
            let steps: Vec<&[f64]> = block.iter().map(Vec::as_slice).collect();
            of_global.add_steps_of(&steps, &kept);
        }
        let mut gathered = FacetStats::new(kept.count(), bins);
        for step in &data {
            let values: Vec<f64> = ranges
                .iter()
                .flat_map(|r| step[r.clone()].iter().copied())
                .collect();
            gathered.add_step(&values);
        }
        assert_eq!(of_global, gathered);
    }

    #[test]
    fn any_partition_merged_in_any_tree_is_bit_identical_to_one_pass() {
        let bins = Bins::covering(25.0, 1400.0);
        let mut rng = TestRng::new(0x9e37_79b9_7f4a_7c15);
        // Values with every magnitude from 1e-9 to the flux, zeros and exact thresholds.
        let data: Vec<Vec<f64>> = (0..257)
            .map(|_| {
                (0..9)
                    .map(|_| match rng.next_u64() % 5 {
                        0 => 0.0,
                        1 => 25.0 * (rng.next_u64() % 57) as f64,
                        _ => {
                            1400.0 * (rng.next_u64() >> 11) as f64
                                / (1u64 << 53) as f64
                                / 10f64.powi((rng.next_u64() % 12) as i32)
                        }
                    })
                    .collect()
            })
            .collect();
        let mut whole = FacetStats::new(9, bins);
        data.iter().for_each(|e| whole.add_step(e));
        for trial in 0..40 {
            // Cut the steps at random points into 1 to 20 parts.
            let parts = 1 + rng.next_u64() as usize % 20;
            let mut cuts: Vec<usize> = (1..parts)
                .map(|_| rng.next_u64() as usize % data.len())
                .collect();
            cuts.extend([0, data.len()]);
            cuts.sort_unstable();
            let mut pieces: Vec<FacetStats> = cuts
                .windows(2)
                .map(|w| {
                    let mut p = FacetStats::new(9, bins);
                    data[w[0]..w[1]].iter().for_each(|e| p.add_step(e));
                    p
                })
                .collect();
            // Merge neighbours chosen at random until one is left: every tree shape.
            while pieces.len() > 1 {
                let k = rng.next_u64() as usize % (pieces.len() - 1);
                let right = pieces.remove(k + 1);
                pieces[k].merge(&right);
            }
            assert_eq!(pieces[0], whole, "trial {trial}, {parts} parts");
        }
    }

    #[test]
    fn the_state_reads_back_as_written() {
        let bins = Bins::covering(10.0, 200.0);
        let mut s = FacetStats::new(17, bins);
        series(17, 33).iter().for_each(|e| s.add_step(e));
        let mut bytes = Vec::new();
        s.write_to(&mut bytes).unwrap();
        assert!(bytes.len() < 17 * (ENCODED_MOMENT_BYTES + 4 * bins.count));
        let back = FacetStats::read_from(&mut bytes.as_slice(), 17, 33, bins).unwrap();
        assert_eq!(back, s);
        assert!(FacetStats::read_from(&mut &bytes[..bytes.len() - 1], 17, 33, bins).is_err());
        // Read straight into earlier statistics: as read, then merged.
        let mut earlier = FacetStats::new(17, bins);
        series(17, 9).iter().for_each(|e| earlier.add_step(e));
        let mut merged = earlier.clone();
        merged.merge(&s);
        earlier.merge_from(&mut bytes.as_slice(), 33).unwrap();
        assert_eq!(earlier, merged);
    }

    #[test]
    fn a_selection_within_a_range_counts_among_the_selected() {
        // Bodies of 4, 3 (no outputs) and 5 facets: kept ids 0..4 and 7..12.
        let kept = Selection::new(vec![0..4, 7..12], 12);
        let values: Vec<f64> = (0..12).map(f64::from).collect();
        let mut buffer = Vec::new();
        let part = kept.clone().within(Some(2..6));
        assert_eq!(part.count(), 4);
        assert_eq!(part.pick(&values, &mut buffer), &[2.0, 3.0, 7.0, 8.0]);
        let all = Selection::all(12).within(Some(0..12));
        assert_eq!(all.pick(&values, &mut buffer).len(), 12);
        assert_eq!(kept.within(None).count(), 9);
    }

    #[test]
    fn facet_parts_appended_equal_one_pass() {
        let bins = Bins::covering(10.0, 200.0);
        let data = series(17, 50);
        let mut whole = FacetStats::new(17, bins);
        data.iter().for_each(|e| whole.add_step(e));
        let mut left = FacetStats::new(5, bins);
        let mut right = FacetStats::new(12, bins);
        for e in &data {
            left.add_step(&e[..5]);
            right.add_step(&e[5..]);
        }
        left.append(right).unwrap();
        assert_eq!(left, whole);
        let short = FacetStats::new(3, bins);
        assert!(left.append(short).unwrap_err().contains("50 steps"));
    }

    #[test]
    fn a_constant_flux_has_its_exact_mean_and_no_spread() {
        // Welford's running mean of a constant is exact too, but its m2 need not be 0 on
        // values that are not representable sums; the exact sums give 0 and the value.
        let bins = Bins::covering(1.0, 1361.0);
        let mut s = FacetStats::new(1, bins);
        let e = 1361.0 / 3.0;
        for _ in 0..10_007 {
            s.add_step(&[e]);
        }
        assert_eq!(s.std(0), 0.0);
        assert!((s.mean(0) - e).abs() <= 1e-13 * e, "{}", s.mean(0) - e);
    }

    #[test]
    fn a_large_mean_with_a_tiny_spread_keeps_the_spread() {
        // 1000 ± 1e-6 W/m²: the std is 1e-6 exactly (half the steps each way); a
        // one-pass Σx² − (Σx)²/n in f64 would lose it to cancellation (ε·1000² ≫ 1e-12).
        let bins = Bins::covering(1.0, 1361.0);
        let mut s = FacetStats::new(1, bins);
        for t in 0..1000 {
            s.add_step(&[if t % 2 == 0 {
                1000.0 + 1e-6
            } else {
                1000.0 - 1e-6
            }]);
        }
        assert!((s.std(0) - 1e-6).abs() <= 1e-9, "{}", s.std(0));
        assert!((s.mean(0) - 1000.0).abs() <= 1e-12);
    }

    /// The longest run of dark steps, counted by a plain scan.
    fn longest_dark_by_scan(xs: &[f64]) -> u32 {
        let (mut run, mut longest) = (0u32, 0u32);
        for &x in xs {
            run = if x > 0.0 { 0 } else { run + 1 };
            longest = longest.max(run);
        }
        longest
    }

    #[test]
    fn darkness_runs_match_a_scan_and_merge_exactly_in_any_split() {
        // Dark stretches at the start, the end, across split points, and a facet always
        // dark and one never dark.
        let steps: usize = 97;
        let data: Vec<Vec<f64>> = (0..steps)
            .map(|t| {
                vec![
                    if (t / 7) % 3 == 0 { 0.0 } else { 5.0 },
                    if (20..=80).contains(&t) { 1.0 } else { 0.0 },
                    0.0,
                    1.0,
                    if t % 2 == 0 { 0.0 } else { 1.0 },
                ]
            })
            .collect();
        let bins = Bins::covering(10.0, 20.0);
        let scan: Vec<u32> = (0..5)
            .map(|i| longest_dark_by_scan(&data.iter().map(|e| e[i]).collect::<Vec<_>>()))
            .collect();
        assert_eq!(scan, vec![7, 20, 97, 0, 1]);
        for parts in [1, 2, 3, 7, 13] {
            let mut merged = FacetStats::new(5, bins);
            let per = steps.div_ceil(parts);
            for chunk in data.chunks(per) {
                let mut part = FacetStats::new(5, bins);
                chunk.iter().for_each(|e| part.add_step(e));
                merged.merge(&part);
            }
            for (i, expected) in scan.iter().enumerate() {
                assert_eq!(
                    merged.longest_dark_steps(i),
                    *expected,
                    "{parts} parts, facet {i}"
                );
            }
        }
    }

    #[test]
    fn moments_match_two_pass_formulas() {
        let data = series(5, 64);
        let mut s = FacetStats::new(5, Bins::covering(10.0, 200.0));
        data.iter().for_each(|e| s.add_step(e));
        for i in 0..5 {
            let xs: Vec<f64> = data.iter().map(|e| e[i]).collect();
            let mean = xs.iter().sum::<f64>() / xs.len() as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
            assert!((s.mean(i) - mean).abs() < 1e-12);
            assert!((s.std(i) - var.sqrt()).abs() < 1e-12);
            let below_50 = xs.iter().filter(|&&x| x <= 50.0).count() as f64 / xs.len() as f64;
            assert_eq!(s.cdf(i)[5], below_50);
            assert_eq!(*s.cdf(i).last().unwrap(), 1.0);
        }
    }

    #[test]
    fn bin_index_is_the_ceiling_of_the_ratio() {
        for width in [0.1, 1.0, 3.0, 10.0, 1e-300] {
            let bins = Bins {
                width_w_m2: width,
                count: 1 << 20,
            };
            let reference = |e: f64| {
                if e <= 0.0 {
                    0
                } else {
                    ((e / width).ceil() as usize).min(bins.count - 1)
                }
            };
            let mut rng = TestRng::new(0x1234_5678_9abc_def1);
            let mut values = vec![
                0.0,
                -0.0,
                -5.0,
                f64::NAN,
                f64::INFINITY,
                f64::MIN_POSITIVE,
                5e-324,
                1e300,
                // Ratios about 2⁶³, where a signed conversion saturates.
                width * 2f64.powi(63),
                width * 1.5 * 2f64.powi(63),
                width * 2f64.powi(64),
            ];
            for k in 0..2000 {
                let on = k as f64 * width;
                // Thresholds and the floats on either side of them.
                values.extend([
                    on,
                    f64::from_bits(on.to_bits() + 1),
                    f64::from_bits(on.to_bits().saturating_sub(1)),
                ]);
                values.push(rng.unit() * 1400.0);
            }
            for e in values {
                assert_eq!(bins.index(e), reference(e), "width {width}, value {e:e}");
            }
        }
    }

    #[test]
    fn values_on_thresholds_count_as_at_most() {
        let bins = Bins::covering(10.0, 30.0);
        let mut s = FacetStats::new(1, bins);
        for e in [0.0, 10.0, 20.0, 20.000001, 30.0] {
            s.add_step(&[e]);
        }
        assert_eq!(s.cdf(0), vec![0.2, 0.4, 0.6, 1.0]);
    }
}
