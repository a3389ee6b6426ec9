//! Prepare: everything a run needs, assembled once from a validated scene.
//!
//! In: a [`Scene`] (checked by [`Scene::load`]). Out: an [`Assembly`] — the loaded SPICE
//! kernels inside the ephemeris, the [`World`] of bodies (metres, each in its own frame)
//! with each mesh's inspection record and warnings, and the [`Ephemeris`]; and for a
//! whole run a [`Prepared`] — that assembly plus every step's [`EpochState`], the
//! scattered-light settings, the CDF bins (W/m²) and the [`Plan`].
//!
//! This is the only place where a scene becomes geometry: `slim run`, the service's job
//! planning and point queries, `slim render` and `slim fit` all start here.

use crate::budget::{Budget, Demand};
use crate::ephemeris::fixed::{normalized_direction, FixedGeometry, FixedSun};
use crate::ephemeris::spice::{parse_aberration, Kernels, SpiceBody, SpiceEphemeris, SpiceMember};
use crate::ephemeris::spin::{Spin, SpinModel};
use crate::ephemeris::synthetic::{CircularOrbit, SyntheticMotion};
use crate::ephemeris::{flux_at, Ephemeris, EpochState, SunReturn};
use crate::error::{Error, Result};
use crate::horizon::shadows::{bound_detail_for_run, recall_for_run, steps_back, RunSteps};
use crate::horizon::Shadows;
use crate::illum::{look_up_sweep_bytes, sweep_bytes};
use crate::mesh::generate::ellipsoid;
use crate::mesh::inspect::inspect;
use crate::mesh::projection::PolarStereographic;
use crate::mesh::{read_mesh, LengthUnit, Mesh, MeshFormat, RawMesh};
use crate::output::record::{input_file, BodyRecord, InputFile};
use crate::plan::{Decision, Plan, REPEATED_STEPS};
use crate::progress::Timings;
use crate::scatter::Settings as ScatterSettings;
use crate::scene::{
    BodySection, EphemerisSection, FixedSection, Orient, Scene, Shape, SpiceSection, SpiceSteps,
    SpinSection,
};
use crate::simulate::{Repetition, REPEAT_KEEP_MAX_BYTES};
use crate::stats::Bins;
use crate::trace::{choice, TracerKind};
use crate::world::{Body, Pose, World};
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use std::path::Path;

/// A scene's bodies and ephemeris: what every use of a scene starts from.
pub struct Assembly {
    /// Every body's mesh, in scene order.
    pub world: World,
    /// Each body's mesh as loaded and inspected (for `run.json`).
    pub bodies: Vec<BodyRecord>,
    /// Problems found in the meshes and what was done about them, one line each.
    pub warnings: Vec<String>,
    /// Where the Sun and every body are at each step; a SPICE ephemeris owns the kernels.
    pub ephemeris: Box<dyn Ephemeris>,
}

/// Loads the scene's kernels (SPICE scenes), builds every body's mesh and the ephemeris,
/// after checking what the scene alone asks for (generated facets, steps) against
/// `budget`. `timings` gets the stages "kernels" and "mesh input".
pub fn assemble(scene: &Scene, budget: &Budget, timings: &mut Timings) -> Result<Assembly> {
    budget.check(&scene_demand(scene).estimate())?;
    let kernels = timings.time("kernels", || load_kernels(scene))?;
    let (world, bodies, warnings) =
        timings.time("mesh input", || build_world(scene, kernels.as_ref()))?;
    let ephemeris = build_ephemeris(scene, kernels)?;
    Ok(Assembly {
        world,
        bodies,
        warnings,
        ephemeris,
    })
}

impl Assembly {
    /// The SHA-256 record of every kernel the ephemeris loaded (none without SPICE).
    pub fn kernel_files(&self) -> Result<Vec<InputFile>> {
        self.ephemeris
            .kernels()
            .map_or(&[][..], Kernels::files)
            .iter()
            .map(|f| input_file(f))
            .collect()
    }
}

/// Everything a run of the whole scene needs before its first step.
pub struct Prepared {
    pub assembly: Assembly,
    /// The geometry of every step.
    pub states: Vec<EpochState>,
    /// Scattered light, when the scene asks for it.
    pub scatter: Option<ScatterSettings>,
    /// The CDF thresholds, covering the largest flux of the run.
    pub bins: Bins,
    /// What runs and what is left out, and why.
    pub plan: Plan,
    /// The shadow tracer, `auto` resolved by the whole run's steps (a time shard takes
    /// the same, so that its counts add up to the run's).
    pub tracer: TracerKind,
    /// How the bodies' own shadows are found.
    pub shadows: Shadows,
    /// Per body, whether it uses a horizon map.
    pub horizon_maps: Vec<bool>,
}

/// [`assemble`], then every step's geometry, the scattered-light settings, the CDF bins
/// and the plan with the memory estimate; each allocation is checked against `budget`
/// first. `timings` also gets the stage "ephemeris".
pub fn prepare(scene: &Scene, budget: &Budget, timings: &mut Timings) -> Result<Prepared> {
    let mut assembly = assemble(scene, budget, timings)?;
    let mut demand = Demand {
        facets: assembly.world.facet_count() as f64,
        silent_facets: (assembly.world.facet_count() - assembly.world.output_facet_count()) as f64,
        surrounding_facets: assembly
            .world
            .bodies
            .iter()
            .map(|b| (b.shadow_mesh().len() - b.mesh.len()) as f64)
            .sum(),
        block_values: block_values(scene, assembly.world.facet_count() as f64),
        ..scene_demand(scene)
    };
    budget.check(&demand.estimate())?;
    let states = timings.time("ephemeris", || epoch_states(assembly.ephemeris.as_ref()))?;
    if let Some(first) = states.first() {
        let coincident = coincident_bodies(&assembly.world, first);
        assembly.warnings.extend(coincident);
    }
    let world = &assembly.world;
    let bins = bins_for(scene, &states)?;
    let scatter = ScatterSettings::from_scene(scene, world)?;
    demand.bins = bins.count as f64;
    demand.form_factor_entries = scatter
        .as_ref()
        .map_or(0.0, |s| s.estimated_entries(world, &states));
    // A geometry that repeats has the light of its first period computed, and the choices
    // below weigh those steps.
    let repetition = Repetition::of(&states, world.facet_count());
    let computed = repetition.computed();
    demand.repeat_values = (computed < states.len()) as u8 as f64 * computed as f64;
    let mut shadows = scene.shadows();
    // A map serves the directions the Sun takes over the steps computed.
    shadows.bands = shadows.bands_for_run(world, &states[..computed]);
    shadows.recall = recall_for_run(
        world,
        &states[..computed],
        budget.remembered_blocker_bytes(),
    );
    // A map must beat the steps taken facet by facet where the run would take them so.
    let sweepable = sweeps_by_facet(scene, world, (computed, states.len()));
    shadows.sweeps = sweepable;
    let (horizon_maps, reasons): (Vec<bool>, Vec<String>) = shadows
        .choose(world, computed, scene.run.tracer)
        .into_iter()
        .unzip();
    // Decided below, with the maps and the tracer chosen.
    shadows.sweeps = false;
    demand.horizon_map_bytes = shadows.map_bytes(world, &horizon_maps);
    let map_decisions = world
        .bodies
        .iter()
        .zip(horizon_maps.iter().zip(reasons))
        .filter(|(b, _)| !b.convex)
        .map(|(b, (&runs, reason))| Decision {
            stage: format!("horizon map of '{}'", b.name),
            runs,
            reason,
        })
        .collect();
    let (tracer, mut why) = choice::choose(
        scene.run.tracer,
        world,
        computed,
        shadows.disk_samples(),
        &horizon_maps,
    );
    let mapped = horizon_maps.first().copied().unwrap_or(false);
    if tracer == TracerKind::Bvh {
        let steps = RunSteps {
            count: computed,
            recall: shadows.recall,
        };
        let (detail, reason) =
            bound_detail_for_run(world, &horizon_maps, steps, shadows.disk_samples());
        shadows.bound_detail = detail;
        why = format!("{why}; {reason}");
        shadows.sweeps = sweepable && !mapped;
        if shadows.sweeps {
            // No block of steps is held, nor rows of recalled blockers.
            demand.block_values = 0.0;
            demand.sweep_bytes =
                sweep_bytes(states.len(), world.facet_count(), shadows.disk_samples());
            why = format!(
                "{why}; each chunk of facets takes every step in the order of the Sun's path, \
                 and a cone around the Sun decides a facet's rays while the Sun stays within it"
            );
        }
        if shadows.remembers_blockers(false) {
            let SunReturn { lag, turn_deg } = shadows.recall;
            let back = steps_back(lag);
            why = format!(
                "{why}; rays start from the blockers met {back} before, where the Sun stood \
                 {turn_deg:.1}° away"
            );
        }
    }
    if sweepable && mapped && shadows.maps_decide_alone() {
        shadows.sweeps = true;
        // No block of steps is held: each chunk of facets keeps its values for every step.
        demand.block_values = 0.0;
        demand.sweep_bytes = look_up_sweep_bytes(states.len(), world.facet_count());
        why = format!(
            "{why}; each chunk of facets takes every step from the horizon map, its \
             statistics in cache"
        );
    }
    // Counted once the tracer and the bound's detail say whose rays remember blockers.
    demand.remembered_blocker_bytes = shadows.bound_walk_bytes(world, &horizon_maps, tracer);
    let memory = demand.estimate();
    budget.check(&memory)?;
    let mut plan = Plan::new(scene, world, states.len(), (tracer, why), &horizon_maps);
    plan.set_horizon_maps(map_decisions);
    plan.decisions.extend(repeat_decision(&repetition));
    if let Some(settings) = &scatter {
        plan.set_scatter(settings.decisions(world, &states));
    }
    plan.memory = memory;
    Ok(Prepared {
        bins,
        assembly,
        states,
        scatter,
        plan,
        tracer,
        shadows,
        horizon_maps,
    })
}

/// Whether the run would take its steps facet by facet ([`crate::illum::Direct::sweep`])
/// unless its body reads a horizon map: one body that shadows itself (through the BVH
/// tracer's bound, toward a point Sun or a disk), every step computed (no repeats), and
/// nothing that needs a step's values for all facets at once (history, scattered light,
/// spectral bands).
fn sweeps_by_facet(scene: &Scene, world: &World, (computed, steps): (usize, usize)) -> bool {
    let [body] = world.bodies.as_slice() else {
        return false;
    };
    let per_step_outputs = scene.output.history || !scene.bands.is_empty();
    !body.convex
        && !scene.scatter.as_ref().is_some_and(|s| s.enabled)
        && !per_step_outputs
        && computed == steps
}

/// The plan's word on a geometry that repeats (none when it does not): whether the
/// later steps take the direct light of the first period, and what that keeps.
fn repeat_decision(repetition: &Repetition) -> Option<Decision> {
    let Repetition {
        steps,
        period,
        kept_bytes,
    } = *repetition;
    let mb = kept_bytes / 1e6;
    let stage = REPEATED_STEPS.to_string();
    match (repetition.repeats(), repetition.computed() < steps) {
        (false, _) => None,
        (true, true) => Some(Decision {
            stage,
            runs: true,
            reason: format!(
                "the bodies' geometry repeats every {period} steps: the direct light of the \
                 first {period} is computed and kept ({mb:.1} MB), the other {} copy it; \
                 statistics, history and scattered light still take every step",
                steps - period
            ),
        }),
        (true, false) => Some(Decision {
            stage,
            runs: false,
            reason: format!(
                "the bodies' geometry repeats every {period} steps, but keeping their direct \
                 light would take {mb:.0} MB (more than {:.0}): every step is computed",
                REPEAT_KEEP_MAX_BYTES / 1e6
            ),
        }),
    }
}

/// A warning for every pair of bodies that occupy the same place at `state`: centres and
/// bounding radii equal to 1 % of the smaller radius. Such a pair (a body listed twice)
/// shadows itself and doubles its scattered light, which nothing else would reveal.
fn coincident_bodies(world: &World, state: &EpochState) -> Vec<String> {
    let bodies = &world.bodies;
    let mut warnings = Vec::new();
    for a in 0..bodies.len() {
        for b in a + 1..bodies.len() {
            let (ra, rb) = (bodies[a].bounding_radius_m, bodies[b].bounding_radius_m);
            let tolerance = 0.01 * ra.min(rb);
            let apart = state.bodies[a]
                .pose
                .position_m
                .distance(state.bodies[b].pose.position_m);
            if apart <= tolerance && (ra - rb).abs() <= tolerance {
                warnings.push(format!(
                    "bodies '{}' and '{}' coincide (same place and size at the first step): \
                     each hides the other and scattered light counts both; remove one",
                    bodies[a].name, bodies[b].name
                ));
            }
        }
    }
    warnings
}

/// The facets of the scene's generated ellipsoids (20·4^levels each), known before any
/// mesh is built; mesh files count once they are read.
pub fn generated_facets(scene: &Scene) -> f64 {
    scene
        .bodies
        .iter()
        .map(|b| match b.shape() {
            Shape::Ellipsoid { levels, .. } => 20.0 * 4f64.powi(levels as i32),
            Shape::File { .. } => 0.0,
        })
        .sum()
}

/// What the scene asks for before any file is read: generated facets, steps and the sets
/// of statistics.
fn scene_demand(scene: &Scene) -> Demand {
    let scatter = scene.scatter.as_ref().is_some_and(|s| s.enabled);
    let bands = scene.bands.len() as f64;
    Demand {
        facets: generated_facets(scene),
        surrounding_facets: 0.0,
        silent_facets: 0.0,
        bodies: scene.bodies.len() as f64,
        steps: scene.step_count(),
        bins: 0.0,
        stat_sets: 1.0
            + if scatter { 2.0 } else { 0.0 }
            + if bands > 0.0 { bands + 1.0 } else { 0.0 },
        block_values: block_values(scene, generated_facets(scene)),
        history: scene.output.history,
        form_factor_entries: 0.0,
        kernel_bytes: kernel_bytes(scene),
        horizon_map_bytes: 0.0,
        remembered_blocker_bytes: 0.0,
        sweep_bytes: 0.0,
        repeat_values: 0.0,
    }
}

/// Values per facet the step loop's block of steps holds for `facets` facets.
fn block_values(scene: &Scene, facets: f64) -> f64 {
    let scattering = scene.scatter.as_ref().is_some_and(|s| s.enabled);
    let bands = !scene.bands.is_empty();
    let steps = crate::simulate::steps_per_batch(None, scattering, bands, facets as usize);
    let steps = (steps as f64).min(scene.step_count()).max(1.0);
    steps * crate::simulate::step_buffers(scattering, bands) as f64
}

/// The size of the scene's SPICE kernel files (a file that cannot be read counts 0 here:
/// loading it reports the error).
fn kernel_bytes(scene: &Scene) -> f64 {
    let EphemerisSection::Spice(s) = &scene.ephemeris else {
        return 0.0;
    };
    s.kernels
        .iter()
        .filter_map(|k| std::fs::metadata(k).ok())
        .map(|m| m.len() as f64)
        .sum()
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
        let LoadedShape {
            mut mesh,
            file,
            shape,
            ellipsoid_radii_m,
        } = load_shape(scene, i, kernels)?;
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
        let mut body = Body::new(b.name.clone(), mesh, convex);
        body.outputs = b.outputs;
        body.open = report.is_patch();
        if let Some(radii_m) = ellipsoid_radii_m {
            body = body.with_ellipsoid(radii_m);
        }
        let mut surroundings_file = None;
        if let Some(s) = &b.surroundings {
            let around = read_projected(s.mesh.as_path(), s.units, s.format, b)?;
            body = body.with_surroundings(&around);
            surroundings_file = Some(input_file(&s.mesh)?);
        }
        records.push(BodyRecord {
            name: b.name.clone(),
            mesh: file,
            shape,
            report,
            surroundings: surroundings_file,
        });
        world.bodies.push(body);
    }
    Ok((world, records, warnings))
}

/// A mesh file of body `b` in metres, taken through the body's polar-stereographic
/// projection when it has one.
fn read_projected(
    path: &Path,
    units: LengthUnit,
    format: Option<MeshFormat>,
    b: &BodySection,
) -> Result<Mesh> {
    let mut raw = read_mesh(path, format)?;
    if let Some(p) = &b.stereographic {
        let projection = PolarStereographic {
            pole: p.pole,
            radius: p.radius_km * 1000.0 / units.metres(),
        };
        raw = projection.apply(raw);
    }
    Ok(Mesh::from_raw(raw, units))
}

/// A body's mesh as read or generated.
struct LoadedShape {
    mesh: Mesh,
    /// The mesh file's record (none when generated).
    file: Option<InputFile>,
    /// What the shape is, for the plan.
    shape: String,
    /// A generated ellipsoid's semi-axes, metres.
    ellipsoid_radii_m: Option<DVec3>,
}

/// Body `i`'s shape.
fn load_shape(scene: &Scene, i: usize, kernels: Option<&Kernels>) -> Result<LoadedShape> {
    let b = &scene.bodies[i];
    match b.shape() {
        Shape::File {
            path,
            units,
            format,
        } => Ok(LoadedShape {
            mesh: read_projected(path, units, format, b)?,
            file: Some(input_file(path)?),
            shape: format!("mesh file {}", path.display()),
            ellipsoid_radii_m: None,
        }),
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
            Ok(LoadedShape {
                mesh,
                file: None,
                shape,
                ellipsoid_radii_m: Some(radii * LengthUnit::Km.metres()),
            })
        }
    }
}

fn flipped(mesh: Mesh) -> Mesh {
    let raw = RawMesh {
        vertices: mesh.vertices,
        triangles: mesh.triangles.iter().map(|&[a, b, c]| [a, c, b]).collect(),
    };
    Mesh::from_raw(raw, LengthUnit::M)
}

/// The scene's ephemeris; a SPICE scene takes its loaded kernels (or loads them).
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
    let step_s = match s.steps {
        SpiceSteps::Window { step_s, .. } => step_s,
        SpiceSteps::Spins {
            steps_per_spin,
            spins,
        } => {
            let period_s = match scene.bodies[0].spin_period_h {
                Some(h) => h * 3600.0,
                None => first_period_s.ok_or_else(|| Error::Scene {
                    path: scene.path.clone(),
                    key: "body[0].spin_period_h".into(),
                    msg: "the PCK gives this body no rotation rate: set the spin period".into(),
                })?,
            };
            let span_s = period_s * spins;
            if span_s.is_nan() || span_s > crate::scene::MAX_SPAN_S {
                return Err(scene.err(
                    "ephemeris.spins",
                    format!(
                        "the PCK's rotation period of body[0], {period_s:e} s, makes the run \
                         span {span_s:e} s; at most {:e} s: set body[0].spin_period_h",
                        crate::scene::MAX_SPAN_S
                    ),
                ));
            }
            period_s / steps_per_spin as f64
        }
    };
    let count = scene.step_count() as usize;
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
    let steps = scene.step_count() as usize;
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

/// The most CDF thresholds a run may have. Each facet keeps a count per threshold, so
/// this bounds the CDF's memory per facet; a million thresholds is 0.1 W/m² bins up to
/// 100 kW/m², far beyond any solar flux in the solar system's airless bodies.
pub const MAX_BINS: usize = 1_000_000;

/// CDF bins covering the largest flux of the run, or an error naming
/// `run.bin_width_w_m2` when they would be more than [`MAX_BINS`] (an absurdly small
/// width, or an absurd flux).
pub fn bins_for(scene: &Scene, states: &[EpochState]) -> Result<Bins> {
    let max_flux = states
        .iter()
        .flat_map(|s| s.bodies.iter().map(|b| b.flux_w_m2))
        .fold(0.0, f64::max);
    let width = scene.run.bin_width_w_m2;
    let count = (max_flux / width).ceil() + 1.0;
    if count.is_nan() || count > MAX_BINS as f64 {
        return Err(scene.err(
            "run.bin_width_w_m2",
            format!(
                "{width} W/m² bins up to the run's largest flux, {max_flux:e} W/m², are \
                 {count:e} CDF thresholds; at most {MAX_BINS}: use wider bins (or check the \
                 solar constant and fluxes)"
            ),
        ));
    }
    Ok(Bins::covering(width, max_flux))
}
