//! Plan: what a scene needs, decided before any work starts.
//!
//! In: the world (bodies, convexity) and the scene's options. Out: a [`Plan`] — the stages
//! that run, the ones left out and why — printed by the CLI and stored in `run.json`. A
//! scene pays only for what it needs.

use crate::budget::Estimate;
use crate::horizon::{HorizonMode, SunShape};
use crate::scene::Scene;
use crate::trace::TracerKind;
use crate::world::World;
use serde::{Deserialize, Serialize};

/// One decision of the plan.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Decision {
    /// The stage or piece of work.
    pub stage: String,
    /// Whether it runs.
    pub runs: bool,
    /// Why.
    pub reason: String,
}

/// The plan of a run.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Plan {
    pub bodies: usize,
    pub facets: usize,
    pub steps: usize,
    pub tracer: String,
    pub decisions: Vec<Decision>,
    /// The memory the run will hold, estimated before it is allocated (empty in a plan
    /// made without the step geometry, and in records older than the estimate).
    #[serde(default)]
    pub memory: Estimate,
}

/// The stage of the plan's decision on steps that repeat ([`crate::prepare`]).
pub const REPEATED_STEPS: &str = "repeated steps";

impl Plan {
    /// Whether later steps take the direct light of the first period instead of
    /// computing it (the geometry repeats; [`crate::ephemeris::repeat_period`]).
    pub fn repeats(&self) -> bool {
        (self.decisions.iter()).any(|d| d.stage == REPEATED_STEPS && d.runs)
    }

    /// The plan for `scene` over `world` with `steps` steps, its shadows traced by
    /// `tracer` (chosen, and why: [`crate::trace::choice::choose`]); `maps[b]` says
    /// whether body `b` takes its own shadows from a horizon map.
    pub fn new(
        scene: &Scene,
        world: &World,
        steps: usize,
        (tracer, why): (TracerKind, String),
        maps: &[bool],
    ) -> Plan {
        let mut decisions = vec![
            Decision {
                stage: "direct irradiance".into(),
                runs: true,
                reason: "E = S·max(0, n·s) at every facet centroid; facets facing away from the \
                         Sun get E = 0 and no shadow ray"
                    .into(),
            },
            Decision {
                stage: "shadow tracer".into(),
                runs: true,
                reason: why,
            },
        ];
        assert_eq!(maps.len(), world.bodies.len(), "one map flag per body");
        for (body, &mapped) in world.bodies.iter().zip(maps) {
            let rays = own_shadows(scene, tracer, mapped);
            decisions.push(if body.convex {
                Decision {
                    stage: format!("self-shadowing of '{}'", body.name),
                    runs: false,
                    reason: "the mesh is a closed convex surface: no facet facing the Sun can be \
                             hidden by the same body"
                        .into(),
                }
            } else if body.casters.is_some() {
                Decision {
                    stage: format!("self-shadowing of '{}'", body.name),
                    runs: true,
                    reason: format!(
                        "the mesh and its surroundings ({} facets that only cast shadows): \
                         {rays}",
                        body.shadow_mesh().len() - body.mesh.len()
                    ),
                }
            } else {
                Decision {
                    stage: format!("self-shadowing of '{}'", body.name),
                    runs: true,
                    reason: format!("the mesh is not convex (or not closed): {rays}"),
                }
            });
        }
        decisions.push(between_bodies(scene, world));
        decisions.extend(world.bodies.iter().filter(|b| !b.outputs).map(|b| {
            Decision {
                stage: format!("outputs of '{}'", b.name),
                runs: false,
                reason:
                    "outputs = false: it casts shadows (and scatters light) only; no statistics, \
                     summary or CDF rows, history or PLY (its geometry rows stay)"
                        .into(),
            }
        }));
        decisions.push(Decision {
            stage: "scattered light".into(),
            runs: false,
            reason: if scene.scatter.as_ref().is_some_and(|s| !s.enabled) {
                "switched off ([scatter] enabled = false): direct sunlight only".into()
            } else {
                "not asked for (no [scatter] section): direct sunlight only".into()
            },
        });
        decisions.push(Decision {
            stage: "history output".into(),
            runs: scene.output.history,
            reason: if scene.output.history {
                "asked for: one row per step and facet, streamed".into()
            } else {
                "not asked for ([output] history = true): statistics are streamed, no per-step \
                 values are kept"
                    .into()
            },
        });
        Plan {
            bodies: world.bodies.len(),
            facets: world.facet_count(),
            steps,
            tracer: tracer.name().to_string(),
            decisions,
            memory: Estimate::default(),
        }
    }
}

/// How a body's own shadows are found with a horizon map (`mapped`), or else by rays.
fn own_shadows(scene: &Scene, tracer: TracerKind, mapped: bool) -> String {
    let shadows = scene.shadows();
    match (mapped, scene.sun(), shadows.mode) {
        (false, ..) => own_rays(scene, tracer),
        (true, SunShape::Point, HorizonMode::Exact) => "from its horizon map (next line), with \
             a ray, through a BVH, only where the map is not certain"
            .into(),
        (true, ..) => "from its horizon map (next line), without rays".into(),
    }
}

/// How a body's own shadows are found without a map: by rays, which the BVH tracer's
/// horizon bound spares where the Sun (or the whole disk) stands above everything the
/// facet sees, and for a disk its cone tests decide first.
fn own_rays(scene: &Scene, tracer: TracerKind) -> String {
    let bvh = tracer == TracerKind::Bvh;
    match (scene.sun(), bvh) {
        (SunShape::Point, false) => "one shadow ray per facet facing the Sun".to_string(),
        (SunShape::Point, true) => "one shadow ray per facet facing the Sun below its horizon \
                                    bound (tracer bvh)"
            .to_string(),
        (SunShape::Disk, false) => format!(
            "shadow rays toward {} points of the disk (run.sun_samples) per facet that sees \
             part of it",
            scene.run.sun_samples
        ),
        (SunShape::Disk, true) => format!(
            "per facet whose horizon bound the disk does not clear, the disk's cone through \
             the tree (tracer bvh): clear, covered, or its {} sample rays (run.sun_samples) \
             answered by the few facets reaching in",
            scene.run.sun_samples
        ),
    }
}

/// How other bodies' shadows are found, and for a disk Sun what each caster costs.
fn between_bodies(scene: &Scene, world: &World) -> Decision {
    let stage = "shadows between bodies".to_string();
    if world.bodies.len() < 2 {
        return Decision {
            stage,
            runs: false,
            reason: "one body".into(),
        };
    }
    let pairs = "each step, only pairs whose bounding spheres can reach into each other's \
                 shadow are traced";
    let reason = match scene.sun() {
        SunShape::Point => pairs.to_string(),
        SunShape::Disk => {
            let casters: Vec<String> = world
                .bodies
                .iter()
                .map(|b| match b.ellipsoid_radii_m {
                    Some(_) => format!("'{}' hides the disk in closed form (an ellipsoid)", b.name),
                    None => format!(
                        "'{}' by {} rays per facet through the disk (run.sun_samples; {}× a \
                         point Sun's rays)",
                        b.name, scene.run.sun_samples, scene.run.sun_samples
                    ),
                })
                .collect();
            format!(
                "{pairs}, and only facets whose view of the disk a caster can reach: {}",
                casters.join("; ")
            )
        }
    };
    Decision {
        stage,
        runs: true,
        reason,
    }
}

impl Plan {
    /// Puts each horizon-map decision after the self-shadowing decision of its body
    /// (stage "horizon map of 'name'"), or at the end.
    pub fn set_horizon_maps(&mut self, decisions: Vec<Decision>) {
        for d in decisions {
            let body = d.stage.trim_start_matches("horizon map of ");
            let at = self
                .decisions
                .iter()
                .position(|x| x.stage == format!("self-shadowing of {body}"))
                .map_or(self.decisions.len(), |i| i + 1);
            self.decisions.insert(at, d);
        }
    }

    /// Replaces the scattered-light decision by the scattering stage's own decisions.
    pub fn set_scatter(&mut self, decisions: Vec<Decision>) {
        let at = self
            .decisions
            .iter()
            .position(|d| d.stage == "scattered light")
            .unwrap_or(self.decisions.len());
        self.decisions
            .splice(at..(at + 1).min(self.decisions.len()), decisions);
    }
}

impl std::fmt::Display for Plan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "plan: {}, {} facets, {} steps, tracer {}",
            plural(self.bodies, "body", "bodies"),
            self.facets,
            self.steps,
            self.tracer
        )?;
        for d in &self.decisions {
            let mark = if d.runs { "run " } else { "skip" };
            writeln!(f, "  {mark} {}: {}", d.stage, d.reason)?;
        }
        if !self.memory.items.is_empty() {
            writeln!(f, "  memory: {}", self.memory)?;
        }
        Ok(())
    }
}

fn plural(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}
