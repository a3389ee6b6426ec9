//! Budget: the memory a run will hold, estimated before it is allocated.
//!
//! In: a [`Demand`] — the counts a scene asks for (facets, bodies, steps, CDF thresholds,
//! the sets of statistics kept, history, form-factor entries) — and the memory a run may
//! use ([`Budget`], bytes). Out: an [`Estimate`] in bytes, item by item, that the plan
//! prints and `run.json` keeps; or, when the total is above the budget, an
//! [`Error::OverBudget`] naming the total, the largest item and the key that shrinks it.
//!
//! [`crate::prepare`] checks twice: from the scene alone before any mesh is built or read
//! (generated facets and steps, so that a 2 kB scene cannot ask for 20 million facets), and
//! with the exact counts before the step geometry, statistics and form factors are
//! allocated. The sizes per item are the engine's own structures; docs/performance.md
//! compares estimates with measured peaks.

use crate::error::{Error, Result};
use crate::horizon::shadows::{RECALL_MAX_BYTES, RECALL_MAX_LAG};
use serde::{Deserialize, Serialize};

/// The memory a run may use, bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budget {
    pub max_bytes: u64,
    /// Where the limit comes from and how it is raised, for the refusal.
    pub source: &'static str,
}

/// The share of the machine's memory a run may use by default.
const MACHINE_SHARE: f64 = 0.75;

/// The default when the machine's memory cannot be read (not Linux): 8 GiB.
const FALLBACK_BYTES: u64 = 8 << 30;

/// The share of a run's memory budget the remembered blockers may take at most: they
/// only save time, so they shrink before a run is refused.
const REMEMBERED_BLOCKER_SHARE: f64 = 0.125;

impl Budget {
    /// Three quarters of the machine's memory (`MemTotal` in `/proc/meminfo`), or 8 GiB
    /// where that cannot be read.
    pub fn machine() -> Budget {
        let total = std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|text| mem_total_bytes(&text));
        Budget {
            max_bytes: total.map_or(FALLBACK_BYTES, |t| (t as f64 * MACHINE_SHARE) as u64),
            source: "three quarters of this machine's memory by default; --max-memory sets it",
        }
    }

    /// `Ok` when `estimate` fits, else an error naming the total, the budget and where it
    /// comes from, the largest item and what shrinks it.
    pub fn check(&self, estimate: &Estimate) -> Result<()> {
        let total = estimate.total_bytes();
        if total <= self.max_bytes {
            return Ok(());
        }
        let largest = estimate
            .items
            .iter()
            .max_by_key(|i| i.bytes)
            .expect("an estimate over a budget has items");
        Err(Error::OverBudget(format!(
            "the run needs about {} of memory, more than the {} it may use ({}); the \
             largest part is {} ({}): {}",
            human_bytes(total),
            human_bytes(self.max_bytes),
            self.source,
            largest.what,
            human_bytes(largest.bytes),
            largest.shrink
        )))
    }

    /// The most memory the shadow rays' remembered blockers may take in a run under this
    /// budget, bytes: [`RECALL_MAX_BYTES`], and an eighth of the budget at most.
    pub fn remembered_blocker_bytes(&self) -> f64 {
        RECALL_MAX_BYTES.min(self.max_bytes as f64 * REMEMBERED_BLOCKER_SHARE)
    }
}

impl Default for Budget {
    fn default() -> Self {
        Budget::machine()
    }
}

/// `MemTotal` of a `/proc/meminfo` text, bytes.
fn mem_total_bytes(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// Parses a size such as `8G`, `512M`, `1.5GiB` or `1000000` (bytes); K, M, G and T are
/// powers of 1024.
pub fn parse_bytes(text: &str) -> Option<u64> {
    let t = text.trim();
    let digits = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(digits);
    let scale: u64 = match unit.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 1,
        "K" | "KB" | "KIB" => 1 << 10,
        "M" | "MB" | "MIB" => 1 << 20,
        "G" | "GB" | "GIB" => 1 << 30,
        "T" | "TB" | "TIB" => 1 << 40,
        _ => return None,
    };
    let bytes = number.parse::<f64>().ok()? * scale as f64;
    (bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64).then_some(bytes as u64)
}

/// A byte count as people read it: `1.5 GiB`, `320 MiB`.
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit < UNITS.len() - 1 {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 || value >= 100.0 {
        format!("{value:.0} {}", UNITS[unit])
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

/// The counts a run asks for. Counts are floats so that absurd scenes (1e30 steps) are
/// estimated, not overflowed.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Demand {
    /// Facets of all bodies.
    pub facets: f64,
    /// Facets of surrounding terrain, which only casts shadows.
    pub surrounding_facets: f64,
    /// Facets of the bodies without outputs (counted in `facets`; no statistics kept).
    pub silent_facets: f64,
    pub bodies: f64,
    pub steps: f64,
    /// CDF thresholds per facet (0 before they are known).
    pub bins: f64,
    /// Sets of per-facet statistics kept: 1 for the total, 3 with scattered light (total,
    /// direct, scattered), and more for spectral bands.
    pub stat_sets: f64,
    /// Values per facet the block of steps computed together holds: steps per block
    /// times buffers per step (`simulate::steps_per_batch`, `simulate::step_buffers`).
    pub block_values: f64,
    /// Whether the per-step history is written.
    pub history: bool,
    /// Form-factor entries the scattered light stores (an upper bound from the pairs
    /// that face each other).
    pub form_factor_entries: f64,
    /// Bytes of the SPICE kernel files.
    pub kernel_bytes: f64,
    /// Bytes of the horizon maps the run uses.
    pub horizon_map_bytes: f64,
    /// Bytes of the blockers that the shadow rays through the BVH tracer's horizon bounds
    /// remember ([`crate::horizon::Shadows::bound_walk_bytes`]; a map's are counted
    /// with it).
    pub remembered_blocker_bytes: f64,
    /// Bytes a run taken facet by facet holds for its chunks of facets
    /// ([`crate::illum::sweep_bytes`]; 0 for a run taken step by step).
    pub sweep_bytes: f64,
    /// Steps whose direct light is kept for the later steps that repeat them
    /// ([`crate::simulate::Repetition::computed`]; 0 when nothing repeats).
    pub repeat_values: f64,
}

/// Bytes per facet of the mesh (vertices, triangles, centroids, normals, areas), its
/// inspection and the shadow tracer's index, as measured on the shipped meshes.
pub const GEOMETRY_BYTES_PER_FACET: f64 = 400.0;

/// Bytes per step and body of the step geometry kept for the run and of its `geometry`
/// table, plus the per-step part that does not depend on the bodies: 616 B per step of
/// one body measured over two million steps.
const STATE_BYTES_PER_STEP: f64 = 96.0;
const STATE_BYTES_PER_BODY_STEP: f64 = 520.0;

/// The program, its threads and libraries before any scene is loaded (12 MB measured).
const BASE_BYTES: f64 = 16.0 * 1024.0 * 1024.0;

/// SPICE kernels are held in memory as read and once more as parsed.
const KERNEL_COPIES: f64 = 2.0;

/// Bytes per facet of one set of statistics besides its CDF counts (min, max, exact
/// sums, lit steps, darkness runs), and per CDF count.
const MOMENT_BYTES: f64 = crate::stats::MOMENT_BYTES as f64;
const CDF_COUNT_BYTES: f64 = 4.0;

/// The rows the CDF table is written in at a time (see [`crate::output`]), and its bytes
/// per row and set of statistics in a batch: as built (facet, threshold and value, 20 B),
/// its Arrow copy while the CSV encoder shares it (20 B) and the body name's text (8 B).
pub const CDF_ROWS_PER_BATCH: usize = 1 << 18;
const CDF_ROW_BYTES: f64 = 48.0;

/// Rows the history table holds before it writes them out, and its bytes per row once
/// encoded (5 MB measured for 32,000 facets × 360 steps).
const HISTORY_BUFFER_ROWS: f64 = (1u64 << 20) as f64;
const HISTORY_ROW_BYTES: f64 = 8.0;
/// Bytes per facet of a step's history batch as built: step, epoch, facet, the values
/// (up to three) and the body name's text.
const HISTORY_BATCH_BYTES: f64 = 56.0;

/// Batches of a table held at once: one being built, one waiting and one being encoded
/// (`output::table`).
const BATCHES_IN_FLIGHT: f64 = 3.0;

/// Bytes per form-factor entry at the peak of building: the rows as computed (8 B) and
/// the packed block with its transpose (up to 16 B).
const FORM_FACTOR_ENTRY_BYTES: f64 = 24.0;

/// One item of an estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Item {
    /// What holds the memory.
    pub what: String,
    pub bytes: u64,
    /// What makes it smaller.
    pub shrink: String,
}

/// The memory a run will hold, item by item.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub items: Vec<Item>,
}

impl Estimate {
    /// The sum of the items, bytes.
    pub fn total_bytes(&self) -> u64 {
        self.items
            .iter()
            .fold(0, |sum, i| sum.saturating_add(i.bytes))
    }

    fn push(&mut self, what: &str, bytes: f64, shrink: &str) {
        if bytes > 0.0 {
            self.items.push(Item {
                what: what.into(),
                // Saturating: an absurd scene estimates at u64::MAX bytes, and is refused.
                bytes: if bytes.is_finite() {
                    bytes.min(u64::MAX as f64) as u64
                } else {
                    u64::MAX
                },
                shrink: shrink.into(),
            });
        }
    }
}

impl std::fmt::Display for Estimate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "about {}", human_bytes(self.total_bytes()))?;
        let parts: Vec<String> = self
            .items
            .iter()
            .map(|i| format!("{} {}", i.what, human_bytes(i.bytes)))
            .collect();
        if !parts.is_empty() {
            write!(f, " ({})", parts.join(", "))?;
        }
        Ok(())
    }
}

impl Demand {
    /// Facets whose statistics are kept and written.
    fn reported(&self) -> f64 {
        self.facets - self.silent_facets
    }

    /// The memory these counts take, item by item.
    pub fn estimate(&self) -> Estimate {
        let mut e = Estimate::default();
        e.push("program", BASE_BYTES, "nothing: this is the program itself");
        e.push(
            "SPICE kernels",
            self.kernel_bytes * KERNEL_COPIES,
            "load only the kernels the scene needs (subsets of large SPKs)",
        );
        e.push(
            "meshes and shadow index",
            (self.facets + self.surrounding_facets) * GEOMETRY_BYTES_PER_FACET,
            "use a coarser mesh (fewer facets or ellipsoid levels) or coarser surroundings",
        );
        e.push(
            "step geometry",
            self.steps * (STATE_BYTES_PER_STEP + self.bodies * STATE_BYTES_PER_BODY_STEP),
            "use fewer steps (a shorter window or longer steps), or split the run in time",
        );
        e.push(
            "statistics",
            self.stat_sets * self.reported() * (MOMENT_BYTES + CDF_COUNT_BYTES * self.bins),
            "use wider CDF bins (run.bin_width_w_m2), fewer bands, or a coarser mesh",
        );
        e.push(
            "per-step irradiance",
            self.facets * 8.0 * (self.block_values + 2.0 + 3.0 * self.stat_sets),
            "use a coarser mesh",
        );
        if self.sweep_bytes > 0.0 {
            e.push(
                "chunks of facets over every step",
                self.sweep_bytes,
                "use fewer steps (a shorter window or longer steps), or split the run in time",
            );
        }
        if self.repeat_values > 0.0 {
            e.push(
                "repeated steps' light",
                self.facets * 8.0 * self.repeat_values,
                "use fewer steps per period (the light of one period is kept) or a coarser mesh",
            );
        }
        let cdf_rows = (self.reported() * self.bins).min(CDF_ROWS_PER_BATCH as f64);
        e.push(
            "CDF table batches",
            cdf_rows * CDF_ROW_BYTES * self.stat_sets.min(3.0) * BATCHES_IN_FLIGHT,
            "use wider CDF bins (run.bin_width_w_m2)",
        );
        if self.history {
            e.push(
                "history buffer",
                (self.reported() * self.steps).min(HISTORY_BUFFER_ROWS) * HISTORY_ROW_BYTES
                    + self.reported() * HISTORY_BATCH_BYTES * BATCHES_IN_FLIGHT,
                "switch the history off (output.history = false)",
            );
        }
        e.push(
            "horizon maps",
            self.horizon_map_bytes,
            "use fewer azimuth wedges (run.horizon_azimuths) or run.shadows = \"rays\"",
        );
        e.push(
            "remembered blockers",
            self.remembered_blocker_bytes,
            &format!(
                "use a coarser mesh (the rays keep the blockers of up to {RECALL_MAX_LAG} steps \
                 back, at most {} MiB and an eighth of the memory limit, and 12 bytes of \
                 neighbours per facet)",
                RECALL_MAX_BYTES / (1024.0 * 1024.0)
            ),
        );
        e.push(
            "form factors",
            self.form_factor_entries * FORM_FACTOR_ENTRY_BYTES,
            "use a coarser mesh for scattered light, or raise scatter.inter_body_tolerance \
             to leave out blocks between bodies",
        );
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blockers take 512 MiB at most, and an eighth of a smaller budget.
    #[test]
    fn remembered_blockers_take_an_eighth_of_a_budget_at_most() {
        let budget = |max_bytes| Budget {
            max_bytes,
            source: "a test",
        };
        assert_eq!(
            budget(2 << 30).remembered_blocker_bytes(),
            (256 << 20) as f64
        );
        assert_eq!(
            budget(64 << 30).remembered_blocker_bytes(),
            RECALL_MAX_BYTES
        );
    }

    #[test]
    fn sizes_parse_in_powers_of_1024() {
        assert_eq!(parse_bytes("8G"), Some(8 << 30));
        assert_eq!(parse_bytes("512 MiB"), Some(512 << 20));
        assert_eq!(parse_bytes("1.5gb"), Some(3 << 29));
        assert_eq!(parse_bytes("1000"), Some(1000));
        for bad in ["", "G", "-1G", "0", "1e400", "12 parsecs", "nan"] {
            assert_eq!(parse_bytes(bad), None, "{bad}");
        }
    }

    #[test]
    fn meminfo_total_is_read_in_kib() {
        let text = "MemTotal:       24576000 kB\nMemFree:        100 kB\n";
        assert_eq!(mem_total_bytes(text), Some(24_576_000 * 1024));
        assert_eq!(mem_total_bytes("nothing here"), None);
    }

    #[test]
    fn the_statistics_of_a_fine_cdf_are_facets_times_bins_counts() {
        // 63,000 facets with 0.1 W/m² bins up to 1,400 W/m²: 14,001 counts of 4 bytes each,
        // the case the hardening issue measured at more than 10 GB with 8-byte counts.
        let d = Demand {
            facets: 63_000.0,
            bodies: 1.0,
            steps: 360.0,
            bins: 14_001.0,
            stat_sets: 1.0,
            block_values: 2.0,
            ..Demand::default()
        };
        let stats = d
            .estimate()
            .items
            .into_iter()
            .find(|i| i.what == "statistics");
        let expected = 63_000.0 * (MOMENT_BYTES + 4.0 * 14_001.0);
        assert_eq!(stats.unwrap().bytes, expected as u64);
    }

    #[test]
    fn an_absurd_demand_is_refused_naming_its_largest_part() {
        let d = Demand {
            facets: 1e3,
            bodies: 1.0,
            steps: 1e30,
            stat_sets: 1.0,
            block_values: 2.0,
            ..Demand::default()
        };
        let budget = Budget {
            max_bytes: 1 << 30,
            source: "--max-memory",
        };
        let err = budget.check(&d.estimate()).unwrap_err().to_string();
        assert!(err.contains("step geometry"), "{err}");
        assert!(err.contains("--max-memory"), "{err}");
        assert!(err.contains("1.0 GiB"), "{err}");
    }

    #[test]
    fn a_small_run_fits() {
        let d = Demand {
            facets: 5120.0,
            bodies: 1.0,
            steps: 360.0,
            bins: 150.0,
            stat_sets: 1.0,
            block_values: 2.0,
            ..Demand::default()
        };
        let e = d.estimate();
        // The program, then mostly the CDF table's batch of 262,144 rows.
        assert!(e.total_bytes() < 64 << 20, "{e}");
        let budget = Budget {
            max_bytes: 1 << 30,
            source: "",
        };
        assert!(budget.check(&e).is_ok());
    }
}
