//! What the benchmarks share: command-line options, the thread count, the test body (a
//! mesh file, km, optionally subdivided) spinning under a fixed Sun, and peak memory.
//! `folded` builds the bilobed test shape.

pub mod folded;

use glam::DVec3;
use slim::ephemeris::spin::{Spin, SpinModel};
use slim::ephemeris::EpochState;
use slim::horizon::Shadows;
use slim::illum::Direct;
use slim::mesh::{generate::subdivide, inspect::inspect, read_mesh, LengthUnit, Mesh, RawMesh};
use slim::prepare::epoch_states;
use slim::world::{Body, World};
use std::path::PathBuf;

/// Itokawa's spin period, seconds: the benchmarks' spin.
const SPIN_PERIOD_S: f64 = 12.13 * 3600.0;

/// The command line: `[MESH] [--flag value]…`; `flags` are the flags that take a value.
pub struct Options {
    argv: Vec<String>,
    flags: &'static [&'static str],
}

impl Options {
    /// This process's arguments; `flags` lists every flag that takes a value.
    pub fn from_env(flags: &'static [&'static str]) -> Options {
        Options {
            argv: std::env::args().skip(1).collect(),
            flags,
        }
    }

    /// The value after `flag`, parsed, or `None` when the flag is absent.
    pub fn optional<T: std::str::FromStr>(&self, flag: &str) -> Result<Option<T>, String> {
        match self.argv.iter().position(|a| a == flag) {
            None => Ok(None),
            Some(k) => match self.argv.get(k + 1) {
                None => Err(format!("{flag} needs a value")),
                Some(v) => v
                    .parse()
                    .map(Some)
                    .map_err(|_| format!("{flag}: cannot read the value {v:?}")),
            },
        }
    }

    /// The value after `flag`, parsed, or `default` when the flag is absent.
    pub fn value<T: std::str::FromStr>(&self, flag: &str, default: T) -> Result<T, String> {
        Ok(self.optional(flag)?.unwrap_or(default))
    }

    /// True when the switch `flag` (a flag without a value) is given.
    pub fn has(&self, flag: &str) -> bool {
        self.argv.iter().any(|a| a == flag)
    }

    /// An error naming the first argument that starts with `--` but is neither a flag
    /// that takes a value nor one of `switches`, and any second positional argument.
    pub fn check(&self, switches: &[&str]) -> Result<(), String> {
        let mut positional = 0;
        let mut k = 0;
        while k < self.argv.len() {
            let a = self.argv[k].as_str();
            if self.flags.contains(&a) {
                k += 2;
                continue;
            }
            if a.starts_with("--") && !switches.contains(&a) {
                let known: Vec<&str> = self.flags.iter().chain(switches).copied().collect();
                return Err(format!("unknown flag {a} (known: {})", known.join(", ")));
            }
            if !a.starts_with("--") {
                positional += 1;
                if positional > 1 {
                    return Err(format!("unexpected argument {a}: give at most one mesh"));
                }
            }
            k += 1;
        }
        Ok(())
    }

    /// The argument that is neither a flag nor a flag's value, if any.
    pub fn positional(&self) -> Option<PathBuf> {
        let argv = &self.argv;
        argv.iter()
            .enumerate()
            .find(|(k, a)| {
                !a.starts_with("--") && (*k == 0 || !self.flags.contains(&argv[k - 1].as_str()))
            })
            .map(|(_, a)| PathBuf::from(a))
    }

    /// The mesh: the argument that is neither a flag nor a flag's value, or the
    /// 49,152-facet Itokawa model.
    pub fn mesh(&self) -> PathBuf {
        self.positional().unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("data/shapes/itokawa/ItokawaHayabusa.obj")
        })
    }

    /// `--threads N` (0 or absent: rayon's default) applied to the global pool.
    pub fn apply_threads(&self) -> Result<(), Box<dyn std::error::Error>> {
        let threads: usize = self.value("--threads", 0)?;
        if threads > 0 {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build_global()?;
        }
        Ok(())
    }

    /// One body from the mesh (km) subdivided `--subdivide` times (×4 facets per level,
    /// same shape), `default_subdivide` when the flag is absent.
    pub fn world(&self, default_subdivide: u32) -> Result<World, Box<dyn std::error::Error>> {
        self.world_from(read_mesh(&self.mesh(), None)?, default_subdivide)
    }

    /// One body from `raw` (km) subdivided as in [`Options::world`].
    pub fn world_from(
        &self,
        raw: RawMesh,
        default_subdivide: u32,
    ) -> Result<World, Box<dyn std::error::Error>> {
        let levels: u32 = self.value("--subdivide", default_subdivide)?;
        let raw = (0..levels).fold(raw, |m, _| subdivide(&m));
        let mesh = Mesh::from_raw(raw, LengthUnit::Km);
        let convex = inspect(&mesh).convex;
        Ok(World {
            bodies: vec![Body::new("body", mesh, convex)],
        })
    }
}

/// `steps` states over one spin of the body about z, the Sun at 1 AU along `sun_dir`.
pub fn spin_states(steps: usize, sun_dir: DVec3) -> Result<Vec<EpochState>, slim::Error> {
    epoch_states(&SpinModel {
        start: hifitime::Epoch::from_tdb_seconds(0.0),
        duration_s: SPIN_PERIOD_S,
        steps,
        sun_dir_scene: sun_dir.normalize(),
        sun_distance_m: slim::AU_M,
        solar_constant_w_m2: slim::SOLAR_CONSTANT_W_M2,
        bodies: vec![Spin {
            period_s: Some(SPIN_PERIOD_S),
            initial_angle_rad: 0.0,
            position_m: DVec3::ZERO,
        }],
    })
}

/// The direct stage with a horizon map of every body, built or read from the cache as
/// `shadows` says (each for its body's band in `shadows.bands`, as `slim run` sets them
/// from its steps); the few rays a map leaves go to the BVH, as in `slim run`.
pub fn mapped_direct<'w>(world: &'w World, shadows: &Shadows) -> Result<Direct<'w>, slim::Error> {
    let maps = (world.bodies.iter().enumerate())
        .map(|(b, body)| {
            shadows
                .obtain(body, shadows.band(b), &slim::progress::Silent)
                .map(|(map, _)| Some(map))
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Direct::with_maps(
        world,
        slim::trace::TracerKind::Bvh,
        maps,
        shadows,
    ))
}

/// Peak resident memory of this process, MB (Linux; 0 elsewhere).
pub fn peak_rss_mb() -> f64 {
    proc_status_mb("VmHWM:")
}

/// A memory line of /proc/self/status (`VmHWM:`, `VmRSS:`…), MB (Linux; 0 elsewhere).
pub fn proc_status_mb(key: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}
