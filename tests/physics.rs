//! Physics validation of the direct-illumination engine against independent values.
//!
//! In: generated meshes (icospheres, cube, octahedron, height fields, V-grooves, plates,
//! slivers) and the real shape models under `data/shapes`. Out: comparisons with closed
//! forms (the rotating sphere, `slim::analytic::SphereLatitude`, itself checked here
//! against a brute-force quadrature), with exact analytic geometry (ray–sphere tests,
//! 2-D shadow lengths, plates a known distance apart), and between the two tracers, which
//! must classify every shadow ray identically. Every tolerance is derived in a comment;
//! nothing is compared with a value the engine computed itself, except where identity is
//! the property under test (tracer agreement, position and thread-count invariance).

use glam::{DMat3, DVec3};
use hifitime::Epoch;
use slim::analytic::SphereLatitude;
use slim::ephemeris::fixed::{FixedGeometry, FixedSun};
use slim::ephemeris::spin::{Spin, SpinModel};
use slim::ephemeris::{repeat_period, sun_return, Ephemeris, SunReturn};
use slim::horizon::band::SunBand;
use slim::horizon::bound::BoundDetail;
use slim::horizon::map::{HorizonMap, PointHorizon};
use slim::horizon::shadows::CENTRES_HEADROOM;
use slim::horizon::tangent_frame;
use slim::horizon::{HorizonMode, Shadows, SunShape};
use slim::illum::{Direct, StepCounts};
use slim::mesh::generate::{self, icosphere};
use slim::mesh::inspect::inspect;
use slim::mesh::{read_mesh, LengthUnit, Mesh, RawMesh};
use slim::prepare::epoch_states;
use slim::progress::{Silent, Timings};
use slim::simulate::{simulate, Options, Simulation, StepIrradiance};
use slim::stats::{Bins, FacetStats};
use slim::trace::{self, TracerKind};
use slim::world::{Body, Pose, World};
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::PathBuf;

// ---------------------------------------------------------------------------------------
// Helpers

const KINDS: [TracerKind; 2] = [TracerKind::Grid, TracerKind::Sunview];

/// 1361 W/m² at 1.52 AU (a Mars-like distance).
const FLUX_152: f64 = 1361.0 / (1.52 * 1.52);

fn start() -> Epoch {
    Epoch::from_tai_seconds(0.0)
}

fn mesh_m(vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Mesh {
    Mesh::from_raw(
        RawMesh {
            vertices,
            triangles,
        },
        LengthUnit::M,
    )
}

fn sphere(levels: u32, radius_m: f64) -> Mesh {
    Mesh::from_raw(icosphere(levels, radius_m, DVec3::ZERO), LengthUnit::M)
}

fn load_km(relative: &str) -> Mesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(relative);
    let raw = read_mesh(&path, None).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Mesh::from_raw(raw, LengthUnit::Km)
}

fn at(position_m: DVec3) -> Pose {
    Pose {
        body_to_scene: DMat3::IDENTITY,
        position_m,
    }
}

fn fixed(suns: &[DVec3], flux_w_m2: f64, poses: Vec<Pose>) -> FixedGeometry {
    FixedGeometry {
        start: start(),
        step_s: 1.0,
        suns: suns
            .iter()
            .map(|&dir_scene| FixedSun {
                dir_scene,
                distance_m: slim::AU_M,
                flux_w_m2,
            })
            .collect(),
        poses,
    }
}

fn run(world: &World, eph: &dyn Ephemeris, kind: TracerKind, bins: Bins) -> Simulation {
    let states = epoch_states(eph).expect("epoch states");
    simulate(
        world,
        &states,
        Options::direct(kind, bins),
        &mut Timings::default(),
        &Silent,
        None,
    )
    .expect("simulate")
}

/// Irradiance of every facet (global ids) at every step, through the engine's direct
/// stage, with the per-step counters.
fn history(world: &World, eph: &dyn Ephemeris, kind: TracerKind) -> Vec<(Vec<f64>, StepCounts)> {
    let direct = Direct::new(world, kind);
    epoch_states(eph)
        .expect("epoch states")
        .iter()
        .map(|state| {
            let mut e = vec![f64::NAN; world.facet_count()];
            let counts = direct.compute(state, &mut e).expect("compute");
            (e, counts)
        })
        .collect()
}

/// The engine's self-shadow guard, replicated from its documentation (src/illum.rs): a
/// hit counts only above `1e-9·L + 256·ε·R` over the facet's plane (L its longest edge, R
/// the body's bounding radius), i.e. at `t > h_min / cos i`.
fn min_height(mesh: &Mesh, bounding_radius_m: f64, i: usize) -> f64 {
    let [a, b, c] = mesh.corners(i);
    let longest = (b - a).length().max((c - b).length()).max((a - c).length());
    1e-9 * longest + 256.0 * f64::EPSILON * bounding_radius_m
}

/// Triangles re-oriented so that each faces away from `centre` (for convex solids built
/// by hand, where getting every winding right by eye is error-prone).
fn outward(vertices: &[DVec3], triangles: &[[u32; 3]], centre: DVec3) -> Vec<[u32; 3]> {
    triangles
        .iter()
        .map(|&[a, b, c]| {
            let [pa, pb, pc] = [a, b, c].map(|i| vertices[i as usize]);
            if (pb - pa).cross(pc - pa).dot(pa + pb + pc - 3.0 * centre) > 0.0 {
                [a, b, c]
            } else {
                [a, c, b]
            }
        })
        .collect()
}

/// Axis-aligned cube of half-side `h` about the origin, two triangles per face.
fn cube(h: f64) -> Mesh {
    let vertices: Vec<DVec3> = (0..8)
        .map(|i| {
            let s = |bit: u32| if i & bit != 0 { h } else { -h };
            DVec3::new(s(1), s(2), s(4))
        })
        .collect();
    let mut triangles = Vec::new();
    for axis in [1u32, 2, 4] {
        let others: Vec<u32> = [1u32, 2, 4].into_iter().filter(|&b| b != axis).collect();
        for side in [0, axis] {
            // Quad corners in cyclic order around the face.
            let q = [0, others[0], others[0] | others[1], others[1]].map(|o| o | side);
            triangles.push([q[0], q[1], q[2]]);
            triangles.push([q[0], q[2], q[3]]);
        }
    }
    let triangles = outward(&vertices, &triangles, DVec3::ZERO);
    mesh_m(vertices, triangles)
}

/// Regular octahedron with vertices at distance `r` on the axes.
fn octahedron(r: f64) -> Mesh {
    let vertices = vec![
        DVec3::X * r,
        -DVec3::X * r,
        DVec3::Y * r,
        -DVec3::Y * r,
        DVec3::Z * r,
        -DVec3::Z * r,
    ];
    let mut triangles = Vec::new();
    for x in [0u32, 1] {
        for y in [2u32, 3] {
            for z in [4u32, 5] {
                triangles.push([x, y, z]);
            }
        }
    }
    let triangles = outward(&vertices, &triangles, DVec3::ZERO);
    mesh_m(vertices, triangles)
}

/// A height field z(x, y) over a regular nx × ny grid of cells on [x0, x1] × [y0, y1],
/// each cell split along its (x0,y0)–(x1,y1) diagonal; facets face up (+z side).
fn height_field(
    cells: (usize, usize),
    x: (f64, f64),
    y: (f64, f64),
    z: impl Fn(f64, f64) -> f64,
) -> Mesh {
    Mesh::from_raw(generate::height_field(cells, x, y, z), LengthUnit::M)
}

/// The self-shadow guard the engine holds per facet (`Direct::t_min` at normal incidence)
/// is the documented height rounded up to an `f32`: never below it, so that rounding can
/// never let a facet's own neighbourhood count as a blocker, and above it by less than two
/// `f32` steps. The stiff case: metre facets and slivers 3,700 km from the origin, where
/// the coordinates' rounding term is most of the guard, and Itokawa at its own scale.
#[test]
fn the_self_shadow_guard_is_never_below_its_documented_height() {
    let far = DVec3::new(3.0e6, -1.0e6, 2.0e6);
    let mut slivers = generate::height_field((6, 4), (0.0, 3.0), (0.0, 0.01), |x, y| {
        0.2 * (3.0 * x).sin() + 5.0 * y
    });
    slivers.vertices.iter_mut().for_each(|v| *v += far);
    let bodies = [
        Mesh::from_raw(slivers, LengthUnit::M),
        load_km("data/shapes/itokawa/itokawa_16.obj"),
    ];
    for mesh in bodies {
        let world = World {
            bodies: vec![Body::new("body", mesh.clone(), false)],
        };
        let radius = world.bodies[0].bounding_radius_m;
        let direct = Direct::new(&world, TracerKind::Sunview);
        for i in 0..mesh.len() {
            let documented = min_height(&mesh, radius, i);
            let held = direct.t_min(0, i, 1.0);
            assert!(held >= documented, "facet {i}: {held} below {documented}");
            let step = f64::from(f32::EPSILON);
            assert!(
                held <= documented * (1.0 + 2.0 * step),
                "facet {i}: {held} over {documented}"
            );
        }
    }
}

/// The 26 directions of the grid axes, face diagonals and space diagonals.
fn lattice_directions() -> Vec<DVec3> {
    let mut dirs = Vec::new();
    for x in -1..=1 {
        for y in -1..=1 {
            for z in -1..=1 {
                if (x, y, z) != (0, 0, 0) {
                    dirs.push(DVec3::new(x as f64, y as f64, z as f64).normalize());
                }
            }
        }
    }
    dirs
}

/// Unit vector at `elevation` (rad) above the xy plane, toward horizontal direction (dx, dy).
fn elevated(dx: f64, dy: f64, elevation: f64) -> DVec3 {
    (DVec3::new(dx, dy, 0.0).normalize() * elevation.cos() + DVec3::Z * elevation.sin()).normalize()
}

// ---------------------------------------------------------------------------------------
// 1. Rotating sphere without shadows: closed form, and convergence in time and mesh

fn spin_model(steps: usize, subsolar_rad: f64) -> SpinModel {
    SpinModel {
        start: start(),
        duration_s: 3600.0,
        steps,
        sun_dir_scene: SpinModel::sun_dir_for_subsolar_latitude(subsolar_rad),
        sun_distance_m: 1.52 * slim::AU_M,
        solar_constant_w_m2: 1361.0,
        bodies: vec![Spin {
            period_s: Some(3600.0),
            initial_angle_rad: 0.3,
            position_m: DVec3::ZERO,
        }],
    }
}

/// Largest deviation over facets of each statistic from the closed form.
#[derive(Debug, Default, Clone, Copy)]
struct SphereErrors {
    mean: f64,
    max: f64,
    lit: f64,
    cdf: f64,
}

fn sphere_errors(stats: &FacetStats, closed: impl Fn(usize) -> SphereLatitude) -> SphereErrors {
    let bins = stats.bins();
    let mut e = SphereErrors::default();
    for i in 0..stats.facets() {
        let c = closed(i);
        e.mean = e.mean.max((stats.mean(i) - c.mean()).abs());
        e.max = e.max.max((stats.max(i) - c.max()).abs());
        e.lit = e.lit.max((stats.lit_fraction(i) - c.lit_fraction()).abs());
        for (b, f) in stats.cdf(i).into_iter().enumerate() {
            e.cdf = e.cdf.max((f - c.cdf(bins.threshold(b))).abs());
        }
    }
    e
}

/// Bound on |uniform-sample mean − true mean| of E(h) = S·max(0, a + b cos h) with n
/// samples per period (the rectangle rule on a periodic function). On each interval of
/// width Δ = 2π/n the rule's error is ∫K(t) dE'(t) with a Peano kernel 0 ≤ K ≤ Δ²/8, so
/// the error of the integral is at most Δ²/8 · V(E'), V the total variation of E' over a
/// period: |E''| = S·b|cos h| integrates to at most 4·S·b, and the two kinks at the
/// terminator jump by S·b·sin h₀ ≤ S·b each, so V ≤ 6·S. Dividing by 2π:
/// |error of the mean| ≤ 6·S·Δ²/(16π) = 3πS/(2n²).
fn mean_time_bound(flux: f64, n: usize) -> f64 {
    3.0 * PI * flux / (2.0 * (n * n) as f64)
}

/// The closed form itself, checked against a brute-force quadrature written here, so the
/// sphere tests do not rest on src/analytic.rs alone.
#[test]
fn closed_form_agrees_with_quadrature() {
    let m = 100_000;
    for subsolar in [0.0f64, 25f64.to_radians(), -40f64.to_radians()] {
        for lat_deg in [
            -89.0, -70.0, -50.0, -20.0, 0.0, 10.0, 45.0, 64.0, 66.0, 80.0,
        ] {
            let lat = f64::to_radians(lat_deg);
            let normal = DVec3::new(lat.cos(), 0.0, lat.sin());
            let (mut sum, mut lit, mut below) = (0.0, 0usize, 0usize);
            for k in 0..m {
                let h = 2.0 * PI * (k as f64 + 0.5) / m as f64;
                // The Sun seen from a frame that rotates by h about z.
                let s = DVec3::new(
                    subsolar.cos() * h.cos(),
                    subsolar.cos() * h.sin(),
                    subsolar.sin(),
                );
                let e = 1000.0 * normal.dot(s).max(0.0);
                sum += e;
                lit += (e > 0.0) as usize;
                below += (e <= 400.0) as usize;
            }
            let c = SphereLatitude::new(lat, subsolar, 1000.0);
            // Midpoint rule with 1e5 points: mean error ≤ 3π·1000/(2·1e10) ≈ 5e-7 W/m²
            // (same bound as above); fractions are off by at most one point each side.
            assert!(
                (c.mean() - sum / m as f64).abs() < 1e-6,
                "{lat_deg} {subsolar}"
            );
            assert!((c.lit_fraction() - lit as f64 / m as f64).abs() <= 2.0 / m as f64);
            assert!((c.cdf(400.0) - below as f64 / m as f64).abs() <= 2.0 / m as f64);
            let max = 1000.0 * (lat - subsolar).cos().max(0.0);
            assert!((c.max() - max).abs() < 1e-9);
        }
    }
}

/// Time refinement on a fixed mesh: with the facet normal's own latitude the closed form
/// is exact for the facet, so the only error is the time sampling. Shadow rays are traced
/// (convex = false) and must find nothing.
#[test]
fn rotating_sphere_converges_in_time() {
    let mesh = sphere(3, 1000.0);
    for (subsolar_deg, kind) in [(0.0f64, TracerKind::Sunview), (25.0, TracerKind::Grid)] {
        let subsolar = subsolar_deg.to_radians();
        let world = World {
            bodies: vec![Body::new("sphere", mesh.clone(), false)],
        };
        let mut mean_errors = Vec::new();
        for n in [36, 144, 576] {
            let model = spin_model(n, subsolar);
            let states = epoch_states(&model).unwrap();
            let flux = states[0].bodies[0].flux_w_m2;
            assert!((flux - FLUX_152).abs() <= 1e-12 * FLUX_152, "flux {flux}");
            let sim = run(&world, &model, kind, Bins::covering(50.0, flux));
            assert_eq!(sim.counts.shadowed, 0, "a convex sphere shadowed itself");
            assert!(sim.counts.rays > 0, "the tracer was not exercised");
            let normals = &world.bodies[0].mesh.normals;
            let e = sphere_errors(&sim.stats, |i| {
                SphereLatitude::from_normal_z(normals[i].z, subsolar, flux)
            });
            println!("time refinement δ={subsolar_deg}° n={n}: {e:?}");
            let dh = 2.0 * PI / n as f64;
            // Rounding in n·s and in the running mean: far below 1e-9·S.
            let eps = 1e-9 * flux;
            assert!(e.mean <= mean_time_bound(flux, n) + eps, "mean {e:?}");
            // The nearest sample is within Δ/2 of the noon hour angle.
            assert!(e.max <= flux * (1.0 - (dh / 2.0).cos()) + eps, "max {e:?}");
            // {E > x} is one arc of hour angle; n uniform samples count its length to
            // within one sample.
            assert!(e.lit <= 1.0 / n as f64 + 1e-12, "lit {e:?}");
            assert!(e.cdf <= 1.0 / n as f64 + 1e-12, "cdf {e:?}");
            mean_errors.push(e.mean);
        }
        assert!(
            mean_errors.windows(2).all(|w| w[1] < w[0]),
            "mean error does not shrink with the time step: {mean_errors:?}"
        );
    }
}

/// Mesh refinement with a fine time grid: against the true sphere (latitude of the facet
/// centroid's radial direction ĉ), the error is the facet normal's tilt from ĉ, which
/// shrinks with the facet size.
#[test]
fn rotating_sphere_converges_with_mesh() {
    let subsolar = 25f64.to_radians();
    let n = 720;
    let model = spin_model(n, subsolar);
    let flux = epoch_states(&model).unwrap()[0].bodies[0].flux_w_m2;
    let mut mean_errors = Vec::new();
    for level in 2..=5 {
        let mesh = sphere(level, 1000.0);
        let world = World {
            bodies: vec![Body::new("sphere", mesh, true)],
        };
        let sim = run(
            &world,
            &model,
            TracerKind::Sunview,
            Bins::covering(50.0, flux),
        );
        let mesh = &world.bodies[0].mesh;
        let radial = |i: usize| mesh.centroids[i].normalize();
        let e = sphere_errors(&sim.stats, |i| {
            SphereLatitude::from_normal_z(radial(i).z, subsolar, flux)
        });
        // max(0, ·) is 1-Lipschitz, so for every Sun direction |E(n) − E(ĉ)| ≤ S·|n − ĉ|;
        // the same holds for the mean and the maximum over time. Add the time-sampling
        // bounds of the test above.
        let tilt = (0..mesh.len())
            .map(|i| (mesh.normals[i] - radial(i)).length())
            .fold(0.0, f64::max);
        let dh = 2.0 * PI / n as f64;
        let eps = 1e-9 * flux;
        println!("mesh refinement level {level}: max |n−ĉ| = {tilt:.3e}, {e:?}");
        assert!(
            e.mean <= flux * tilt + mean_time_bound(flux, n) + eps,
            "{e:?}"
        );
        assert!(
            e.max <= flux * tilt + flux * (1.0 - (dh / 2.0).cos()) + eps,
            "{e:?}"
        );
        mean_errors.push(e.mean);
    }
    assert!(
        mean_errors.windows(2).all(|w| w[1] < w[0]),
        "mean error does not shrink with the mesh: {mean_errors:?}"
    );
}

// ---------------------------------------------------------------------------------------
// 2. Convex bodies never shadow themselves

/// Sun directions that stress a convex mesh: grid axes and diagonals, every edge of some
/// facets (both ways), facet normals, and Suns grazing a facet at 1e-2 … 1e-11 rad.
fn awkward_suns(mesh: &Mesh, facets: usize) -> Vec<DVec3> {
    let mut suns = lattice_directions();
    let stride = (mesh.len() / facets).max(1);
    for f in (0..mesh.len()).step_by(stride) {
        let [a, b, c] = mesh.corners(f);
        for e in [b - a, c - b, a - c] {
            suns.push(e.normalize());
            suns.push(-e.normalize());
        }
        let n = mesh.normals[f];
        suns.push(n);
        let t = (b - a).normalize();
        for g in [1e-2, 1e-5, 1e-7, 1e-9, 1e-11] {
            suns.push((n * g + t * (1.0 - g * g).sqrt()).normalize());
        }
    }
    suns
}

#[test]
fn convex_bodies_are_never_shadowed() {
    let flux = 1000.0;
    let shapes = [
        ("icosphere", sphere(2, 1000.0)),
        ("icosphere off-centre", {
            Mesh::from_raw(
                icosphere(1, 3.0, DVec3::new(40.0, -7.0, 2.0)),
                LengthUnit::M,
            )
        }),
        ("cube", cube(1.0)),
        ("octahedron", octahedron(2.0)),
    ];
    for (name, mesh) in shapes {
        assert!(inspect(&mesh).convex, "{name} must be convex for this test");
        let suns = awkward_suns(&mesh, 16);
        // convex = false: the engine must trace every lit facet and find nothing.
        let world = World {
            bodies: vec![Body::new(name, mesh, false)],
        };
        let mesh = &world.bodies[0].mesh;
        let eph = fixed(&suns, flux, vec![Pose::IDENTITY]);
        for kind in KINDS {
            let mut lit = 0;
            for (step, (e, counts)) in history(&world, &eph, kind).iter().enumerate() {
                let s = suns[step];
                assert_eq!(counts.shadowed, 0, "{name} {kind:?} sun {s}");
                for (i, &ei) in e.iter().enumerate() {
                    let cos = mesh.normals[i].dot(s);
                    if cos > 0.0 {
                        lit += 1;
                        // Same product as the engine's up to rounding of the dot product.
                        assert!(
                            ei > 0.0 && (ei - flux * cos).abs() <= 1e-12 * flux * cos,
                            "{name} {kind:?}: facet {i} sun {s}: E = {} expected {}",
                            ei,
                            flux * cos
                        );
                    } else {
                        assert_eq!(ei, 0.0);
                    }
                }
            }
            println!(
                "{name} {kind:?}: {} suns, {lit} lit facet checks",
                suns.len()
            );
        }
    }
}

/// The same through the tracers directly, with the engine's guard: every lit facet's
/// ray leaves a convex body unhit, and with `t_min = 0` as well when the origin is moved
/// off the surface along the normal by far more than rounding.
#[test]
fn convex_tracer_queries_find_nothing() {
    for (name, mesh) in [("icosphere", sphere(3, 1000.0)), ("cube", cube(0.5))] {
        let radius = Body::new(name, mesh.clone(), false).bounding_radius_m;
        let suns = awkward_suns(&mesh, 24);
        for kind in KINDS {
            let tracer = trace::build(kind, &mesh);
            for &s in &suns {
                let q = tracer.toward(s);
                for i in 0..mesh.len() {
                    let cos = mesh.normals[i].dot(s);
                    if cos <= 0.0 {
                        continue;
                    }
                    let c = mesh.centroids[i];
                    let t_min = min_height(&mesh, radius, i) / cos;
                    assert!(
                        !q.blocked(c, t_min, Some(i as u32)),
                        "{name} {kind:?} {i} {s}"
                    );
                    // Lifted 1e-6·R above the facet, a ray toward a lit direction is in
                    // the open half-space the convex body never reaches: nothing to hit.
                    let lifted = c + mesh.normals[i] * 1e-6 * radius;
                    assert!(
                        !q.blocked(lifted, 0.0, None),
                        "{name} {kind:?} {i} {s} lifted"
                    );
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// 3. Two spheres (SLIM paper, Fig. 13)

/// True when the ray `p + t·d` (t > 0, unit d) meets the open ball of `radius` about
/// `centre`; also the ray's closest approach to the centre.
fn ray_meets_ball(p: DVec3, d: DVec3, centre: DVec3, radius: f64) -> (bool, f64) {
    let o = centre - p;
    let along = o.dot(d);
    let perp = (o - along * d).length();
    (along > 0.0 && perp < radius, perp)
}

#[test]
fn two_spheres_shadow_matches_exact_spheres() {
    let r = 1.2e6;
    let centres = [DVec3::ZERO, DVec3::new(-3.0e6, 1.0e6, 0.5e6)];
    let mesh = sphere(5, r);
    let n = mesh.len();
    // The inscribed mesh lies between the balls of radius r − sag and r, sag = r − the
    // least distance from the centre to a facet plane. A ray passing the caster's centre
    // closer than r − sag must hit the mesh (the ray starts outside it); one passing
    // farther than r must miss. Only rays in between may disagree with the exact sphere.
    let sag = (0..n)
        .map(|i| r - mesh.normals[i].dot(mesh.corners(i)[0]))
        .fold(0.0, f64::max);
    // Coordinates of 1e6 m carry rounding ~1e-9 m; 1 mm is a generous margin.
    let margin = 1e-3;
    let world = World {
        bodies: vec![
            Body::new("sunward", mesh.clone(), false),
            Body::new("behind", mesh.clone(), false),
        ],
    };
    let flux = 1000.0;
    let s = DVec3::X;
    let eph = fixed(&[s], flux, centres.iter().map(|&c| at(c)).collect());
    let mut results = Vec::new();
    for kind in KINDS {
        let (e, counts) = history(&world, &eph, kind).remove(0);
        // Sphere 1 is sunward of sphere 2: never shadowed.
        for (i, &ei) in e[..n].iter().enumerate() {
            let cos = mesh.normals[i].dot(s);
            let expected = if cos > 0.0 { flux * cos } else { 0.0 };
            assert!((ei - expected).abs() <= 1e-12 * flux, "sphere 1 facet {i}");
        }
        let (mut sure_shadow, mut band, mut silhouette_cut, mut shadowed, mut disagree) =
            (0, 0, 0, 0, 0);
        for i in 0..n {
            let cos = mesh.normals[i].dot(s);
            let got = e[n + i];
            if cos <= 0.0 {
                assert_eq!(got, 0.0);
                continue;
            }
            let scene = |p: DVec3| p + centres[1];
            let (hit, perp) = ray_meets_ball(scene(mesh.centroids[i]), s, centres[0], r);
            let in_band = perp > r - sag - margin && perp < r + margin;
            let corners_differ = mesh
                .corners(i)
                .iter()
                .any(|&c| ray_meets_ball(scene(c), s, centres[0], r).0 != hit);
            band += in_band as usize;
            silhouette_cut += corners_differ as usize;
            sure_shadow += (hit && !in_band) as usize;
            let is_shadowed = got == 0.0;
            shadowed += is_shadowed as usize;
            if is_shadowed != hit {
                disagree += 1;
                assert!(
                    in_band,
                    "{kind:?}: facet {i} of sphere 2 shadowed={is_shadowed}, exact sphere \
                     says {hit}, ray passes {perp} m from the centre (band {} … {})",
                    r - sag,
                    r
                );
            } else if !is_shadowed {
                assert!(
                    (got - flux * cos).abs() <= 1e-12 * flux,
                    "{kind:?} facet {i}"
                );
            }
        }
        println!(
            "two spheres {kind:?}: shadowed {shadowed}, sure {sure_shadow}, band {band} \
             (sag {sag:.1} m), silhouette-cut {silhouette_cut}, disagreements {disagree}, \
             counts {counts:?}"
        );
        assert_eq!(counts.shadowed as usize, shadowed);
        assert!(
            sure_shadow > 1000,
            "the test scene must put a real shadow on sphere 2"
        );
        assert!(shadowed >= sure_shadow && shadowed <= sure_shadow + band);
        results.push(e);
    }
    assert!(
        results[0]
            .iter()
            .zip(&results[1])
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "Grid and Sunview differ"
    );
}

// ---------------------------------------------------------------------------------------
// 4. Every tracer classifies identically on real meshes

/// Compares each fast tracer (Sunview, and the BVH with its horizon bound) with the Grid
/// reference on every lit facet for every Sun, once through the tracers' queries (with
/// the engine's guard replicated) and once through the engine's direct stage, where the
/// BVH run also skips the rays its horizon bound clears (irradiance compared bit for
/// bit).
fn compare_tracers(name: &str, mesh: &Mesh, suns: &[DVec3]) {
    let world = World {
        bodies: vec![Body::new(name, mesh.clone(), false)],
    };
    let eph = fixed(suns, 1000.0, vec![Pose::IDENTITY]);
    let by_grid = history(&world, &eph, TracerKind::Grid);
    for kind in [TracerKind::Sunview, TracerKind::Bvh] {
        compare_queries(name, mesh, suns, world.bodies[0].bounding_radius_m, kind);
        let by_fast = history(&world, &eph, kind);
        let mut engine_mismatches = Vec::new();
        for (k, ((eg, _), (ef, _))) in by_grid.iter().zip(&by_fast).enumerate() {
            for i in 0..mesh.len() {
                if eg[i].to_bits() != ef[i].to_bits() {
                    engine_mismatches.push((i, suns[k], eg[i], ef[i]));
                }
            }
        }
        let cleared: u64 = by_fast.iter().map(|(_, c)| c.above_horizon).sum();
        println!(
            "{name} {kind:?}: {} engine mismatches, {cleared} rays cleared by the horizon bound",
            engine_mismatches.len()
        );
        assert!(
            engine_mismatches.is_empty(),
            "{name}: engine irradiance of Grid and {kind:?} differs {} times, first (facet, \
             sun, E grid, E {kind:?}): {:?}",
            engine_mismatches.len(),
            &engine_mismatches[..engine_mismatches.len().min(5)]
        );
        assert!(
            kind != TracerKind::Bvh || cleared > 0,
            "{name}: the horizon bound cleared no ray, so it went untested"
        );
    }
}

/// The highest elevation (radians) at azimuth `phi` around `up` at which a ray from `p`
/// meets `mesh`, by bisection between straight down and straight up (the blocked set of
/// a height field seen from above it is one interval from straight down).
fn horizon_by_rays(bvh: &slim::trace::bvh::Bvh, p: DVec3, up: DVec3, phi: f64) -> f64 {
    let (t1, t2) = tangent_frame(up);
    let level = t1 * phi.cos() + t2 * phi.sin();
    let blocked = |e: f64| {
        let dir = level * e.cos() + up * e.sin();
        bvh.segment_blocked(p, p + dir * 1e8, [u32::MAX; 2], 0.0)
    };
    let (mut lo, mut hi) = (-FRAC_PI_2 + 1e-6, FRAC_PI_2 - 1e-6);
    assert!(blocked(lo) && !blocked(hi));
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if blocked(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[test]
fn horizons_from_points_above_haworth_match_ray_casts() {
    // Points 2 m and 300 m above facets of the shipped Haworth patch (heights along +z),
    // among them its highest facet, whose horizon dips below the horizontal.
    let mesh = load_km("data/shapes/moon/haworth5412.obj");
    let bvh = slim::trace::bvh::Bvh::build(&mesh);
    let highest = (0..mesh.len())
        .max_by(|&a, &b| mesh.centroids[a].z.total_cmp(&mesh.centroids[b].z))
        .unwrap();
    let (mut below_horizontal, mut checked) = (0, 0);
    for i in [highest, 17, 1500, 2900, 4400, 5300] {
        for height in [2.0, 300.0] {
            let p = mesh.centroids[i] + DVec3::Z * height;
            let h = PointHorizon::build(&mesh, &bvh, p, DVec3::Z, 32);
            let width = 2.0 * PI / 32.0;
            for k in 0..32 {
                let [upper, centre] = h.wedge(k);
                // At the wedge's centre the horizon is exact; the predicate's rounding
                // and the bisection's 1e-16 leave far less than 1e-9 rad.
                let by_rays = horizon_by_rays(&bvh, p, DVec3::Z, width * (k as f64 + 0.5));
                assert!(
                    (centre - by_rays).abs() < 1e-9,
                    "facet {i} +{height} m wedge {k}: {centre} vs {by_rays}"
                );
                // Anywhere in the wedge the horizon stays under the upper bound.
                for t in [0.01, 0.3, 0.7, 0.99] {
                    let e = horizon_by_rays(&bvh, p, DVec3::Z, width * (k as f64 + t));
                    assert!(
                        e <= upper + 1e-12,
                        "facet {i} +{height} m wedge {k} at {t}: {e} > {upper}"
                    );
                }
                below_horizontal += (centre < 0.0) as usize;
                checked += 1;
            }
            // The lookup agrees with its wedge: a direction just above the centre horizon
            // at a wedge centre is above the approximate horizon there.
            let dir = |e: f64| {
                let (t1, t2) = tangent_frame(DVec3::Z);
                let phi = width * 0.5;
                (t1 * phi.cos() + t2 * phi.sin()) * e.cos() + DVec3::Z * e.sin()
            };
            let at = h.position(dir(h.wedge(0)[1] + 1e-3));
            assert_eq!(at.wedge, 0);
            assert!(at.elevation() > h.horizon(&at).elevation);
        }
    }
    assert!(
        below_horizontal > 0,
        "no horizon below the horizontal was tested"
    );
    eprintln!("{checked} wedges checked, {below_horizontal} with the horizon below the horizontal");
}

/// The engine's direct stage with a horizon map of `mesh` (`azimuths` wedges) in
/// `mode`, against the Grid reference on every facet for every Sun: the exact mode must
/// give bit-identical irradiance while sparing rays; the approximate mode's lit/dark
/// disagreements are counted and returned (share of facet–Suns facing the Sun), with
/// the step counts summed over the Suns, taken in order by one `Direct`. The map is
/// built for the band of the Suns, as `slim run` builds it.
fn compare_horizon_map(
    name: &str,
    mesh: &Mesh,
    suns: &[DVec3],
    mode: HorizonMode,
) -> (f64, StepCounts) {
    let band = SunBand::of_suns(suns.iter().copied(), 0.0);
    let (differ, facing, total) = banded_map_errors(name, mesh, suns, (mode, band));
    match mode {
        HorizonMode::Exact => {
            assert_eq!(
                differ, 0,
                "{name}: the exact horizon mode differs from the Grid"
            );
            assert!(
                total.above_horizon > 0,
                "{name}: the map spared no ray, so it went untested"
            );
        }
        HorizonMode::Approximate => assert!(total.horizon_lookups > 0),
    }
    (differ as f64 / facing as f64, total)
}

/// The facet–Suns where a horizon map built for `band` in `mode` lights a facet other
/// than the Grid does (bit for bit), of those facing the Sun, and the step counts.
fn banded_map_errors(
    name: &str,
    mesh: &Mesh,
    suns: &[DVec3],
    (mode, band): (HorizonMode, SunBand),
) -> (u64, u64, StepCounts) {
    let world = World {
        bodies: vec![Body::new(name, mesh.clone(), false)],
    };
    let eph = fixed(suns, 1000.0, vec![Pose::IDENTITY]);
    let by_grid = history(&world, &eph, TracerKind::Grid);
    let bvh = slim::trace::bvh::Bvh::build(mesh);
    let map = HorizonMap::build(mesh, mesh.len(), &bvh, (64, band));
    let shadows = Shadows {
        mode,
        ..Shadows::default()
    };
    let direct = Direct::with_maps(&world, TracerKind::Sunview, vec![Some(map)], &shadows);
    let (mut facing, mut differ, mut total) = (0u64, 0u64, StepCounts::default());
    for (state, (eg, _)) in epoch_states(&eph).expect("states").iter().zip(&by_grid) {
        let mut e = vec![f64::NAN; mesh.len()];
        total += direct.compute(state, &mut e).expect("compute");
        for i in 0..mesh.len() {
            facing += (mesh.normals[i].dot(state.bodies[0].sun_dir) > 0.0) as u64;
            differ += (e[i].to_bits() != eg[i].to_bits()) as u64;
        }
    }
    println!(
        "{name} {mode:?} ({band}): {differ} of {facing} facing facet–Suns differ; {} rays \
         cleared, {} lookups, {} rays remembered",
        total.above_horizon, total.horizon_lookups, total.remembered
    );
    (differ, facing, total)
}

/// Compares `kind`'s queries with the Grid's on every lit facet for every Sun, the
/// engine's guard replicated; the Grid must find some shadow, or the comparison is
/// vacuous.
fn compare_queries(name: &str, mesh: &Mesh, suns: &[DVec3], radius: f64, kind: TracerKind) {
    let grid = trace::build(TracerKind::Grid, mesh);
    let fast = trace::build(kind, mesh);
    let (mut rays, mut shadowed, mut mismatches) = (0, 0, Vec::new());
    for &s in suns {
        let (qg, qf) = (grid.toward(s), fast.toward(s));
        for i in 0..mesh.len() {
            let cos = mesh.normals[i].dot(s);
            if cos <= 0.0 {
                continue;
            }
            let c = mesh.centroids[i];
            let t_min = min_height(mesh, radius, i) / cos;
            let skip = Some(i as u32);
            let (g, f) = (qg.blocked(c, t_min, skip), qf.blocked(c, t_min, skip));
            if g != f {
                mismatches.push((i, s, cos, g, f));
            }
            rays += 1;
            shadowed += g as usize;
        }
    }
    println!(
        "{name} {kind:?}: {} facets, {} suns, {rays} rays, {shadowed} shadowed, {} query \
         mismatches",
        mesh.len(),
        suns.len(),
        mismatches.len(),
    );
    assert!(
        mismatches.is_empty(),
        "{name}: Grid and {kind:?} disagree on {} rays, first (facet, sun, cos i, grid \
         blocked, {kind:?} blocked): {:?}",
        mismatches.len(),
        &mismatches[..mismatches.len().min(5)],
    );
    assert!(
        shadowed > 0,
        "{name}: no shadow at all, the comparison is vacuous"
    );
}

/// Lattice directions, both directions of every edge of a few facets, a few normals and
/// some generic directions.
fn tracer_suns(mesh: &Mesh, edge_facets: usize) -> Vec<DVec3> {
    let mut suns = lattice_directions();
    for k in 0..edge_facets {
        let f = k * mesh.len() / edge_facets + k;
        let [a, b, c] = mesh.corners(f);
        for e in [b - a, c - b, a - c] {
            if e.length() > 0.0 {
                suns.extend([e.normalize(), -e.normalize()]);
            }
        }
        if mesh.normals[f] != DVec3::ZERO {
            suns.push(mesh.normals[f]);
        }
    }
    for v in [
        [0.3, -0.8, 0.52],
        [-0.61, 0.2, -0.77],
        [0.9, 0.05, -0.1],
        [0.123, 0.456, 0.789],
    ] {
        suns.push(DVec3::from_array(v).normalize());
    }
    suns
}

#[test]
fn tracers_agree_on_itokawa() {
    let mesh = load_km("data/shapes/itokawa/itokawa_16.obj");
    let suns = tracer_suns(&mesh, 3);
    compare_tracers("itokawa_16", &mesh, &suns);
    compare_horizon_map("itokawa_16", &mesh, &suns, HorizonMode::Exact);
    // The approximate mode errs only where the Sun stands within the interpolation
    // error of a facet's horizon: 0.075 % of the facing facet–Suns on this rough, small
    // shape with 64 wedges (5.6° each) when written; a broken lookup errs on tens of
    // per cent.
    let (wrong, _) = compare_horizon_map("itokawa_16", &mesh, &suns, HorizonMode::Approximate);
    assert!(wrong < 0.005, "{wrong}");
}

#[test]
fn tracers_agree_on_eros() {
    let mesh = load_km("data/shapes/eros/EROS856Vert1708Fac.txt");
    let suns = tracer_suns(&mesh, 3);
    compare_tracers("eros 1708", &mesh, &suns);
    compare_horizon_map("eros 1708", &mesh, &suns, HorizonMode::Exact);
}

/// Exposes a Sunview bug (see the report): m1phobos.obj welds into a "watertight" mesh
/// (`inspect::is_watertight`), so `SunView::toward` bins only Sun-averted facets, on the
/// premise that a ray leaving the surface starts outside the body. At its y = 0 seam the
/// model has 30 facets lying in the plane y = 0 (vertical fins under the surface, e.g.
/// 25381 with normal −y beside 25382 with normal +y): the ray from facet 25381 toward −y
/// leaves the body through the Sun-facing facet 25021 at t ≈ 20 m. Grid reports 25381
/// shadowed; Sunview, which never binned 25021, reports it fully lit (E = S).
#[test]
fn tracers_agree_on_phobos() {
    let mesh = load_km("data/shapes/phobos/m1phobos.obj");
    assert_eq!(mesh.len(), 32070);
    let mut suns = vec![
        DVec3::X,
        -DVec3::Y,
        DVec3::Z,
        DVec3::new(1.0, 1.0, 0.0).normalize(),
    ];
    let [a, b, _] = mesh.corners(12345);
    suns.push((b - a).normalize());
    suns.push(DVec3::new(-0.4, 0.7, 0.3).normalize());
    compare_tracers("phobos m1", &mesh, &suns);
}

/// Directions along the edges of `facets` of `mesh`, each turned to rise (+z), those
/// that do: on terrain, grazing Suns exactly along the mesh's edges.
fn rising_edges(mesh: &Mesh, facets: &[usize]) -> Vec<DVec3> {
    facets
        .iter()
        .flat_map(|&f| {
            let [a, b, c] = mesh.corners(f);
            [b - a, c - b, a - c]
        })
        .map(|e| if e.z < 0.0 { -e } else { e })
        .filter(|e| e.z > 0.0)
        .map(DVec3::normalize)
        .collect()
}

#[test]
fn tracers_agree_on_haworth_terrain() {
    let mesh = load_km("data/shapes/moon/haworth5412.obj");
    // Open terrain facing +z: low Suns as python-flux uses (3°), other elevations, the
    // horizontal axes (elevation exactly 0, lighting only tilted facets), and Suns along
    // mesh edges that rise (edges of a terrain are nearly horizontal: grazing Suns).
    let mut suns = Vec::new();
    for az in (0..360).step_by(30) {
        let az = f64::to_radians(az as f64);
        suns.push(elevated(az.cos(), az.sin(), 3f64.to_radians()));
    }
    for (az, el) in [(45.0f64, 10.0f64), (200.0, 1.0), (100.0, 25.0)] {
        let az = az.to_radians();
        suns.push(elevated(az.cos(), az.sin(), el.to_radians()));
    }
    suns.extend([DVec3::X, DVec3::Y, -DVec3::X, -DVec3::Y, DVec3::Z]);
    suns.push(DVec3::new(1.0, 1.0, 0.0).normalize());
    suns.extend(rising_edges(&mesh, &[0, 1000, 2706, 4999]));
    compare_tracers("haworth", &mesh, &suns);
    compare_horizon_map("haworth", &mesh, &suns, HorizonMode::Exact);
}

/// A map built for the band of a spin's Suns (one declination about z, as a spin scene's
/// Suns keep; `SunBand`) leaves out every facet outside the cone of those directions from
/// each centroid, yet its exact mode must classify every facet as the Grid does at every
/// Sun of the band: Itokawa (3,072 facets, Suns 20° above its equator) and Haworth's
/// terrain (Suns circling 4° and 0.5° above the horizontal, where the horizon decides),
/// a Sun every 3° of a turn. A map built for a band 10° off the Suns must err: the test
/// tells a band that holds the Suns from one that does not. The approximate mode, whose
/// centres a band may set lower where the horizon stands above the band, errs on no
/// more than a thousandth of the facing facet–Suns beyond the whole map's errors.
#[test]
fn a_map_for_the_suns_band_classifies_as_the_grid() {
    let cases = [
        ("itokawa_16", "data/shapes/itokawa/itokawa_16.obj", 20.0),
        ("haworth", "data/shapes/moon/haworth5412.obj", 4.0),
        ("haworth", "data/shapes/moon/haworth5412.obj", 0.5),
    ];
    for (name, path, declination) in cases {
        let mesh = load_km(path);
        let at = |d: f64| -> Vec<DVec3> {
            let d = d.to_radians();
            (0..120)
                .map(|k| {
                    let h = (k as f64 * 3.0).to_radians();
                    DVec3::new(d.cos() * h.cos(), d.cos() * h.sin(), d.sin())
                })
                .collect()
        };
        let suns = at(declination);
        let band = SunBand::of_suns(suns.iter().copied(), 0.0);
        assert!(suns.iter().all(|&s| band.holds(s)) && !band.is_whole());
        let (differ, _, total) = banded_map_errors(name, &mesh, &suns, (HorizonMode::Exact, band));
        assert_eq!(
            differ, 0,
            "{name}: the band's exact map differs from the Grid"
        );
        assert!(total.above_horizon > 0, "{name}: the map spared no ray");
        let off = SunBand::of_suns(at(declination + 10.0), 0.0);
        let (missed, _, _) = banded_map_errors(name, &mesh, &suns, (HorizonMode::Exact, off));
        assert!(missed > 0, "{name}: a band without the Suns made no error");
        // Where centres are read, a run widens the band (`CENTRES_HEADROOM`).
        let headroom = CENTRES_HEADROOM * std::f64::consts::TAU / 64.0;
        let read = SunBand::of_suns(suns.iter().copied(), headroom);
        let approximate =
            |band| banded_map_errors(name, &mesh, &suns, (HorizonMode::Approximate, band));
        let ((banded, facing, _), (whole, _, _)) = (approximate(read), approximate(SunBand::WHOLE));
        assert!(
            banded <= whole + facing / 1000,
            "{name}: {banded} against {whole} of {facing}"
        );
    }
}

/// Metre- and millimetre-sized terrain in a planet-centred frame (about 4,150 km from
/// the origin, as a lunar or Martian site's coordinates are), where every coordinate
/// carries rounding of about 5e-10 m: the BVH with its horizon bound and the exact
/// horizon map must classify every facet as the Grid does. Suns low (1° and 3°, where
/// horizons decide), higher, along the grid's axes and diagonal (rays along the cells'
/// edges), along rising mesh edges, and from centroids exactly toward nearby corners
/// (grazing them). With the triangles' widening set to zero the test still passes (the
/// margins by which a Sun must clear a bound, 1e-9, and luck; at millimetres the bound
/// and the map then clear 13 and 68 more rays, all in fact clear): it guards the
/// classification, not that safeguard alone.
#[test]
fn tracers_and_maps_agree_on_small_terrain_far_from_the_origin() {
    let offset = DVec3::new(3.9e6, 1.2e6, -0.8e6);
    for cell in [1.0, 1e-3] {
        let mut raw =
            generate::height_field((16, 16), (0.0, 16.0 * cell), (0.0, 16.0 * cell), |x, y| {
                let (x, y) = (x / cell, y / cell);
                cell * (1.5 * (x / 1.7).sin() * (y / 2.3).cos() + 0.1 * x)
            });
        raw.vertices.iter_mut().for_each(|v| *v += offset);
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let mut suns = Vec::new();
        for az in (0..360).step_by(40) {
            let az = f64::to_radians(az as f64 + 7.0);
            for el in [1.0f64, 3.0, 20.0] {
                suns.push(elevated(az.cos(), az.sin(), el.to_radians()));
            }
        }
        suns.extend([
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(1.0, 1.0, 0.0).normalize(),
        ]);
        suns.extend(rising_edges(&mesh, &[3, 200, 411]));
        for f in [3, 200, 411] {
            let (c, n) = (mesh.centroids[f], mesh.normals[f]);
            for v in mesh
                .vertices
                .iter()
                .filter(|v| (**v - c).length() < 3.0 * cell)
            {
                if n.dot(*v - c) > 0.0 && (*v - c).z > 0.0 {
                    suns.push((*v - c).normalize());
                }
            }
        }
        let name = format!("terrain of {cell} m cells far away");
        compare_tracers(&name, &mesh, &suns);
        compare_horizon_map(&name, &mesh, &suns, HorizonMode::Exact);
    }
}

/// Triangles with a corner exactly on a facet's normal line (below the floor, or above
/// it), standing over a flat floor whose normals are exactly +z, with that corner first,
/// second or third in the triangle: a corner there has no azimuth in the facet's sky,
/// and a map once gave such a triangle the span of one azimuth, clearing Suns through
/// it. Suns toward each blocker's top edge (just above, on and just below it), low all
/// around, and overhead: the BVH with its bound and the exact horizon map must classify
/// every facet as the Grid does.
#[test]
fn tracers_and_maps_agree_when_corners_stand_on_facets_normal_lines() {
    let floor = generate::height_field((8, 8), (0.0, 8.0), (0.0, 8.0), |_, _| 0.0);
    let flat = Mesh::from_raw(floor.clone(), LengthUnit::M);
    let mut raw = floor;
    let mut suns = Vec::new();
    for (j, f) in [9usize, 30, 47, 66, 85, 100].into_iter().enumerate() {
        let c = flat.centroids[f];
        assert_eq!(flat.normals[f], DVec3::Z);
        let turn = 0.7 + 1.1 * j as f64;
        let (u, v) = (
            DVec3::new(turn.cos(), turn.sin(), 0.0),
            DVec3::new(-turn.sin(), turn.cos(), 0.0),
        );
        // Below the floor on the normal line, or above it (every second blocker).
        let on_line = DVec3::new(c.x, c.y, if j % 2 == 0 { -0.5 } else { 2.5 });
        let top = [c + u * 2.0 + v * 0.6, c + u * 2.0 - v * 0.6].map(|p| p + DVec3::Z * 1.5);
        let first = raw.vertices.len() as u32;
        raw.vertices.extend([on_line, top[0], top[1]]);
        let corners = [first, first + 1, first + 2];
        raw.triangles
            .push(std::array::from_fn(|k| corners[(k + j) % 3]));
        let edge = (top[0] + top[1]) * 0.5 - c;
        for dip in [-0.5f64, 0.0, 0.5] {
            let (along, up) = (edge.truncate().length(), edge.z);
            let elevation = up.atan2(along) + dip.to_radians();
            suns.push(elevated(edge.x, edge.y, elevation));
        }
    }
    for az in (0..360).step_by(30) {
        let az = f64::to_radians(az as f64 + 3.0);
        suns.push(elevated(az.cos(), az.sin(), 5f64.to_radians()));
    }
    suns.push(DVec3::Z);
    let mesh = Mesh::from_raw(raw, LengthUnit::M);
    let name = "corners on facets' normal lines";
    compare_tracers(name, &mesh, &suns);
    compare_horizon_map(name, &mesh, &suns, HorizonMode::Exact);
}

/// The benchmark's folded body (`examples/common/folded.rs`): Phobos and a scaled
/// Itokawa interpenetrating at a neck, so that buried facets, fins and overhangs stack
/// over the same spot seen from the Sun.
#[path = "../examples/common/folded.rs"]
mod folded;

#[test]
fn tracers_agree_on_a_folded_bilobed_body() {
    let mesh = Mesh::from_raw(folded::folded_raw().expect("folded shape"), LengthUnit::Km);
    let mut suns = vec![
        DVec3::X,
        -DVec3::X,
        DVec3::Y,
        -DVec3::Z,
        DVec3::new(1.0, 1.0, 0.0).normalize(),
    ];
    // Along an edge near the neck, and a generic direction.
    let [a, b, _] = mesh.corners(32_070 + 100);
    suns.push((b - a).normalize());
    suns.push(DVec3::new(0.3, -0.8, 0.52).normalize());
    compare_tracers("folded", &mesh, &suns);
}

// ---------------------------------------------------------------------------------------
// 5. Extreme cases

/// A crater of metre-sized facets and a boulder floating above it; the pair is placed at
/// the scene origin and 20,000 km away (positions exactly representable, so the relative
/// offset is exactly the same): the irradiance must be bit-identical, and the boulder's
/// shadow under an overhead Sun must match the exact sphere.
#[test]
fn far_from_origin_equals_at_origin() {
    let terrain = height_field((24, 24), (-6.0, 6.0), (-6.0, 6.0), |x, y| {
        let r2 = x * x + y * y;
        if r2 < 16.0 {
            -2.0 * (1.0 - r2 / 16.0)
        } else {
            0.0
        }
    });
    let boulder_r = 1.5;
    let boulder = sphere(2, boulder_r);
    let lift = DVec3::new(0.0, 0.0, 6.0);
    let world = World {
        bodies: vec![
            Body::new("crater", terrain.clone(), false),
            Body::new("boulder", boulder.clone(), false),
        ],
    };
    let suns = [
        DVec3::Z,
        elevated(1.0, 0.0, 50f64.to_radians()),
        elevated(-0.5, 0.866, 35f64.to_radians()),
        elevated(-0.3, -1.0, 70f64.to_radians()),
    ];
    let far = DVec3::new(12.0e6, -16.0e6, 0.0); // 20,000 km from the origin
    assert_eq!(
        (far + lift) - far,
        lift,
        "offsets must be exact for this test"
    );
    // The crater turns about its vertical only, so the overhead Sun and the boulder's
    // centre stay where the analytic check below expects them in the crater's frame.
    let rotations = [
        (DMat3::IDENTITY, DMat3::IDENTITY),
        (
            DMat3::from_rotation_z(0.4),
            DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0),
        ),
    ];
    let sag = (0..boulder.len())
        .map(|i| boulder_r - boulder.normals[i].dot(boulder.corners(i)[0]))
        .fold(0.0, f64::max);
    for (crater_rot, boulder_rot) in rotations {
        let poses = |origin: DVec3| {
            vec![
                Pose {
                    body_to_scene: crater_rot,
                    position_m: origin,
                },
                Pose {
                    body_to_scene: boulder_rot,
                    position_m: origin + lift,
                },
            ]
        };
        let near_eph = fixed(&suns, 1000.0, poses(DVec3::ZERO));
        let far_eph = fixed(&suns, 1000.0, poses(far));
        for kind in KINDS {
            let near = history(&world, &near_eph, kind);
            let away = history(&world, &far_eph, kind);
            let mut shadowed = 0;
            for (step, ((a, ca), (b, cb))) in near.iter().zip(&away).enumerate() {
                assert_eq!(ca, cb, "{kind:?} step {step}");
                for i in 0..a.len() {
                    assert_eq!(
                        a[i].to_bits(),
                        b[i].to_bits(),
                        "{kind:?} step {step} facet {i}: {} at the origin, {} far away",
                        a[i],
                        b[i]
                    );
                }
                shadowed += ca.shadowed;
            }
            assert!(shadowed > 0, "the scene must cast shadows");
            // Overhead Sun: a height field cannot shadow itself; a terrain facet is
            // shadowed iff the vertical through its centroid meets the boulder, whose
            // inscribed mesh lies between radii r − sag and r (see the two-sphere test),
            // whatever its rotation. 1e-9 m covers rounding of metre-sized coordinates.
            let (mut in_shadow, mut band) = (0, 0);
            for i in 0..terrain.len() {
                let c = terrain.centroids[i];
                let (hit, perp) = ray_meets_ball(c, DVec3::Z, lift, boulder_r);
                let e = away[0].0[i];
                if perp < boulder_r - sag - 1e-9 || perp > boulder_r + 1e-9 {
                    assert_eq!(e == 0.0, hit, "{kind:?} facet {i} at {c}");
                } else {
                    band += 1;
                }
                in_shadow += hit as usize;
            }
            println!(
                "far body {kind:?}: shadowed facet-steps {shadowed}, overhead boulder \
                 shadow {in_shadow} facets (band {band})"
            );
            assert!(in_shadow > 20);
        }
    }
}

/// A long V-groove (two walls at slope α meeting along the y axis) lit from +x at
/// elevation e in the xz plane. In the 2-D cross-section, a point on the far (x < 0) wall
/// at horizontal distance u from the bottom is shadowed by the near wall's rim (x = W,
/// z = W tan α) iff u·(tan α + tan e) < W·(tan α − tan e); the near wall is dark
/// (n·s = sin(e − α) < 0) for e < α and lit, unshadowed, for e > α.
#[test]
fn v_groove_shadow_matches_2d_geometry() {
    let (w, alpha) = (10.0, 45f64.to_radians());
    let mesh = height_field((80, 8), (-w, w), (-20.0, 20.0), |x, _| {
        x.abs() * alpha.tan()
    });
    let world = World {
        bodies: vec![Body::new("groove", mesh.clone(), false)],
    };
    let flux = 1000.0;
    let elevations = [5.0f64, 10.0, 20.0, 30.0, 44.0, 46.0, 50.0, 80.0];
    // Mirrored Suns (from −x) swap the roles of the walls.
    let mut suns = Vec::new();
    for &e in &elevations {
        suns.push(elevated(1.0, 0.0, e.to_radians()));
        suns.push(elevated(-1.0, 0.0, e.to_radians()));
    }
    for kind in KINDS {
        for (step, (e, counts)) in history(&world, &fixed(&suns, flux, vec![Pose::IDENTITY]), kind)
            .iter()
            .enumerate()
        {
            let s = suns[step];
            let elevation = s.z.asin();
            let sign = s.x.signum();
            let u_star = w * (alpha.tan() - elevation.tan()) / (alpha.tan() + elevation.tan());
            let mut expected_shadowed = 0;
            for (i, &ei) in e.iter().enumerate() {
                let c = mesh.centroids[i];
                let cos = mesh.normals[i].dot(s);
                // u: distance from the bottom line on the wall away from the Sun.
                let u = -sign * c.x;
                let shadowed = cos > 0.0 && u > 0.0 && u < u_star;
                if cos > 0.0 && u > 0.0 && u_star > 0.0 {
                    assert!(
                        (u - u_star).abs() > 1e-6,
                        "centroid too close to the shadow edge"
                    );
                }
                expected_shadowed += shadowed as u64;
                let expected = if shadowed || cos <= 0.0 {
                    0.0
                } else {
                    flux * cos
                };
                assert!(
                    (ei - expected).abs() <= 1e-12 * flux,
                    "{kind:?} sun el {:.1}° x-sign {sign}: facet {i} (u = {u:.4}, u* = \
                     {u_star:.4}) E = {} expected {expected}",
                    elevation.to_degrees(),
                    ei
                );
            }
            assert_eq!(counts.shadowed, expected_shadowed);
            if step == 4 {
                println!(
                    "v-groove {kind:?} el 20°: {expected_shadowed} of {} facets shadowed",
                    mesh.len()
                );
            }
        }
    }
}

/// Slivers of aspect ratio 1e6 as casters and receivers, and two plates 1e-6 m apart.
#[test]
fn slivers_and_nearly_touching_plates() {
    let flux = 1000.0;
    // A strip 1 m × 1e-6 m (two slivers) 1 cm above two sliver receivers: A (centroid y =
    // 3.3e-7, under the strip) and B (centroid y = 2.33e-6, beside it). A Sun tilted by
    // s_y/s_z moves the ray's crossing of the strip's height by 0.01·s_y/s_z in y.
    let h = 0.01;
    let vertices = vec![
        DVec3::new(0.0, 0.0, h),
        DVec3::new(1.0, 0.0, h),
        DVec3::new(1.0, 1e-6, h),
        DVec3::new(0.0, 1e-6, h),
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.5, 1e-6, 0.0),
        DVec3::new(0.0, 2e-6, 0.0),
        DVec3::new(1.0, 2e-6, 0.0),
        DVec3::new(0.5, 3e-6, 0.0),
    ];
    let triangles = vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [7, 8, 9]];
    let slivers = mesh_m(vertices, triangles);
    for i in 0..4 {
        let [a, b, c] = slivers.corners(i);
        let longest = (b - a).length().max((c - b).length()).max((a - c).length());
        let aspect = longest * longest / (2.0 * slivers.areas[i]);
        assert!(aspect > 0.9e6, "facet {i} aspect {aspect}");
        assert_eq!(slivers.normals[i], DVec3::Z);
    }
    // (Sun, expected shadow of [strip, strip, A, B]): A's ray crosses z = h at
    // y = 3.3e-7 + 0.01·s_y/s_z, B's at 2.33e-6 + 0.01·s_y/s_z; shadowed iff in [0, 1e-6].
    let cases = [
        (DVec3::Z, [false, false, true, false]),
        (
            elevated(1.0, 0.0, 60f64.to_radians()),
            [false, false, true, false],
        ),
        (
            DVec3::new(0.0, -1e-4, 1.0).normalize(),
            [false, false, false, false],
        ),
        (
            DVec3::new(0.0, -2e-4, 1.0).normalize(),
            [false, false, false, true],
        ),
        (
            DVec3::new(0.3, -2e-4, 1.0).normalize(),
            [false, false, false, true],
        ),
    ];
    check_cases("slivers", &slivers, &cases, flux);

    // Two unit plates (4×4 cells each), the upper 1e-6 m above the lower, both facing up.
    let lower = height_field((4, 4), (0.0, 1.0), (0.0, 1.0), |_, _| 0.0);
    let upper = height_field((4, 4), (0.0, 1.0), (0.0, 1.0), |_, _| 1e-6);
    let k = lower.len();
    let mut vertices = lower.vertices.clone();
    vertices.extend(&upper.vertices);
    let offset = lower.vertices.len() as u32;
    let mut triangles = lower.triangles.clone();
    triangles.extend(upper.triangles.iter().map(|t| t.map(|v| v + offset)));
    let plates = mesh_m(vertices, triangles);
    // The nearest centroid to a plate edge is 1/12 m in; a Sun at 60° elevation shifts
    // the ray by 1e-6/tan 60° = 5.8e-7 m before it reaches the upper plate: still inside.
    let lower_shadowed: Vec<bool> = (0..2 * k).map(|i| i < k).collect();
    let cases: Vec<(DVec3, Vec<bool>)> = [
        DVec3::Z,
        elevated(1.0, 0.0, 60f64.to_radians()),
        elevated(-0.37, 0.8, 89f64.to_radians()),
    ]
    .into_iter()
    .map(|s| (s, lower_shadowed.clone()))
    .collect();
    check_cases("plates 1e-6 m apart", &plates, &cases, flux);
}

/// Runs one body under each listed Sun with both tracers; `expected[i]` says whether
/// facet i is shadowed; unshadowed facets must get exactly flux·(n·s).
fn check_cases<E: AsRef<[bool]>>(name: &str, mesh: &Mesh, cases: &[(DVec3, E)], flux: f64) {
    let world = World {
        bodies: vec![Body::new(name, mesh.clone(), false)],
    };
    let suns: Vec<DVec3> = cases.iter().map(|c| c.0).collect();
    let eph = fixed(&suns, flux, vec![Pose::IDENTITY]);
    for kind in KINDS {
        for (step, (e, _)) in history(&world, &eph, kind).iter().enumerate() {
            let (s, expected) = (&cases[step].0, cases[step].1.as_ref());
            for i in 0..mesh.len() {
                let cos = mesh.normals[i].dot(*s);
                assert!(cos > 0.0);
                let want = if expected[i] { 0.0 } else { flux * cos };
                assert!(
                    (e[i] - want).abs() <= 1e-12 * flux,
                    "{name} {kind:?} sun {s}: facet {i} E = {} expected {want}",
                    e[i]
                );
            }
        }
    }
}

/// A flat plate under a Sun 1e-7 rad above its plane, from many azimuths including the
/// grid axes and the cells' diagonals (exactly along facet edges): coplanar neighbours
/// never shadow. The plate sits 100 m from the body origin so the guard's rounding term
/// is not negligible against its size.
#[test]
fn grazing_sun_over_flat_plate() {
    let plate = height_field((16, 16), (100.0, 108.0), (-4.0, 4.0), |_, _| 0.0);
    let world = World {
        bodies: vec![Body::new("plate", plate.clone(), false)],
    };
    let elevation = 1e-7;
    let suns: Vec<DVec3> = [
        (1.0, 0.0),
        (0.0, 1.0),
        (-1.0, 0.0),
        (0.0, -1.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (1.0, -1.0),
        (3.0, 1.0),
        (-2.0, 5.0),
    ]
    .into_iter()
    .map(|(x, y)| elevated(x, y, elevation))
    .collect();
    let flux = 1000.0;
    for kind in KINDS {
        let eph = fixed(&suns, flux, vec![Pose::IDENTITY]);
        for (step, (e, counts)) in history(&world, &eph, kind).iter().enumerate() {
            let s = suns[step];
            assert!((s.z - elevation).abs() < 1e-20);
            assert_eq!(counts.shadowed, 0, "{kind:?} sun {s}");
            assert_eq!(counts.rays as usize, plate.len());
            for (i, &ei) in e.iter().enumerate() {
                assert_eq!(plate.normals[i], DVec3::Z);
                assert!(
                    (ei - flux * s.z).abs() <= 1e-12 * flux * s.z,
                    "{kind:?} facet {i}"
                );
            }
        }
    }
}

/// Results do not depend on the number of threads: every statistic bit for bit.
#[test]
fn thread_count_does_not_change_results() {
    let mesh = load_km("data/shapes/itokawa/itokawa_16.obj");
    let world = World {
        bodies: vec![Body::new("itokawa", mesh, false)],
    };
    let mut model = spin_model(48, 20f64.to_radians());
    model.sun_distance_m = slim::AU_M;
    let bins = Bins::covering(25.0, 1361.0);
    for kind in KINDS {
        let sims: Vec<Simulation> = [1, 2]
            .into_iter()
            .map(|threads| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| run(&world, &model, kind, bins))
            })
            .collect();
        let (a, b) = (&sims[0], &sims[1]);
        assert_eq!(a.counts, b.counts);
        assert!(a.counts.shadowed > 0);
        let s = (&a.stats, &b.stats);
        assert_eq!(s.0.steps(), s.1.steps());
        for i in 0..s.0.facets() {
            for (x, y) in [
                (s.0.min(i), s.1.min(i)),
                (s.0.max(i), s.1.max(i)),
                (s.0.mean(i), s.1.mean(i)),
                (s.0.std(i), s.1.std(i)),
                (s.0.lit_fraction(i), s.1.lit_fraction(i)),
            ] {
                assert_eq!(x.to_bits(), y.to_bits(), "{kind:?} facet {i}");
            }
            assert_eq!(s.0.histogram(i), s.1.histogram(i), "{kind:?} facet {i}");
        }
    }
}

/// A Sun moving 2° per step over Itokawa (3,072 facets) with an exact horizon map: each
/// own shadow ray looks for its blocker first on the surface around the facet that
/// blocked it at the step before (`StepCounts::remembered`), which must change no bit of
/// the irradiance against the Grid's (`compare_horizon_map`, one Direct kept over all
/// steps). Three quarters of the shadowed rays must be answered so, or the walk went
/// untested or lost its way: the last blocker alone answers 31 % of them at this pace
/// (82 % with a walk of six facets). The BVH with its bound remembers nothing.
#[test]
fn remembered_blockers_change_no_shadow() {
    let mesh = load_km("data/shapes/itokawa/itokawa_16.obj");
    let suns: Vec<DVec3> = (0..120)
        .map(|k| {
            let turn = (k as f64 * 2.0).to_radians();
            elevated(turn.cos(), turn.sin(), 10f64.to_radians())
        })
        .collect();
    let (_, total) = compare_horizon_map(
        "itokawa_16 turning slowly",
        &mesh,
        &suns,
        HorizonMode::Exact,
    );
    assert!(
        total.remembered * 4 > total.shadowed * 3,
        "remembered {} of {} shadowed",
        total.remembered,
        total.shadowed
    );
    let world = World {
        bodies: vec![Body::new("itokawa_16", mesh, false)],
    };
    let eph = fixed(&suns, 1000.0, vec![Pose::IDENTITY]);
    let by_bvh = history(&world, &eph, TracerKind::Bvh);
    assert_eq!(by_bvh.iter().map(|(_, c)| c.remembered).sum::<u64>(), 0);
}

/// A run taken facet by facet along the Sun's path (`Direct::sweep`) must give the
/// statistics of the step loop bit for bit: its cones decide a facet's rays only while
/// the Sun stays within them, by the facets reaching in, and the statistics take each
/// facet's steps in time order. The Suns come as a year of hours does (a spin of 12.13
/// steps, so that consecutive steps stand 30° apart and the path's order is not the time
/// order), on two latitudes 0.3° apart, 10° and 25° above the equator (several bands
/// of the path, short and long rays over the concavities of Itokawa), with both bounds,
/// and a disk Sun (its cones' views, and so the samples each answers, must be the step
/// loop's). The sweep must use its cones where 2,400 steps put the Suns 0.3° apart on
/// the path, none where 300 steps put them 2.4° apart, and the walks from a last blocker
/// (for the disk, the facet that covered it the step before).
#[test]
fn a_sweep_facet_by_facet_gives_the_step_loops_statistics() {
    let mesh = load_km("data/shapes/itokawa/itokawa_16.obj");
    let world = World {
        bodies: vec![Body::new("itokawa_16", mesh, false)],
    };
    for (steps, latitude) in [(2400, 10.0f64), (2400, 25.0), (300, 10.0)] {
        let suns: Vec<DVec3> = (0..steps)
            .map(|k| {
                let turn = -std::f64::consts::TAU * k as f64 / 12.13;
                let lat = (latitude + 0.3 * (k % 2) as f64).to_radians();
                DVec3::new(lat.cos() * turn.cos(), lat.cos() * turn.sin(), lat.sin())
            })
            .collect();
        let states = epoch_states(&fixed(&suns, 1000.0, vec![Pose::IDENTITY])).expect("states");
        let kinds = [BoundDetail::Whole, BoundDetail::Sectors].map(|d| (d, SunShape::Point));
        for (detail, sun) in kinds
            .into_iter()
            .chain([(BoundDetail::Whole, SunShape::Disk)])
        {
            let by = |sweeps: bool| {
                let shadows = Shadows {
                    bound_detail: detail,
                    sun,
                    sweeps,
                    ..Shadows::default()
                };
                let options = Options {
                    shadows,
                    ..Options::direct(TracerKind::Bvh, Bins::covering(20.0, 1000.0))
                };
                simulate(
                    &world,
                    &states,
                    options,
                    &mut Timings::default(),
                    &Silent,
                    None,
                )
                .expect("simulate")
            };
            let (stepped, swept) = (by(false), by(true));
            let case =
                format!("{steps} steps, latitude {latitude}°, {detail:?} bound, {sun:?} Sun");
            assert!(
                stepped.counts.shadowed > 1_000,
                "{case}: {:?}",
                stepped.counts
            );
            // 300 steps stand 2.4° apart on the path: too far for cones to pay.
            let cones = swept.counts.cones > 1_000;
            assert_eq!(cones, steps > 300, "{case}: {:?}", swept.counts);
            assert!(swept.counts.remembered > 100, "{case}: {:?}", swept.counts);
            assert_eq!(
                stepped.counts.cones, 0,
                "{case}: the step loop takes no cones"
            );
            assert_eq!(swept.stats, stepped.stats, "{case}");
            assert_eq!(swept.counts.shadowed, stepped.counts.shadowed, "{case}");
            // Under a disk, a facet kept dark answers its samples by walks where the
            // step loop may have found its cone covered and answered none.
            if sun == SunShape::Point {
                assert_eq!(swept.counts.rays, stepped.counts.rays, "{case}");
            }
        }
    }
}

/// A run whose horizon map decides alone (a disk Sun, or a point Sun in the approximate
/// mode), taken facet by facet from the map (`Direct::sweep`), must give the step loop's
/// statistics and counts bit for bit: the same lookups, each facet's steps added in time
/// order. The Suns are a year's hours as above (consecutive steps 30° apart), 500 of
/// them: more than one block of the step loop, so that the blocks' seams are crossed.
/// The swept run must not have a statistics stage of its own (else it did not sweep).
#[test]
fn a_map_read_facet_by_facet_gives_the_step_loops_statistics() {
    let mesh = load_km("data/shapes/itokawa/itokawa_16.obj");
    let world = World {
        bodies: vec![Body::new("itokawa_16", mesh, false)],
    };
    let suns: Vec<DVec3> = (0..500)
        .map(|k| {
            let turn = -std::f64::consts::TAU * k as f64 / 12.13;
            let lat = 15f64.to_radians();
            DVec3::new(lat.cos() * turn.cos(), lat.cos() * turn.sin(), lat.sin())
        })
        .collect();
    let states = epoch_states(&fixed(&suns, 1000.0, vec![Pose::IDENTITY])).expect("states");
    for (mode, sun) in [
        (HorizonMode::Exact, SunShape::Disk),
        (HorizonMode::Approximate, SunShape::Point),
    ] {
        let by = |sweeps: bool| {
            let shadows = Shadows {
                mode,
                sun,
                sweeps,
                ..Shadows::default()
            };
            let options = Options {
                shadows,
                horizon_maps: vec![true],
                ..Options::direct(TracerKind::Grid, Bins::covering(20.0, 1000.0))
            };
            let mut timings = Timings::default();
            let sim = simulate(&world, &states, options, &mut timings, &Silent, None);
            let stages: Vec<String> = timings.0.into_iter().map(|(stage, _)| stage).collect();
            (sim.expect("simulate"), stages)
        };
        let ((stepped, stepped_stages), (swept, swept_stages)) = (by(false), by(true));
        let case = format!("{mode:?} mode, {sun:?} Sun");
        assert!(stepped_stages.iter().any(|s| s == "statistics"), "{case}");
        assert!(!swept_stages.iter().any(|s| s == "statistics"), "{case}");
        assert!(
            stepped.counts.horizon_lookups > 10_000,
            "{case}: {:?}",
            stepped.counts
        );
        assert!(
            stepped.counts.shadowed > 10_000,
            "{case}: {:?}",
            stepped.counts
        );
        assert_eq!(swept.counts, stepped.counts, "{case}");
        assert_eq!(swept.stats, stepped.stats, "{case}");
    }
}

/// An icosphere is found convex by the inspection, and a lone convex body costs no
/// shadow rays at all.
#[test]
fn convex_body_casts_no_rays() {
    let mesh = sphere(3, 1000.0);
    let report = inspect(&mesh);
    assert!(report.convex && report.closed);
    let world = World {
        bodies: vec![Body::new("sphere", mesh, report.convex)],
    };
    assert!(world.bodies[0].convex);
    let model = spin_model(24, 0.2);
    let sim = run(
        &world,
        &model,
        TracerKind::Sunview,
        Bins::covering(50.0, 1000.0),
    );
    assert_eq!(sim.counts.rays, 0);
    assert_eq!(sim.counts.shadowed, 0);
    assert!(sim.counts.night > 0);
    // A non-convex shape is not declared convex.
    let itokawa = load_km("data/shapes/itokawa/itokawa_16.obj");
    assert!(!inspect(&itokawa).convex);
}

/// Itokawa (ICQ q = 16, 3,072 facets, km) with a 120 m moonlet 900 m away,
/// and `suns` Sun directions `turn` radians apart around the equator, 0.2 above it:
/// some of them through the moonlet onto Itokawa.
fn itokawa_and_moonlet(suns: usize, turn: f64) -> (Mesh, World, Vec<slim::ephemeris::EpochState>) {
    let itokawa = load_km("data/shapes/itokawa/itokawa_16.obj");
    let world = World {
        bodies: vec![
            Body::new("itokawa", itokawa.clone(), false),
            Body::new("moonlet", sphere(2, 120.0), true),
        ],
    };
    let suns: Vec<DVec3> = (0..suns)
        .map(|k| elevated((k as f64 * turn).cos(), (k as f64 * turn).sin(), 0.2))
        .collect();
    let eph = fixed(
        &suns,
        1000.0,
        vec![Pose::IDENTITY, at(DVec3::new(900.0, 0.0, 120.0))],
    );
    let states = epoch_states(&eph).expect("states");
    (itokawa, world, states)
}

/// The step loop computes steps in blocks (`Direct::compute_steps`): every facet of a
/// block must get the bits it gets step by step, with the same counters, for rays, the
/// BVH's bound, exact and approximate maps and a disk Sun, with a second body casting
/// shadows on the first at some of the steps. Each way starts from a fresh `Direct`,
/// since an exact map's rays (and those of the BVH's bound by sectors) remember their
/// last blockers (`StepCounts::remembered`). The bound by sectors, which clears other
/// rays than the whole one, must light every facet as the rays alone do.
#[test]
fn blocks_of_steps_light_every_facet_as_single_steps() {
    let (itokawa, world, states) = itokawa_and_moonlet(13, 0.5);
    let mapped = |mode, sun| {
        let bvh = slim::trace::bvh::Bvh::build(&itokawa);
        let map = HorizonMap::build(&itokawa, itokawa.len(), &bvh, (64, SunBand::WHOLE));
        let shadows = Shadows {
            mode,
            sun,
            ..Shadows::default()
        };
        Direct::with_maps(&world, TracerKind::Sunview, vec![Some(map), None], &shadows)
    };
    let setup = |name: &str| match name {
        "sunview rays" => Direct::new(&world, TracerKind::Sunview),
        "bvh bound" => Direct::new(&world, TracerKind::Bvh),
        "bvh bound by sectors" => {
            let shadows = Shadows {
                bound_detail: BoundDetail::Sectors,
                ..Shadows::default()
            };
            Direct::with_maps(&world, TracerKind::Bvh, vec![None, None], &shadows)
        }
        "exact map" => mapped(HorizonMode::Exact, SunShape::Point),
        "approximate map" => mapped(HorizonMode::Approximate, SunShape::Point),
        _ => mapped(HorizonMode::Exact, SunShape::Disk),
    };
    let n = world.facet_count();
    let mut by_rays = Vec::new();
    for name in [
        "sunview rays",
        "bvh bound",
        "bvh bound by sectors",
        "exact map",
        "approximate map",
        "disk Sun",
    ] {
        let direct = setup(name);
        let mut single_counts = StepCounts::default();
        let single: Vec<Vec<f64>> = states
            .iter()
            .map(|state| {
                let mut e = vec![f64::NAN; n];
                single_counts += direct.compute(state, &mut e).expect("compute");
                e
            })
            .collect();
        let direct = setup(name);
        let mut block_counts = StepCounts::default();
        let mut blocked = vec![vec![f64::NAN; n]; states.len()];
        for (chunk, outs) in states.chunks(5).zip(blocked.chunks_mut(5)) {
            let mut outs: Vec<&mut [f64]> = outs.iter_mut().map(Vec::as_mut_slice).collect();
            block_counts += direct.compute_steps(chunk, &mut outs).expect("compute");
        }
        assert_eq!(block_counts, single_counts, "{name}: counters");
        for (k, (a, b)) in blocked.iter().zip(&single).enumerate() {
            for i in 0..n {
                assert_eq!(a[i].to_bits(), b[i].to_bits(), "{name}: step {k} facet {i}");
            }
        }
        // The comparison is not vacuous: shadows and the moonlet's shadow occur.
        assert!(single_counts.shadowed > 0, "{name}: nothing shadowed");
        match name {
            "sunview rays" => by_rays = single,
            "bvh bound by sectors" => {
                assert!(single_counts.remembered > 0, "{name}: nothing remembered");
                for (k, (a, b)) in single.iter().zip(&by_rays).enumerate() {
                    for i in 0..n {
                        assert_eq!(a[i].to_bits(), b[i].to_bits(), "{name}: step {k} facet {i}");
                    }
                }
            }
            _ => {}
        }
    }
}

/// Walks from remembered blockers go on where they find blockers and stop where they do
/// not (`StepCounts::walks`): with the Sun 0.5° apart from step to step most shadowed
/// rays walk, and nearly all of those walks find one; 137.5° apart (no step near the one
/// before), walks find few, and after the first steps only the probes walk (always
/// walking, 0.63 of the shadowed rays would). Either way every facet gets the bits of the
/// rays alone (Sunview, which remembers nothing).
#[test]
fn walks_from_remembered_blockers_stop_where_they_do_not_pay() {
    let sectors = Shadows {
        bound_detail: BoundDetail::Sectors,
        ..Shadows::default()
    };
    for (turn_deg, pays) in [(0.5f64, true), (137.5, false)] {
        let (_, world, states) = itokawa_and_moonlet(60, turn_deg.to_radians());
        let walking = Direct::with_maps(&world, TracerKind::Bvh, vec![None, None], &sectors);
        let by_rays = Direct::new(&world, TracerKind::Sunview);
        let mut counts = StepCounts::default();
        for (k, state) in states.iter().enumerate() {
            let mut e = vec![f64::NAN; world.facet_count()];
            let mut expected = e.clone();
            counts += walking.compute(state, &mut e).expect("compute");
            by_rays.compute(state, &mut expected).expect("compute");
            for (i, (a, b)) in e.iter().zip(&expected).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{turn_deg}°: step {k} facet {i}");
            }
        }
        let walked = counts.walks as f64 / counts.shadowed as f64;
        let found = counts.remembered as f64 / counts.walks as f64;
        match pays {
            true => assert!(walked > 0.5 && found > 0.9, "{turn_deg}°: {counts:?}"),
            false => assert!(walked < 0.1, "{turn_deg}°: {counts:?}"),
        }
    }
}

/// `Direct::compute_facets` (a few facets asked for, as the service's place queries do)
/// gives each facet the bits the step loop gives it under a disk Sun: its own body's
/// samples' rays (with the BVH's cones, and with the Sun-view tracer), or its map's
/// horizon, and a second body's mesh hiding part of the disk.
#[test]
fn facets_asked_for_get_the_step_loops_bits_under_a_disk_sun() {
    let (itokawa, world, states) = itokawa_and_moonlet(9, 0.7);
    let shadows = Shadows {
        sun: SunShape::Disk,
        ..Shadows::default()
    };
    let map = || {
        let bvh = slim::trace::bvh::Bvh::build(&itokawa);
        HorizonMap::build(&itokawa, itokawa.len(), &bvh, (64, SunBand::WHOLE))
    };
    let setups = [
        ("bvh rays", TracerKind::Bvh, None),
        ("sunview rays", TracerKind::Sunview, None),
        ("map", TracerKind::Sunview, Some(map())),
    ];
    // A sample: the Sun-view tracer builds a grid per disk sample for every facet asked.
    let facets: Vec<(usize, usize)> = (0..itokawa.len())
        .step_by(29)
        .map(|i| (0, i))
        .chain([(1, 3)])
        .collect();
    let offset = itokawa.len();
    for (name, kind, map) in setups {
        let direct = Direct::with_maps(&world, kind, vec![map, None], &shadows);
        let (mut dark, mut partly) = (0, 0);
        for state in &states {
            let mut all = vec![f64::NAN; world.facet_count()];
            direct.compute(state, &mut all).expect("compute");
            let few = direct.compute_facets(state, &facets).expect("facets");
            for (&(b, i), got) in facets.iter().zip(few) {
                let want = all[if b == 0 { i } else { offset + i }];
                assert_eq!(got.to_bits(), want.to_bits(), "{name}: body {b} facet {i}");
                let full = 1000.0 * world.bodies[b].mesh.normals[i].dot(state.bodies[b].sun_dir);
                dark += (want == 0.0 && full > 0.0) as usize;
                partly += (want > 0.0 && want < 0.999 * full) as usize;
            }
        }
        // Not vacuous: some facets facing the Sun are dark, some partly lit.
        assert!(
            dark > 0 && partly > 0,
            "{name}: {dark} dark, {partly} partly lit"
        );
    }
}

// ---------------------------------------------------------------------------------------
// 6. The Sun as a disk

/// python-flux's 100-point quadrature of a limb-darkened solar disk
/// (tests/fixtures/solar_disk): (x, y) in solar radii and weights summing to 1.
fn disk_quadrature() -> Vec<(f64, f64, f64)> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(
        "tests/fixtures/solar_disk/coordflux_100pts_outline33_centerlast_R1_F1_stdlimbdark.txt",
    );
    std::fs::read_to_string(&path)
        .expect("quadrature file")
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split(',')
                .map(|x| x.trim().parse().expect("number"))
                .collect();
            (v[0], v[1], v[2])
        })
        .collect()
}

/// A disk Sun over the facets of a convex body, whose own planes are their only horizon,
/// at centre elevations from one solar radius below to three above: the engine's closed
/// form (linear limb darkening u = 0.53, the quadrature's) against python-flux's
/// quadrature, `E/S = Σ w·max(0, n·p)` over its 100 points p on the disk.
#[test]
fn disk_sun_matches_the_python_flux_quadrature() {
    let points = disk_quadrature();
    assert_eq!(points.len(), 100);
    let mesh = sphere(3, 1000.0);
    let world = World {
        bodies: vec![Body::new("ball", mesh.clone(), true)],
    };
    let rho = slim::horizon::disk::SolarDisk::angular_radius(slim::AU_M);
    let shadows = Shadows {
        sun: SunShape::Disk,
        disk: slim::horizon::disk::SolarDisk {
            limb_darkening: 0.53,
        },
        ..Shadows::default()
    };
    let direct = Direct::with_maps(&world, TracerKind::Sunview, vec![None], &shadows);
    let (mut compared, mut worst) = (0, 0.0f64);
    for facet in [0usize, 17, 200, 513] {
        let n = mesh.normals[facet];
        let side = n.any_orthonormal_vector();
        for step in -12..=36 {
            let e = step as f64 / 12.0 * rho;
            let sun = (n * e.sin() + side * e.cos()).normalize();
            let eph = fixed(&[sun], 1000.0, vec![Pose::IDENTITY]);
            let state = &epoch_states(&eph).expect("states")[0];
            let mut out = vec![f64::NAN; mesh.len()];
            direct.compute(state, &mut out).expect("compute");
            let (u, v) = (
                sun.any_orthonormal_vector(),
                sun.cross(sun.any_orthonormal_vector()),
            );
            let reference: f64 = points
                .iter()
                .map(|&(x, y, w)| {
                    let p = (sun + (u * x + v * y) * rho.tan()).normalize();
                    w * n.dot(p).max(0.0)
                })
                .sum();
            let got = out[facet] / 1000.0;
            // In units of the disk's n·s spread (sin ρ): the 100-point quadrature resolves
            // a chord across the disk in steps of about a tenth of its radius.
            let error = (got - reference).abs() / rho.sin();
            worst = worst.max(error);
            compared += 1;
            assert!(
                error < 0.01,
                "facet {facet}, e = {:.3} ρ: E/S {got:e} vs quadrature {reference:e}",
                e / rho
            );
        }
    }
    println!("disk Sun vs python-flux quadrature: {compared} cases, worst error {worst:.4} sin ρ");
}

/// A disk Sun without a horizon map, behind a wall whose top is a straight horizon across
/// the disk: the share the engine's rays toward the disk's samples leave lit against
/// python-flux's 100-point quadrature of the same disk (u = 0.53), `E/S = Σ w·n·p` over
/// its points p above both the floor's plane and the wall's top. Both tracers; centre
/// elevations from two radii below the wall's top (dark) to two above (fully lit).
#[test]
fn disk_sun_behind_a_wall_without_a_map_matches_the_python_flux_quadrature() {
    let points = disk_quadrature();
    // A 2 m floor at z = 0 and, 4 m away along +x, a 3 m wall 2 km wide: its top is a
    // straight line across the 0.53° disk to a few parts in a million.
    let (h, wall_x, half) = (3.0, 4.0, 1000.0);
    let mesh = Mesh::from_raw(generate::floor_and_wall(h, wall_x, half), LengthUnit::M);
    let world = World {
        bodies: vec![Body::new("floor and wall", mesh.clone(), false)],
    };
    let rho = slim::horizon::disk::SolarDisk::angular_radius(slim::AU_M);
    let shadows = Shadows {
        sun: SunShape::Disk,
        disk: slim::horizon::disk::SolarDisk {
            limb_darkening: 0.53,
        },
        sun_samples: 256,
        ..Shadows::default()
    };
    let mut worst = 0.0f64;
    for kind in [TracerKind::Bvh, TracerKind::Sunview] {
        let direct = Direct::with_maps(&world, kind, vec![None], &shadows);
        for facet in [0usize, 1] {
            let c = mesh.centroids[facet];
            let top = (h / (wall_x - c.x)).atan();
            for step in -8..=8 {
                let e = top + step as f64 / 4.0 * rho;
                let sun = DVec3::new(e.cos(), 0.0, e.sin());
                let eph = fixed(&[sun], 1000.0, vec![Pose::IDENTITY]);
                let state = &epoch_states(&eph).expect("states")[0];
                let mut out = vec![f64::NAN; mesh.len()];
                direct.compute(state, &mut out).expect("compute");
                let (u, v) = (DVec3::Y, sun.cross(DVec3::Y));
                let reference: f64 = points
                    .iter()
                    .map(|&(x, y, w)| {
                        let p = (sun + (u * x + v * y) * rho.tan()).normalize();
                        let above_wall = p.z.asin() > top;
                        w * p.z.max(0.0) * f64::from(above_wall)
                    })
                    .sum();
                // As a share of the whole disk's flux on the facet.
                let got = out[facet] / 1000.0 / sun.z;
                let reference = reference / sun.z;
                let error = (got - reference).abs();
                worst = worst.max(error);
                // A chord across the disk moves the quadrature's share in steps of up
                // to a few hundredths (its 100 points in rings a tenth of a radius
                // apart), the 256 samples' in steps of a few thousandths.
                assert!(
                    error < 0.04,
                    "{kind:?}, facet {facet}, {step}/4 ρ from the wall's top: share {got:.4} \
                     vs quadrature {reference:.4}"
                );
                if step <= -5 {
                    assert_eq!(out[facet], 0.0, "{kind:?}: the whole disk behind the wall");
                }
                if step >= 5 {
                    assert!(
                        (got - 1.0).abs() < 1e-12,
                        "{kind:?}: the whole disk in view"
                    );
                }
            }
        }
    }
    println!("disk Sun behind a wall, no map: worst share error {worst:.4}");
}

/// Four vertical walls of height `h` standing on the square of half-side `d` about the
/// origin (metres), each facing inward.
fn walls(d: f64, h: f64) -> Mesh {
    let corners = [(-d, -d), (d, -d), (d, d), (-d, d)];
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for k in 0..4 {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        let base = vertices.len() as u32;
        vertices.extend([
            DVec3::new(a.0, a.1, 0.0),
            DVec3::new(b.0, b.1, 0.0),
            DVec3::new(b.0, b.1, h),
            DVec3::new(a.0, a.1, h),
        ]);
        // Counter-clockwise seen from inside the square.
        triangles.extend([[base, base + 2, base + 1], [base, base + 3, base + 2]]);
    }
    mesh_m(vertices, triangles)
}

#[test]
fn surrounding_walls_shadow_a_patch_where_their_height_says() {
    // A flat 80 m patch inside walls 20 m high on a 200 m square: with the Sun toward +x
    // at elevation e, a facet at x is dark exactly when e < atan(h / (d − x)). The walls
    // get no statistics; with rays and with an exact horizon map built over patch and
    // walls alike, every facet–Sun must follow the closed form (Suns within 1e-3 rad of
    // the edge are left out).
    let (d, h) = (100.0, 20.0);
    let patch = height_field((4, 4), (-40.0, 40.0), (-40.0, 40.0), |_, _| 0.0);
    let body = Body::new("patch", patch.clone(), false).with_surroundings(&walls(d, h));
    let world = World {
        bodies: vec![body.clone()],
    };
    assert_eq!(world.facet_count(), patch.len());
    let elevations: Vec<f64> = (1..60).map(|k| (k as f64 * 0.25).to_radians()).collect();
    let suns: Vec<DVec3> = elevations.iter().map(|&e| elevated(1.0, 0.0, e)).collect();
    let eph = fixed(&suns, 1000.0, vec![Pose::IDENTITY]);
    let casters = body.shadow_mesh();
    let map = HorizonMap::build(
        casters,
        patch.len(),
        &slim::trace::bvh::Bvh::build(casters),
        (256, SunBand::WHOLE),
    );
    let by_map = Direct::with_maps(
        &world,
        TracerKind::Sunview,
        vec![Some(map)],
        &Shadows::default(),
    );
    let states = epoch_states(&eph).expect("states");
    let (mut checked, mut dark) = (0, 0);
    for kind in [TracerKind::Sunview, TracerKind::Bvh, TracerKind::Grid] {
        let by_rays = Direct::new(&world, kind);
        for (state, &e) in states.iter().zip(&elevations) {
            let mut rays = vec![0.0; patch.len()];
            let mut mapped = vec![0.0; patch.len()];
            by_rays.compute(state, &mut rays).unwrap();
            by_map.compute(state, &mut mapped).unwrap();
            for i in 0..patch.len() {
                let edge = (h / (d - patch.centroids[i].x)).atan();
                if (e - edge).abs() < 1e-3 {
                    continue;
                }
                let expected = if e < edge { 0.0 } else { 1000.0 * e.sin() };
                assert!(
                    (rays[i] - expected).abs() < 1e-9,
                    "{kind:?} facet {i} at {e}"
                );
                assert_eq!(
                    mapped[i].to_bits(),
                    rays[i].to_bits(),
                    "map, facet {i} at {e}"
                );
                checked += 1;
                dark += (expected == 0.0) as usize;
            }
        }
    }
    assert!(
        checked > 1000 && dark > 300 && checked - dark > 300,
        "{checked} {dark}"
    );
}

// ---------------------------------------------------------------------------------------
// Panels

/// A flat square 20 km wide touching a sphere of 1,000 km at latitude `lat` (longitude 0),
/// in metres, facing out.
fn plain_at(lat: f64) -> (Mesh, DVec3) {
    let up = DVec3::new(lat.cos(), 0.0, lat.sin());
    let north = DVec3::new(-lat.sin(), 0.0, lat.cos());
    let east = DVec3::Y;
    let centre = up * 1.0e6;
    let raw = generate::height_field((8, 8), (-1e4, 1e4), (-1e4, 1e4), |_, _| 0.0);
    let raw = RawMesh {
        vertices: raw
            .vertices
            .iter()
            .map(|v| centre + east * v.x + north * v.y)
            .collect(),
        triangles: raw.triangles,
    };
    (Mesh::from_raw(raw, LengthUnit::M), centre)
}

#[test]
fn panels_on_a_plain_follow_the_closed_form_over_a_day() {
    use slim::horizon::disk::SolarDisk;
    use slim::panel::{Orientation, Panel, Site};
    // 60° S, the Sun at declination 10° (it rises and sets), hour angles every 5°.
    let (lat, dec) = ((-60f64).to_radians(), 10f64.to_radians());
    let (mesh, surface) = plain_at(lat);
    let bvh = slim::trace::bvh::Bvh::build(&mesh);
    let site = Site::new(&mesh, &bvh, surface, 2.0).expect("site");
    let flux = 1361.0;
    let radius = SolarDisk::angular_radius(slim::AU_M);
    let disk = SolarDisk {
        limb_darkening: 0.6,
    };
    let panel = |orientation| Panel {
        orientation,
        area_m2: 2.0,
        efficiency: 0.3,
    };
    let (vertical_north, tilted) = (
        panel(Orientation::Fixed {
            tilt_deg: 90.0,
            azimuth_deg: 0.0,
        }),
        panel(Orientation::Fixed {
            tilt_deg: 30.0,
            azimuth_deg: 45.0,
        }),
    );
    let (mut lit, mut dark) = (0, 0);
    for k in 0..72 {
        let h = (5.0 * k as f64).to_radians();
        // The Sun in the body frame, hour angle h west of the meridian of longitude 0.
        let sun = DVec3::new(dec.cos() * h.cos(), -dec.cos() * h.sin(), dec.sin());
        // The textbook elevation and azimuth (from north toward east).
        let e = (lat.sin() * dec.sin() + lat.cos() * dec.cos() * h.cos()).asin();
        let az =
            (-dec.cos() * h.sin()).atan2(lat.cos() * dec.sin() - lat.sin() * dec.cos() * h.cos());
        let cos_on = |tilt: f64, facing: f64| {
            let (t, f) = (tilt.to_radians(), facing.to_radians());
            e.sin() * t.cos() + e.cos() * t.sin() * (az - f).cos()
        };
        if e.abs() < 0.01 {
            continue; // the plain's own horizon (−0.01°) decides
        }
        for (p, tilt, facing) in [(&vertical_north, 90.0, 0.0), (&tilted, 30.0, 45.0)] {
            let expected = if e > 0.0 {
                flux * cos_on(tilt, facing).max(0.0)
            } else {
                0.0
            };
            let got = site.sunlight(p, sun, flux, None);
            assert!(
                (got.irradiance_w_m2 - expected).abs() < 1e-9 * flux,
                "h {k}: {got:?} vs {expected}"
            );
            assert!((got.power_w - expected * 2.0 * 0.3).abs() < 1e-9 * flux);
            if e > 2.0 * radius {
                // The whole disk is up: its flux centroid is its centre.
                let with_disk = site.sunlight(p, sun, flux, Some((&disk, radius)));
                assert!((with_disk.irradiance_w_m2 - expected).abs() < 1e-9 * flux);
            }
        }
        let tracking = site.sunlight(
            &panel(Orientation::SunTracking),
            sun,
            flux,
            Some((&disk, radius)),
        );
        let turning = site.sunlight(
            &panel(Orientation::AzimuthTracking { tilt_deg: 90.0 }),
            sun,
            flux,
            None,
        );
        if e > 2.0 * radius {
            assert!(
                (tracking.irradiance_w_m2 - flux).abs() < 1e-9 * flux,
                "{tracking:?}"
            );
            assert!((turning.irradiance_w_m2 - flux * e.cos()).abs() < 1e-9 * flux);
            lit += 1;
        } else if e < -2.0 * radius {
            assert_eq!(tracking.irradiance_w_m2, 0.0);
            dark += 1;
        }
    }
    assert!(lit > 10 && dark > 10, "{lit} lit, {dark} dark steps");
}

#[test]
fn a_panel_at_a_height_sees_the_sun_that_the_ground_below_it_does_not() {
    use slim::panel::{Orientation, Panel, Site};
    // A wall 10 m high, 100 m from the place: the Sun 4° up beyond it is behind it
    // from the ground (atan(10/100) = 5.7°) and above it from a 4 m mast (atan(6/100) = 3.4°).
    let mut raw = generate::height_field((40, 40), (-200.0, 200.0), (-200.0, 200.0), |_, y| {
        if (100.0..=110.0).contains(&y) {
            10.0
        } else {
            0.0
        }
    });
    // Put the plain on a sphere's top (up = +z there): shift it up by the radius.
    raw.vertices.iter_mut().for_each(|v| v.z += 1.0e6);
    let mesh = Mesh::from_raw(raw, LengthUnit::M);
    let bvh = slim::trace::bvh::Bvh::build(&mesh);
    let e = 4f64.to_radians();
    // The Sun over the wall (toward +y), the panel turned to it.
    let sun = DVec3::new(0.0, e.cos(), e.sin());
    let panel = Panel {
        orientation: Orientation::SunTracking,
        area_m2: 1.0,
        efficiency: 1.0,
    };
    let surface = DVec3::new(0.0, 0.0, 1.0e6);
    let low = Site::new(&mesh, &bvh, surface, 0.5).expect("site");
    let high = Site::new(&mesh, &bvh, surface, 4.0).expect("site");
    // The horizon toward the Sun from 0.5 m: the wall's top edge, atan(9.5/100).
    let toward = low.horizon_toward(sun).to_degrees();
    assert!(
        (toward - 9.5f64.atan2(100.0).to_degrees()).abs() < 0.01,
        "{toward}"
    );
    assert_eq!(low.sunlight(&panel, sun, 1000.0, None).irradiance_w_m2, 0.0);
    let seen = high.sunlight(&panel, sun, 1000.0, None).irradiance_w_m2;
    assert!((seen - 1000.0).abs() < 1e-9, "{seen}");
    assert!(Site::new(&mesh, &bvh, surface, 0.0).is_err());
}

#[test]
fn a_battery_fills_and_drains_as_the_closed_form_says() {
    use slim::panel::Battery;
    // 20 h at 100 W then 20 h dark, a 50 W load, hourly steps: +45 Wh/h stored (90 %)
    // until full at 11.1 h, then −62.5 Wh/h drawn (80 %) from 20 h: below 200 Wh from
    // 32.8 h, empty from 36 h, so 4 h × 50 W go unserved.
    let power: Vec<f64> = (0..40).map(|k| if k < 20 { 100.0 } else { 0.0 }).collect();
    let battery = Battery {
        capacity_wh: 1000.0,
        initial_wh: 500.0,
        charge_efficiency: 0.9,
        discharge_efficiency: 0.8,
    };
    let run = battery.run(&power, &[50.0; 40], &[3600.0; 40], 200.0);
    for (k, held) in run.charge_wh.iter().enumerate() {
        let hours = (k + 1) as f64;
        let expected = if hours <= 20.0 {
            (500.0 + 45.0 * hours).min(1000.0)
        } else {
            (1000.0 - 62.5 * (hours - 20.0)).max(0.0)
        };
        assert!(
            (held - expected).abs() < 1e-9,
            "hour {hours}: {held} vs {expected}"
        );
    }
    assert_eq!(run.min_wh, 0.0);
    assert!(
        (run.below_low_s - 7.2 * 3600.0).abs() < 1e-6,
        "{}",
        run.below_low_s
    );
    assert!((run.unmet_wh - 200.0).abs() < 1e-9, "{}", run.unmet_wh);
}

// ---------------------------------------------------------------------------------------
// Steps that repeat

/// A bowl (z = 0.1·r², 8 m across) that shadows its own floor under a Sun 0.5 rad up.
fn bowl() -> World {
    let bowl = height_field((8, 8), (-4.0, 4.0), (-4.0, 4.0), |x, y| {
        0.1 * (x * x + y * y)
    });
    World {
        bodies: vec![Body::new("bowl", bowl, false)],
    }
}

/// The spin of [`spin_model`] over `periods` periods in `steps` steps.
fn spins(steps: usize, periods: f64) -> SpinModel {
    SpinModel {
        duration_s: 3600.0 * periods,
        ..spin_model(steps, 0.5)
    }
}

/// The spin model takes a step's rotation from its place within the period when whole
/// steps fill the period, so that every period repeats the first bit for bit; the Sun
/// must still stand where the continuous rotation θ₀ + 2π·t/P puts it (to rounding).
#[test]
fn a_spin_of_whole_periods_repeats_bit_for_bit_where_the_rotation_puts_the_sun() {
    let model = spins(36, 3.0);
    let states = epoch_states(&model).expect("epoch states");
    assert_eq!(repeat_period(&states), 12);
    let sun = model.sun_dir_scene;
    for (k, state) in states.iter().enumerate() {
        let angle = 0.3 + 2.0 * PI * (k as f64 * 300.0) / 3600.0;
        let expected = DMat3::from_rotation_z(angle).transpose() * sun;
        let off = state.bodies[0].sun_dir.distance(expected);
        assert!(off < 1e-12, "step {k}: {off:e}");
    }
    // 37 steps over 3 periods: no whole number of steps per period, nothing repeats.
    assert_eq!(repeat_period(&epoch_states(&spins(37, 3.0)).unwrap()), 37);
}

/// A geometry that returns to its first step without repeating (Suns A, A, B: step 1
/// repeats step 0, step 2 does not repeat step 1) is not taken as repeating; one Sun
/// listed once per step is, every step.
#[test]
fn only_a_geometry_that_repeats_throughout_counts_as_repeating() {
    let a = DVec3::new(1.0, 0.0, 1.0).normalize();
    let b = DVec3::new(0.0, 1.0, 1.0).normalize();
    let aab = fixed(&[a, a, b], 1361.0, vec![Pose::IDENTITY]);
    assert_eq!(repeat_period(&epoch_states(&aab).unwrap()), 3);
    let aaa = fixed(&[a, a, a, a], 1361.0, vec![Pose::IDENTITY]);
    assert_eq!(repeat_period(&epoch_states(&aaa).unwrap()), 1);
    assert_eq!(repeat_period(&[]), 0);
}

/// Over three whole periods the run computes the first period's light and hands it on to
/// the other two: every step's light, as the step loop hands it on, must equal the light
/// of that step computed on its own (the bowl's floor is partly shadowed, so a copy from
/// the wrong step shows), and the run's counts the sum of the steps' own counts.
#[test]
fn a_repeating_spin_computes_one_period_and_every_copy_equals_its_own_step() {
    let world = bowl();
    let states = epoch_states(&spins(36, 3.0)).expect("epoch states");
    let mut handed_on = Vec::new();
    let sim = simulate(
        &world,
        &states,
        Options::direct(TracerKind::Bvh, Bins::covering(50.0, FLUX_152)),
        &mut Timings::default(),
        &Silent,
        Some(&mut |_, e: StepIrradiance| {
            handed_on.push(e.total.to_vec());
            Ok(())
        }),
    )
    .expect("simulate");
    assert!(sim.counts.shadowed > 0, "the bowl shadows its floor");
    let direct = Direct::new(&world, TracerKind::Bvh);
    let mut counts = StepCounts::default();
    for (k, state) in states.iter().enumerate() {
        let mut own = vec![f64::NAN; world.facet_count()];
        counts += direct.compute(state, &mut own).expect("compute");
        assert_eq!(handed_on[k], own, "step {k}");
    }
    assert_eq!(sim.counts, counts);
    assert_ne!(
        handed_on[0], handed_on[1],
        "the steps differ from each other"
    );
}

/// The Sun's turn from step to step in the body frame, which the horizon bound's detail
/// weighs: a spin of 36 steps turns the Sun 10° about the spin axis, at sub-solar
/// latitude δ an arc of 2·asin(cos δ · sin 5°) (the chord of a small circle). No earlier
/// step comes closer, so the rays recall the step before.
#[test]
fn the_suns_turn_between_steps_is_the_arc_of_its_small_circle() {
    let states = epoch_states(&spins(36, 1.0)).expect("epoch states");
    let expected = 2.0 * (0.5f64.cos() * 5f64.to_radians().sin()).asin();
    let recall = sun_return(&states, &[0], 48);
    assert_eq!(recall.lag, 1);
    assert!(
        (recall.turn_deg - expected.to_degrees()).abs() < 1e-9,
        "{recall:?}"
    );
    assert_eq!(sun_return(&states[..1], &[0], 48).turn_deg, 0.0);
    assert_eq!(sun_return(&states, &[0], 1).lag, 1);
}

/// `suns` Suns 10° above the equator of a body that turns 30° plus `drift_deg` a step:
/// every 12th step the Sun comes back to within 12 · `drift_deg` of where it stood.
fn hourly_suns(steps: usize, drift_deg: f64) -> Vec<DVec3> {
    (0..steps)
        .map(|k| {
            let turn = (k as f64 * (30.0 + drift_deg)).to_radians();
            elevated(turn.cos(), turn.sin(), 10f64.to_radians())
        })
        .collect()
}

/// Hourly steps on a 12-hour spin: consecutive Suns are 30° apart, but the Sun of 12
/// steps before stands 12 · 0.05° = 0.6° of spin away, an arc of 2·asin(cos 10° · sin
/// 0.3°) on the Sun's small circle; shorter lags (1 to 11, 30–330° of spin) are farther.
#[test]
fn the_sun_returns_a_spin_later_within_the_spins_drift() {
    let suns = hourly_suns(60, 0.05);
    let states = epoch_states(&fixed(&suns, 1000.0, vec![Pose::IDENTITY])).expect("states");
    let recall = sun_return(&states, &[0], 48);
    let expected = 2.0 * (10f64.to_radians().cos() * 0.3f64.to_radians().sin()).asin();
    assert_eq!(recall.lag, 12, "{recall:?}");
    assert!(
        (recall.turn_deg - expected.to_degrees()).abs() < 1e-9,
        "{recall:?}"
    );
    // Looking back no farther than 11 steps, the nearest is a step of 30°.
    assert_eq!(sun_return(&states, &[0], 11).lag, 1);
    // Where every spin back is within 0.1° (all as good for the walks), the shortest.
    let close = hourly_suns(60, 0.001);
    let states = epoch_states(&fixed(&close, 1000.0, vec![Pose::IDENTITY])).expect("states");
    assert_eq!(sun_return(&states, &[0], 48).lag, 12);
}

/// True hours of Itokawa's 12.13 h spin: the Sun comes back nearest where a whole number
/// of spins is nearest a whole number of hours: 12 h (0.13 h from one spin, 3.86° of
/// spin), 85 h (0.09 h from seven) and 97 h (0.04 h from eight, 1.19°); the spins between
/// miss by 0.22 h or more. At sub-solar latitude 15° the Sun's arc for a spin angle φ is
/// 2·asin(cos 15° · sin(φ/2)): 1.15° eight spins back, 3.73° one spin back.
#[test]
fn true_hours_of_a_spin_recall_the_spin_that_comes_back_nearest() {
    let spin_deg = |h: f64| h / 12.13 * 360.0;
    let suns: Vec<DVec3> = (0..300)
        .map(|k| {
            let turn = -spin_deg(k as f64).to_radians();
            elevated(turn.cos(), turn.sin(), 15f64.to_radians())
        })
        .collect();
    let states = epoch_states(&fixed(&suns, 3600.0, vec![Pose::IDENTITY])).expect("states");
    let arc = |spin: f64| {
        let half = (spin / 2.0).to_radians();
        (2.0 * (15f64.to_radians().cos() * half.sin()).asin()).to_degrees()
    };
    let eight = sun_return(&states, &[0], 128);
    assert_eq!(eight.lag, 97, "{eight:?}");
    assert!(
        (eight.turn_deg - arc(spin_deg(0.04))).abs() < 1e-6,
        "{eight:?}"
    );
    assert_eq!(sun_return(&states, &[0], 96).lag, 85);
    let one = sun_return(&states, &[0], 84);
    assert_eq!(one.lag, 12, "{one:?}");
    assert!((one.turn_deg - arc(spin_deg(0.13))).abs() < 1e-6, "{one:?}");
}

/// The Sun's return is weighed in the frames of the bodies whose rays recall blockers
/// only: an occluder turning 1.4 times as fast returns at other lags, and weighed with the
/// first body it pulls the median away from the first's 12-step return.
#[test]
fn the_suns_return_is_weighed_in_the_frames_of_the_bodies_asked() {
    let mut model = spin_model(240, 0.2);
    // 20.04 turns of body 0 in 240 steps: 12 steps back is 0.72° of its spin.
    model.duration_s = 3600.0 * 20.04;
    model.bodies.push(Spin {
        period_s: Some(3600.0 / 1.4),
        initial_angle_rad: 0.0,
        position_m: DVec3::new(1e7, 0.0, 0.0),
    });
    let states = epoch_states(&model).expect("epoch states");
    let first = sun_return(&states, &[0], 48);
    assert_eq!(first.lag, 12, "{first:?}");
    assert!(first.turn_deg < 1.0, "{first:?}");
    // The other frame returns elsewhere (12 steps are 1.4 of its turns), and both frames
    // together stand farther at the first body's lag than it alone.
    let both = sun_return(&states, &[0, 1], 48);
    assert!(both.turn_deg > first.turn_deg, "{both:?} against {first:?}");
    assert_eq!(sun_return(&states, &[], 48).turn_deg, f64::INFINITY);
}

/// Rays that start from the blockers the same facets met a spin earlier, 12 steps back,
/// change no shadow: every facet at every step is lit or dark as the Sun-view tracer's
/// rays alone find, under a whole horizon bound and one by sectors. And the recall is
/// what answers the rays: from a spin back, more than three quarters of the shadowed rays
/// after the first spin are answered on the surface; recalling the step before (30°
/// away) answers fewer.
#[test]
fn rays_recall_the_blockers_of_the_step_where_the_sun_returns() {
    let mesh = load_km("data/shapes/itokawa/itokawa_16.obj");
    let world = World {
        bodies: vec![Body::new("itokawa_16", mesh, false)],
    };
    let suns = hourly_suns(48, 0.05);
    let states = epoch_states(&fixed(&suns, 1000.0, vec![Pose::IDENTITY])).expect("states");
    let recall = sun_return(&states, &[0], 48);
    assert_eq!(recall.lag, 12);
    let n = world.facet_count();
    let run = |direct: Direct| -> (Vec<Vec<f64>>, StepCounts) {
        let mut after_first_spin = StepCounts::default();
        let lights = (states.iter())
            .map(|state| {
                let mut e = vec![f64::NAN; n];
                let counts = direct.compute(state, &mut e).expect("compute");
                if state.step >= 12 {
                    after_first_spin += counts;
                }
                e
            })
            .collect();
        (lights, after_first_spin)
    };
    let (by_rays, _) = run(Direct::new(&world, TracerKind::Sunview));
    let with = |detail, recall| {
        let shadows = Shadows {
            bound_detail: detail,
            recall,
            ..Shadows::default()
        };
        assert!(shadows.remembers_blockers(false));
        Direct::with_maps(&world, TracerKind::Bvh, vec![None], &shadows)
    };
    let step_before = SunReturn {
        lag: 1,
        turn_deg: 0.0,
    };
    for detail in [BoundDetail::Whole, BoundDetail::Sectors] {
        let (recalled, spin_back) = run(with(detail, recall));
        let (_, step_back) = run(with(detail, step_before));
        for (k, (a, b)) in recalled.iter().zip(&by_rays).enumerate() {
            for i in 0..n {
                assert_eq!(
                    a[i].to_bits(),
                    b[i].to_bits(),
                    "{detail:?}: step {k} facet {i}"
                );
            }
        }
        assert!(spin_back.shadowed > 1000, "{detail:?}: {spin_back:?}");
        assert!(
            spin_back.remembered * 4 > spin_back.shadowed * 3,
            "{detail:?}: {spin_back:?}"
        );
        assert!(
            spin_back.remembered > step_back.remembered,
            "{detail:?}: a spin back {spin_back:?}, a step back {step_back:?}"
        );
    }
    // Neither bound's rays recall anything when the Sun does not come back near where it
    // stood; a whole bound's, mostly lit, nor when that is not known.
    for bound_detail in [BoundDetail::Whole, BoundDetail::Sectors] {
        let far = Shadows {
            recall: SunReturn {
                lag: 1,
                turn_deg: 30.0,
            },
            bound_detail,
            ..Shadows::default()
        };
        assert!(!far.remembers_blockers(false), "{bound_detail:?}");
    }
    assert!(!Shadows::default().remembers_blockers(false));
    let unknown_sectors = Shadows {
        bound_detail: BoundDetail::Sectors,
        ..Shadows::default()
    };
    assert!(unknown_sectors.remembers_blockers(false));
}

/// A block of no steps lights nothing and counts nothing (it once divided the steps into
/// blocks of zero).
#[test]
fn a_block_of_no_steps_computes_nothing() {
    let world = bowl();
    let point = Shadows {
        sun: SunShape::Point,
        ..Shadows::default()
    };
    // Toward a point Sun through the BVH a block's steps go in one pass.
    let direct = Direct::with_maps(&world, TracerKind::Bvh, vec![None], &point);
    let each = direct.compute_steps_each(&[], &mut []).expect("no steps");
    assert!(each.is_empty());
}
