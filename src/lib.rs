//! # slim — sunlight on airless bodies
//!
//! slim computes the direct solar irradiance on every facet of one or more triangle meshes
//! (asteroids, moons, comet nuclei, terrain patches) over time, with cast shadows between
//! facets and between bodies, and reduces each facet's irradiance history to statistics:
//! minimum, maximum, mean, standard deviation, lit fraction and the cumulative distribution
//! F_k(x) (the fraction of time facet k receives at most x W/m²).
//!
//! The modules follow the pipeline:
//!
//! ```text
//! scene.toml ─► scene ─► mesh ─► world ─► ephemeris (per epoch: Sun in each body frame, poses)
//!                                  │
//!                                  ├─► trace (uniform grid reference, sun-parallel fast path)
//!                                  ▼
//!                    illum (direct irradiance per facet per epoch)
//!                                  ▼
//!                    scatter (optional: light scattered between facets, all orders)
//!                                  ▼
//!                    stats (streaming, mergeable) ─► output (Parquet, CSV, PLY, run.json)
//! ```
//!
//! [`run::run_scene`] drives the whole pipeline; [`plan`] decides what a scene needs;
//! [`serve`] puts it behind an HTTP service (`slim serve`).

pub mod analytic;
pub mod bands;
pub mod cli;
pub mod compare;
pub mod ephemeris;
pub mod error;
pub mod fit;
pub mod illum;
pub mod image;
pub mod mesh;
pub mod output;
pub mod photometry;
pub mod plan;
pub mod prepare;
pub mod progress;
pub mod render;
pub mod report;
pub mod run;
pub mod scatter;
pub mod scene;
pub mod serve;
pub mod simulate;
pub mod stats;
pub mod trace;
pub mod world;

pub use error::{Error, Result};

/// Solar irradiance at 1 AU in W/m² used unless a scene sets its own.
pub const SOLAR_CONSTANT_W_M2: f64 = 1361.0;

/// One astronomical unit in metres (IAU 2012).
pub const AU_M: f64 = 149_597_870_700.0;

/// A file name's extension in lower case, empty when it has none (or is not UTF-8): what
/// the readers dispatch on (mesh, kernel and image formats).
pub(crate) fn lowercase_extension(path: &std::path::Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

/// A seeded xorshift generator for unit tests' random cases: reproducible, and not the
/// code under test.
#[cfg(test)]
pub(crate) struct TestRng(u64);

#[cfg(test)]
impl TestRng {
    pub(crate) fn new(seed: u64) -> TestRng {
        TestRng(seed.max(1))
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}
