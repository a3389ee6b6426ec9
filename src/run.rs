//! Run: the whole pipeline for one scene, from the TOML file to the output folder.
//!
//! In: a validated [`Scene`] and an output folder. Out: the files described in
//! [`crate::output`] and the [`RunRecord`] also saved as `run.json`. Progress is reported
//! through [`Progress`] so the CLI can draw a bar and a service can track jobs.

use crate::bands::Bands;
use crate::ephemeris::fixed::{normalized_direction, FixedGeometry, FixedSun};
use crate::ephemeris::spice::{parse_aberration, Kernels, SpiceBody, SpiceEphemeris, SpiceMember};
use crate::ephemeris::spin::{Spin, SpinModel};
use crate::ephemeris::synthetic::{CircularOrbit, SyntheticMotion};
use crate::ephemeris::{flux_at, Ephemeris, EpochState};
use crate::error::{Error, Result};
use crate::illum::{Direct, StepCounts};
use crate::mesh::generate::ellipsoid;
use crate::mesh::inspect::inspect;
use crate::mesh::projection::PolarStereographic;
use crate::mesh::LengthUnit;
use crate::mesh::{read_mesh, Mesh};
use crate::output::record::{input_file, BodyRecord, InputFile, RunRecord};
use crate::output::{self, HistoryWriter};
use crate::plan::Plan;
use crate::scatter::{Scatter, ScatterRecord, Settings as ScatterSettings, LANES};
use crate::scene::{
    BodySection, EphemerisSection, FixedSection, Orient, Scene, Shape, SpiceSection, SpinSection,
};
use crate::stats::{Bins, FacetStats};
use crate::trace::TracerKind;
use crate::world::{Body, Pose, World};
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use std::path::Path;
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
    /// fails with [`Error::Cancelled`] and writes no result.
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

/// Wall-clock timings of named stages.
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

/// The scene's SPICE kernels, loaded, if it is a SPICE scene.
pub fn load_kernels(scene: &Scene) -> Result<Option<Kernels>> {
    match &scene.ephemeris {
        EphemerisSection::Spice(s) => Kernels::load(&s.kernels).map(Some),
        _ => Ok(None),
    }
}

/// Loads or generates every body's mesh, applies the orientation option and inspects it.
/// Ellipsoids without radii take them from the kernels' text PCK.
pub fn build_world(
    scene: &Scene,
    kernels: Option<&Kernels>,
) -> Result<(World, Vec<BodyRecord>, Vec<String>)> {
    let mut world = World::default();
    let mut records = Vec::new();
    let mut warnings = Vec::new();
    for (i, b) in scene.bodies.iter().enumerate() {
        let (mut mesh, file, shape) = load_shape(scene, i, kernels)?;
        let mut report = inspect(&mesh);
        let flip = match b.orient {
            Orient::AsIs => false,
            Orient::Flip => true,
            Orient::Outward if !report.closed => {
                warnings.push(format!(
                    "body '{}': orient = \"outward\" needs a closed mesh; left as it is",
                    b.name
                ));
                false
            }
            Orient::Outward => report.signed_volume_m3 < 0.0,
        };
        if flip {
            mesh = flipped(mesh);
            report = inspect(&mesh);
            warnings.push(format!(
                "body '{}': every facet was flipped (orient option)",
                b.name
            ));
        }
        warnings.extend(
            report
                .problems()
                .into_iter()
                .map(|p| format!("body '{}': {p}", b.name)),
        );
        let convex = report.convex;
        records.push(BodyRecord {
            name: b.name.clone(),
            mesh: file,
            shape,
            report,
        });
        world.bodies.push(Body::new(b.name.clone(), mesh, convex));
    }
    Ok((world, records, warnings))
}

/// Body `i`'s mesh, its file record (none when generated) and a description.
fn load_shape(
    scene: &Scene,
    i: usize,
    kernels: Option<&Kernels>,
) -> Result<(Mesh, Option<InputFile>, String)> {
    let b = &scene.bodies[i];
    match b.shape() {
        Shape::File {
            path,
            units,
            format,
        } => {
            let mut raw = read_mesh(path, format)?;
            if let Some(p) = &b.stereographic {
                let projection = PolarStereographic {
                    pole: p.pole,
                    radius: p.radius_km * 1000.0 / units.metres(),
                };
                raw = projection.apply(raw);
            }
            let mesh = Mesh::from_raw(raw, units);
            Ok((
                mesh,
                Some(input_file(path)?),
                format!("mesh file {}", path.display()),
            ))
        }
        Shape::Ellipsoid { radii_km, levels } => {
            let radii = match (radii_km, b.naif_id, kernels) {
                (Some(r), _, _) => DVec3::from_array(r),
                (None, Some(id), Some(k)) => k.radii_km(id).ok_or_else(|| Error::Scene {
                    path: scene.path.clone(),
                    key: format!("body[{i}].ellipsoid.radii_km"),
                    msg: format!("the loaded text PCKs give no BODY{id}_RADII; give radii_km"),
                })?,
                _ => {
                    return Err(Error::Scene {
                        path: scene.path.clone(),
                        key: format!("body[{i}].ellipsoid.radii_km"),
                        msg: "missing".into(),
                    })
                }
            };
            let mesh = Mesh::from_raw(ellipsoid(levels, radii), LengthUnit::Km);
            let shape = format!(
                "ellipsoid {} x {} x {} km, {} facets",
                radii.x,
                radii.y,
                radii.z,
                mesh.len()
            );
            Ok((mesh, None, shape))
        }
    }
}

fn flipped(mesh: Mesh) -> Mesh {
    let raw = crate::mesh::RawMesh {
        vertices: mesh.vertices,
        triangles: mesh.triangles.iter().map(|&[a, b, c]| [a, c, b]).collect(),
    };
    Mesh::from_raw(raw, crate::mesh::LengthUnit::M)
}

/// The scene's ephemeris; a SPICE scene takes its loaded kernels.
pub fn build_ephemeris(scene: &Scene, kernels: Option<Kernels>) -> Result<Box<dyn Ephemeris>> {
    Ok(match (&scene.ephemeris, kernels) {
        (EphemerisSection::Spin(s), _) => Box::new(spin_model(scene, s)),
        (EphemerisSection::Fixed(f), _) => Box::new(fixed_geometry(scene, f)),
        (EphemerisSection::Spice(s), Some(k)) => Box::new(spice_ephemeris(scene, s, k)?),
        (EphemerisSection::Spice(s), None) => {
            Box::new(spice_ephemeris(scene, s, Kernels::load(&s.kernels)?)?)
        }
    })
}

fn spice_ephemeris(scene: &Scene, s: &SpiceSection, kernels: Kernels) -> Result<SpiceEphemeris> {
    let members = scene
        .bodies
        .iter()
        .map(|b| spice_member(b, &kernels))
        .collect::<Result<Vec<_>>>()?;
    let first_period_s = match &members[0] {
        SpiceMember::Kernel(body) => body.rotation_period_s,
        SpiceMember::Synthetic { .. } => None,
    };
    let (step_s, count) = match (scene.stop, s.step_s, s.spins) {
        (Some(stop), Some(step), _) => (
            step,
            ((stop - scene.start).to_seconds() / step).ceil() as usize,
        ),
        (_, _, Some(spins)) => {
            let per_spin = s.steps_per_spin.unwrap_or(360);
            let period_s = match scene.bodies[0].spin_period_h {
                Some(h) => h * 3600.0,
                None => first_period_s.ok_or_else(|| Error::Scene {
                    path: scene.path.clone(),
                    key: "body[0].spin_period_h".into(),
                    msg: "the PCK gives this body no rotation rate: set the spin period".into(),
                })?,
            };
            (
                period_s / per_spin as f64,
                (per_spin as f64 * spins).round().max(1.0) as usize,
            )
        }
        _ => unreachable!("validated by Scene::load"),
    };
    let epochs = (0..count)
        .map(|k| scene.start + hifitime::Duration::from_seconds(step_s * k as f64))
        .collect();
    SpiceEphemeris::new(
        kernels,
        members,
        epochs,
        step_s,
        parse_aberration(&s.aberration).flatten(),
        s.solar_constant_w_m2,
    )
}

/// A SPICE-mode body: placed by the kernels in its frame, or synthetically.
fn spice_member(b: &BodySection, kernels: &Kernels) -> Result<SpiceMember> {
    let motion = match (b.naif_id, &b.orbit) {
        (Some(id), _) => {
            let body = match &b.frame {
                Some(frame) => SpiceBody::with_frame(kernels, &b.name, id, frame)?,
                None => SpiceBody::new(kernels, &b.name, id)?,
            };
            return Ok(body.into());
        }
        (None, Some(o)) => SyntheticMotion::Orbit(CircularOrbit::new(
            o.radius_km,
            o.period_h * 3600.0,
            o.pole_ra_deg,
            o.pole_dec_deg,
            o.phase_deg,
        )),
        (None, None) => SyntheticMotion::Fixed {
            offset_km: DVec3::from_array(b.position_km),
        },
    };
    Ok(SpiceMember::Synthetic {
        name: b.name.clone(),
        motion,
    })
}

fn spin_model(scene: &Scene, s: &SpinSection) -> SpinModel {
    let latitude = match (
        s.subsolar_latitude_deg,
        s.obliquity_deg,
        s.solar_longitude_deg,
    ) {
        (Some(lat), _, _) => lat.to_radians(),
        (None, Some(obl), Some(ls)) => (obl.to_radians().sin() * ls.to_radians().sin()).asin(),
        _ => 0.0,
    };
    let hour = 3600.0;
    let period_s = scene.bodies[0].spin_period_h.unwrap_or(1.0) * hour;
    let steps = ((s.steps_per_period as f64 * s.periods).round() as usize).max(1);
    SpinModel {
        start: scene.start,
        duration_s: period_s * s.periods,
        steps,
        sun_dir_scene: SpinModel::sun_dir_for_subsolar_latitude(latitude),
        sun_distance_m: s.distance_au * crate::AU_M,
        solar_constant_w_m2: s.solar_constant_w_m2,
        bodies: scene
            .bodies
            .iter()
            .map(|b| Spin {
                period_s: b.spin_period_h.map(|p| p * hour),
                initial_angle_rad: b.initial_rotation_deg.to_radians(),
                position_m: DVec3::from_array(b.position_km) * 1000.0,
            })
            .collect(),
    }
}

fn fixed_geometry(scene: &Scene, f: &FixedSection) -> FixedGeometry {
    FixedGeometry {
        start: scene.start,
        step_s: f.step_s,
        suns: f
            .sun
            .iter()
            .map(|s| {
                // A Sun given only by its flux has no distance: NaN, not a made-up one.
                let distance_m = s.distance_au.map_or(f64::NAN, |au| au * crate::AU_M);
                FixedSun {
                    dir_scene: normalized_direction(s.direction).unwrap_or(DVec3::X),
                    distance_m,
                    flux_w_m2: s
                        .flux_w_m2
                        .unwrap_or_else(|| flux_at(f.solar_constant_w_m2, distance_m)),
                }
            })
            .collect(),
        poses: scene
            .bodies
            .iter()
            .map(|b| Pose {
                body_to_scene: DMat3::IDENTITY,
                position_m: DVec3::from_array(b.position_km) * 1000.0,
            })
            .collect(),
    }
}

/// Every step's geometry, computed in parallel.
pub fn epoch_states(ephemeris: &dyn Ephemeris) -> Result<Vec<EpochState>> {
    (0..ephemeris.steps())
        .into_par_iter()
        .map(|k| ephemeris.state(k))
        .collect()
}

/// The result of stepping through time: statistics and counters.
pub struct Simulation {
    /// Statistics of the total irradiance (direct plus scattered).
    pub stats: FacetStats,
    pub counts: StepCounts,
    /// With scattering: statistics of the direct and the scattered parts, and what the
    /// scattered-light stage did.
    pub parts: Option<Parts>,
}

/// Direct and scattered statistics of a run with scattered light.
pub struct Parts {
    pub direct: FacetStats,
    pub scattered: FacetStats,
    pub record: ScatterRecord,
}

/// One step's irradiance (W/m², global facet order).
#[derive(Debug, Clone, Copy)]
pub struct StepIrradiance<'a> {
    /// Direct plus scattered.
    pub total: &'a [f64],
    /// With scattering: (direct, scattered).
    pub parts: Option<(&'a [f64], &'a [f64])>,
}

/// Computes direct irradiance at every step and accumulates statistics. `on_step` sees
/// each step's irradiance (global facet order), e.g. to stream the history.
pub fn simulate(
    world: &World,
    states: &[EpochState],
    tracer: TracerKind,
    bins: Bins,
    timings: &mut Timings,
    progress: &dyn Progress,
    mut on_step: impl FnMut(&EpochState, &[f64]) -> Result<()>,
) -> Result<Simulation> {
    simulate_with_scatter(
        world,
        states,
        tracer,
        None,
        None,
        bins,
        timings,
        progress,
        |s, e| on_step(s, e.total),
    )
}

/// [`simulate`] with scattered light when `scatter` is given: after the direct
/// irradiance of each step, the scattered-light solve; statistics of the total and of
/// both parts.
#[allow(clippy::too_many_arguments)]
pub fn simulate_with_scatter(
    world: &World,
    states: &[EpochState],
    tracer: TracerKind,
    scatter: Option<ScatterSettings>,
    mut bands: Option<&mut Bands>,
    bins: Bins,
    timings: &mut Timings,
    progress: &dyn Progress,
    mut on_step: impl FnMut(&EpochState, StepIrradiance) -> Result<()>,
) -> Result<Simulation> {
    let direct = timings.time("trace build", || Direct::new(world, tracer));
    let mut scatter = scatter.map(|settings| {
        timings.time("form factors", || {
            let first = settings.first_bounce.scatterer();
            Scatter::new(world, settings, first)
        })
    });
    let n = world.facet_count();
    let mut stats = FacetStats::new(n, bins);
    let mut part_stats = scatter
        .as_ref()
        .map(|_| (FacetStats::new(n, bins), FacetStats::new(n, bins)));
    // With scattered light on a single body, whose exchange areas are the same at every
    // step, up to LANES steps are traced first and then solved together.
    let batch = if scatter.is_some() && world.bodies.len() == 1 {
        LANES
    } else {
        1
    };
    let mut directs = vec![vec![0.0; n]; batch];
    let mut scattered = vec![vec![0.0; n]; batch];
    let mut total = vec![0.0; n];
    let mut counts = StepCounts::default();
    progress.begin_steps(states.len() as u64);
    for chunk in states.chunks(batch) {
        for (state, irradiance) in chunk.iter().zip(directs.iter_mut()) {
            if progress.cancelled() {
                return Err(Error::Cancelled);
            }
            counts += timings.time("direct irradiance", || direct.compute(state, irradiance))?;
        }
        if let Some(stage) = scatter.as_mut() {
            timings.time("scattered light", || {
                let d: Vec<&[f64]> = directs.iter().map(Vec::as_slice).collect();
                let mut s: Vec<&mut [f64]> = scattered.iter_mut().map(Vec::as_mut_slice).collect();
                let lanes = chunk.len();
                stage.step_many(chunk, &d[..lanes], &mut s[..lanes])
            });
        }
        for ((state, irradiance), scattered) in chunk.iter().zip(&directs).zip(&scattered) {
            let step = match part_stats.as_mut() {
                Some((direct_stats, scattered_stats)) => {
                    timings.time("statistics", || {
                        total
                            .iter_mut()
                            .zip(irradiance.iter().zip(scattered))
                            .for_each(|(t, (d, s))| *t = d + s);
                        stats.add_step(&total);
                        direct_stats.add_step(irradiance);
                        scattered_stats.add_step(scattered);
                    });
                    StepIrradiance {
                        total: &total,
                        parts: Some((irradiance, scattered)),
                    }
                }
                None => {
                    timings.time("statistics", || stats.add_step(irradiance));
                    StepIrradiance {
                        total: irradiance,
                        parts: None,
                    }
                }
            };
            if let Some(bands) = bands.as_deref_mut() {
                timings.time("spectral bands", || {
                    bands.add_step(state, irradiance, scatter.as_mut())
                });
            }
            timings.time("history", || on_step(state, step))?;
            progress.step_done();
        }
    }
    progress.end_steps();
    Ok(Simulation {
        stats,
        counts,
        parts: scatter
            .zip(part_stats)
            .map(|(stage, (direct, scattered))| Parts {
                direct,
                scattered,
                record: stage.record,
            }),
    })
}

/// [`simulate`] without timings, progress or per-step output: the statistics alone.
pub fn statistics(
    world: &World,
    states: &[EpochState],
    tracer: TracerKind,
    bins: Bins,
) -> Result<Simulation> {
    simulate(
        world,
        states,
        tracer,
        bins,
        &mut Timings::default(),
        &Silent,
        |_, _| Ok(()),
    )
}

/// CDF bins covering the largest flux of the run.
pub fn bins_for(scene: &Scene, states: &[EpochState]) -> Bins {
    let max_flux = states
        .iter()
        .flat_map(|s| s.bodies.iter().map(|b| b.flux_w_m2))
        .fold(0.0, f64::max);
    Bins::covering(scene.run.bin_width_w_m2, max_flux)
}

/// Runs `scene`, writing results into `out_dir`.
pub fn run_scene(scene: &Scene, out_dir: &Path, progress: &dyn Progress) -> Result<RunRecord> {
    let mut timings = Timings::default();
    prepare_output_dir(out_dir)?;
    let kernels = timings.time("kernels", || load_kernels(scene))?;
    let kernel_files = match &kernels {
        Some(k) => k
            .files()
            .iter()
            .map(|f| input_file(f))
            .collect::<Result<Vec<_>>>()?,
        None => Vec::new(),
    };
    let (world, bodies, warnings) =
        timings.time("mesh input", || build_world(scene, kernels.as_ref()))?;
    for w in &warnings {
        progress.note(&format!("warning: {w}"));
    }
    let ephemeris = build_ephemeris(scene, kernels)?;
    let states = timings.time("ephemeris", || epoch_states(ephemeris.as_ref()))?;
    let scatter = ScatterSettings::from_scene(scene, &world)?;
    let mut plan = Plan::new(scene, &world, states.len());
    if let Some(settings) = &scatter {
        plan.set_scatter(settings.decisions(&world, &states));
    }
    progress.note(&plan.to_string());
    let bins = bins_for(scene, &states);
    let csv = scene.output.csv;
    let mut history = scene
        .output
        .history
        .then(|| HistoryWriter::new(out_dir, csv, &world));
    let mut bands = Bands::from_scene(scene, &world, scatter.as_ref(), bins)?;
    let sim = simulate_with_scatter(
        &world,
        &states,
        scene.run.tracer,
        scatter,
        bands.as_mut(),
        bins,
        &mut timings,
        progress,
        |s, e| history.as_mut().map_or(Ok(()), |h| h.write_step(s, e)),
    )?;
    let mut named: Vec<(String, &FacetStats)> = Vec::new();
    if let Some(p) = &sim.parts {
        named.push(("direct".into(), &p.direct));
        named.push(("scattered".into(), &p.scattered));
    }
    let band_parts = bands.map(Bands::into_parts).unwrap_or_default();
    named.extend(band_parts.iter().map(|(name, stats)| (name.clone(), stats)));
    let parts = &named[..];
    let mut outputs = timings.time("output", || -> Result<Vec<_>> {
        let mut files = output::write_summary(out_dir, csv, &world, &sim.stats, parts)?;
        files.extend(output::write_cdf(out_dir, csv, &world, &sim.stats, parts)?);
        files.extend(output::write_geometry(out_dir, csv, &world, &states)?);
        if let Some(h) = history.take() {
            files.extend(h.finish()?);
        }
        if scene.output.ply {
            for (b, offset) in world.offsets().into_iter().enumerate() {
                let path = out_dir.join(format!("{}.ply", world.bodies[b].name));
                output::ply::write_ply(&path, &world.bodies[b].mesh, &sim.stats, offset)?;
                files.push(path);
            }
        }
        Ok(files)
    })?;
    outputs.push(out_dir.join("run.json"));
    let record = RunRecord {
        program: "slim".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        name: scene.name.clone(),
        scene: InputFile {
            path: scene.path.clone(),
            sha256: output::record::sha256_hex(&scene.source),
        },
        kernels: kernel_files,
        bodies,
        plan,
        counts: sim.counts,
        scatter: sim.parts.map(|p| p.record),
        bins_w_m2: bins,
        duration_s: ephemeris.duration_s(),
        threads: rayon::current_num_threads(),
        timings_s: timings.0,
        warnings,
        outputs: outputs
            .iter()
            .filter_map(|p| Some(p.file_name()?.to_string_lossy().into_owned()))
            .collect(),
    };
    record.write(out_dir)?;
    Ok(record)
}

/// Creates the output folder and clears a previous run out of it: the files its
/// `run.json` lists, unfinished `.partial` files, then `run.json` itself. The folder never
/// vouches for files this run has not written; nothing else in it is touched.
fn prepare_output_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let record = dir.join("run.json");
    let listed = std::fs::read(&record)
        .ok()
        .and_then(|bytes| serde_json::from_slice::<PreviousRun>(&bytes).ok())
        .map_or_else(Vec::new, |r| r.outputs);
    let partial = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|entry| entry.ok()?.file_name().into_string().ok())
        .filter(|name| name.ends_with(".partial"));
    for name in listed
        .into_iter()
        .filter(|n| n != "run.json")
        .chain(partial)
    {
        if Path::new(&name).file_name() == Some(std::ffi::OsStr::new(&name)) {
            remove_if_present(&dir.join(name))?;
        }
    }
    remove_if_present(&record)
}

/// The part of an earlier `run.json` needed to clear its files.
#[derive(serde::Deserialize)]
struct PreviousRun {
    outputs: Vec<String>,
}

fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(path, e)),
    }
}
