//! Shadows: how each body's own shadows are found, chosen before the run.
//!
//! In: the scene's `[run]` keys `shadows`, `horizon_mode`, `horizon_azimuths`, `sun`,
//! `limb_darkening` and `cache_dir` ([`Shadows`]), the world and the number of steps.
//! Out: per body, rays or a [`HorizonMap`] (with the reason, printed in the plan and
//! kept in `run.json`), and the maps themselves — read from the cache or built there.
//!
//! `shadows = "auto"` picks a map when one is cached for the mesh, or when the run is
//! long enough that building one costs less than the rays it spares (break-even below).
//! In the exact horizon mode every facet–step the map cannot decide for certain is
//! traced, so the choice never changes a result; the approximate mode and the Sun as a
//! disk read the horizon from the map alone.

use super::band::SunBand;
use super::bound::{BoundDetail, HorizonBound};
use super::cache;
use super::disk::SolarDisk;
use super::map::{
    HorizonMap, MapKind, MapParts, AZIMUTHS_MAX, AZIMUTHS_MIN, CEILING_BYTES, MAP_PART,
};
use crate::cache::Lookup;
use crate::ephemeris::{sun_return, EpochState, SunReturn};
use crate::error::{Error, Result};
use crate::journal::Journal;
use crate::progress::Progress;
use crate::trace::bvh::Bvh;
use crate::trace::{choice, TracerKind};
use crate::world::{Body, World};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `[run] shadows`: how a body's own shadows are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ShadowMethod {
    /// A horizon map when it is cached or pays for itself, rays otherwise.
    #[default]
    Auto,
    /// A shadow ray per facet facing the Sun, every step.
    Rays,
    /// A horizon map per body that can shadow itself.
    Horizon,
}

/// `[run] horizon_mode`: how a horizon map decides.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum HorizonMode {
    /// The map decides where it is certain (the Sun above its wedge's upper bound); a ray
    /// decides the rest, so a point Sun's lit/dark classification equals the tracers'.
    #[default]
    Exact,
    /// The map decides everything from its interpolated horizon (no rays).
    Approximate,
}

/// `[run] sun`: the Sun as a point or as a disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SunShape {
    #[default]
    Point,
    /// A disk of the angular radius seen at each step's Sun distance: the visible share
    /// above the horizon, from the map; without one, the share above the facet's own
    /// plane, times the share of the disk's samples its own body leaves in view (rays,
    /// none on a convex body or where the BVH tracer's bound clears the whole disk).
    Disk,
}

/// The shadow settings of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct Shadows {
    pub method: ShadowMethod,
    pub mode: HorizonMode,
    pub azimuths: u32,
    pub sun: SunShape,
    pub disk: SolarDisk,
    /// Rays per facet through the disk Sun toward another body's mesh (generated
    /// ellipsoids need none: their share is a closed form), and through the body's own
    /// where no horizon map decides.
    pub sun_samples: u32,
    /// Where maps are cached; `None`: not cached.
    pub cache_dir: Option<PathBuf>,
    /// How finely the BVH tracer's horizon bounds follow the horizon (the run's length
    /// decides: [`bound_detail_for_run`]).
    pub bound_detail: BoundDetail,
    /// The earlier step whose blockers a step's shadow rays start from, where they
    /// remember any ([`Shadows::remembers_blockers`]; the run's steps decide:
    /// [`crate::ephemeris::sun_return`]).
    pub recall: SunReturn,
    /// Whether the run takes its steps facet by facet along the Sun's path
    /// ([`crate::illum::Direct::sweep`]; the run's outputs and bodies decide:
    /// `prepare`), so that no ray recalls blockers. Before the maps are chosen: whether
    /// it would without a map, which a map must then beat.
    pub sweeps: bool,
    /// Per body (in the world's order), the directions its Sun takes over the steps a map
    /// serves ([`Shadows::bands_for_run`], set before the maps are chosen): a map is built for
    /// them alone. A body past the end of the list takes [`SunBand::WHOLE`].
    pub bands: Vec<SunBand>,
}

impl Default for Shadows {
    fn default() -> Self {
        Shadows {
            method: ShadowMethod::Rays,
            mode: HorizonMode::Exact,
            azimuths: DEFAULT_AZIMUTHS,
            sun: SunShape::Point,
            disk: SolarDisk {
                limb_darkening: 0.0,
            },
            sun_samples: DEFAULT_SUN_SAMPLES,
            cache_dir: None,
            bound_detail: BoundDetail::Whole,
            recall: SunReturn::UNKNOWN,
            sweeps: false,
            bands: Vec::new(),
        }
    }
}

/// Where a map's centre horizons are read, its band is widened by this share of a wedge's
/// width ([`Shadows::bands_for_run`]). A Sun's horizon is interpolated between the
/// centres of the wedges either side of it, up to a wedge away, where the band stands at
/// other elevations: a centre the band leaves lower than the whole mesh's (below or above
/// the band there) moves the interpolated horizon. With a third of a wedge the
/// approximate mode errs against rays as often as with the map of every direction
/// (`a_map_for_the_suns_band_classifies_as_the_grid` in tests/physics.rs: Haworth, Suns
/// circling 4° up, 64 wedges: on 2,786 facet–Suns of 443,411 against 2,787; without the
/// widening on 3,766).
pub const CENTRES_HEADROOM: f64 = 1.0 / 3.0;

/// Azimuth wedges of a map unless the scene says otherwise (2.8° each).
pub const DEFAULT_AZIMUTHS: u32 = 128;

/// Disk samples toward other bodies' meshes unless the scene says otherwise: the hidden
/// share then comes in steps of 1/32 (see docs/accuracy.md).
pub const DEFAULT_SUN_SAMPLES: u32 = 32;

/// Under a horizon bound, rays remember their blockers when the Sun stands within this
/// many degrees of where it stood at the step they recall (with a bound by sectors, also
/// when that is not known). Walks always against never (`bench_peer`, one thread): under
/// a whole bound at 49k (2026-11-28) they changed the step by −22 % at 0.2°, −18 % at
/// 1°, −13 % at 2°, 0 at 5°, +12 % at 10° and +17 % at 30°; under a bound by sectors
/// (2026-11-29) at 10° by +25 % at 786k, +16 % on the folded shape and +6–40 % at 49k,
/// at 5° by +23 %, −18 % and +7 %. Within it, each group of facets walks only while its
/// walks pay (`illum`'s `WalkYield`); beyond it nothing is kept for them (16 bytes a
/// facet).
pub const RECALL_DEG: f64 = 5.0;

/// The most steps back that shadow rays look for a Sun near their own: an hourly Phobos
/// needs 23 (three of its 7.65 h spins), an hourly 12 h spin 12, Itokawa's 12.13 h spin
/// in hourly steps 97 (eight spins, where the Sun stands 1.2° from its place; one spin
/// back it stands 3.7° away, where the walks of a whole bound's rays no longer pay).
pub const RECALL_MAX_LAG: usize = 128;

/// The most memory the remembered blockers may take (4 bytes per facet and step back),
/// and never more than an eighth of the run's memory budget
/// ([`crate::budget::Budget::remembered_blocker_bytes`]): 97 steps back at 786,432
/// facets take 305 MB.
pub const RECALL_MAX_BYTES: f64 = 512.0 * 1024.0 * 1024.0;

/// The most steps back whose blockers `facets` facets may keep: [`RECALL_MAX_LAG`], or
/// as many rows of 4 bytes per facet as `max_bytes` holds, at least one.
fn recall_rows_within_memory(facets: usize, max_bytes: f64) -> usize {
    let fits = (max_bytes / (4.0 * facets.max(1) as f64)) as usize;
    fits.clamp(1, RECALL_MAX_LAG)
}

/// The earlier step whose blockers the rays of a run over `states` recall: where the Sun
/// returns in the frames of the bodies that can shadow themselves (an occluder turns at
/// its own pace), at most [`RECALL_MAX_LAG`] steps back and fewer where their blockers
/// would pass `max_bytes` ([`crate::budget::Budget::remembered_blocker_bytes`]).
pub fn recall_for_run(world: &World, states: &[EpochState], max_bytes: f64) -> SunReturn {
    let shadowing: Vec<usize> = (world.bodies.iter().enumerate())
        .filter(|(_, b)| !b.convex)
        .map(|(i, _)| i)
        .collect();
    let facets = shadowing.iter().map(|&b| world.bodies[b].mesh.len()).sum();
    sun_return(
        states,
        &shadowing,
        recall_rows_within_memory(facets, max_bytes),
    )
}

/// The most disk samples a scene may ask for.
pub const SUN_SAMPLES_MAX: u32 = 1024;

/// Measured costs behind `auto` and the build's announced time (CPU seconds, 128 wedges;
/// see docs/performance.md). Building a map costs per facet a fixed part and a part that
/// grows with the casting facets N. A horizon is a line across the mesh, which suggests
/// √N, but the Itokawa builds grow faster (one thread, 2026-11-26: 12,288 facets 0.18 ms,
/// 49,152 0.39 ms, 786,432 subdivided 2.5 ms per facet; 0.35 ms at 49k on 2026-11-28):
/// as N^(2/3), fitted as a bound above them all, the fit gives 0.20, 0.44 and 2.52 ms,
/// and 0.34 for m1phobos's 32,070 (0.24 measured) — where a √N fit through the 786k
/// build gave 0.36, 0.67 and 0.55, announcing the smaller maps' builds at up to twice
/// their time and building them later than they pay. Terrain ([`Body::open`]), whose
/// horizons are far and low all around, costs about four times more and keeps a √N term
/// of its own, a bound above Haworth's 5,412 facets (0.84 ms; 1.24 on the Intel machine
/// of 2026-11-26, where its year's patch with 9,528 facets of surroundings took 1.52,
/// the fit 1.37). The saving: what a map spares over Sun-view rays per facet and step in
/// the exact mode (m1phobos, 360 steps: 0.37 µs).
///
/// A map for a band of Sun directions ([`SunBand`]) searches only what meets the band's
/// cone, so its growing part shrinks by [`band_share`].
fn build_s_per_facet(body: &Body, band: SunBand) -> f64 {
    let casters = body.shadow_mesh().len() as f64;
    let growing = match body.open {
        true => 10.8e-6 * casters.sqrt(),
        false => 0.29e-6 * casters.powf(2.0 / 3.0),
    };
    0.05e-3 + growing * band_share(band, casters)
}

/// The share of a whole map's growing cost that a map for `band` over `casters` facets
/// takes: `(N / 49,152)^(−1/3) × (0.2 + 0.06 × w)`, `w` the band's half-width in degrees,
/// never above one. The cone a thin band leaves meets the surface along a line through
/// each facet, not all around it, and the finer the mesh, the smaller its part of the
/// facets a whole search opens. With the whole map's fit it gives a bound above the
/// band's builds of 2026-12-03 (CPU per facet, one thread unless said, Intel Xeon;
/// measured against the model): Itokawa 49,152 facets at ±0.1° 0.061 ms against 0.130,
/// at ±1.0° 0.079 against 0.151; m1phobos at ±1.0° 0.081 against 0.138; 786,432 facets at
/// ±1.0°, two threads, 0.216 against 0.305; Haworth's year (5,412 facets, 14,940 with its
/// surroundings) at ±2.8° 0.70 against 0.77. As shares of the whole map's measured build:
/// 0.17, 0.23, 0.32 and 0.14 (786k: 170 against 1,254 s of CPU); at 49k ±5° 0.42 and
/// ±15° 0.78.
fn band_share(band: SunBand, casters: f64) -> f64 {
    if band.is_whole() {
        return 1.0;
    }
    let (lo, hi) = band.degrees();
    let half_width = 0.5 * (hi - lo);
    ((casters / 49152.0).powf(-1.0 / 3.0) * (0.2 + 0.06 * half_width)).min(1.0)
}

/// CPU seconds the map of `body` for `band` takes to build (its facets against all it
/// casts from).
fn build_seconds(body: &Body, band: SunBand) -> f64 {
    body.mesh.len() as f64 * build_s_per_facet(body, band)
}

const SAVED_S_PER_FACET_STEP: f64 = 0.37e-6;

/// What a map spares per facet and step over the BVH tracer's rays (CPU seconds), for a
/// point Sun and for a disk Sun of 32 samples: m1phobos, 360 steps on one thread
/// (`bench_direct MESH --threads 1` with `--tracer bvh`, `--horizon exact`, `--sun
/// disk`; 2026-11-26): the BVH 2.30 ms per step (disk, with the cones' leaf screen of
/// a4318f1: 11.9), the map 1.26 (disk: 1.28). Checked for a point Sun on 2026-11-28
/// (`bench_peer MESH --tracer map-exact|bvh-sectors|bvh --steps 360 --threads 1`): the
/// exact map spares 0.052 µs (m1phobos) and 0.049 µs (Itokawa) over the whole bound, but
/// only 0.012 and 0.011 µs over the bound by sectors refined by outlines (the same run,
/// later that morning), which a run long enough for a map takes (with 1° steps; steps
/// far apart leave sectors less). 0.032 lies between.
const SAVED_OVER_BVH: (f64, f64) = (0.032e-6, 0.33e-6);

/// What a map spares per facet and step over the BVH's rays where the run takes its
/// steps facet by facet ([`Shadows::sweeps`]), for a point Sun and for a disk Sun of 32
/// samples (CPU seconds). Whole runs of the true-hour year of Itokawa (12.132371 h spin,
/// `bench/common.sh`'s `hourly_scene`) on 2 threads, the map cached against
/// `shadows = "rays"`: a disk Sun at 49k facets 5.2 s against 15.8 s, 0.049 µs; at 786k
/// 75.0 s against 508.6 s, 0.126 µs (2026-12-03, Intel Xeon, one run each, the disk's
/// lookups sparing a disk wholly above a facet's cells, [`HorizonMap::disk_above_all`]);
/// the smaller is taken. A point Sun's sweep of that year at 786k took 55.6 s in all
/// (2026-11-29), less than the disk's map lookups alone then: a map spares it next to
/// nothing.
const SAVED_OVER_SWEEP: (f64, f64) = (0.002e-6, 0.049e-6);

impl Shadows {
    /// Checks the settings, naming the key at fault.
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(AZIMUTHS_MIN..=AZIMUTHS_MAX).contains(&self.azimuths) {
            return Err(format!(
                "run.horizon_azimuths = {} is outside {AZIMUTHS_MIN}..={AZIMUTHS_MAX}",
                self.azimuths
            ));
        }
        let u = self.disk.limb_darkening;
        if !(0.0..=1.0).contains(&u) {
            return Err(format!("run.limb_darkening = {u} is outside 0..=1"));
        }
        if !(1..=SUN_SAMPLES_MAX).contains(&self.sun_samples) {
            return Err(format!(
                "run.sun_samples = {} is outside 1..={SUN_SAMPLES_MAX}",
                self.sun_samples
            ));
        }
        Ok(())
    }

    /// Per body, whether it uses a horizon map, and why (for the plan); without one its
    /// own shadows take rays through `tracer`.
    pub fn choose(&self, world: &World, steps: usize, tracer: TracerKind) -> Vec<(bool, String)> {
        (world.bodies.iter().enumerate())
            .map(|(b, body)| self.choose_for(body, self.band(b), steps, tracer))
            .collect()
    }

    /// Whether a map decides every facet-step from its centre horizons, without a ray:
    /// in the approximate mode, and for a disk Sun.
    pub fn maps_decide_alone(&self) -> bool {
        self.mode == HorizonMode::Approximate || self.sun == SunShape::Disk
    }

    /// The kind of map a run builds: the centre horizons alone where they decide alone
    /// (no upper bound is ever read), else with the upper bounds.
    fn map_kind(&self) -> MapKind {
        match self.maps_decide_alone() {
            true => MapKind::Centres,
            false => MapKind::Bounded,
        }
    }

    /// Body `b`'s band: the directions its map must serve.
    pub fn band(&self, b: usize) -> SunBand {
        self.bands.get(b).copied().unwrap_or(SunBand::WHOLE)
    }

    /// Per body of `world`, the band its map needs to serve its Sun over `states` (the
    /// steps the map serves): a disk Sun widened by the largest angular radius it takes
    /// there, and where the map's centre horizons are read (the approximate mode, a disk
    /// Sun) by [`CENTRES_HEADROOM`] of a wedge more.
    pub fn bands_for_run(&self, world: &World, states: &[EpochState]) -> Vec<SunBand> {
        let headroom = match self.maps_decide_alone() {
            true => CENTRES_HEADROOM * std::f64::consts::TAU / self.azimuths as f64,
            false => 0.0,
        };
        (0..world.bodies.len())
            .map(|b| {
                let radius = match self.sun {
                    SunShape::Point => 0.0,
                    SunShape::Disk => (states.iter())
                        .map(|s| SolarDisk::angular_radius(s.bodies[b].sun_distance_m))
                        .fold(0.0, f64::max),
                };
                SunBand::of_suns(
                    states.iter().map(|s| s.bodies[b].sun_dir),
                    radius + headroom,
                )
            })
            .collect()
    }

    fn choose_for(
        &self,
        body: &Body,
        band: SunBand,
        steps: usize,
        tracer: TracerKind,
    ) -> (bool, String) {
        if body.convex {
            return (
                false,
                "closed convex surface: nothing of it rises above a facet's plane".into(),
            );
        }
        let facets = body.mesh.len();
        let bytes = facets as f64 * self.map_bytes_per_facet();
        let size = format!(
            "{facets} facets × {} wedges, {:.1} MB, for {band}",
            self.azimuths,
            bytes / 1e6
        );
        let mode = match (self.sun, self.mode) {
            (SunShape::Disk, _) => "the disk's visible share from the map's horizon, no rays",
            (_, HorizonMode::Exact) => "exact: rays where the map is not certain",
            (_, HorizonMode::Approximate) => "approximate: no rays",
        };
        let rays = match self.sun {
            SunShape::Point => "a ray per facet facing the Sun".to_string(),
            SunShape::Disk => format!(
                "rays toward {} points of the disk (run.sun_samples) from each facet whose \
                 view of it something may block",
                self.sun_samples
            ),
        };
        match self.method {
            ShadowMethod::Rays => (false, format!("run.shadows = \"rays\": {rays}")),
            ShadowMethod::Horizon => (true, format!("run.shadows = \"horizon\" ({mode}); {size}")),
            ShadowMethod::Auto => {
                if let Some(file) = self.cached_file(body, band) {
                    return (
                        true,
                        format!("cached in {} ({mode}); {size}", file.display()),
                    );
                }
                let per_facet = build_s_per_facet(body, band);
                let saved = self.saved_s_per_facet_step(tracer);
                let break_even = (per_facet / saved).ceil() as usize;
                if steps >= break_even {
                    (
                        true,
                        format!(
                            "{steps} steps ≥ {break_even}, where building it (about {:.0} s on \
                             one core) costs less than the rays it spares ({mode}); {size}",
                            build_seconds(body, band)
                        ),
                    )
                } else {
                    (
                        false,
                        format!(
                            "{steps} steps < {break_even}: rays cost less than building a map \
                             (run.shadows = \"horizon\" forces one): {rays}"
                        ),
                    )
                }
            }
        }
    }

    /// The rays per facet toward a disk Sun where rays decide; `None` for a point Sun
    /// (one ray).
    pub fn disk_samples(&self) -> Option<u32> {
        match self.sun {
            SunShape::Point => None,
            SunShape::Disk => Some(self.sun_samples),
        }
    }

    /// What a map spares per facet and step over the rays `tracer` traces instead: for a
    /// point Sun one ray, for a disk Sun rays toward its samples. The Sun-view grid's
    /// disk rays are each about as dear as a point Sun's one (each is a direction of its
    /// own). The BVH's are cheaper ([`SAVED_OVER_BVH`]), and cheaper still where the run
    /// would take its steps facet by facet without a map ([`Shadows::sweeps`] set
    /// before the choice; [`SAVED_OVER_SWEEP`]); `auto` counts as the BVH, which it
    /// takes for any run long enough for a map to pay.
    fn saved_s_per_facet_step(&self, tracer: TracerKind) -> f64 {
        let samples = self.sun_samples as f64;
        let bvh = matches!(tracer, TracerKind::Bvh | TracerKind::Auto);
        match (tracer, self.sun) {
            (_, SunShape::Point) if bvh && self.sweeps => SAVED_OVER_SWEEP.0,
            (_, SunShape::Disk) if bvh && self.sweeps => {
                SAVED_OVER_SWEEP.1 * samples / DEFAULT_SUN_SAMPLES as f64
            }
            (TracerKind::Bvh | TracerKind::Auto, SunShape::Point) => SAVED_OVER_BVH.0,
            (TracerKind::Bvh | TracerKind::Auto, SunShape::Disk) => {
                SAVED_OVER_BVH.1 * samples / DEFAULT_SUN_SAMPLES as f64
            }
            (_, SunShape::Point) => SAVED_S_PER_FACET_STEP,
            (_, SunShape::Disk) => SAVED_S_PER_FACET_STEP * samples,
        }
    }

    /// The cache file of a map of `body` that serves `band` when one is there (not yet
    /// checked): the band's own, else the map of every direction.
    fn cached_file(&self, body: &Body, band: SunBand) -> Option<PathBuf> {
        let dir = self.cache_dir.as_deref()?;
        (self.map_keys(body, band).into_iter())
            .map(|(key, ..)| cache::file_for(dir, &key))
            .find(|file| file.is_file())
    }

    /// The content keys of the maps of `body` that serve `band`, with the band and the
    /// kind each is built for: the band's own first, then (for a band short of every
    /// direction) the map of every direction, which serves any band; each of the run's
    /// kind first, then (for a map of centres) with the upper bounds, which serves too.
    fn map_keys(&self, body: &Body, band: SunBand) -> Vec<([u8; 32], SunBand, MapKind)> {
        let key = |band, kind| {
            let settings = (self.azimuths, band, kind);
            let key = cache::content_key(body.shadow_mesh(), body.mesh.len(), settings);
            (key, band, kind)
        };
        let bands = match band.is_whole() {
            true => vec![band],
            false => vec![band, SunBand::WHOLE],
        };
        let kinds = match self.map_kind() {
            MapKind::Centres => vec![MapKind::Centres, MapKind::Bounded],
            MapKind::Bounded => vec![MapKind::Bounded],
        };
        (bands.into_iter())
            .flat_map(|band| kinds.iter().map(move |&kind| key(band, kind)))
            .collect()
    }

    /// The BVH tracer's horizon bound of `body` (over `bvh`, built on its shadow mesh):
    /// read from the cache when an intact one is there, else built and stored (a bound
    /// that cannot be stored is only built again next time); with where it came from.
    pub fn bound(&self, body: &Body, bvh: &Bvh) -> (HorizonBound, BoundRecord) {
        let (mesh, receivers) = (body.shadow_mesh(), body.mesh.len());
        let file = self.bound_file(body);
        let mut record = BoundRecord {
            body: body.name.clone(),
            source: "cache".into(),
            file: file.as_ref().map(|(f, _)| f.clone()),
            build_s: 0.0,
            detail: self.bound_detail,
        };
        if let Some((file, key)) = &file {
            let lookup = cache::load_bound(file, key, mesh, (receivers, self.bound_detail));
            if let Lookup::Hit(bound) = lookup {
                return (bound, record);
            }
        }
        let started = Instant::now();
        let bound = HorizonBound::new(mesh, receivers, bvh, self.bound_detail);
        record.build_s = started.elapsed().as_secs_f64();
        record.source = "built".into();
        if let Some((file, key)) = &file {
            if cache::store_bound(file, key, &bound).is_err() {
                // Not kept: the next run builds it again.
                record.file = None;
            }
        }
        (bound, record)
    }

    /// Per body, whether its horizon bound is in the cache (a file is there; it is
    /// checked when read).
    pub fn cached_bounds(&self, world: &World) -> Vec<bool> {
        (world.bodies.iter())
            .map(|b| self.bound_file(b).is_some_and(|(f, _)| f.is_file()))
            .collect()
    }

    /// The cache file of `body`'s horizon bound and its content key.
    fn bound_file(&self, body: &Body) -> Option<(PathBuf, [u8; 32])> {
        let dir = self.cache_dir.as_deref()?;
        let key = cache::bound_key(body.shadow_mesh(), body.mesh.len(), self.bound_detail);
        Some((crate::cache::file_for(dir, &cache::BOUND_KIND, &key), key))
    }

    /// Memory the maps of the bodies in `uses` hold, bytes, with what the step loop keeps
    /// beside an exact map for a point Sun: its rays' remembered blockers and the edge
    /// neighbours their walks follow.
    pub fn map_bytes(&self, world: &World, uses: &[bool]) -> f64 {
        (world.bodies.iter().zip(uses))
            .filter(|(_, &u)| u)
            .map(|(b, _)| {
                b.mesh.len() as f64 * self.map_bytes_per_facet() + self.walk_bytes(b, true)
            })
            .sum()
    }

    /// Memory the blockers remembered by the shadow rays of the bodies that trace through
    /// the BVH tracer's horizon bound (`tracer`; the bodies without a map in `maps`),
    /// bytes: 4 per facet and step back, 12 per facet that casts shadows.
    pub fn bound_walk_bytes(&self, world: &World, maps: &[bool], tracer: TracerKind) -> f64 {
        if tracer != TracerKind::Bvh {
            return 0.0;
        }
        (choice::bounded(world, maps).iter())
            .map(|b| self.walk_bytes(b, false))
            .sum()
    }

    /// What the walks from remembered blockers keep for `body` (`map`: it has a horizon
    /// map), bytes, when its rays remember any: per facet the blocker of each of the
    /// [`SunReturn::lag`] steps back (4 bytes each) and, for every facet that casts
    /// shadows (the surroundings too), its neighbours across its edges, where the walk
    /// goes (12 bytes).
    fn walk_bytes(&self, body: &Body, map: bool) -> f64 {
        match self.remembers_blockers(map) {
            true => {
                let rows = self.recall.lag as f64;
                (body.mesh.len() as f64 * 4.0 * rows) + body.shadow_mesh().len() as f64 * 12.0
            }
            false => 0.0,
        }
    }

    /// Whether a body's own shadow rays toward a point Sun start from the blockers the
    /// same facets' rays met at an earlier step ([`SunReturn`]), walking the surface from
    /// there before the tracer (`map`: the body has a horizon map; else it has the BVH
    /// tracer's bound). An exact map's rays, mostly shadowed and in its uncertainty band,
    /// always. A bound's when the Sun comes back within [`RECALL_DEG`] of where it stood;
    /// a bound by sectors, whose rays are mostly shadowed, also when that is not known.
    pub fn remembers_blockers(&self, map: bool) -> bool {
        let point = self.sun == SunShape::Point;
        let turn = self.recall.turn_deg;
        let recalls = match map {
            true => self.mode == HorizonMode::Exact,
            false if self.bound_detail == BoundDetail::Sectors => {
                turn <= RECALL_DEG || turn.is_infinite()
            }
            false => turn <= RECALL_DEG,
        };
        point && recalls && !self.sweeps
    }

    /// A map's bytes per facet: its cells (4 per wedge) and its ceilings.
    fn map_bytes_per_facet(&self) -> f64 {
        self.azimuths as f64 * 4.0 + CEILING_BYTES as f64
    }

    /// The map of `body` for Suns of `band`: read from the cache when an intact one that
    /// serves the band is there (its own, or the map of every direction), built (and
    /// stored) otherwise. A build keeps its finished parts in a journal beside the cache
    /// file and goes on from the parts an earlier, stopped build left there; while
    /// another process builds the same map, this one waits for it.
    pub fn obtain(
        &self,
        body: &Body,
        band: SunBand,
        progress: &dyn Progress,
    ) -> Result<(HorizonMap, MapRecord)> {
        self.obtain_in_parts(body, band, progress, MAP_PART)
    }

    /// [`Shadows::obtain`], a build going by parts of `part` facets.
    fn obtain_in_parts(
        &self,
        body: &Body,
        band: SunBand,
        progress: &dyn Progress,
        part: usize,
    ) -> Result<(HorizonMap, MapRecord)> {
        let keys = self.map_keys(body, band);
        let (key, _, kind) = keys[0];
        let file = self.cache_dir.as_deref().map(|d| cache::file_for(d, &key));
        let mut record = MapRecord {
            body: body.name.clone(),
            azimuths: self.azimuths,
            band_deg: (!band.is_whole()).then(|| band.degrees().into()),
            bytes: 0,
            source: "cache".into(),
            file: file.clone(),
            build_s: 0.0,
            helped_parts: 0,
            kind,
        };
        let cached = |map: HorizonMap, (file, band): (&Path, SunBand), record: MapRecord| {
            progress.note(&format!(
                "horizon map of '{}': read from {}",
                body.name,
                file.display()
            ));
            let (bytes, kind) = (map.bytes(), map.kind());
            Ok((
                map,
                MapRecord {
                    bytes,
                    kind,
                    file: Some(file.to_path_buf()),
                    band_deg: (!band.is_whole()).then(|| band.degrees().into()),
                    ..record
                },
            ))
        };
        if let Some(dir) = &self.cache_dir {
            for &(key, served, kind) in &keys {
                let file = cache::file_for(dir, &key);
                match self.load(body, &file, (&key, kind)) {
                    Lookup::Hit(map) => return cached(map, (&file, served), record),
                    Lookup::Missing => {}
                    Lookup::Rejected(why) => progress.note(&format!(
                        "warning: horizon map cache {} not used ({why}); {}",
                        file.display(),
                        match served == band {
                            true => "rebuilding it",
                            false => "building the band's own",
                        }
                    )),
                }
            }
        }
        let casters = body.shadow_mesh();
        let bvh = Bvh::build(casters);
        let parts = MapParts::new(casters, body.mesh.len(), &bvh, (self.azimuths, band), part)
            .of_kind(kind);
        let journal = match &file {
            Some(file) => {
                let start = self.journal_or_wait(
                    body,
                    (file, &key),
                    &parts,
                    progress,
                    &mut record.helped_parts,
                )?;
                match start {
                    Start::Cached(map) => return cached(map, (file, band), record),
                    Start::Journal(j) => Some(j),
                    Start::Alone => None,
                }
            }
            None => None,
        };
        let helpers = file.as_deref().map(|f| (f, &key));
        let built = build_parts(body, &parts, journal, helpers, progress)?;
        record.source = if built.resumed { "resumed" } else { "built" }.into();
        record.build_s = built.seconds;
        record.bytes = built.map.bytes();
        if let Some(file) = &file {
            match cache::store(file, &key, &built.map) {
                // Stored: the journal has served. A failure to delete it only leaves a
                // file that a rebuild of this map would resume from.
                Ok(()) => {
                    if let Some(j) = built.journal {
                        j.finish().ok();
                    }
                    cache::clear_parts(file, parts.count());
                }
                Err(e) => {
                    progress.note(&format!("warning: horizon map not cached: {e}"));
                    record.file = None;
                }
            }
        }
        Ok((built.map, record))
    }

    /// The build journal beside the cache `file` of content `key`, with the parts it
    /// holds; while another process holds it (building the same map), helps it (builds
    /// the parts it has not reached, counted in `helped`) and waits until that process
    /// has stored the map (then read) or let go of the journal.
    fn journal_or_wait(
        &self,
        body: &Body,
        (file, key): (&Path, &[u8; 32]),
        parts: &MapParts,
        progress: &dyn Progress,
        helped: &mut usize,
    ) -> Result<Start> {
        let mut waiting = false;
        let started = Instant::now();
        let mut last_note = 0.0;
        loop {
            match cache::resume(file, key, parts) {
                Ok(Some(resumable)) => {
                    // The other process may have stored the map and let go just before:
                    // then the journal (held here, so no one else's) has no use.
                    if waiting {
                        if let Lookup::Hit(map) = self.load(body, file, (key, parts.kind())) {
                            resumable.journal.finish().ok();
                            return Ok(Start::Cached(map));
                        }
                    }
                    return Ok(Start::Journal(resumable));
                }
                Ok(None) => {}
                Err(e) => {
                    progress.note(&format!("warning: horizon map build journal not used: {e}"));
                    return Ok(Start::Alone);
                }
            }
            if !waiting {
                waiting = true;
                progress.note(&format!(
                    "another process is building the horizon map {} now: helping it with \
                     the parts it has not reached, then waiting for it (should it stop, this \
                     run goes on from its build journal)",
                    file.display()
                ));
            }
            let waited = started.elapsed().as_secs_f64();
            if waited - last_note >= BUILD_NOTE_EVERY_S {
                last_note = waited;
                progress.note(&format!(
                    "horizon map of '{}': the other process has built about {} of {} facets, \
                     this one {} parts of {} facets for it; waited {}",
                    body.name,
                    cache::facets_journaled(file, parts),
                    body.mesh.len(),
                    helped,
                    parts.facets(0).len(),
                    minutes_and_seconds(waited)
                ));
            }
            if progress.cancelled() {
                return Err(Error::Cancelled);
            }
            if help_build(file, key, parts) {
                *helped += 1;
            } else {
                std::thread::sleep(WAIT_POLL);
            }
            if let Lookup::Hit(map) = self.load(body, file, (key, parts.kind())) {
                if *helped > 0 {
                    // A part finished after the builder cleared them has no use now.
                    cache::clear_parts(file, parts.count());
                }
                return Ok(Start::Cached(map));
            }
        }
    }

    /// `body`'s map from the cache `file` of content `key`.
    fn load(
        &self,
        body: &Body,
        file: &Path,
        (key, kind): (&[u8; 32], MapKind),
    ) -> Lookup<HorizonMap> {
        cache::load(file, key, body.mesh.len(), (self.azimuths, kind))
    }
}

/// Builds one part of the map at `file` (content `key`) for the process that holds its
/// journal: the highest part above those the journal holds that no one has taken (the
/// builder goes up from the first, helpers down from the last), stored as a part file
/// that the builder takes instead of building the part itself. False when none is left
/// or the part could not be claimed or stored (a folder this run may not write).
fn help_build(file: &Path, key: &[u8; 32], parts: &MapParts) -> bool {
    // The part after those the journal holds is the builder's own now.
    let reached = cache::parts_journaled(file, parts) + 1;
    let claimed = (reached..parts.count())
        .rev()
        .filter(|&p| !cache::part_taken(file, p))
        .find(|&p| cache::claim_part(file, p).unwrap_or(false));
    claimed.is_some_and(|p| cache::store_part(file, key, parts, p, &parts.rows(p)).is_ok())
}

/// How often a run waiting for another process's build of the same map looks again.
const WAIT_POLL: std::time::Duration = std::time::Duration::from_millis(500);

/// How a map's build starts.
enum Start {
    /// From its journal (and the parts it holds).
    Journal(cache::Resumable),
    /// Without one (no cache folder, or the journal cannot be used).
    Alone,
    /// Not at all: another process built it meanwhile.
    Cached(HorizonMap),
}

/// Builds `body`'s map part by part, beginning after the parts `journal` holds and
/// adding each part built to it. A part that another process built meanwhile (a part
/// file beside the map file, `helpers`: that file and the map's key) is taken from it.
fn build_parts(
    body: &Body,
    parts: &MapParts,
    journal: Option<cache::Resumable>,
    helpers: Option<(&Path, &[u8; 32])>,
    progress: &dyn Progress,
) -> Result<Built> {
    let started = Instant::now();
    let facets = body.mesh.len();
    let (mut journal, mut cells, first) = match journal {
        Some(r) => (Some(r.journal), r.cells, r.parts),
        None => (None, Vec::with_capacity(parts.cell_count()), 0),
    };
    let done_before = parts.facets(first).start.min(facets);
    let left_s =
        build_seconds(body, parts.band()) * (facets - done_before) as f64 / facets.max(1) as f64;
    progress.note(&if done_before > 0 {
        format!(
            "resuming the horizon map of '{}' from its build journal: {done_before} of \
             {facets} facets done, about {left_s:.0} s left on one core",
            body.name
        )
    } else {
        format!(
            "building the horizon map of '{}' ({facets} facets × {} wedges; about \
             {left_s:.0} s on one core)",
            body.name,
            parts.azimuths()
        )
    });
    let (mut last_note, mut taken, mut taken_facets) = (0.0, 0, 0);
    for p in first..parts.count() {
        let elapsed = started.elapsed().as_secs_f64();
        let done = parts.facets(p).start;
        // The pace counts only the facets built here, and the time left only those still
        // to build here: helpers' parts cost nothing to take.
        let built_here = done - done_before - taken_facets;
        if built_here > 0 && elapsed - last_note >= BUILD_NOTE_EVERY_S {
            last_note = elapsed;
            let helped_ahead = helpers.map_or(0, |(file, _)| stored_by_helpers(file, parts, p));
            let pace = BuildPace {
                done,
                facets,
                built_here,
                to_build: facets - done - helped_ahead,
            };
            progress.note(&build_progress(&body.name, &pace, elapsed));
        }
        if progress.cancelled() {
            return Err(Error::Cancelled);
        }
        let rows = match helpers.map(|(file, key)| cache::load_part(file, key, parts, p)) {
            Some(Lookup::Hit(rows)) => {
                taken += 1;
                taken_facets += parts.facets(p).len();
                rows
            }
            Some(Lookup::Rejected(why)) => {
                progress.note(&format!(
                    "warning: part {p} of the horizon map of '{}' that another process \
                     built is not used ({why}); building it",
                    body.name
                ));
                parts.rows(p)
            }
            _ => parts.rows(p),
        };
        if let Some(j) = &mut journal {
            if let Err(e) = cache::keep(j, &rows) {
                progress.note(&format!("warning: horizon map build journal dropped: {e}"));
                journal = None;
            }
        }
        cells.extend(rows);
    }
    if taken > 0 {
        progress.note(&format!(
            "horizon map of '{}': {taken} of its {} parts were built by other runs of the \
             same map, which helped",
            body.name,
            parts.count()
        ));
    }
    Ok(Built {
        map: parts
            .assemble(cells)
            .expect("the parts' rows make the whole map"),
        seconds: started.elapsed().as_secs_f64(),
        resumed: done_before > 0,
        journal,
    })
}

/// A map just built.
struct Built {
    map: HorizonMap,
    /// Seconds the build took in this run.
    seconds: f64,
    /// Whether it went on from parts a journal held.
    resumed: bool,
    /// Its journal (all parts), to delete once the map is stored.
    journal: Option<Journal>,
}

/// Seconds between two notes of a map build's progress.
const BUILD_NOTE_EVERY_S: f64 = 30.0;

/// How far a map build has come, in facets.
struct BuildPace {
    /// Facets whose rows the build holds (from its journal, built, or taken from helpers).
    done: usize,
    facets: usize,
    /// Of `done`, those built in this run (not zero).
    built_here: usize,
    /// Facets left to build in this run: not done, nor in parts helpers have stored.
    to_build: usize,
}

/// The facets of the parts from `from` on that helpers have stored beside the map `file`.
fn stored_by_helpers(file: &Path, parts: &MapParts, from: usize) -> usize {
    (from..parts.count())
        .filter(|&q| cache::part_file(file, q).exists())
        .map(|q| parts.facets(q).len())
        .sum()
}

/// How far the map build of `body` has come after `elapsed_s` in this run, and the time
/// left at this run's own pace.
fn build_progress(body: &str, pace: &BuildPace, elapsed_s: f64) -> String {
    let BuildPace {
        done,
        facets,
        built_here,
        to_build,
    } = *pace;
    let left_s = elapsed_s * to_build as f64 / built_here as f64;
    format!(
        "horizon map of '{body}': {done} of {facets} facets ({:.0} %) in {}, about {} left",
        100.0 * done as f64 / facets as f64,
        minutes_and_seconds(elapsed_s),
        minutes_and_seconds(left_s)
    )
}

/// A duration as "42 s" or "3 min 05 s".
fn minutes_and_seconds(s: f64) -> String {
    let whole = s.round() as u64;
    if whole < 60 {
        format!("{whole} s")
    } else {
        format!("{} min {:02} s", whole / 60, whole % 60)
    }
}

/// CPU seconds per facet that a bound by sectors costs beyond a whole one over `casters`
/// facets (proving each sector's horizon, each triangle's part in it, not only the
/// highest): growing as √N, fitted from above to the builds measured on 2026-11-28,
/// evening, with each box's sectors handed on to the boxes below it (`bench_peer MESH
/// --tracer bvh-sectors`, then `--tracer bvh`, `--threads 1 --steps 2`, pinned, the
/// difference of their setups, two rounds alike within 2 %): 68.1 µs on m1phobos (32k
/// facets), 84.0 µs on Itokawa (49k); the model gives 68.2 and 84.5. At 196k facets it
/// gives 169 µs, more than the whole setup by sectors took there (29.2 s, 149 µs per
/// facet, the tree's build included).
fn sectors_extra_s_per_facet(casters: usize) -> f64 {
    0.381e-6 * (casters as f64).sqrt()
}

/// CPU seconds a bound by sectors spares over a whole one per facet and step of a point
/// Sun with steps 1° apart or closer: the rays of a Sun below the facet's highest horizon
/// but above its sector's, and the walk from the last blocker that the mostly shadowed
/// rays left then allow. Measured with the builds above (360 steps, 1° apart, two rounds
/// each): 0.040 µs on m1phobos (2.39 → 1.10 ms per step), 0.036 µs on Itokawa (3.43 →
/// 1.66); 0.035–0.037 µs at 0.1° and 0.5° as well ([`sectors_saving_share`]).
const SECTORS_SAVED_S_PER_FACET_STEP: f64 = 0.037e-6;

/// The share of [`SECTORS_SAVED_S_PER_FACET_STEP`] kept where the Sun stands `turn_deg`
/// from where it stood at the step whose blockers the rays recall: farther, the blocker
/// is seldom still in the way, and what remains is the rays the sectors spare. Measured
/// on 2026-11-28 with the step before recalled (`bench_peer MESH --tracer
/// bvh|bvh-sectors --steps N --threads 1 --block 16`, pinned, two rounds; Itokawa 49k and
/// m1phobos 32k): the same saving at 0.1°, 0.5° and 1°, then 0.74 and 0.85 of it at 5°,
/// 0.50 and 0.60 at 15°, 0.51 and 0.42 at 30° (three rounds); taken between those points
/// linearly in the angle's logarithm, and 0.45 beyond 30°.
fn sectors_saving_share(turn_deg: f64) -> f64 {
    const MEASURED: [(f64, f64); 4] = [(1.0, 1.0), (5.0, 0.8), (15.0, 0.55), (30.0, 0.45)];
    let x = turn_deg.clamp(1.0, 30.0).ln();
    MEASURED
        .windows(2)
        .find(|w| x <= w[1].0.ln())
        .map_or(MEASURED[3].1, |w| {
            let (x0, x1) = (w[0].0.ln(), w[1].0.ln());
            w[0].1 + (w[1].1 - w[0].1) * (x - x0) / (x1 - x0)
        })
}

/// CPU seconds on one core that bounds by sectors take beyond whole ones, for the bodies
/// that get a bound ([`crate::trace::choice::bounded`]; `maps[b]`: body `b` has a
/// horizon map) and are not in the cache (`cached[b]`).
pub fn sectors_extra_seconds(world: &World, maps: &[bool], cached: &[bool]) -> f64 {
    (world.bodies.iter().zip(maps).zip(cached))
        .filter(|((body, &map), &cached)| choice::needs_bound(body, map) && !cached)
        .map(|((b, _), _)| b.mesh.len() as f64 * sectors_extra_s_per_facet(b.shadow_mesh().len()))
        .sum()
}

/// A run's steps as the bound's detail weighs them: how many are computed, and how near
/// the Sun of each stands to that of the step whose blockers its rays recall
/// ([`crate::ephemeris::sun_return`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunSteps {
    pub count: usize,
    pub recall: SunReturn,
}

/// The detail of the BVH tracer's horizon bounds for a run of `steps`, and why: by
/// sectors when the steps spare more than the sectors cost to build (counted on one
/// core, as built, like the tracer's choice, [`crate::trace::choice::choose`], and
/// whatever the cache holds, so that the parts of a run choose alike), else whole. A
/// disk Sun (`disk_samples`) reads the whole horizon: its cones span sectors.
pub fn bound_detail_for_run(
    world: &World,
    maps: &[bool],
    steps: RunSteps,
    disk_samples: Option<u32>,
) -> (BoundDetail, String) {
    if disk_samples.is_some() {
        let why = "horizon bound whole: a disk Sun's cones read the whole horizon";
        return (BoundDetail::Whole, why.into());
    }
    let facets: usize = (choice::bounded(world, maps).iter())
        .map(|b| b.mesh.len())
        .sum();
    if facets == 0 {
        return (BoundDetail::Whole, "no horizon bound".into());
    }
    let extra_s = sectors_extra_seconds(world, maps, &vec![false; maps.len()]);
    let RunSteps { count, recall } = steps;
    let share = sectors_saving_share(recall.turn_deg);
    let per_step = facets as f64 * SECTORS_SAVED_S_PER_FACET_STEP * share;
    let break_even = (extra_s / per_step).ceil() as usize;
    let cost = choice::about_seconds(extra_s);
    let apart = match share < 1.0 {
        true => format!(
            "; where the Sun stands {:.1}° from its place {} before, sectors spare {:.0} % \
             of what they spare at 1°",
            recall.turn_deg,
            steps_back(recall.lag),
            100.0 * share
        ),
        false => String::new(),
    };
    if count >= break_even {
        let why = format!(
            "horizon bound by sectors: {count} steps ≥ {break_even}, where its sectors \
             ({cost} more on one core) cost less than the rays they spare{apart}"
        );
        (BoundDetail::Sectors, why)
    } else {
        let why = format!(
            "horizon bound whole: {count} steps < {break_even}, too few to pay for its \
             sectors ({cost} more on one core{apart})"
        );
        (BoundDetail::Whole, why)
    }
}

/// "the step" for a lag of one, "N steps" for more.
pub fn steps_back(lag: usize) -> String {
    match lag {
        1 => "the step".into(),
        n => format!("{n} steps"),
    }
}

/// Where a run's horizon bound came from (kept in `run.json`): the BVH tracer's, per
/// body that has one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoundRecord {
    pub body: String,
    /// "cache" or "built".
    pub source: String,
    /// The cache file read or written (none without a cache folder, or when it could not
    /// be written).
    pub file: Option<PathBuf>,
    /// Seconds spent building it (0 when read).
    pub build_s: f64,
    /// How finely it follows the horizon (runs before there were sectors: whole).
    #[serde(default)]
    pub detail: BoundDetail,
}

/// Where a run's horizon map came from (kept in `run.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapRecord {
    pub body: String,
    pub azimuths: u32,
    /// The least and greatest Sun declination (degrees, about the body's z axis) the map
    /// serves; `None`: every direction.
    #[serde(default)]
    pub band_deg: Option<[f64; 2]>,
    /// Memory the map holds, bytes.
    pub bytes: usize,
    /// "cache", "built", or "resumed" (built on from the parts its build journal held,
    /// left by an earlier run that stopped part-way).
    pub source: String,
    /// The cache file read or written.
    pub file: Option<PathBuf>,
    /// Seconds spent building it (0 when read).
    pub build_s: f64,
    /// Parts of the map this run built for another process that was building it at the
    /// same time (handed over beside the map file; 0 for the builder).
    #[serde(default)]
    pub helped_parts: usize,
    /// "bounded" (each wedge's upper bound kept) or "centres" (the centres alone).
    #[serde(default)]
    pub kind: MapKind,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sectors once the steps pay for their extra build, from both sides; never for a
    /// disk Sun, nor for a body with a map; their build is counted beside the tree's.
    #[test]
    fn the_bound_takes_sectors_once_the_steps_pay_for_them() {
        let raw =
            crate::mesh::generate::height_field((14, 14), (-10.0, 10.0), (-10.0, 10.0), |x, y| {
                2.5 * (x / 2.3).sin() * (y / 3.1).cos()
            });
        let mesh = crate::mesh::Mesh::from_raw(raw, crate::mesh::LengthUnit::M);
        let body = Body::new("terrain", mesh, false);
        let w = World { bodies: vec![body] };
        let casters = w.bodies[0].shadow_mesh().len();
        let even =
            (sectors_extra_s_per_facet(casters) / SECTORS_SAVED_S_PER_FACET_STEP).ceil() as usize;
        assert!(even > 100, "{even}");
        let at = |count, turn_deg| RunSteps {
            count,
            recall: SunReturn { lag: 1, turn_deg },
        };
        let pick = |steps, sun| bound_detail_for_run(&w, &[false], steps, sun);
        assert_eq!(pick(at(even, 1.0), None).0, BoundDetail::Sectors);
        let (detail, why) = pick(at(even - 1, 1.0), None);
        assert_eq!(detail, BoundDetail::Whole);
        assert!(why.contains(&format!("< {even}")), "{why}");
        assert_eq!(pick(at(1_000_000, 1.0), Some(32)).0, BoundDetail::Whole);
        assert_eq!(
            bound_detail_for_run(&w, &[true], at(1_000_000, 1.0), None).0,
            BoundDetail::Whole
        );
        // Steps 30° apart spare 0.45 of what steps 1° apart spare: they need 1/0.45 as
        // many steps.
        let far = (sectors_extra_s_per_facet(casters) / (SECTORS_SAVED_S_PER_FACET_STEP * 0.45))
            .ceil() as usize;
        assert!(far > 2 * even, "{far} against {even}");
        assert_eq!(pick(at(far, 30.0), None).0, BoundDetail::Sectors);
        let (detail, why) = pick(at(far - 1, 30.0), None);
        assert_eq!(detail, BoundDetail::Whole);
        assert!(
            why.contains("30.0° from its place the step before"),
            "{why}"
        );
        assert!(sectors_extra_seconds(&w, &[false], &[false]) > 0.0);
        assert_eq!(sectors_extra_seconds(&w, &[false], &[true]), 0.0);
    }

    /// The rows of recalled blockers stay within the memory given: at 512 MiB, 170 steps
    /// back would fit at 786,432 facets (170 · 4 B · 786,432 = 534.8 MB ≤ 536.9 MB), so
    /// all 128; 42 at 3,145,728 (528.5 MB, 43 would pass it); all 128 up to 1,048,576
    /// facets and 127 beyond; always at least the step before.
    #[test]
    fn the_recalled_steps_are_held_to_their_memory() {
        let most = RECALL_MAX_BYTES;
        assert_eq!(recall_rows_within_memory(786_432, most), 128);
        assert_eq!(recall_rows_within_memory(3_145_728, most), 42);
        assert_eq!(recall_rows_within_memory(1_048_576, most), 128);
        assert_eq!(recall_rows_within_memory(1_048_577, most), 127);
        assert_eq!(recall_rows_within_memory(100_000_000, most), 1);
        assert_eq!(recall_rows_within_memory(0, most), 128);
        // A budget of 2 GiB leaves the blockers an eighth of it, 256 MiB: 85 rows.
        let quarter_gib = 256.0 * 1024.0 * 1024.0;
        assert_eq!(recall_rows_within_memory(786_432, quarter_gib), 85);
    }

    /// The share follows the measured points (1°, 5°, 15°, 30°) and lies between them.
    #[test]
    fn steps_farther_apart_keep_the_measured_share_of_the_sectors_saving() {
        for (deg, share) in [
            (0.1, 1.0),
            (1.0, 1.0),
            (5.0, 0.8),
            (15.0, 0.55),
            (30.0, 0.45),
            (90.0, 0.45),
        ] {
            assert!((sectors_saving_share(deg) - share).abs() < 1e-12, "{deg}°");
        }
        let mid = sectors_saving_share(10.0);
        assert!(mid < 0.8 && mid > 0.55, "{mid}");
    }

    #[test]
    fn a_builds_progress_says_how_far_it_is_and_how_long_is_left() {
        let pace = |done, facets, built_here, to_build| BuildPace {
            done,
            facets,
            built_here,
            to_build,
        };
        assert_eq!(
            build_progress("phobos", &pace(196_608, 786_432, 196_608, 589_824), 300.0),
            "horizon map of 'phobos': 196608 of 786432 facets (25 %) in 5 min 00 s, about 15 min 00 s left"
        );
        assert_eq!(
            build_progress("b", &pace(1, 3, 1, 2), 20.4),
            "horizon map of 'b': 1 of 3 facets (33 %) in 20 s, about 41 s left"
        );
        // Resumed from a journal (4 facets): the pace counts only the facets of this run.
        assert_eq!(
            build_progress("b", &pace(5, 7, 1, 2), 20.4),
            "horizon map of 'b': 5 of 7 facets (71 %) in 20 s, about 41 s left"
        );
        // Helped: 2 facets taken from a helper's part, 3 more stored ahead; 2 built here
        // in 20 s, 1 left to build.
        assert_eq!(
            build_progress("b", &pace(4, 8, 2, 1), 20.0),
            "horizon map of 'b': 4 of 8 facets (50 %) in 20 s, about 10 s left"
        );
    }

    /// Notes taken, and a cancel once `cancel_after` parts were allowed.
    struct StopAfter {
        cancel_after: usize,
        checks: AtomicUsize,
        notes: Mutex<Vec<String>>,
    }

    impl StopAfter {
        fn new(cancel_after: usize) -> StopAfter {
            StopAfter {
                cancel_after,
                checks: AtomicUsize::new(0),
                notes: Mutex::new(Vec::new()),
            }
        }

        fn noted(&self, part: &str) -> bool {
            self.notes
                .lock()
                .expect("notes")
                .iter()
                .any(|n| n.contains(part))
        }
    }

    impl Progress for StopAfter {
        fn note(&self, line: &str) {
            self.notes.lock().expect("notes").push(line.to_string());
        }
        fn begin_steps(&self, _: u64) {}
        fn step_done(&self) {}
        fn end_steps(&self) {}
        fn cancelled(&self) -> bool {
            self.checks.fetch_add(1, Ordering::Relaxed) >= self.cancel_after
        }
    }

    /// The settings of the tests' maps: 32 wedges, every direction, upper bounds kept.
    const BOUNDED_32: (u32, SunBand, MapKind) = (32, SunBand::WHOLE, MapKind::Bounded);

    /// A disk Sun's run builds a map of centres alone and keeps it apart from the exact
    /// mode's; with only a map with upper bounds in the cache, it reads that one.
    #[test]
    fn a_disk_sun_builds_a_map_of_centres_and_reads_a_bounded_one_when_cached() {
        let dir = crate::TempDir::new("unit", "map-kinds");
        let (body, exact) = bumps_in(&dir);
        let disk = Shadows {
            sun: SunShape::Disk,
            ..exact.clone()
        };
        let silent = &crate::progress::Silent;
        let (centres, record) = disk.obtain(&body, SunBand::WHOLE, silent).expect("built");
        assert_eq!(
            (centres.kind(), record.source.as_str()),
            (MapKind::Centres, "built")
        );
        let (bounded, record) = exact.obtain(&body, SunBand::WHOLE, silent).expect("built");
        assert_eq!(
            (bounded.kind(), record.source.as_str()),
            (MapKind::Bounded, "built")
        );
        assert_eq!(bounded, whole_build(&body, &exact));
        let own = cache::file_for(&dir, &disk.map_keys(&body, SunBand::WHOLE)[0].0);
        std::fs::remove_file(own).expect("remove");
        let (read, record) = disk.obtain(&body, SunBand::WHOLE, silent).expect("read");
        let got = (read, record.source.as_str(), record.kind);
        assert_eq!(got, (bounded, "cache", MapKind::Bounded));
    }

    /// Rough terrain of 512 facets, and settings that cache its map in `dir`.
    fn bumps_in(dir: &Path) -> (Body, Shadows) {
        let raw = height_field((16, 16), (-8.0, 8.0), (-8.0, 8.0), |x, y| {
            1.5 * (0.9 * x).sin() * (0.7 * y).cos()
        });
        let body = Body::new("bumps", Mesh::from_raw(raw, LengthUnit::M), false);
        let shadows = Shadows {
            azimuths: 32,
            cache_dir: Some(dir.to_path_buf()),
            ..Shadows::default()
        };
        (body, shadows)
    }

    #[test]
    fn the_plan_counts_the_map_and_what_an_exact_maps_walks_keep() {
        // Bumps with a ring of surroundings: the estimate must be what the map holds,
        // plus, for an exact map under a point Sun, the last blocker of every facet of
        // the patch and the neighbours of every facet that casts shadows.
        let dir = crate::TempDir::new("unit", "map-journal-bytes");
        let (body, shadows) = bumps_in(&dir);
        let ring = height_field((8, 8), (-24.0, 24.0), (-24.0, 24.0), |x, y| {
            0.05 * (x * x + y * y)
        });
        let body = body.with_surroundings(&Mesh::from_raw(ring, LengthUnit::M));
        let casters = body.shadow_mesh();
        let map = HorizonMap::build(
            casters,
            body.mesh.len(),
            &Bvh::build(casters),
            (32, SunBand::WHOLE),
        );
        let walks = body.mesh.len() * std::mem::size_of::<std::sync::atomic::AtomicU32>()
            + crate::mesh::inspect::edge_neighbours(casters).len()
                * std::mem::size_of::<[u32; 3]>();
        let patch = body.mesh.len();
        assert!(casters.len() > patch);
        let world = World { bodies: vec![body] };
        for (mode, sun, kept) in [
            (HorizonMode::Exact, SunShape::Point, map.bytes() + walks),
            (HorizonMode::Approximate, SunShape::Point, map.bytes()),
            (HorizonMode::Exact, SunShape::Disk, map.bytes()),
        ] {
            let shadows = Shadows {
                mode,
                sun,
                ..shadows.clone()
            };
            assert_eq!(
                shadows.map_bytes(&world, &[true]),
                kept as f64,
                "{mode:?} {sun:?}"
            );
            assert_eq!(shadows.map_bytes(&world, &[false]), 0.0);
        }
    }

    fn whole_build(body: &Body, shadows: &Shadows) -> HorizonMap {
        let mesh = body.shadow_mesh();
        HorizonMap::build(
            mesh,
            mesh.len(),
            &Bvh::build(mesh),
            (shadows.azimuths, SunBand::WHOLE),
        )
    }

    #[test]
    fn a_build_stopped_part_way_goes_on_from_its_journal_to_the_same_map() {
        let dir = crate::TempDir::new("unit", "map-journal-resume");
        let (body, shadows) = bumps_in(&dir);
        let whole = whole_build(&body, &shadows);
        // Cancelled before the fourth part of eight: three parts are in the journal.
        let stopped = StopAfter::new(3);
        assert!(matches!(
            shadows.obtain_in_parts(&body, SunBand::WHOLE, &stopped, 64),
            Err(Error::Cancelled)
        ));
        let file = shadows.cached_file(&body, SunBand::WHOLE);
        assert!(file.is_none(), "no map file after a stop");
        let key = cache::content_key(body.shadow_mesh(), body.mesh.len(), BOUNDED_32);
        let journal = crate::journal::path_for(&cache::file_for(&dir, &key));
        assert!(journal.is_file());

        let resumed = StopAfter::new(usize::MAX);
        let (map, record) = shadows
            .obtain_in_parts(&body, SunBand::WHOLE, &resumed, 64)
            .expect("resumed");
        assert_eq!(map, whole, "the map of one whole build, bit for bit");
        assert_eq!(record.source, "resumed");
        assert!(resumed.noted("192 of 512 facets done"));
        assert!(
            !journal.exists(),
            "the journal is deleted once the map is stored"
        );
        assert!(shadows.cached_file(&body, SunBand::WHOLE).is_some());

        // Read back from the cache now.
        let (again, record) = shadows
            .obtain_in_parts(&body, SunBand::WHOLE, &StopAfter::new(usize::MAX), 64)
            .expect("cached");
        assert_eq!((again, record.source.as_str()), (whole, "cache"));
    }

    /// The BVH's horizon bound is stored once built and read back as it was; a damaged
    /// file is built again, never used.
    #[test]
    fn a_bound_is_kept_in_the_cache_and_read_back_as_built() {
        let dir = crate::TempDir::new("unit", "map-journal-bound");
        let (body, shadows) = bumps_in(&dir);
        let bvh = Bvh::build(body.shadow_mesh());
        let world = World {
            bodies: vec![body.clone()],
        };
        assert_eq!(shadows.cached_bounds(&world), vec![false]);
        let fresh = HorizonBound::new(
            body.shadow_mesh(),
            body.mesh.len(),
            &bvh,
            BoundDetail::Whole,
        );
        let sines = |b: &HorizonBound| {
            (0..body.mesh.len())
                .map(|i| b.sin_max(i))
                .collect::<Vec<_>>()
        };
        assert!(sines(&fresh).iter().any(|&s| s > 0.1), "the bumps rise");
        // The sines of the bound `shadows` gives, and where it says they came from.
        let obtained = || {
            let (bound, record) = shadows.bound(&body, &bvh);
            (sines(&bound), record.source)
        };
        assert_eq!(obtained(), (sines(&fresh), "built".to_string()));
        assert_eq!(shadows.cached_bounds(&world), vec![true]);
        let (file, _) = shadows.bound_file(&body).expect("a cache folder");
        let stored = std::fs::read(&file).expect("stored");
        assert_eq!(obtained(), (sines(&fresh), "cache".to_string()));
        // Read back, not rebuilt: a file holding other sines (with a valid checksum)
        // would be believed, so fake one and see it come back.
        let key = cache::bound_key(body.shadow_mesh(), body.mesh.len(), BoundDetail::Whole);
        let faked = HorizonBound::from_sines(
            body.shadow_mesh(),
            vec![51; body.mesh.len()],
            BoundDetail::Whole,
        );
        cache::store_bound(&file, &key, &faked).expect("store");
        assert!(obtained().0.iter().all(|&s| s == 0.2));
        // A damaged file is refused and replaced by a fresh build.
        let mut damaged = stored.clone();
        damaged[crate::cache::PAYLOAD_OFFSET + 9] ^= 1;
        std::fs::write(&file, &damaged).expect("write");
        assert_eq!(obtained(), (sines(&fresh), "built".to_string()));
        assert_eq!(std::fs::read(&file).expect("rewritten"), stored);
    }

    #[test]
    fn a_journal_of_parts_of_another_size_is_not_taken() {
        let dir = crate::TempDir::new("unit", "map-journal-other");
        let (body, shadows) = bumps_in(&dir);
        assert!(shadows
            .obtain_in_parts(&body, SunBand::WHOLE, &StopAfter::new(2), 64)
            .is_err());
        let progress = StopAfter::new(usize::MAX);
        let (map, record) = shadows
            .obtain_in_parts(&body, SunBand::WHOLE, &progress, 128)
            .expect("built");
        assert_eq!(
            (map, record.source.as_str()),
            (whole_build(&body, &shadows), "built")
        );
    }

    /// Another build holding the journal with its first `parts` parts.
    fn another_build(body: &Body, dir: &Path, parts: usize) -> Journal {
        let mesh = body.shadow_mesh();
        let key = cache::content_key(mesh, mesh.len(), BOUNDED_32);
        let bvh = Bvh::build(mesh);
        let map_parts = MapParts::new(mesh, mesh.len(), &bvh, (32, SunBand::WHOLE), 64);
        let file = cache::file_for(dir, &key);
        let mut journal = cache::resume(&file, &key, &map_parts)
            .expect("open")
            .expect("not held")
            .journal;
        for p in 0..parts {
            cache::keep(&mut journal, &map_parts.rows(p)).expect("keep");
        }
        journal
    }

    #[test]
    fn a_run_waits_for_another_build_of_its_map_and_reads_it_or_goes_on_from_it() {
        let dir = crate::TempDir::new("unit", "map-journal-wait");
        let (body, shadows) = bumps_in(&dir);
        let whole = whole_build(&body, &shadows);
        let key = cache::content_key(body.shadow_mesh(), body.mesh.len(), BOUNDED_32);
        let file = cache::file_for(&dir, &key);
        // The other build holds two parts of eight: this run builds the six others but
        // the one after them (the other's own), from the last down, for it to take.
        let helped = 3..8;
        let obtain_beside = |other: Journal, finish: bool| {
            let progress = StopAfter::new(usize::MAX);
            let got = std::thread::scope(|scope| {
                let waiting =
                    scope.spawn(|| shadows.obtain_in_parts(&body, SunBand::WHOLE, &progress, 64));
                let started = std::time::Instant::now();
                while !helped.clone().all(|p| cache::part_file(&file, p).is_file()) {
                    assert!(started.elapsed().as_secs() < 120, "no help came");
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                std::thread::sleep(std::time::Duration::from_millis(700));
                assert!(!waiting.is_finished(), "it waits while the other builds");
                assert!(!cache::part_file(&file, 2).exists(), "the other's own part");
                if finish {
                    cache::store(&file, &key, &whole).expect("store");
                    other.finish().expect("finish");
                } else {
                    drop(other);
                }
                waiting.join().expect("thread").expect("obtained")
            });
            assert!(progress.noted("waiting for it"));
            (got, progress)
        };
        // The other build stores the map: it is read, and no journal is left behind.
        let ((map, record), _) = obtain_beside(another_build(&body, &dir, 2), true);
        assert_eq!((&map, record.source.as_str()), (&whole, "cache"));
        assert_eq!(record.helped_parts, 5);
        // The helper clears its parts away once the map is there.
        assert_eq!(cache_files(&dir), ["horizon"]);
        // The other build stops after two parts: this one goes on from them, takes the
        // parts it built as a helper, and clears them away once the map is stored.
        std::fs::remove_file(&file).expect("remove the map");
        let ((map, record), progress) = obtain_beside(another_build(&body, &dir, 2), false);
        assert_eq!((&map, record.source.as_str()), (&whole, "resumed"));
        assert!(progress.noted("128 of 512 facets done"));
        assert!(progress.noted("5 of its 8 parts were built by other runs"));
        assert_eq!(cache_files(&dir), ["horizon"]);
    }

    /// What the files of the cache folder `dir` hold (`slim cache`'s names).
    fn cache_files(dir: &Path) -> Vec<String> {
        let entries = crate::cache::entries(dir).expect("listed");
        entries.into_iter().map(|e| e.what).collect()
    }

    /// A build takes the parts other runs built for it as they are (a part file with a
    /// valid checksum is believed, so fake one and see it come back), and builds a
    /// damaged one itself.
    #[test]
    fn a_build_takes_the_parts_that_helpers_stored_and_rebuilds_damaged_ones() {
        let dir = crate::TempDir::new("unit", "map-journal-helped");
        let (body, shadows) = bumps_in(&dir);
        let whole = whole_build(&body, &shadows);
        let mesh = body.shadow_mesh();
        let key = cache::content_key(mesh, mesh.len(), BOUNDED_32);
        let file = cache::file_for(&dir, &key);
        let bvh = Bvh::build(mesh);
        let map_parts = MapParts::new(mesh, mesh.len(), &bvh, (32, SunBand::WHOLE), 64);
        let faked = vec![[7u16, 7u16]; 64 * 32];
        cache::store_part(&file, &key, &map_parts, 5, &faked).expect("store");
        cache::store_part(&file, &key, &map_parts, 6, &map_parts.rows(6)).expect("store");
        let part_6 = cache::part_file(&file, 6);
        let mut damaged = std::fs::read(&part_6).expect("read");
        damaged[crate::cache::PAYLOAD_OFFSET + 30] ^= 1;
        std::fs::write(&part_6, &damaged).expect("write");
        let progress = StopAfter::new(usize::MAX);
        let (map, record) = shadows
            .obtain_in_parts(&body, SunBand::WHOLE, &progress, 64)
            .expect("built");
        assert_eq!(record.source, "built");
        assert!(progress.noted("1 of its 8 parts were built by other runs"));
        assert!(progress.noted("part 6 of the horizon map of 'bumps' that another process"));
        for i in 0..body.mesh.len() {
            for k in 0..32 {
                let expected = if (320..384).contains(&i) {
                    [7.0 / (65535.0 / std::f64::consts::FRAC_PI_2); 2]
                } else {
                    whole.wedge(i, k)
                };
                assert_eq!(map.wedge(i, k), expected, "facet {i}, wedge {k}");
            }
        }
        assert!(!part_6.exists() && !cache::part_file(&file, 5).exists());
    }
    use crate::mesh::generate::{floor_and_wall, height_field};
    use crate::mesh::{LengthUnit, Mesh};
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Mutex;

    /// A floor with a wall beside it: a body that shadows itself.
    fn floor_and_wall_body() -> Body {
        let mesh = Mesh::from_raw(floor_and_wall(3.0, 4.0, 50.0), LengthUnit::M);
        Body::new("floor and wall", mesh, false)
    }

    /// Terrain's maps take longer to build (far, low horizons all around; about four
    /// times as long but for the fixed part per facet, which dominates this small mesh),
    /// so `auto` waits for more steps before it builds one, and the plan announces the
    /// longer build.
    #[test]
    fn auto_builds_a_terrain_map_later() {
        let closed = floor_and_wall_body();
        let open = Body {
            open: true,
            ..floor_and_wall_body()
        };
        let shadows = Shadows {
            method: ShadowMethod::Auto,
            sun: SunShape::Point,
            ..Shadows::default()
        };
        let break_even =
            |body: &Body| (build_s_per_facet(body, SunBand::WHOLE) / SAVED_S_PER_FACET_STEP).ceil();
        let (steps, terrain_steps) = (break_even(&closed), break_even(&open));
        assert!(
            terrain_steps > 1.2 * steps,
            "{terrain_steps} against {steps}"
        );
        let steps = steps as usize;
        assert!(
            shadows
                .choose_for(&closed, SunBand::WHOLE, steps, TracerKind::Sunview)
                .0
        );
        assert!(
            !shadows
                .choose_for(&open, SunBand::WHOLE, steps, TracerKind::Sunview)
                .0
        );
        assert!(
            build_seconds(&open, SunBand::WHOLE) > 1.2 * build_seconds(&closed, SunBand::WHOLE)
        );
    }

    /// `auto` weighs a map's build against the rays it spares, which for a disk Sun are
    /// `sun_samples` per facet where a point Sun needs one.
    #[test]
    fn auto_builds_a_map_sooner_for_a_disk_sun_by_its_samples() {
        let body = floor_and_wall_body();
        let auto = |sun, steps| {
            let shadows = Shadows {
                method: ShadowMethod::Auto,
                sun,
                ..Shadows::default()
            };
            shadows.choose_for(&body, SunBand::WHOLE, steps, TracerKind::Sunview)
        };
        let point = build_s_per_facet(&body, SunBand::WHOLE) / SAVED_S_PER_FACET_STEP;
        let disk = (point / DEFAULT_SUN_SAMPLES as f64).ceil() as usize;
        assert!(disk > 1 && disk < point as usize);
        let (uses_map, why) = auto(SunShape::Disk, disk - 1);
        assert!(!uses_map && why.contains("32 points of the disk"), "{why}");
        assert!(auto(SunShape::Disk, disk).0);
        assert!(!auto(SunShape::Point, disk).0);
        assert!(auto(SunShape::Point, point.ceil() as usize).0);
    }

    /// Where the run would take its steps facet by facet, a map pays later still: a
    /// disk Sun's year of hourly steps (8,760) at 49k facets no longer builds one.
    #[test]
    fn auto_builds_a_map_later_where_the_steps_are_swept() {
        let body = floor_and_wall_body();
        for sun in [SunShape::Point, SunShape::Disk] {
            let by = |sweeps| Shadows {
                method: ShadowMethod::Auto,
                sun,
                sweeps,
                ..Shadows::default()
            };
            let even = |shadows: Shadows| {
                (build_s_per_facet(&body, SunBand::WHOLE)
                    / shadows.saved_s_per_facet_step(TracerKind::Auto))
                .ceil() as usize
            };
            let (stepped, swept) = (even(by(false)), even(by(true)));
            assert!(swept > 3 * stepped, "{sun:?}: {swept} against {stepped}");
            assert!(
                by(false)
                    .choose_for(&body, SunBand::WHOLE, stepped, TracerKind::Auto)
                    .0
            );
            assert!(
                !by(true)
                    .choose_for(&body, SunBand::WHOLE, stepped, TracerKind::Auto)
                    .0
            );
            assert!(
                by(true)
                    .choose_for(&body, SunBand::WHOLE, swept, TracerKind::Auto)
                    .0
            );
        }
        // A closed 49,152-facet body's map of every direction against a year of hourly
        // disk Suns, swept; the map of the year's band (within 1.3° of one declination)
        // pays for it.
        let growing = 0.29e-6 * 49_152f64.powf(2.0 / 3.0);
        let per_facet = 0.05e-3 + growing;
        assert!(per_facet / SAVED_OVER_SWEEP.1 > 8_760.0);
        assert!(per_facet / SAVED_OVER_BVH.1 < 8_760.0);
        let d = 15f64.to_radians();
        let band = SunBand::of_suns(
            [glam::DVec3::new(d.cos(), 0.0, d.sin())],
            1.3f64.to_radians(),
        );
        let banded = 0.05e-3 + growing * band_share(band, 49_152.0);
        assert!(banded / SAVED_OVER_SWEEP.1 < 8_760.0);
        assert!(band_share(SunBand::WHOLE, 49_152.0) == 1.0);
    }

    /// Against the BVH's rays (under `bvh` or `auto`) a map pays later: its bound and
    /// cones make rays cheaper, a point Sun's most of all.
    #[test]
    fn auto_builds_a_map_later_when_the_bvh_would_trace() {
        let body = floor_and_wall_body();
        let per_facet = build_s_per_facet(&body, SunBand::WHOLE);
        for (sun, saved) in [
            (SunShape::Point, SAVED_OVER_BVH.0),
            (SunShape::Disk, SAVED_OVER_BVH.1),
        ] {
            let shadows = Shadows {
                method: ShadowMethod::Auto,
                sun,
                ..Shadows::default()
            };
            let even = (per_facet / saved).ceil() as usize;
            let grid_even =
                (per_facet / shadows.saved_s_per_facet_step(TracerKind::Sunview)).ceil();
            assert!(
                even as f64 > 1.5 * grid_even,
                "{sun:?}: {even} against {grid_even}"
            );
            for tracer in [TracerKind::Bvh, TracerKind::Auto] {
                assert!(shadows.choose_for(&body, SunBand::WHOLE, even, tracer).0);
                let (uses_map, why) = shadows.choose_for(&body, SunBand::WHOLE, even - 1, tracer);
                assert!(!uses_map && why.contains(&format!("< {even}")), "{why}");
            }
        }
    }
}
