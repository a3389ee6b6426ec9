//! Choice: which tracer `tracer = "auto"` (the default) takes for a run.
//!
//! In: the world, the number of steps the run computes, the Sun's shape (a point, or a
//! disk sampled by so many rays per facet) and which bodies take their own shadows from a
//! horizon map. Out: a concrete [`TracerKind`] and the reason, for the plan.
//!
//! Every tracer classifies every ray identically, so the choice changes run time only.
//! The Sun-view tracer needs no setup but rebuilds its grid at every step; the BVH tracer
//! builds once a tree and, for each body that shadows itself without a map, a horizon
//! bound, which then spares most rays (and under a disk Sun most of the samples' rays,
//! by its cone tests). The bound is what costs: about 14 µs of CPU per facet at 49k
//! facets, growing slowly with the facets that cast shadows. So the BVH is taken when the
//! run's steps spare more than that, counted on one core as measured with `cargo run
//! --release --example bench_direct -- MESH --threads 1` (2026-11-26, 2-core AMD EPYC;
//! the `build s` column and the difference per step between the two tracers):
//!
//! | mesh | bound, s | Sun-view, ms/step | BVH, ms/step | point Sun: saved per facet-step | disk, 32 samples: Sun-view, BVH (ms/step) |
//! |---|---:|---:|---:|---:|---:|
//! | m1phobos, 32,070 | 0.455 | 9.46 | 2.30 | 0.223 µs | 252, 11.9 |
//! | Itokawa, 49,152 | 0.625 | 9.96 | 3.42 | 0.133 µs | 324, 16.6 |
//!
//! (The bounds and the disk's cone tests as since 2021f95; the Sun-view disk figures are
//! from the same day, before.)
//!
//! The model takes the lower saving, so that a run near the break-even keeps the tracer
//! that needs no setup. With two cores the BVH gains more (its steps scale better than
//! the Sun-view grid's), which the model leaves out on the same side.
//!
//! With the BVH, [`crate::horizon::shadows::bound_detail_for_run`] then picks the
//! bound's detail the same way: by sectors of azimuth (a build 5–8× as dear, each step
//! about 1.8× faster under a point Sun) once the run's steps spare more than the sectors
//! cost, else whole.

use super::TracerKind;
use crate::world::{Body, World};

/// CPU seconds per facet of the BVH's tree and horizon bound over `casters` facets: a
/// fixed part and one growing as √N (the triangles that set a horizon lie along a line
/// across the mesh), fitted from above to the bounds measured on 2026-11-26
/// (`bench_direct --tracer bvh --threads 1`, since 2021f95): 14.2 µs on m1phobos (32k
/// facets), 12.7 µs at 49k, 16.8 µs at 786k and 19.3 µs at 3.1M; the model gives 14.3,
/// 14.5, 17.5 and 21.5.
fn bound_s_per_facet(casters: usize) -> f64 {
    13.5e-6 + 0.0045e-6 * (casters as f64).sqrt()
}

/// CPU seconds the BVH spares over the Sun-view tracer per facet and step: one ray's
/// worth for a point Sun (`disk_samples` `None`); for a disk Sun, the Sun-view tracer's
/// rays toward every sample against the BVH's cone tests (6.3–7.5 µs measured with 32
/// samples).
fn saved_s_per_facet_step(disk_samples: Option<u32>) -> f64 {
    const POINT: f64 = 0.128e-6;
    match disk_samples {
        None => POINT,
        Some(samples) => 6.0e-6 * samples as f64 / 32.0,
    }
}

/// The bodies that get a horizon bound with the BVH tracer: those that shadow themselves
/// without a horizon map (`maps[b]`).
pub fn bounded<'w>(world: &'w World, maps: &[bool]) -> Vec<&'w Body> {
    (world.bodies.iter().zip(maps))
        .filter(|&(body, &map)| needs_bound(body, map))
        .map(|(body, _)| body)
        .collect()
}

/// Whether `body` gets a horizon bound: it shadows itself and has no map (`map`).
pub(crate) fn needs_bound(body: &Body, map: bool) -> bool {
    !body.convex && !map
}

/// CPU seconds per facet of the BVH's tree alone, as when the horizon bound is read from
/// the cache: 0.8 µs measured at 49k facets, 1.4 µs at 786k (`Bvh::build`, one thread,
/// 2026-11-26).
const TREE_S_PER_FACET: f64 = 1.5e-6;

/// CPU seconds on one core that the BVH tracer's trees and whole horizon bounds take to
/// build (the [`bounded`] bodies'), a bound in the cache (`cached[b]`) costing only its
/// tree. (Bounds by sectors cost more:
/// [`crate::horizon::shadows::sectors_extra_seconds`].)
pub fn bound_seconds(world: &World, maps: &[bool], cached: &[bool]) -> f64 {
    (world.bodies.iter().zip(maps).zip(cached))
        .filter(|((body, &map), _)| needs_bound(body, map))
        .map(|((b, _), &cached)| {
            let per_facet = if cached {
                TREE_S_PER_FACET
            } else {
                bound_s_per_facet(b.shadow_mesh().len())
            };
            b.mesh.len() as f64 * per_facet
        })
        .sum()
}

/// A setup's time for the plan: "about 1.2 s", or "under 0.1 s".
pub fn about_seconds(s: f64) -> String {
    if s < 0.05 {
        "under 0.1 s".into()
    } else {
        format!("about {s:.1} s")
    }
}

/// Whether every body that needs a horizon bound has it in the cache (`cached[b]`).
pub fn bounds_all_cached(world: &World, maps: &[bool], cached: &[bool]) -> bool {
    (world.bodies.iter().zip(maps).zip(cached))
        .all(|((body, &map), &cached)| cached || !needs_bound(body, map))
}

/// The tracer a run of `steps` steps takes: `kind` itself unless it is
/// [`TracerKind::Auto`], and why. `disk_samples`: the rays per facet toward a disk Sun
/// (`None`: a point Sun). `maps[b]` says whether body `b` takes its own shadows from a
/// horizon map (its few remaining rays then go to a BVH whatever the tracer).
///
/// The choice counts every bound as built, even one the cache holds: it must not hang on
/// what earlier runs left behind, so that a scene's plan and counts are the same in every
/// run and every part of a run (`slim merge` compares them).
pub fn choose(
    kind: TracerKind,
    world: &World,
    steps: usize,
    disk_samples: Option<u32>,
    maps: &[bool],
) -> (TracerKind, String) {
    if kind != TracerKind::Auto {
        let name = kind.name();
        return (kind, format!("run.tracer = \"{name}\""));
    }
    let bounded = bounded(world, maps);
    if bounded.is_empty() {
        return match world.bodies.len() {
            1 => (
                TracerKind::Sunview,
                "auto: sunview, nothing to bound (the body is convex, or has a horizon map) and \
                 no other body: no setup"
                    .into(),
            ),
            _ => (
                TracerKind::Bvh,
                "auto: bvh, no body needs a horizon bound (convex, or with a horizon map): its \
                 trees alone answer the bodies' rays on each other, without a grid per step"
                    .into(),
            ),
        };
    }
    let bound_s = bound_seconds(world, maps, &vec![false; maps.len()]);
    let facets: usize = bounded.iter().map(|b| b.mesh.len()).sum();
    let per_step = facets as f64 * saved_s_per_facet_step(disk_samples);
    let break_even = (bound_s / per_step).ceil() as usize;
    let cost = about_seconds(bound_s);
    if steps >= break_even {
        (
            TracerKind::Bvh,
            format!(
                "auto: bvh, {steps} steps ≥ {break_even}, where its horizon bound ({cost} on \
                 one core) costs less than the rays it spares"
            ),
        )
    } else {
        (
            TracerKind::Sunview,
            format!(
                "auto: sunview, {steps} steps < {break_even}: too few to pay for the BVH's \
                 horizon bound ({cost} on one core; run.tracer = \"bvh\" forces it)"
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::{floor_and_wall, icosphere};
    use crate::mesh::{LengthUnit, Mesh};
    use glam::DVec3;

    /// A world of the given bodies, each with its convexity as stated.
    fn world(bodies: Vec<(Mesh, bool)>) -> World {
        let bodies = (bodies.into_iter().enumerate())
            .map(|(k, (mesh, convex))| Body::new(format!("b{k}"), mesh, convex))
            .collect();
        World { bodies }
    }

    fn wall() -> Mesh {
        Mesh::from_raw(floor_and_wall(3.0, 4.0, 50.0), LengthUnit::M)
    }

    /// The break-even follows the bound's cost over the saving per step, from both
    /// sides; a disk Sun pays for it far sooner; a kind given is kept.
    #[test]
    fn auto_takes_the_bvh_once_the_steps_pay_for_its_bound() {
        let w = world(vec![(wall(), false)]);
        let point = None;
        let facets = w.bodies[0].mesh.len();
        let casters = w.bodies[0].shadow_mesh().len();
        let even = (bound_s_per_facet(casters) / 0.128e-6).ceil() as usize;
        assert!(facets > 0 && even > 100, "{even}");
        let pick = |steps, sun: Option<u32>| choose(TracerKind::Auto, &w, steps, sun, &[false]);
        assert_eq!(pick(even, point).0, TracerKind::Bvh);
        let (kind, why) = pick(even - 1, point);
        assert_eq!(kind, TracerKind::Sunview);
        assert!(why.contains(&format!("< {even}")), "{why}");
        let disk = Some(32);
        assert_eq!(pick(even / 30, disk).0, TracerKind::Bvh);
        assert_eq!(pick(1, disk).0, TracerKind::Sunview);
        for kind in [TracerKind::Grid, TracerKind::Sunview, TracerKind::Bvh] {
            assert_eq!(choose(kind, &w, 1_000_000, point, &[false]).0, kind);
        }
    }

    /// Bodies that need no bound (convex, or with a map) cost nothing to bound: the BVH
    /// from the first step where bodies shadow each other; a lone one needs no tracer.
    #[test]
    fn auto_takes_the_bvh_when_no_body_needs_a_bound() {
        let ball = || Mesh::from_raw(icosphere(2, 1.0, DVec3::ZERO), LengthUnit::Km);
        let w = world(vec![(ball(), true), (wall(), false)]);
        let pick = |w: &World, maps: &[bool]| choose(TracerKind::Auto, w, 1, None, maps).0;
        assert_eq!(pick(&w, &[false, true]), TracerKind::Bvh);
        assert_eq!(pick(&w, &[false, false]), TracerKind::Sunview);
        assert_eq!(
            pick(&world(vec![(ball(), true)]), &[false]),
            TracerKind::Sunview
        );
    }

    /// A bound in the cache costs only its tree, some ten times less; the choice still
    /// counts it as built, so that it does not depend on what the cache holds.
    #[test]
    fn a_cached_bound_costs_only_the_tree_but_the_choice_ignores_it() {
        let w = world(vec![(wall(), false)]);
        let casters = w.bodies[0].shadow_mesh().len();
        let facets = w.bodies[0].mesh.len() as f64;
        let built = bound_seconds(&w, &[false], &[false]);
        let cached = bound_seconds(&w, &[false], &[true]);
        assert_eq!(built, facets * bound_s_per_facet(casters));
        assert_eq!(cached, facets * TREE_S_PER_FACET);
        assert!(cached * 5.0 < built, "{cached} against {built}");
        assert!(bounds_all_cached(&w, &[false], &[true]));
        assert!(!bounds_all_cached(&w, &[false], &[false]));
        assert!(
            bounds_all_cached(&w, &[true], &[false]),
            "a map needs no bound"
        );
        let even = (built / (facets * 0.128e-6)).ceil() as usize;
        let (kind, why) = choose(TracerKind::Auto, &w, even - 1, None, &[false]);
        assert_eq!(kind, TracerKind::Sunview, "{why}");
    }
}
