//! Progress: how a long run reports what it does, and how long each stage took.
//!
//! In: calls from the pipeline as it goes (notes, steps done). Out: whatever the
//! receiver makes of them — the CLI draws a bar, the service tracks its jobs, tests
//! ignore them ([`Silent`]). [`Timings`] adds up wall-clock seconds per named stage for
//! `run.json`.

use std::time::Instant;

/// Receives progress of a run.
pub trait Progress: Sync {
    /// A line worth showing the user (the plan, warnings).
    fn note(&self, line: &str);
    /// The step loop starts with `steps` steps.
    fn begin_steps(&self, steps: u64);
    /// One more step is done.
    fn step_done(&self);
    /// The step loop is over.
    fn end_steps(&self);
    /// True when the run should stop early (checked before each step); the run then
    /// fails with [`crate::Error::Cancelled`] and writes no result.
    fn cancelled(&self) -> bool {
        false
    }
}

/// Progress that goes nowhere.
pub struct Silent;

impl Progress for Silent {
    fn note(&self, _: &str) {}
    fn begin_steps(&self, _: u64) {}
    fn step_done(&self) {}
    fn end_steps(&self) {}
}

/// Wall-clock timings of named stages, seconds, in the order the stages first ran.
#[derive(Debug, Default, Clone)]
pub struct Timings(pub Vec<(String, f64)>);

impl Timings {
    /// Runs `f`, adding its wall time to `stage`.
    pub fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        let t0 = Instant::now();
        let value = f();
        let dt = t0.elapsed().as_secs_f64();
        match self.0.iter_mut().find(|(s, _)| s == stage) {
            Some((_, total)) => *total += dt,
            None => self.0.push((stage.to_string(), dt)),
        }
        value
    }
}
