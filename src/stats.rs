//! Stats: streaming, mergeable per-facet statistics of irradiance over time.
//!
//! In: one irradiance value (W/m²) per facet per step, all steps of equal weight. Out, per
//! facet: minimum, maximum, mean, standard deviation (population, over time), lit fraction
//! (share of steps with E > 0) and the cumulative distribution F_k(x_b) = share of steps
//! with E ≤ x_b at thresholds x_b = b·w, b = 0 … B (SLIM paper eq. 14).
//!
//! Memory is O(facets × bins), never O(facets × steps). Mean and variance use Welford's
//! update; two partial results over disjoint time ranges merge with the pairwise formula
//! of Chan, Golub & LeVeque (1979), so a run split in pieces and merged equals one run
//! (min, max, counts exactly; mean and std to rounding). Each facet is updated in step
//! order by one thread, so results do not depend on the number of threads.

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
            ((e / self.width_w_m2).ceil() as usize).min(self.count - 1)
        }
    }
}

/// Running moments of one facet.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Moments {
    min: f64,
    max: f64,
    mean: f64,
    m2: f64,
    lit: u64,
    /// Runs of dark steps (E ≤ 0): from the first step on, up to the last step, and the
    /// longest anywhere. Consecutive time ranges merge exactly: the longest run is the
    /// longest of either or the first's trailing run joined to the second's leading run.
    dark_leading: u32,
    dark_trailing: u32,
    dark_longest: u32,
}

const EMPTY: Moments = Moments {
    min: f64::INFINITY,
    max: f64::NEG_INFINITY,
    mean: 0.0,
    m2: 0.0,
    lit: 0,
    dark_leading: 0,
    dark_trailing: 0,
    dark_longest: 0,
};

/// The facets whose statistics a run keeps (those of the bodies that get outputs), as
/// ranges of global facet ids in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// `None`: every facet.
    ranges: Option<Vec<std::ops::Range<usize>>>,
    count: usize,
}

impl Selection {
    /// The facets in `ranges` out of `facets` in all.
    pub fn new(ranges: Vec<std::ops::Range<usize>>, facets: usize) -> Selection {
        let count = ranges.iter().map(|r| r.len()).sum();
        Selection {
            ranges: (count < facets).then_some(ranges),
            count,
        }
    }

    /// Every one of `facets` facets.
    pub fn all(facets: usize) -> Selection {
        Selection {
            ranges: None,
            count: facets,
        }
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

/// Statistics of every facet over the steps seen so far.
#[derive(Debug, Clone, PartialEq)]
pub struct FacetStats {
    bins: Bins,
    steps: u64,
    moments: Vec<Moments>,
    /// `hist[i·bins + b]`: steps with x_{b−1} < E ≤ x_b (b = 0: E ≤ 0).
    hist: Vec<u32>,
}

impl FacetStats {
    /// Empty statistics for `facets` facets.
    pub fn new(facets: usize, bins: Bins) -> FacetStats {
        FacetStats {
            bins,
            steps: 0,
            moments: vec![EMPTY; facets],
            hist: vec![0; facets * bins.count],
        }
    }

    /// Adds one step: `irradiance[i]` is facet i's value in W/m².
    pub fn add_step(&mut self, irradiance: &[f64]) {
        assert_eq!(irradiance.len(), self.moments.len(), "one value per facet");
        let before = self.steps;
        self.steps += 1;
        let n = self.steps as f64;
        let bins = self.bins;
        self.moments
            .par_iter_mut()
            .zip(self.hist.par_chunks_mut(bins.count))
            .zip(irradiance.par_iter())
            .for_each(|((m, h), &e)| {
                m.min = m.min.min(e);
                m.max = m.max.max(e);
                let delta = e - m.mean;
                m.mean += delta / n;
                m.m2 += delta * (e - m.mean);
                if e > 0.0 {
                    m.lit += 1;
                    m.dark_trailing = 0;
                } else {
                    if m.dark_leading as u64 == before {
                        m.dark_leading = m.dark_leading.saturating_add(1);
                    }
                    m.dark_trailing = m.dark_trailing.saturating_add(1);
                    m.dark_longest = m.dark_longest.max(m.dark_trailing);
                }
                h[bins.index(e)] += 1;
            });
    }

    /// Merges statistics of the same facets and bins over the time range that follows
    /// this one's (darkness runs need the order; every other statistic does not).
    pub fn merge(&mut self, other: &FacetStats) {
        assert_eq!(self.bins, other.bins, "merging needs equal bins");
        assert_eq!(
            self.moments.len(),
            other.moments.len(),
            "merging needs equal facets"
        );
        let (na, nb) = (self.steps as f64, other.steps as f64);
        let n = na + nb;
        if other.steps == 0 {
            return;
        }
        for (a, b) in self.moments.iter_mut().zip(&other.moments) {
            let delta = b.mean - a.mean;
            a.min = a.min.min(b.min);
            a.max = a.max.max(b.max);
            a.mean += delta * nb / n;
            a.m2 += b.m2 + delta * delta * na * nb / n;
            a.lit += b.lit;
            let a_dark_throughout = a.dark_leading as u64 == self.steps;
            let b_dark_throughout = b.dark_leading as u64 == other.steps;
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
        for (a, b) in self.hist.iter_mut().zip(&other.hist) {
            *a += b;
        }
        self.steps += other.steps;
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
        self.moments[i].mean
    }

    /// Standard deviation over time of facet i's irradiance, W/m².
    pub fn std(&self, i: usize) -> f64 {
        (self.moments[i].m2.max(0.0) / self.steps as f64).sqrt()
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
        assert_eq!(first.steps(), whole.steps());
        for i in 0..17 {
            assert_eq!(first.min(i), whole.min(i));
            assert_eq!(first.max(i), whole.max(i));
            assert_eq!(first.lit_fraction(i), whole.lit_fraction(i));
            assert_eq!(first.longest_dark_steps(i), whole.longest_dark_steps(i));
            assert_eq!(first.histogram(i), whole.histogram(i));
            assert!((first.mean(i) - whole.mean(i)).abs() <= 1e-12 * whole.mean(i).abs().max(1.0));
            assert!((first.std(i) - whole.std(i)).abs() <= 1e-12 * whole.std(i).abs().max(1.0));
        }
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
    fn values_on_thresholds_count_as_at_most() {
        let bins = Bins::covering(10.0, 30.0);
        let mut s = FacetStats::new(1, bins);
        for e in [0.0, 10.0, 20.0, 20.000001, 30.0] {
            s.add_step(&[e]);
        }
        assert_eq!(s.cdf(0), vec![0.2, 0.4, 0.6, 1.0]);
    }
}
