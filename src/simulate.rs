//! Simulate: the step loop — direct sunlight, scattered light and statistics at every
//! step.
//!
//! In: a [`World`] (metres, each body in its own frame), every step's [`EpochState`] and
//! [`Options`] (tracer, CDF bins, optional scattered light and spectral bands). Out: a
//! [`Simulation`] — streaming statistics of the total irradiance (W/m²) per facet of the
//! bodies that get outputs (in [`World::output_offsets`] order), and with scattered light
//! of its direct and scattered parts; each step's irradiance of those facets is handed to
//! a callback in step order, e.g. to stream history. Bodies with `outputs = false` cast
//! shadows and scatter light but keep no statistics.
//!
//! Steps go through in blocks ([`steps_per_batch`]: up to 64 steps without scattered
//! light, as many as are solved side by side with it), so that lighting and statistics
//! read each facet's data once per block rather than once per step; results do not
//! depend on the block.

use crate::bands::Bands;
use crate::ephemeris::{repeat_period, EpochState};
use crate::error::{Error, Result};
use crate::horizon::bound::BoundDetail;
use crate::horizon::map::HorizonMap;
use crate::horizon::shadows::{sectors_extra_seconds, BoundRecord, MapRecord};
use crate::horizon::Shadows;
use crate::illum::{sweep_chunk_facets, Direct, StepCounts};
use crate::progress::{Progress, Silent, Timings};
use crate::scatter::{Scatter, ScatterRecord, Settings as ScatterSettings, LANES};
use crate::stats::{Bins, FacetStats, Selection};
use crate::trace::{choice, TracerKind};
use crate::world::World;

/// How to step: the tracer, the CDF bins, and what besides direct sunlight to compute.
pub struct Options<'a> {
    pub tracer: TracerKind,
    pub bins: Bins,
    /// How the bodies' own shadows are found and the Sun's shape.
    pub shadows: Shadows,
    /// Per body (scene order), whether it uses a horizon map (empty: none does).
    pub horizon_maps: Vec<bool>,
    /// Scattered light (none: direct sunlight only).
    pub scatter: Option<ScatterSettings>,
    /// Spectral bands, which accumulate their own statistics (none: one broad band).
    pub bands: Option<&'a mut Bands>,
    /// The part of the run to compute (a shard's), everything by default.
    pub slice: Slice,
}

/// The part of a run a shard computes: a range of the steps and a range of the facets
/// that get statistics (counted in [`World::output_ranges`] order). Every facet is still
/// lit and traced against the whole world; only statistics and history are kept for the
/// range. `None`: all of them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Slice {
    pub steps: Option<std::ops::Range<usize>>,
    pub facets: Option<std::ops::Range<usize>>,
}

impl Slice {
    /// The facets statistics are kept for: the bodies that get outputs, within the
    /// slice's facet range.
    pub fn kept(&self, world: &World) -> Selection {
        Selection::new(world.output_ranges(), world.facet_count()).within(self.facets.clone())
    }
}

impl Options<'_> {
    /// Direct sunlight only, with `tracer` and `bins`.
    pub fn direct(tracer: TracerKind, bins: Bins) -> Options<'static> {
        Options {
            tracer,
            bins,
            shadows: Shadows::default(),
            horizon_maps: Vec::new(),
            scatter: None,
            bands: None,
            slice: Slice::default(),
        }
    }
}

/// The result of stepping through time: statistics and counters.
pub struct Simulation {
    /// Statistics of the total irradiance (direct plus scattered) of the facets that get
    /// outputs.
    pub stats: FacetStats,
    pub counts: StepCounts,
    /// With scattering: statistics of the direct and the scattered parts, and what the
    /// scattered-light stage did.
    pub parts: Option<ScatterParts>,
    /// Where each horizon map used came from.
    pub horizon_maps: Vec<MapRecord>,
    /// Where each horizon bound used came from.
    pub horizon_bounds: Vec<BoundRecord>,
}

/// Direct and scattered statistics of a run with scattered light.
pub struct ScatterParts {
    pub direct: FacetStats,
    pub scattered: FacetStats,
    /// With planets: the light they send, as it arrives (a part of `scattered`).
    pub planet: Option<FacetStats>,
    pub record: ScatterRecord,
}

/// What sees each step's irradiance as the step loop goes ([`simulate`]).
pub type OnStep<'a> = dyn FnMut(&EpochState, StepIrradiance) -> Result<()> + 'a;

/// One step's irradiance (W/m²) of the facets that get outputs, body by body (every
/// facet, in global order, when every body gets outputs).
#[derive(Debug, Clone, Copy)]
pub struct StepIrradiance<'a> {
    /// Direct plus scattered.
    pub total: &'a [f64],
    /// With scattering: (direct, scattered).
    pub parts: Option<(&'a [f64], &'a [f64])>,
}

/// Computes the irradiance at every step and accumulates statistics: after the direct
/// irradiance of each step, with scattered light its solve; statistics of the total and
/// of both parts. `on_step`, when given, sees each step's irradiance (global facet
/// order); without it a run whose shadows say so goes facet by facet
/// ([`Direct::sweep`]).
pub fn simulate(
    world: &World,
    states: &[EpochState],
    options: Options,
    timings: &mut Timings,
    progress: &dyn Progress,
    mut on_step: Option<&mut OnStep<'_>>,
) -> Result<Simulation> {
    let Options {
        tracer,
        bins,
        mut shadows,
        horizon_maps,
        scatter,
        mut bands,
        slice,
    } = options;
    // A time shard starts where one run would stand after the steps before it.
    let (earlier, states) = states.split_at(slice.steps.as_ref().map_or(0, |r| r.start));
    let states = &states[..slice.steps.as_ref().map_or(states.len(), |r| r.len())];
    let (maps, records) = timings.time("horizon maps", || {
        obtain_maps(world, &shadows, &horizon_maps, progress)
    })?;
    let mapped: Vec<bool> = maps.iter().map(Option::is_some).collect();
    let computed = Repetition::of(states, world.facet_count()).computed();
    let (tracer, _) = choice::choose(tracer, world, computed, shadows.disk_samples(), &mapped);
    if tracer == TracerKind::Bvh {
        let cached = shadows.cached_bounds(world);
        announce_bvh_build(world, (&mapped, &cached), shadows.bound_detail, progress);
    }
    // A body without outputs needs its own light only when its facets scatter it.
    let needed = world
        .bodies
        .iter()
        .enumerate()
        .map(|(b, body)| body.outputs || scatter.as_ref().is_some_and(|s| !s.is_planet(b)))
        .collect();
    let kept = slice.kept(world);
    // What the plan could not see: a shard's facets, and whether anyone reads the steps.
    shadows.sweeps &= on_step.is_none()
        && world.bodies.len() == 1
        && kept.count() == world.facet_count()
        && computed == states.len()
        && scatter.is_none()
        && bands.is_none();
    let direct = timings.time("trace build", || {
        Direct::with_maps(world, tracer, maps, &shadows).only_for(needed)
    });
    let mut scatter = scatter.map(|settings| {
        timings.time("form factors", || {
            let first = settings.first_bounce.scatterer();
            let mut stage = Scatter::new(world, settings, first);
            stage.prime(earlier);
            stage
        })
    });
    let n = world.facet_count();
    let with_planets = scatter.as_ref().is_some_and(Scatter::has_planets);
    let mut acc = Accumulators::new(kept, bins, scatter.is_some(), with_planets);
    let mut shines: Vec<Vec<f64>> = Vec::new();
    let sweeping = shadows.sweeps && direct.sweeps(0);
    // A sweep computes every step of a chunk of facets at once: no block of steps.
    let batch = match sweeping {
        true => 0,
        false => steps_per_batch(scatter.as_ref(), scatter.is_some(), bands.is_some(), n)
            .min(states.len())
            .max(1),
    };
    let mut directs = vec![vec![0.0; n]; batch];
    let mut scattered = vec![vec![0.0; n]; if scatter.is_some() { batch } else { 0 }];
    let mut counts = StepCounts::default();
    let mut repeats = Repeats::new(computed, states.len());
    progress.begin_steps(states.len() as u64);
    if sweeping {
        let runs = (acc.total_stats).facet_runs(sweep_chunk_facets(states.len(), n), states.len());
        counts = timings.time("direct irradiance", || {
            direct.sweep(0, states, runs, progress)
        })?;
    }
    for (c, chunk) in states
        .chunks(batch.max(1))
        .enumerate()
        .take_while(|_| !sweeping)
    {
        let directs = &mut directs[..chunk.len()];
        let lanes = chunk.len().min(scattered.len());
        let scattered = &mut scattered[..lanes];
        if progress.cancelled() {
            return Err(Error::Cancelled);
        }
        let first = c * batch;
        counts += timings.time("direct irradiance", || {
            repeats.compute(first, chunk, directs, |states, outs| {
                direct.compute_steps_each(states, outs)
            })
        })?;
        let lights = repeats.lights(first, directs);
        if let Some(stage) = scatter.as_mut() {
            timings.time("scattered light", || {
                let mut s: Vec<&mut [f64]> = scattered.iter_mut().map(Vec::as_mut_slice).collect();
                stage.step_many(chunk, &lights, &mut s);
                shines = stage.take_planet_shine();
            });
        }
        if let Some(bands) = bands.as_deref_mut() {
            timings.time("spectral bands", || {
                bands.add_steps(chunk, &lights, scatter.as_mut())
            });
        }
        timings.time("statistics", || acc.add_steps(&lights, scattered, &shines));
        for (k, state) in chunk.iter().enumerate() {
            if let Some(on_step) = on_step.as_mut() {
                timings.time("history", || {
                    on_step(state, acc.step(k, &lights, scattered))
                })?;
            }
            progress.step_done();
        }
    }
    progress.end_steps();
    let horizon_bounds = direct.bound_records().to_vec();
    Ok(Simulation {
        stats: acc.total_stats,
        counts,
        parts: scatter
            .zip(acc.part_stats)
            .map(|(stage, (direct, scattered))| ScatterParts {
                direct,
                scattered,
                planet: acc.planet_stats,
                record: stage.record,
            }),
        horizon_maps: records,
        horizon_bounds,
    })
}

/// The most bytes a run spends keeping one period of every facet's direct light when
/// its geometry repeats ([`Repetition::computed`]).
pub const REPEAT_KEEP_MAX_BYTES: f64 = 1024.0 * 1024.0 * 1024.0;

/// How the geometry of a run's steps repeats, and what keeping one period of every
/// facet's direct light would take.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Repetition {
    pub steps: usize,
    /// [`crate::ephemeris::repeat_period`]: `steps` when nothing repeats.
    pub period: usize,
    pub kept_bytes: f64,
}

impl Repetition {
    /// The repetition of `states` for `facets` facets.
    pub fn of(states: &[EpochState], facets: usize) -> Repetition {
        let period = repeat_period(states);
        Repetition {
            steps: states.len(),
            period,
            kept_bytes: (period * facets * std::mem::size_of::<f64>()) as f64,
        }
    }

    /// Whether the geometry repeats within the run.
    pub fn repeats(&self) -> bool {
        self.period < self.steps
    }

    /// The steps (the first ones) whose direct light the run computes: one period when
    /// the geometry repeats and that period's light fits in [`REPEAT_KEEP_MAX_BYTES`],
    /// every step otherwise. The later steps take theirs from it.
    pub fn computed(&self) -> usize {
        match self.repeats() && self.kept_bytes <= REPEAT_KEEP_MAX_BYTES {
            true => self.period,
            false => self.steps,
        }
    }
}

/// The direct light of a run's first `computed` steps, kept when the geometry repeats so
/// that every later step takes its own from the step a whole number of periods earlier,
/// and their counts, which the later steps count again: a run's counts are those of
/// every step however many were computed, so that the parts of a run split in time add
/// up to the counts of one run.
struct Repeats {
    computed: usize,
    kept: Vec<Vec<f64>>,
    kept_counts: Vec<StepCounts>,
    keeps: bool,
}

impl Repeats {
    fn new(computed: usize, steps: usize) -> Repeats {
        Repeats {
            computed,
            kept: Vec::new(),
            kept_counts: Vec::new(),
            keeps: computed < steps,
        }
    }

    /// Steps of the block starting at step `first` that are computed, not repeated.
    fn fresh(&self, first: usize, block: usize) -> usize {
        self.computed.saturating_sub(first).min(block)
    }

    /// Computes with `compute` into `outs` the direct light of the steps of `chunk` (the
    /// first numbered `first`) among the first `computed`, keeps it when later steps
    /// repeat it, and returns the counts of every step of the chunk.
    fn compute(
        &mut self,
        first: usize,
        chunk: &[EpochState],
        outs: &mut [Vec<f64>],
        compute: impl FnOnce(&[EpochState], &mut [&mut [f64]]) -> Result<Vec<StepCounts>>,
    ) -> Result<StepCounts> {
        let fresh = self.fresh(first, chunk.len());
        let mut counts = StepCounts::default();
        if fresh > 0 {
            let mut views: Vec<&mut [f64]> =
                (outs[..fresh].iter_mut()).map(Vec::as_mut_slice).collect();
            let each = compute(&chunk[..fresh], &mut views)?;
            each.iter().for_each(|&c| counts += c);
            if self.keeps {
                self.kept.extend(outs[..fresh].iter().cloned());
                self.kept_counts.extend(each);
            }
        }
        for k in fresh..chunk.len() {
            counts += self.kept_counts[(first + k) % self.computed];
        }
        Ok(counts)
    }

    /// The direct light of each step of the block starting at step `first`: the computed
    /// ones from `outs`, the repeated ones (not copied) from the kept period.
    fn lights<'a>(&'a self, first: usize, outs: &'a [Vec<f64>]) -> Vec<&'a [f64]> {
        let fresh = self.fresh(first, outs.len());
        (outs.iter().enumerate())
            .map(|(k, out)| match k < fresh {
                true => out.as_slice(),
                false => self.kept[(first + k) % self.computed].as_slice(),
            })
            .collect()
    }
}

/// The horizon maps of the bodies flagged in `uses` (none for the others), each read
/// from the cache or built, and where each came from.
fn obtain_maps(
    world: &World,
    shadows: &Shadows,
    uses: &[bool],
    progress: &dyn Progress,
) -> Result<(Vec<Option<HorizonMap>>, Vec<MapRecord>)> {
    let mut records = Vec::new();
    let mut maps = Vec::with_capacity(world.bodies.len());
    for (b, body) in world.bodies.iter().enumerate() {
        if !uses.get(b).copied().unwrap_or(false) {
            maps.push(None);
            continue;
        }
        let (map, record) = shadows.obtain(body, shadows.band(b), progress)?;
        records.push(record);
        maps.push(Some(map));
    }
    Ok((maps, records))
}

/// Tells the user about the one long silent stage of a BVH run: the tree and horizon
/// bound of every body that shadows itself without a map (the bound read from the cache
/// where `cached`), and roughly how long they take.
fn announce_bvh_build(
    world: &World,
    (mapped, cached): (&[bool], &[bool]),
    detail: BoundDetail,
    progress: &dyn Progress,
) {
    let bounded = choice::bounded(world, mapped);
    let facets: usize = bounded.iter().map(|b| b.mesh.len()).sum();
    let sectors = match detail {
        BoundDetail::Whole => 0.0,
        BoundDetail::Sectors => sectors_extra_seconds(world, mapped, cached),
    };
    if facets > 0 {
        let what = if choice::bounds_all_cached(world, mapped, cached) {
            "the tree (the horizon bound read from the cache)"
        } else {
            "the tree and the horizon bound"
        };
        progress.note(&format!(
            "tracer bvh: building {what} of {facets} facets once ({} on one core)",
            choice::about_seconds(choice::bound_seconds(world, mapped, cached) + sectors)
        ));
    }
}

/// Steps computed before their statistics are added, as one block (and, with scattered
/// light, solved side by side): with scattered light up to [`LANES`] when the stage
/// exchanges light through no inter-body block (one body, or bodies beside planets),
/// otherwise one; without, as many as `BLOCK_BYTES` of per-step buffers hold, up to
/// `MAX_BLOCK_STEPS`. Without `scatter` at hand (the memory estimate), the most a
/// scattering run may take.
pub fn steps_per_batch(
    scatter: Option<&Scatter>,
    scattering: bool,
    bands: bool,
    facets: usize,
) -> usize {
    match scatter {
        Some(stage) if !stage.has_inter_body_pairs() => LANES,
        Some(_) => 1,
        None if scattering => LANES,
        None => {
            let step_bytes = facets.max(1) * 8 * step_buffers(false, bands);
            (BLOCK_BYTES / step_bytes).clamp(1, MAX_BLOCK_STEPS)
        }
    }
}

/// Buffers of one value per facet a step of a block holds: its direct irradiance, with
/// scattered light the scattered part, with bands each band's direct, scattered and
/// total.
pub fn step_buffers(scattering: bool, bands: bool) -> usize {
    1 + usize::from(scattering) + if bands { 3 } else { 0 }
}

/// The per-step buffers a block of steps may hold without scattered light: a block of
/// steps lets the statistics update each facet's moments and CDF counts for all of them
/// at once (see [`FacetStats::add_steps`]); 128 MiB keeps 16 steps up to a million
/// facets, 64 up to 262,144.
const BLOCK_BYTES: usize = 128 << 20;

/// The longest block. The direct stage takes a block's steps in one parallel pass, and
/// each pass wakes the idle threads: on a 2-vCPU VM a wake-up took 2–4 ms in about one
/// pass in four, a third of a 16-step pass at 49k facets, so small meshes take longer
/// blocks (the statistics gain a little too: `bench_stats`, 5.2 ns per facet and step in
/// blocks of 16, 4.2 in blocks of 32).
const MAX_BLOCK_STEPS: usize = 64;

/// The statistics a run accumulates block by block: of the total, and with scattered
/// light of its direct and scattered parts.
struct Accumulators {
    /// The facets statistics are kept for (those of the bodies that get outputs).
    kept: Selection,
    total_stats: FacetStats,
    /// With scattered light: (direct, scattered).
    part_stats: Option<(FacetStats, FacetStats)>,
    /// With planets: statistics of their light as it arrives.
    planet_stats: Option<FacetStats>,
    /// With scattered light, per step of the block: the total (global order).
    totals: Vec<Vec<f64>>,
    /// The kept facets' direct, scattered and total irradiance of the step the history
    /// sees, when not every facet is kept.
    kept_direct: Vec<f64>,
    kept_scattered: Vec<f64>,
    kept_total: Vec<f64>,
}

/// Slices of a block's buffers.
fn slices(buffers: &[Vec<f64>]) -> Vec<&[f64]> {
    buffers.iter().map(Vec::as_slice).collect()
}

impl Accumulators {
    fn new(kept: Selection, bins: Bins, with_parts: bool, with_planets: bool) -> Accumulators {
        let facets = kept.count();
        Accumulators {
            planet_stats: with_planets.then(|| FacetStats::new(facets, bins)),
            kept,
            total_stats: FacetStats::new(facets, bins),
            part_stats: with_parts
                .then(|| (FacetStats::new(facets, bins), FacetStats::new(facets, bins))),
            totals: Vec::new(),
            kept_direct: Vec::new(),
            kept_scattered: Vec::new(),
            kept_total: Vec::new(),
        }
    }

    /// Adds a block of consecutive steps: their direct and (with parts) scattered
    /// irradiance, and with planets counted apart their planet light (global order).
    fn add_steps(&mut self, directs: &[&[f64]], scattered: &[Vec<f64>], shines: &[Vec<f64>]) {
        if let Some(stats) = self.planet_stats.as_mut() {
            stats.add_steps_of(&slices(shines), &self.kept);
        }
        let Some((direct_stats, scattered_stats)) = self.part_stats.as_mut() else {
            self.total_stats.add_steps_of(directs, &self.kept);
            return;
        };
        self.totals.resize_with(directs.len(), Vec::new);
        for ((total, d), s) in self.totals.iter_mut().zip(directs).zip(scattered) {
            total.clear();
            total.extend(d.iter().zip(s).map(|(d, s)| d + s));
        }
        self.total_stats
            .add_steps_of(&slices(&self.totals), &self.kept);
        direct_stats.add_steps_of(directs, &self.kept);
        scattered_stats.add_steps_of(&slices(scattered), &self.kept);
    }

    /// The kept facets' irradiance of step `k` of the block [`Accumulators::add_steps`]
    /// last added, as the history sees it.
    fn step<'a>(
        &'a mut self,
        k: usize,
        directs: &[&'a [f64]],
        scattered: &'a [Vec<f64>],
    ) -> StepIrradiance<'a> {
        let direct = self.kept.pick(directs[k], &mut self.kept_direct);
        if self.part_stats.is_none() {
            return StepIrradiance {
                total: direct,
                parts: None,
            };
        }
        StepIrradiance {
            total: self.kept.pick(&self.totals[k], &mut self.kept_total),
            parts: Some((
                direct,
                self.kept.pick(&scattered[k], &mut self.kept_scattered),
            )),
        }
    }
}

/// [`simulate`] of direct sunlight without timings, progress or per-step output: the
/// statistics alone.
pub fn statistics(
    world: &World,
    states: &[EpochState],
    tracer: TracerKind,
    bins: Bins,
) -> Result<Simulation> {
    simulate(
        world,
        states,
        Options::direct(tracer, bins),
        &mut Timings::default(),
        &Silent,
        None,
    )
}
