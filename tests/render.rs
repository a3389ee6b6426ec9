//! Rendering against independent geometry: a Lambert sphere against the analytic image
//! (exact ray–sphere intersections, brightness A·cos i), a two-sphere scene whose shadow
//! must fall where exact ray–sphere shadow rays say, and FITS/PNG files written and read
//! back (orientation, header, quantisation).

use glam::DVec3;
use hifitime::Epoch;
use slim::ephemeris::{BodyState, EpochState};
use slim::image::png::Stretch;
use slim::image::{fits, png, Image, Value};
use slim::mesh::generate::icosphere;
use slim::mesh::{LengthUnit, Mesh};
use slim::photometry::lambert::Lambert;
use slim::photometry::Reflectance;
use slim::render::camera::Camera;
use slim::render::Renderer;
use slim::trace::TracerKind;
use slim::world::{Body, Pose, World};
use std::path::Path;

const LEVELS: u32 = 4;

fn sphere_body(name: &str, radius_m: f64) -> Body {
    Body::new(
        name,
        Mesh::from_raw(icosphere(LEVELS, radius_m, DVec3::ZERO), LengthUnit::M),
        true,
    )
}

fn state(sun: DVec3, positions: &[DVec3]) -> EpochState {
    EpochState {
        step: 0,
        epoch: Epoch::from_tdb_seconds(0.0),
        bodies: positions
            .iter()
            .map(|&p| BodyState {
                sun_dir: sun,
                sun_distance_m: slim::AU_M,
                flux_w_m2: 1000.0,
                pose: Pose {
                    body_to_scene: glam::DMat3::IDENTITY,
                    position_m: p,
                },
            })
            .collect(),
    }
}

/// Largest angle between a facet's normal and the radial direction of any of its corners:
/// the worst normal error of the faceted sphere against the true one.
fn facet_normal_error(body: &Body) -> f64 {
    let m = &body.mesh;
    (0..m.len())
        .flat_map(|f| m.corners(f).map(|c| m.normals[f].angle_between(c)))
        .fold(0.0, f64::max)
}

/// Exact nearest hit of a ray with spheres (centre, radius): (sphere, distance).
fn hit_spheres(o: DVec3, d: DVec3, spheres: &[(DVec3, f64)]) -> Option<(usize, f64)> {
    spheres
        .iter()
        .enumerate()
        .filter_map(|(k, &(c, r))| {
            let oc = o - c;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            (disc >= 0.0)
                .then(|| (k, -b - disc.sqrt()))
                .filter(|h| h.1 > 0.0)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// Unit ray direction of a pixel centre in the scene frame.
fn pixel_dir(camera: &Camera, col: usize, row: usize) -> DVec3 {
    (camera.pose.body_to_scene * camera.ray(col as f64 + 0.5, row as f64 + 0.5)).normalize()
}

#[test]
fn lambert_sphere_matches_the_analytic_image_pixel_by_pixel() {
    let radius = 1000.0;
    let world = World {
        bodies: vec![sphere_body("ball", radius)],
    };
    let delta = facet_normal_error(&world.bodies[0]);
    let eye = DVec3::new(0.0, -10_000.0, 0.0);
    // Sun 50° from the line of sight, 20° above the equator: the terminator is in view.
    let sun = DVec3::new(50f64.to_radians().sin(), -50f64.to_radians().cos(), 0.35).normalize();
    let st = state(sun, &[DVec3::ZERO]);
    let camera = Camera::with_fov(64, 64, 14.0)
        .unwrap()
        .looking_at(eye, DVec3::ZERO, DVec3::Z)
        .unwrap();
    let albedo = 0.6;
    let lambert = Lambert { albedo };
    let materials: [&dyn Reflectance; 1] = [&lambert];
    let geometry = Renderer::new(&world, TracerKind::Sunview)
        .geometry(&st, &camera)
        .unwrap();
    let iof = geometry.i_over_f(&materials);
    let radiance = geometry.radiance(&materials, 1.0);
    // Inscribed radius: the least distance from the centre to a facet plane.
    let m = &world.bodies[0].mesh;
    let r_in = (0..m.len())
        .map(|f| m.normals[f].dot(m.centroids[f]))
        .fold(f64::INFINITY, f64::min);
    let (mut compared, mut sum_err, mut limb) = (0, 0.0, 0);
    for row in 0..64 {
        for col in 0..64 {
            let d = pixel_dir(&camera, col, row);
            let analytic = hit_spheres(eye, d, &[(DVec3::ZERO, radius)]);
            let seen = geometry.samples[row * 64 + col].is_some();
            match (analytic, seen) {
                (Some((_, t)), true) => {
                    let n = (eye + t * d).normalize();
                    let expected = albedo * n.dot(sun).max(0.0);
                    let got = iof.at(col, row);
                    // Facet normal within δ of the radial at its corners, and the sphere
                    // point within one more facet: |Δ cos i| ≤ 2δ.
                    assert!(
                        (got - expected).abs() <= 2.0 * albedo * delta,
                        "pixel ({col}, {row}): I/F {got} vs analytic {expected}"
                    );
                    let l = radiance.at(col, row);
                    assert!((l - 1000.0 * got / std::f64::consts::PI).abs() < 1e-9);
                    compared += 1;
                    sum_err += (got - expected).abs();
                }
                (None, false) => {}
                _ => {
                    // Only between the inscribed and the circumscribed sphere.
                    let miss = (eye - eye.dot(d) * d).length();
                    assert!(
                        miss >= r_in - 1e-6 && miss <= radius + 1e-6,
                        "pixel ({col}, {row}) seen={seen} at {miss} m from the centre"
                    );
                    limb += 1;
                }
            }
        }
    }
    assert!(compared > 1500, "{compared}");
    assert!(limb < 40, "{limb}");
    // On average the faceting error is well below its bound.
    assert!(sum_err / (compared as f64) < 0.5 * albedo * delta);
}

#[test]
fn image_orientation_follows_the_camera_frame() {
    // A small sphere offset to the camera's right (+x) and down (+y) appears at larger
    // column and row numbers.
    let world = World {
        bodies: vec![sphere_body("dot", 100.0)],
    };
    let camera = Camera::with_fov(64, 64, 10.0)
        .unwrap()
        .looking_at(DVec3::new(0.0, 0.0, -10_000.0), DVec3::ZERO, DVec3::Y)
        .unwrap();
    // Camera x = z × up = (0,0,1)×(0,1,0) = −X; image down = +y camera = z × x = −Y.
    let target = DVec3::new(-400.0, -300.0, 0.0);
    let st = state(DVec3::new(0.0, 0.0, -1.0), &[target]);
    let g = Renderer::new(&world, TracerKind::Sunview)
        .geometry(&st, &camera)
        .unwrap();
    let (u, v) =
        camera.project(camera.pose.body_to_scene.transpose() * (target - camera.pose.position_m));
    assert!(u > 32.0 && v > 32.0);
    let seen = g.samples[v as usize * 64 + u as usize];
    assert!(seen.is_some_and(|s| s.lit));
    assert!(g.samples[(64 - v as usize) * 64 + (64 - u as usize)].is_none());
}

#[test]
fn two_spheres_shadow_where_ray_geometry_says() {
    let (ra, rb) = (1000.0, 400.0);
    let cb = DVec3::new(2500.0, 650.0, 100.0);
    let world = World {
        bodies: vec![sphere_body("a", ra), sphere_body("b", rb)],
    };
    let sun = DVec3::X;
    let st = state(sun, &[DVec3::ZERO, cb]);
    let eye = DVec3::new(8000.0, -3000.0, 3000.0);
    let camera = Camera::with_fov(64, 64, 20.0)
        .unwrap()
        .looking_at(eye, DVec3::ZERO, DVec3::Z)
        .unwrap();
    let g = Renderer::new(&world, TracerKind::Sunview)
        .geometry(&st, &camera)
        .unwrap();
    // A polygonal sphere departs from the true one by at most its sagitta R(1 − cos δ).
    let sagitta = |b: &Body, r: f64| r * (1.0 - facet_normal_error(b).cos());
    let margin = 2.0 * (sagitta(&world.bodies[0], ra) + sagitta(&world.bodies[1], rb));
    let spheres = [(DVec3::ZERO, ra), (cb, rb)];
    let (mut shadowed, mut lit, mut checked) = (0, 0, 0);
    for row in 0..64 {
        for col in 0..64 {
            let d = pixel_dir(&camera, col, row);
            let Some((k, t)) = hit_spheres(eye, d, &spheres) else {
                continue;
            };
            let Some(s) = g.samples[row * 64 + col] else {
                continue;
            };
            let p = eye + t * d;
            let n = (p - spheres[k].0).normalize();
            if k != 0 || s.body != 0 || n.dot(sun) < 0.05 {
                continue; // compare the sunlit side of sphere a only
            }
            // Distance of B's centre from the shadow ray p + s·sun, s > 0.
            let along = (cb - p).dot(sun);
            let miss = (cb - p - along * sun).length();
            if along <= 0.0 || (miss - rb).abs() < margin {
                continue;
            }
            let in_shadow = miss < rb;
            assert_eq!(!s.lit, in_shadow, "pixel ({col}, {row}), miss {miss} m");
            checked += 1;
            if in_shadow {
                shadowed += 1;
            } else {
                lit += 1;
            }
        }
    }
    assert!(
        shadowed > 30 && lit > 300,
        "shadowed {shadowed}, lit {lit}, of {checked}"
    );
}

#[test]
fn empty_and_clipped_views_are_harmless() {
    let world = World {
        bodies: vec![sphere_body("ball", 1000.0)],
    };
    let st = state(DVec3::X, &[DVec3::ZERO]);
    let r = Renderer::new(&world, TracerKind::Sunview);
    let away = Camera::with_fov(16, 16, 10.0)
        .unwrap()
        .looking_at(
            DVec3::new(0.0, -5000.0, 0.0),
            DVec3::new(0.0, -10_000.0, 0.0),
            DVec3::Z,
        )
        .unwrap();
    let g = r.geometry(&st, &away).unwrap();
    assert_eq!(g.covered(), 0);
    // A camera inside the sphere: facets behind it are clipped and counted, no panic.
    let inside = Camera::with_fov(16, 16, 90.0)
        .unwrap()
        .looking_at(DVec3::ZERO, DVec3::X, DVec3::Z)
        .unwrap();
    let g = r.geometry(&st, &inside).unwrap();
    assert!(g.clipped_facets > 0);
    assert!(Camera::with_fov(0, 16, 10.0).is_err());
    assert!(Camera::with_fov(16, 16, 180.0).is_err());
    assert!(away.looking_at(DVec3::ZERO, DVec3::Z, DVec3::Z).is_err());
}

fn test_image() -> Image {
    let mut image = Image::new(5, 3);
    for (k, p) in image.pixels.iter_mut().enumerate() {
        *p = k as f64 * 0.25 - 0.5;
    }
    image.set("BUNIT", Value::Text("W/m2/sr".into()), "radiance");
    image.set("SUNFLUX", Value::Number(267.5), "W/m2");
    image.set("STEP", Value::Integer(7), "");
    image.set("NOTE", Value::Text("it's".into()), "quote inside");
    image
}

#[test]
fn fits_round_trip_with_header_and_orientation() {
    let dir = std::env::temp_dir().join(format!("slim-fits-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("t.fits");
    let image = test_image();
    fits::write(&path, &image).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(bytes.len() % 2880, 0);
    // First stored pixel = bottom-left (row 2, column 0): 10·0.25 − 0.5 = 2.
    let first = f32::from_be_bytes(bytes[2880..2884].try_into().unwrap());
    assert_eq!(first, 2.0);
    let back = fits::read(&path).unwrap();
    assert_eq!((back.width, back.height), (5, 3));
    assert_eq!(back.pixels, image.pixels);
    assert_eq!(back.text("BUNIT"), Some("W/m2/sr"));
    assert_eq!(back.text("NOTE"), Some("it's"));
    assert_eq!(back.number("SUNFLUX"), Some(267.5));
    assert_eq!(back.get("STEP"), Some(&Value::Integer(7)));
    // Truncated and foreign files are refused with the file named.
    std::fs::write(dir.join("cut.fits"), &bytes[..2900]).unwrap();
    let e = fits::read(&dir.join("cut.fits")).unwrap_err().to_string();
    assert!(e.contains("cut.fits"), "{e}");
    std::fs::write(dir.join("x.fits"), b"hello").unwrap();
    assert!(fits::read(&dir.join("x.fits")).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn png_round_trip_within_half_a_step() {
    let dir = std::env::temp_dir().join(format!("slim-png-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let image = test_image();
    let stretch = Stretch { lo: -0.5, hi: 3.0 };
    for (bits, steps) in [(8u8, 255.0), (16, 65535.0)] {
        let path = dir.join(format!("t{bits}.png"));
        png::write(&path, &image, bits, stretch).unwrap();
        let back = png::read(&path).unwrap();
        assert_eq!((back.width, back.height), (5, 3));
        assert_eq!(back.text("BUNIT"), Some("W/m2/sr"));
        for (a, b) in image.pixels.iter().zip(&back.pixels) {
            let expected = a.clamp(-0.5, 3.0);
            assert!((expected - b).abs() <= 0.5 * 3.5 / steps + 1e-12, "{a} {b}");
        }
    }
    assert!(png::write(&dir.join("bad.png"), &image, 12, stretch).is_err());
    let flat = Stretch { lo: 1.0, hi: 1.0 };
    assert!(png::write(&dir.join("bad.png"), &image, 8, flat).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

const SCENE: &str = r#"
[ephemeris]
mode = "fixed"
solar_constant_w_m2 = 1361.0

[[ephemeris.sun]]
direction = [0.342, -0.940, 0.0]
distance_au = 2.2

[[ephemeris.sun]]
direction = [0.985, -0.174, 0.0]
distance_au = 2.2

[camera]
width = 64
height = 64
fov_deg = 8.0
position_km = [0.0, -20.0, 0.0]
png_bits = 16

[[band]]
name = "blue"
solar_constant_w_m2 = 300.0

[[band]]
name = "red"
solar_constant_w_m2 = 500.0

[[body]]
name = "ball"
ellipsoid = { radii_km = [1.0, 1.0, 0.8], levels = 3 }

[body.material]
model = "hapke"
w = 0.4
xi = -0.25
b0 = 1.0
h = 0.06
bands = { red = { w = 0.6 } }
"#;

fn slim(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_slim"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn render_compare_and_fit_from_the_command_line() {
    let dir = std::env::temp_dir().join(format!("slim-cli-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("ball.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = dir.join("images");
    let (ok, _, err) = slim(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let file = |name: &str| out.join(name).to_str().unwrap().to_string();
    // Per band: radiance, I/F (FITS) and I/F (PNG); the summed radiance per step.
    let blue = fits::read(std::path::Path::new(&file("ball_s0000_blue_radiance.fits"))).unwrap();
    let red = fits::read(std::path::Path::new(&file("ball_s0000_red_radiance.fits"))).unwrap();
    let total = fits::read(std::path::Path::new(&file(
        "ball_s0000_total_radiance.fits",
    )))
    .unwrap();
    assert!(std::path::Path::new(&file("ball_s0001_red_iof.png")).exists());
    for ((b, r), t) in blue.pixels.iter().zip(&red.pixels).zip(&total.pixels) {
        assert!(
            (b + r - t).abs() <= 1e-5 * t.abs().max(1e-3),
            "{b} + {r} vs {t}"
        );
    }
    assert_eq!(blue.text("BAND"), Some("blue"));
    assert!((blue.number("FLUXFRAC").unwrap() - 300.0 / 1361.0).abs() < 1e-12);
    assert!(blue.text("MAT0").unwrap().contains("w=0.4"));
    assert!(red.text("MAT0").unwrap().contains("w=0.6"));
    assert!(blue.max() > 0.0);
    // An image against itself: χ² = 0, p = 1. Against another phase angle: p ≈ 0.
    let (ok, text, err) = slim(&[
        "compare",
        &file("ball_s0000_red_radiance.fits"),
        &file("ball_s0000_red_radiance.fits"),
        "--bin-width",
        "0.5",
        "--above",
        "0",
    ]);
    assert!(ok, "{err}");
    assert!(
        text.contains("chi2 = 0.000000e0") && text.contains("p = 1.000000e0"),
        "{text}"
    );
    let (ok, text, _) = slim(&[
        "compare",
        &file("ball_s0000_red_radiance.fits"),
        &file("ball_s0001_red_radiance.fits"),
        "--bin-width",
        "0.5",
        "--above",
        "0",
    ]);
    assert!(ok);
    let p: f64 = text
        .split("p = ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(p < 1e-10, "{text}");
    // Fit w of the red band back from both red images, starting elsewhere.
    let start = SCENE.replace(
        "bands = { red = { w = 0.6 } }",
        "bands = { red = { w = 0.3 } }",
    );
    let scene2 = dir.join("start.toml");
    std::fs::write(&scene2, start).unwrap();
    let (ok, text, err) = slim(&[
        "fit",
        scene2.to_str().unwrap(),
        &file("ball_s0000_red_radiance.fits"),
        &file("ball_s0001_red_radiance.fits"),
        "--params",
        "w",
        "-o",
        dir.join("fit").to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let w: f64 = text
        .split("w = ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    // float32 FITS storage is the only noise: relative 6e-8.
    assert!((w - 0.6).abs() < 1e-4, "{text}");
    assert!(dir.join("fit/start_residual_1.fits").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn scene_errors_name_the_key() {
    let dir = std::env::temp_dir().join(format!("slim-scene-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (from, to, key) in [
        (
            "xi = -0.25",
            "xi = -0.25\nalbedo = 0.3",
            "body[0].material.albedo",
        ),
        ("w = 0.6 }", "w = 1.6 }", "body[0].material.bands.red.w"),
        ("red = {", "green = {", "body[0].material.bands.green"),
        (
            "model = \"hapke\"",
            "model = \"phong\"",
            "body[0].material.model",
        ),
        ("png_bits = 16", "png_bits = 12", "camera.png_bits"),
        ("png_bits = 16", "png_bits = 16\nzoom = 2", "camera"),
        ("width = 64", "preset = \"hubble\"", "camera"),
        (
            "position_km = [0.0, -20.0, 0.0]",
            "observer_naif_id = -203",
            "camera.observer_naif_id",
        ),
        (
            "position_km = [0.0, -20.0, 0.0]",
            "position_km = [0.0, -20.0, 0.0]\nobserver_naif_id = -203",
            "not both",
        ),
        ("position_km = [0.0, -20.0, 0.0]", "", "camera.position_km"),
    ] {
        let text = SCENE.replace(from, to);
        assert_ne!(text, SCENE);
        let path = dir.join("bad.toml");
        std::fs::write(&path, text).unwrap();
        let e = slim::scene::Scene::load(&path).unwrap_err().to_string();
        assert!(e.contains(key), "{key}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A camera placed by SPICE: Phobos seen from Deimos (NAIF 402), both from the MAR085
/// subset. The camera sits where the ephemeris puts Deimos and looks at Phobos's centre.
#[test]
fn a_spice_observer_places_the_camera() {
    let kernels: Vec<String> = [
        "lsk/naif0012.tls",
        "pck/pck00011.tpc",
        "spk/mar085_subset_2018-06/mar085.bsp",
        "spk/mar085_subset_2018-06/de430.bsp",
    ]
    .iter()
    .map(|k| {
        format!(
            "{:?}",
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("data/kernels")
                .join(k)
        )
    })
    .collect();
    let text = format!(
        "[ephemeris]\nmode = \"spice\"\nkernels = [{}]\n\
         start = \"2018-06-10T00:00:00 UTC\"\nstop = \"2018-06-10T02:00:00 UTC\"\nstep_s = 3600\n\
         [camera]\nwidth = 32\nheight = 32\nfov_deg = 1.0\nobserver_naif_id = 402\ntarget = \"phobos\"\n\
         [[body]]\nname = \"phobos\"\nnaif_id = 401\nellipsoid = {{ levels = 1 }}\n\
         [[body]]\nname = \"deimos\"\nnaif_id = 402\nellipsoid = {{ levels = 1 }}\n",
        kernels.join(", ")
    );
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/in-memory-scene.toml");
    let scene = slim::scene::Scene::parse(&path, &text, text.as_bytes().to_vec()).unwrap();
    let view = slim::render::job::View::load(&scene).unwrap();
    let section = slim::render::job::camera_section(&scene).unwrap();
    for step in 0..2 {
        let state = view.state(&scene, step).unwrap();
        let camera = slim::render::job::camera(&scene, section, &view, &state).unwrap();
        let deimos = state.bodies[1].pose.position_m;
        assert!((camera.pose.position_m - deimos).length() < 1e-3);
        // Phobos and Deimos orbit at 9,376 and 23,458 km from Mars.
        let d_km = deimos.length() / 1000.0;
        assert!((14_000.0..33_000.0).contains(&d_km), "{d_km} km");
        let to_phobos = -deimos.normalize();
        assert!(camera.boresight().dot(to_phobos) > 1.0 - 1e-12);
    }
    let moved = edit_scene(&text, "observer_naif_id = 402", "observer_naif_id = -203");
    let scene = slim::scene::Scene::parse(&path, &moved, moved.as_bytes().to_vec()).unwrap();
    let view = slim::render::job::View::load(&scene).unwrap();
    let state = view.state(&scene, 0).unwrap();
    let e = slim::render::job::camera(&scene, section, &view, &state)
        .unwrap_err()
        .to_string();
    assert!(e.contains("-203") && e.contains("provide"), "{e}");
}

fn edit_scene(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from));
    text.replacen(from, to, 1)
}
