//! # slim — sunlight on airless bodies
//!
//! slim computes the direct solar irradiance on every facet of one or more triangle meshes
//! (asteroids, moons, comet nuclei, terrain patches) over time, with cast shadows between
//! facets and between bodies, and reduces each facet's irradiance history to statistics:
//! minimum, maximum, mean, standard deviation, lit fraction and the cumulative distribution
//! F_k(x) (the fraction of time facet k receives at most x W/m²).
//!
//! The modules, in the order data flows through a run:
//!
//! ```text
//! scene.toml ─► scene ─► prepare ─┬─► mesh (OBJ, PLY, STL, PDS) ─► world (bodies, f64, own frames)
//!                                 ├─► ephemeris (spin, fixed Suns, SPICE): EpochState per step
//!                                 └─► plan (what runs, what is left out, why)
//!                                          │
//!               trace (shadow queries) ◄───┤
//!                                          ▼
//!                                      simulate, per step:
//!                                        illum     direct irradiance E = S·max(0, n·s), shadowed
//!                                        scatter   light scattered between facets (optional)
//!                                        bands     per spectral band (optional)
//!                                          ▼
//!                                      stats (streaming, mergeable) ─► output (tables, PLY, run.json)
//!                                                                         │
//!          run: one scene into one folder (prepare, simulate, output)     ▼
//!                                                    report / serve read the files back
//! ```
//!
//! | stage | module | in → out |
//! |---|---|---|
//! | scene file | [`scene`] | TOML → a validated [`scene::Scene`] (paths resolved, every key checked) |
//! | assembly | [`prepare`] | scene → kernels, [`world::World`], [`ephemeris::Ephemeris`], epoch states, bins, [`plan::Plan`] |
//! | shapes | [`mesh`] | mesh files → triangles in metres; inspection; generated ellipsoids |
//! | bodies | [`world`] | meshes and poses in the scene frame |
//! | geometry | [`ephemeris`] | epochs → Sun direction (unit), distance (m), flux (W/m²), poses |
//! | decisions | [`plan`] | scene and world → the stages that run and why |
//! | memory | [`budget`] | counts (facets, steps, bins, pairs) → bytes, checked before allocating |
//! | shadows | [`trace`] | exact shadow rays: uniform grid, Sun-view grid, BVH |
//! | horizons | [`horizon`] | mesh → horizon bounds and maps (cached); the solar disk; eclipses by ellipsoids |
//! | direct light | [`illum`] | one epoch → W/m² per facet, with shadows |
//! | reflectance | [`photometry`] | Lambert, Lommel–Seeliger, Hapke: r (sr⁻¹), I/F |
//! | scattered light | [`scatter`] | direct W/m² → scattered W/m² (form factors, Jacobi/CG) |
//! | spectral bands | [`bands`] | per-band irradiance and statistics |
//! | panels | [`panel`] | a place, height and panel → its horizon; per step W/m² and W on the panel |
//! | sight | [`sight`] | a place and another body → its elevation over the horizon, windows of sight |
//! | traverses | [`route`] | a body's facets, their light over time and a rover → a planned or evaluated route: times, energy, charge, darkness, cost |
//! | caches | [`cache`] | horizon maps and form factors kept on disk between runs |
//! | build journals | [`journal`] | a long build's finished parts, kept so that a stopped build resumes |
//! | step loop | [`simulate`] | world and states → statistics, each step's irradiance |
//! | statistics | [`stats`] | per-step W/m² → min, max, mean, std, lit fraction, CDF |
//! | files | [`output`] | statistics → Parquet/CSV tables, PLY, `run.json`; and read back |
//! | a whole run | [`run`] | scene and folder → the files and the [`output::record::RunRecord`] |
//! | parts of a run | [`shard`] | a time or facet part → its exact partial state; parts → one run's files, byte-identical; Slurm array jobs |
//! | progress | [`progress`] | notes, steps done, stage timings |
//! | integrals | [`quadrature`] | Gauss–Legendre nodes for disk and cap integrals |
//! | validation | [`analytic`] | closed-form irradiance of a rotating sphere |
//! | errors | [`error`] | one typed error with file, line, key, body or epoch |
//! | images (`imaging`) | `render`, `fit`, `compare`, `image` | camera images, fits of reflectance to images, χ² of histograms, FITS/PNG |
//! | reports (`report`) | `report` | a finished run → figures and an HTML page |
//! | service (`serve`) | `serve` | the HTTP service: jobs, files, queries |
//!
//! The last three rows are Cargo features, on by default; `--no-default-features` builds
//! the engine alone (and a `slim run` that writes CSV). The `slim` command line lives in
//! the binary (`src/main.rs`, `src/cli.rs`), not in this library.

#![forbid(unsafe_code)]

pub mod analytic;
pub mod atomic;
pub mod bands;
pub mod budget;
pub mod cache;
#[cfg(feature = "imaging")]
pub mod compare;
pub mod ephemeris;
pub mod error;
#[cfg(feature = "imaging")]
pub mod fit;
pub mod horizon;
pub mod illum;
#[cfg(feature = "imaging")]
pub mod image;
pub mod journal;
pub mod mesh;
pub mod output;
pub mod panel;
pub mod photometry;
pub mod plan;
pub mod prepare;
pub mod progress;
pub mod quadrature;
#[cfg(feature = "imaging")]
pub mod render;
#[cfg(feature = "report")]
pub mod report;
pub mod route;
pub mod run;
pub mod scatter;
pub mod scene;
#[cfg(feature = "serve")]
pub mod serve;
pub mod shard;
pub mod sight;
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

/// `bytes` without a leading UTF-8 byte-order mark: what the text readers read (text
/// meshes and headers, text kernels, albedo files; the TOML reader skips the mark
/// itself), so that a file saved "with BOM" is read like the same file without it.
pub(crate) fn without_bom(bytes: &[u8]) -> &[u8] {
    bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes)
}

/// Fresh folders for unit tests, removed when dropped: the integration tests' own
/// ([`TempDir`]), shared rather than written again.
#[cfg(test)]
#[path = "../tests/common/temp_dir.rs"]
mod temp_dir;
#[cfg(test)]
pub(crate) use temp_dir::TempDir;

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
