//! SPICE geometry against CSPICE (tests/fixtures/spice, made by make_reference.py with
//! CSPICE N0067 through spiceypy): body-fixed rotations, Sun directions and distances for
//! every aberration setting, spin periods from the PCK, eclipses, and the errors.

use glam::{DMat3, DVec3};
use slim::ephemeris::spice::{parse_aberration, Kernels, SpiceBody, SpiceEphemeris};
use slim::ephemeris::Ephemeris;
use std::path::PathBuf;

/// The targets: direction within 1e-6 rad, distance within 1e-9 relative.
const DIRECTION_TOLERANCE_RAD: f64 = 1e-6;
const DISTANCE_TOLERANCE: f64 = 1e-9;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn kernels(names: &[&str]) -> Kernels {
    let paths: Vec<PathBuf> = names
        .iter()
        .map(|n| root().join("data/kernels").join(n))
        .collect();
    Kernels::load(&paths).expect("kernels load")
}

/// Data rows of a fixture CSV as maps from column name to text.
fn rows(name: &str) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(root().join("tests/fixtures/spice").join(name)).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(str::to_string))
                .collect()
        })
        .collect()
}

fn num(row: &std::collections::HashMap<String, String>, key: &str) -> f64 {
    row[key].parse().unwrap()
}

/// The fixture's row-major m00..m22 as a matrix.
fn matrix(row: &std::collections::HashMap<String, String>) -> DMat3 {
    let m = |r: usize, c: usize| num(row, &format!("m{r}{c}"));
    DMat3::from_cols_array(&[
        m(0, 0),
        m(1, 0),
        m(2, 0),
        m(0, 1),
        m(1, 1),
        m(2, 1),
        m(0, 2),
        m(1, 2),
        m(2, 2),
    ])
}

/// Angle between two rotations, radians (robust for tiny angles).
fn rotation_angle(a: DMat3, b: DMat3) -> f64 {
    let d = a * b.transpose();
    let skew = DVec3::new(
        d.y_axis.z - d.z_axis.y,
        d.z_axis.x - d.x_axis.z,
        d.x_axis.y - d.y_axis.x,
    );
    (0.5 * skew.length()).asin()
}

fn angle(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

const PCK: &[&str] = &["lsk/naif0012.tls", "pck/pck00011.tpc"];

fn frame_body(frame: &str) -> Option<i32> {
    Some(match frame {
        "IAU_PHOBOS" => 401,
        "IAU_DEIMOS" => 402,
        "IAU_MARS" => 499,
        "IAU_MOON" => 301,
        "IAU_VESTA" => 2000004,
        "IAU_EROS" => 2000433,
        _ => return None,
    })
}

#[test]
fn iau_rotations_match_cspice() {
    let k = kernels(PCK);
    let mut worst: Vec<(String, f64)> = Vec::new();
    for row in rows("rotations.csv") {
        let Some(id) = frame_body(&row["frame"]) else {
            continue;
        };
        let m = matrix(&row);
        let mine = k
            .rotation_model(id)
            .expect("model")
            .j2000_to_body(num(&row, "et_tdb_s"));
        let err = rotation_angle(mine, m);
        match worst.iter_mut().find(|w| w.0 == row["frame"]) {
            Some(w) => w.1 = w.1.max(err),
            None => worst.push((row["frame"].clone(), err)),
        }
    }
    assert_eq!(
        worst.len(),
        6,
        "every IAU frame of the fixture was checked: {worst:?}"
    );
    for (frame, err) in &worst {
        println!("{frame}: max rotation error {err:.3e} rad");
        assert!(*err < DIRECTION_TOLERANCE_RAD, "{frame}: {err:e} rad");
    }
}

/// Kernels of the lunar frames (MOON_ME through MOON_PA_DE421 from the binary PCK).
const MOON_FRAMES: &[&str] = &[
    "spk/de421.bsp",
    "pck/moon_pa_de421_1900-2050.bpc",
    "fk/moon_080317.tf",
];

#[test]
fn moon_me_rotations_match_cspice() {
    let k = kernels(&[PCK, MOON_FRAMES].concat());
    let body = SpiceBody::with_frame(&k, "moon", 301, "MOON_ME").unwrap();
    let mut worst = 0f64;
    let mut checked = 0;
    for row in rows("rotations.csv")
        .iter()
        .filter(|r| r["frame"] == "MOON_ME")
    {
        let m = matrix(row);
        let epoch = hifitime::Epoch::from_tdb_seconds(num(row, "et_tdb_s"));
        let mine = body.frame.j2000_to_frame(k.almanac(), epoch).unwrap();
        worst = worst.max(rotation_angle(mine, m));
        checked += 1;
    }
    println!("MOON_ME: max rotation error {worst:.3e} rad over {checked} epochs");
    assert_eq!(checked, 10);
    assert!(worst < 1e-9, "MOON_ME: {worst:e} rad");
}

fn case_kernels(case: &str) -> Option<Vec<&'static str>> {
    let mut k = PCK.to_vec();
    match case {
        "phobos" | "mars" => k.extend([
            "spk/mar085_subset_2018-06/mar085.bsp",
            "spk/mar085_subset_2018-06/de430.bsp",
        ]),
        "moon_iau" => k.push("spk/de421.bsp"),
        "moon_me" => k.extend(MOON_FRAMES),
        "vesta" => k.extend(["spk/de421.bsp", "spk/sb_vesta_nav_120628.bsp"]),
        _ => return None,
    }
    Some(k)
}

fn case_body(case: &str) -> i32 {
    match case {
        "phobos" => 401,
        "mars" => 499,
        "moon_iau" | "moon_me" => 301,
        "vesta" => 2000004,
        _ => unreachable!(),
    }
}

#[test]
fn sun_directions_match_cspice_for_every_aberration() {
    let fixture = rows("sun_directions.csv");
    let mut report = Vec::new();
    for case in ["phobos", "mars", "moon_iau", "moon_me", "vesta"] {
        let k = case_kernels(case).unwrap();
        for abcorr in ["NONE", "LT", "LT+S", "CN", "CN+S"] {
            let picked: Vec<_> = fixture
                .iter()
                .filter(|r| r["case"] == case && r["abcorr"] == abcorr)
                .collect();
            assert!(!picked.is_empty(), "{case} {abcorr} in fixture");
            let epochs = picked
                .iter()
                .map(|r| hifitime::Epoch::from_tdb_seconds(num(r, "et_tdb_s")))
                .collect();
            let kernels = kernels(&k);
            let body = match picked[0]["target_frame"].as_str() {
                "MOON_ME" => SpiceBody::with_frame(&kernels, case, 301, "MOON_ME"),
                _ => SpiceBody::new(&kernels, case, case_body(case)),
            }
            .unwrap();
            let eph = SpiceEphemeris::new(
                kernels,
                vec![body.into()],
                epochs,
                1.0,
                parse_aberration(abcorr).unwrap(),
                1361.0,
            )
            .unwrap();
            let (mut dir_err, mut dist_err) = (0f64, 0f64);
            for (step, r) in picked.iter().enumerate() {
                let s = &eph.state(step).unwrap().bodies[0];
                let expected = DVec3::new(num(r, "sun_x"), num(r, "sun_y"), num(r, "sun_z"));
                dir_err = dir_err.max(angle(s.sun_dir, expected));
                let d = num(r, "distance_km") * 1000.0;
                dist_err = dist_err.max((s.sun_distance_m - d).abs() / d);
            }
            report.push(format!(
                "{case:8} {abcorr:5} direction {dir_err:.2e} rad, distance {dist_err:.2e}"
            ));
            assert!(
                dir_err < DIRECTION_TOLERANCE_RAD,
                "{case} {abcorr}: direction {dir_err:e} rad"
            );
            assert!(
                dist_err < DISTANCE_TOLERANCE,
                "{case} {abcorr}: distance {dist_err:e}"
            );
        }
    }
    println!("{}", report.join("\n"));
}

#[test]
fn spin_periods_come_from_the_pck_rates() {
    let k = kernels(PCK);
    for row in rows("spin_periods.csv") {
        let id: i32 = row["naif_id"].parse().unwrap();
        let period_h = k.rotation_model(id).unwrap().rotation_period_s().unwrap() / 3600.0;
        assert!(
            (period_h - num(&row, "period_h")).abs() < 1e-9 * period_h,
            "{}",
            row["body"]
        );
    }
    // Phobos: 7.65 h to the PCK's precision (W1 = 1128.8447592 °/day → 7.6538 h).
    let phobos = k.rotation_model(401).unwrap().rotation_period_s().unwrap() / 3600.0;
    assert!((phobos - 7.65).abs() < 0.005, "{phobos}");
}

#[test]
fn asteroid_frames_are_relative_to_j2000() {
    // anise 0.10's text-PCK conversion gives Vesta and Eros parent frames 20000 and 20004
    // (id / 100), which do not exist; slim evaluates their IAU models itself. Their poles
    // must be where the PCK puts them: Vesta RA 309.031°, Dec 42.235° (pck00011).
    let k = kernels(PCK);
    let r = k.rotation_model(2000004).unwrap().j2000_to_body(0.0);
    let (ra, dec) = (309.031f64.to_radians(), 42.235f64.to_radians());
    let pole = DVec3::new(dec.cos() * ra.cos(), dec.cos() * ra.sin(), dec.sin());
    assert!(angle(r * pole, DVec3::Z) < 1e-12);
    assert!(k.rotation_model(2000433).is_some());
}

#[test]
fn unsupported_kernels_are_refused_by_name() {
    let dir = std::env::temp_dir().join(format!("slim-spice-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (name, kind) in [
        ("a.bc", "CK"),
        ("b.bds", "DSK"),
        ("c.ti", "IK"),
        ("d.xyz", "not a kernel kind"),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, b"x").unwrap();
        let e = Kernels::load(std::slice::from_ref(&path))
            .err()
            .expect("refused")
            .to_string();
        assert!(
            e.contains(name) && e.contains(kind) && e.contains("SPK (.bsp)"),
            "{e}"
        );
    }
    let fake = dir.join("fake.bsp");
    std::fs::write(&fake, b"hello world, not a DAF").unwrap();
    let e = Kernels::load(&[fake]).err().expect("refused").to_string();
    assert!(e.contains("fake.bsp") && e.contains("DAF"), "{e}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn epochs_outside_the_kernels_name_body_frame_epoch_and_window() {
    let k = case_kernels("phobos").unwrap();
    let kernels = kernels(&k);
    let body = SpiceBody::new(&kernels, "phobos", 401).unwrap();
    let epoch = hifitime::Epoch::from_gregorian_utc_at_midnight(2019, 1, 1);
    let eph =
        SpiceEphemeris::new(kernels, vec![body.into()], vec![epoch], 1.0, None, 1361.0).unwrap();
    let e = eph.state(0).unwrap_err().to_string();
    for needle in [
        "phobos",
        "401",
        "IAU",
        "2019-01-01",
        "2018-06-09",
        "2018-06-14",
    ] {
        assert!(e.contains(needle), "'{needle}' missing from: {e}");
    }
}

#[test]
fn missing_bodies_list_what_the_kernels_provide() {
    let k = case_kernels("phobos").unwrap();
    let kernels = kernels(&k);
    let e = SpiceBody::new(&kernels, "nowhere", 999_999)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("999999") && e.contains("401") && e.contains("499"),
        "{e}"
    );
    // A body with a frame but no ephemeris: the error lists the SPK's bodies.
    let body = SpiceBody::new(&kernels, "eros", 2000433).unwrap();
    let epoch = hifitime::Epoch::from_gregorian_utc_at_midnight(2018, 6, 11);
    let eph =
        SpiceEphemeris::new(kernels, vec![body.into()], vec![epoch], 1.0, None, 1361.0).unwrap();
    let e = eph.state(0).unwrap_err().to_string();
    assert!(
        e.contains("2000433") && e.contains("provide") && e.contains("401"),
        "{e}"
    );
}

/// CSPICE's first total (FULL) and partial-or-total (ANY) eclipse of the Sun by Mars seen
/// from Phobos, each as (start, stop) in ET seconds.
fn first_eclipse() -> ((f64, f64), (f64, f64)) {
    let eclipses = rows("phobos_eclipses.csv");
    let first = |kind: &str| {
        let r = eclipses.iter().find(|r| r["type"] == kind).unwrap();
        (num(r, "start_et_tdb_s"), num(r, "stop_et_tdb_s"))
    };
    (first("FULL"), first("ANY"))
}

/// Phobos's lit facets at each epoch, with Mars (a PCK-sized ellipsoid) as occluder.
fn phobos_lit_facets(epochs: Vec<hifitime::Epoch>) -> Vec<usize> {
    use slim::illum::Direct;
    use slim::mesh::{generate::ellipsoid, read_mesh, LengthUnit, Mesh};
    use slim::world::{Body, World};
    let kernels = kernels(&case_kernels("phobos").unwrap());
    let mars_radii = kernels.radii_km(499).expect("pck00011 has Mars radii");
    let bodies = vec![
        SpiceBody::new(&kernels, "phobos", 401).unwrap().into(),
        SpiceBody::new(&kernels, "mars", 499).unwrap().into(),
    ];
    let phobos = read_mesh(&root().join("data/shapes/phobos/m1phobos.obj"), None).unwrap();
    let world = World {
        bodies: vec![
            Body::new("phobos", Mesh::from_raw(phobos, LengthUnit::Km), false),
            Body::new(
                "mars",
                Mesh::from_raw(ellipsoid(5, mars_radii), LengthUnit::Km),
                true,
            ),
        ],
    };
    let n_phobos = world.bodies[0].mesh.len();
    let eph = SpiceEphemeris::new(
        kernels,
        bodies,
        epochs,
        1.0,
        parse_aberration("LT+S").unwrap(),
        1361.0,
    )
    .unwrap();
    let direct = Direct::new(&world, slim::trace::TracerKind::Sunview);
    let mut e = vec![0.0; world.facet_count()];
    (0..eph.steps())
        .map(|k| {
            direct.compute(&eph.state(k).unwrap(), &mut e).unwrap();
            e[..n_phobos].iter().filter(|&&x| x > 0.0).count()
        })
        .collect()
}

#[test]
fn phobos_goes_dark_for_the_mars_eclipse_cspice_predicts() {
    // CSPICE's gfoclt (Sun as an ellipsoid behind Mars, seen from Phobos, LT+S) gives the
    // total and partial intervals. With a point Sun and centroid rays, every facet must be
    // dark inside the total interval and the body lit again outside the partial one; the
    // dark spell must start and end within the penumbral ~30 s at each end.
    let (full, any) = first_eclipse();
    let step = 5.0;
    let t0 = any.0 - 60.0;
    let n = ((any.1 + 60.0 - t0) / step) as usize;
    let times: Vec<f64> = (0..n).map(|k| t0 + step * k as f64).collect();
    let lit = phobos_lit_facets(
        times
            .iter()
            .map(|&t| hifitime::Epoch::from_tdb_seconds(t))
            .collect(),
    );
    for (t, l) in times.iter().zip(&lit) {
        if *t >= full.0 && *t <= full.1 {
            assert_eq!(*l, 0, "lit facets inside the total eclipse at ET {t}");
        }
        if *t < any.0 || *t > any.1 {
            assert!(
                *l > 1000,
                "Phobos should be sunlit at ET {t}, {l} facets lit"
            );
        }
    }
    let dark: Vec<f64> = times
        .iter()
        .zip(&lit)
        .filter(|(_, l)| **l == 0)
        .map(|(t, _)| *t)
        .collect();
    let (begin, end) = (dark[0], dark[dark.len() - 1]);
    println!(
        "dark {:.0} s (ET {begin} .. {end}); CSPICE total {:.0} s, partial {:.0} s",
        end - begin + step,
        full.1 - full.0,
        any.1 - any.0
    );
    assert!(
        begin >= any.0 && begin <= full.0 + step,
        "dark from {begin}"
    );
    assert!(end <= any.1 && end >= full.1 - step, "dark until {end}");
}

/// A SPICE scene whose kernels are the shipped ones (absolute paths), parsed in memory.
fn spice_scene(kernel_names: &[&str], rest: &str) -> slim::scene::Scene {
    let list: Vec<String> = kernel_names
        .iter()
        .map(|n| format!("{:?}", root().join("data/kernels").join(n)))
        .collect();
    let text = format!(
        "[ephemeris]\nmode = \"spice\"\nkernels = [{}]\n{rest}",
        list.join(", ")
    );
    let path = root().join("tests/in-memory-scene.toml");
    slim::scene::Scene::parse(&path, &text, text.as_bytes().to_vec()).unwrap()
}

#[test]
fn a_scene_frame_key_selects_moon_me() {
    let window = "start = \"2024-01-01T00:00:00 TDB\"\nstop = \"2024-01-02T00:00:00 TDB\"\n\
                  step_s = 21600\naberration = \"NONE\"\n";
    let body = |frame: &str| {
        format!("[[body]]\nname = \"moon\"\nnaif_id = 301\n{frame}ellipsoid = {{ levels = 0 }}\n")
    };
    let names = [PCK, MOON_FRAMES].concat();
    let me = spice_scene(
        &names,
        &format!("{window}{}", body("frame = \"MOON_ME\"\n")),
    );
    let iau = spice_scene(&names, &format!("{window}{}", body("")));
    let me = slim::prepare::build_ephemeris(&me, None).unwrap();
    let iau = slim::prepare::build_ephemeris(&iau, None).unwrap();
    let k = kernels(&names);
    let reference = SpiceBody::with_frame(&k, "moon", 301, "MOON_ME").unwrap();
    for step in 0..me.steps() {
        let s = me.state(step).unwrap();
        let expected = reference
            .frame
            .j2000_to_frame(k.almanac(), s.epoch)
            .unwrap();
        assert!(rotation_angle(s.bodies[0].pose.body_to_scene.transpose(), expected) < 1e-15);
        // MOON_ME and IAU_MOON differ by about a hundredth of a degree, so the key matters.
        let apart = angle(
            s.bodies[0].sun_dir,
            iau.state(step).unwrap().bodies[0].sun_dir,
        );
        assert!(apart > 1e-5, "step {step}: {apart:e} rad");
    }
}

#[test]
fn unknown_frames_list_what_the_frame_kernels_define() {
    let k = kernels(&[PCK, MOON_FRAMES].concat());
    let e = SpiceBody::with_frame(&k, "moon", 301, "MOON_XYZ")
        .unwrap_err()
        .to_string();
    for needle in ["moon", "301", "MOON_XYZ", "MOON_ME", "MOON_PA_DE421"] {
        assert!(e.contains(needle), "{needle:?} missing from: {e}");
    }
}

#[test]
fn a_synthetic_moonlet_follows_its_circular_orbit_and_faces_its_primary() {
    let period_h = 2.0;
    let radius_km = 30.0;
    let scene = spice_scene(
        &case_kernels("phobos").unwrap(),
        &format!(
            "start = \"2018-06-10T00:00:00 UTC\"\nstop = \"2018-06-10T02:00:00 UTC\"\nstep_s = 900\n\
             [[body]]\nname = \"phobos\"\nnaif_id = 401\nellipsoid = {{ levels = 0 }}\n\
             [[body]]\nname = \"moonlet\"\nellipsoid = {{ radii_km = [0.1, 0.1, 0.1], levels = 0 }}\n\
             orbit = {{ radius_km = {radius_km}, period_h = {period_h}, phase_deg = 90 }}\n"
        ),
    );
    let eph = slim::prepare::build_ephemeris(&scene, None).unwrap();
    assert_eq!(eph.steps(), 8);
    for step in 0..eph.steps() {
        let s = eph.state(step).unwrap();
        let (primary, moonlet) = (&s.bodies[0], &s.bodies[1]);
        // Pole along J2000 z: the orbit is the equator, phase counted from +x.
        let theta = std::f64::consts::FRAC_PI_2
            + std::f64::consts::TAU * step as f64 * 900.0 / (period_h * 3600.0);
        let expected = DVec3::new(theta.cos(), theta.sin(), 0.0) * radius_km * 1000.0;
        assert!((moonlet.pose.position_m - expected).length() < 1e-6);
        // Tidally locked: body +x toward Phobos, +z along the pole.
        let axes = moonlet.pose.body_to_scene;
        assert!((axes * DVec3::X + expected.normalize()).length() < 1e-12);
        assert!((axes * DVec3::Z - DVec3::Z).length() < 1e-12);
        // The Sun seen from the moonlet: the Sun seen from Phobos, moved by the offset.
        let sun_scene = primary.pose.body_to_scene * primary.sun_dir * primary.sun_distance_m;
        let from_moonlet = sun_scene - expected;
        assert!((moonlet.sun_distance_m - from_moonlet.length()).abs() < 1e-3);
        assert!(angle(axes * moonlet.sun_dir, from_moonlet) < 1e-12);
    }
}

/// The shipped Moon example (data/moon-haworth.toml): the stereographic patch lands where
/// the IAU gazetteer puts Haworth crater (87.45° S, 5.16° W, 51.4 km across), and over the
/// month the crater floor stays dark, as LOLA-based maps of permanent shadow show (Haworth
/// holds one of the largest permanently shadowed regions; Mazarico et al. 2011, Icarus 211).
#[test]
fn the_moon_example_places_haworth_and_keeps_its_floor_in_shadow() {
    let scene = slim::scene::Scene::load(&root().join("data/moon-haworth.toml")).unwrap();
    let prepared =
        slim::prepare::prepare(&scene, &Default::default(), &mut Default::default()).unwrap();
    let (world, states) = (&prepared.assembly.world, &prepared.states);
    assert_eq!(states.len(), 720);
    // The patch is terrain (its map's build is announced at terrain's cost); the Earth's
    // generated ellipsoid is closed.
    assert!(world.bodies[0].open && !world.bodies[1].open);
    let sim = slim::simulate::statistics(world, states, scene.run.tracer, prepared.bins).unwrap();

    let mesh = &world.bodies[0].mesh;
    let radius = |i: usize| mesh.centroids[i].length();
    let mut order: Vec<usize> = (0..mesh.len()).collect();
    order.sort_by(|&a, &b| radius(a).total_cmp(&radius(b)));
    let floor = &order[..mesh.len() / 20];
    let centre = floor.iter().map(|&i| mesh.centroids[i]).sum::<DVec3>() / floor.len() as f64;
    let lat = (centre.z / centre.length()).asin().to_degrees();
    let lon = centre.y.atan2(centre.x).to_degrees();
    println!("Haworth floor centre: {lat:.2}°, {lon:.2}° E");
    // Half the crater's radius is 0.42° of latitude at the Moon's radius.
    assert!((lat - -87.45).abs() < 0.42, "latitude {lat}");
    assert!(
        (lon - -5.16).abs() < 0.42 / 87.45f64.to_radians().cos(),
        "longitude {lon}"
    );

    let lit = floor
        .iter()
        .filter(|&&i| sim.stats.lit_fraction(i) > 0.0)
        .count();
    assert_eq!(lit, 0, "{lit} of {} floor facets saw the Sun", floor.len());
    // The rim and the pole-facing slopes do see the Sun: the run is not trivially dark.
    let brightest = (0..mesh.len())
        .map(|i| sim.stats.max(i))
        .fold(0.0, f64::max);
    assert!(brightest > 300.0, "brightest facet {brightest} W/m2");
}

#[test]
fn an_iau_frame_name_picks_its_own_body() {
    let k = kernels(&case_kernels("phobos").unwrap());
    // Phobos placed in Mars's IAU frame: the rotation is Mars's, not Phobos's.
    let body = SpiceBody::with_frame(&k, "phobos", 401, "IAU_MARS").unwrap();
    let epoch = hifitime::Epoch::from_tdb_seconds(5.8e8);
    let mars = k.rotation_model(499).unwrap().j2000_to_body(5.8e8);
    let got = body.frame.j2000_to_frame(k.almanac(), epoch).unwrap();
    assert!(rotation_angle(got, mars) < 1e-15);
    let e = SpiceBody::with_frame(&k, "phobos", 401, "IAU_NOWHERE")
        .unwrap_err()
        .to_string();
    assert!(e.contains("NOWHERE") && e.contains("NAIF_BODY_NAME"), "{e}");
}

/// A text kernel saved with a UTF-8 byte-order mark reads like the same file without it
/// (here the mark stands right before `\begindata`, which it used to hide).
#[test]
fn a_text_kernel_with_a_byte_order_mark_reads_the_same() {
    let dir = std::env::temp_dir().join(format!("slim-spice-bom-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("radii.tpc");
    std::fs::write(&path, "\u{feff}\\begindata\nBODY999_RADII = ( 3 2 1 )\n").unwrap();
    let kernels = Kernels::load(std::slice::from_ref(&path)).expect("kernel loads");
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(kernels.radii_km(999), Some(DVec3::new(3.0, 2.0, 1.0)));
}

/// A text PCK whose phase-angle degree is absurd (1e30) is refused when it is loaded,
/// naming the file and the variable (the degree + 1 used to overflow and panic when a
/// rotation model was built).
#[test]
fn an_absurd_phase_angle_degree_is_refused_with_the_file() {
    let dir = std::env::temp_dir().join(format!("slim-spice-degree-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("crafted.tpc");
    let text = "\\begindata\nBODY4_MAX_PHASE_DEGREE = 1e30\nBODY4_NUT_PREC_ANGLES = ( 1 2 )\n\
                BODY401_POLE_RA = ( 0 0 0 )\nBODY401_POLE_DEC = ( 90 0 0 )\nBODY401_PM = ( 0 1 0 )\n";
    std::fs::write(&path, text).unwrap();
    let loaded = Kernels::load(std::slice::from_ref(&path));
    std::fs::remove_dir_all(&dir).ok();
    let e = loaded.err().expect("refused").to_string();
    assert!(
        e.contains("crafted.tpc") && e.contains("BODY4_MAX_PHASE_DEGREE"),
        "{e}"
    );
}

/// Irradiance of every facet of Phobos (its PCK ellipsoid, 1,280 facets) at each epoch
/// under a limb-darkened disk Sun, with Mars and without it; and per epoch the transform
/// from Phobos's frame to Mars's with the Sun in Mars's frame. Mars is a closed-form
/// ellipsoid, or with `mesh_samples` a 20,480-facet mesh met by that many rays per facet.
struct DiskEclipse {
    with_mars: Vec<Vec<f64>>,
    without: Vec<Vec<f64>>,
    to_mars: Vec<(slim::world::FrameTransform, DVec3, f64)>,
    centroids: Vec<DVec3>,
    mars_radii_m: DVec3,
}

const LIMB_DARKENING: f64 = 0.6;

fn phobos_disk_eclipse(epochs: &[hifitime::Epoch], mesh_samples: Option<u32>) -> DiskEclipse {
    use slim::horizon::{disk::SolarDisk, Shadows, SunShape};
    use slim::illum::Direct;
    use slim::mesh::{generate::ellipsoid, LengthUnit, Mesh};
    use slim::world::{Body, World};
    let kernels = kernels(&case_kernels("phobos").unwrap());
    let mars_radii_m = kernels.radii_km(499).unwrap() * 1000.0;
    let phobos_mesh = Mesh::from_raw(ellipsoid(3, kernels.radii_km(401).unwrap()), LengthUnit::Km);
    let phobos = Body::new("phobos", phobos_mesh, true);
    let levels = if mesh_samples.is_some() { 5 } else { 1 };
    let mars_mesh = Mesh::from_raw(ellipsoid(levels, mars_radii_m / 1000.0), LengthUnit::Km);
    let mars = match mesh_samples {
        Some(_) => Body::new("mars", mars_mesh, true),
        None => Body::new("mars", mars_mesh, true).with_ellipsoid(mars_radii_m),
    };
    let shadows = Shadows {
        sun: SunShape::Disk,
        disk: SolarDisk {
            limb_darkening: LIMB_DARKENING,
        },
        sun_samples: mesh_samples.unwrap_or(1),
        ..Shadows::default()
    };
    let run = |world: &World, ids: &[(&str, i32)]| {
        let kernels = self::kernels(&case_kernels("phobos").unwrap());
        let bodies = ids
            .iter()
            .map(|&(name, id)| SpiceBody::new(&kernels, name, id).unwrap().into())
            .collect();
        let lt_s = parse_aberration("LT+S").unwrap();
        let eph = SpiceEphemeris::new(kernels, bodies, epochs.to_vec(), 1.0, lt_s, 1361.0).unwrap();
        let none = world.bodies.iter().map(|_| None).collect();
        let direct = Direct::with_maps(world, slim::trace::TracerKind::Bvh, none, &shadows);
        let mut e = vec![0.0; world.facet_count()];
        let mut poses = Vec::new();
        let values = (0..eph.steps())
            .map(|k| {
                let state = eph.state(k).unwrap();
                direct.compute(&state, &mut e).unwrap();
                if let [p, m] = &state.bodies[..] {
                    let t = p.pose.relative_to(&m.pose);
                    let rho = SolarDisk::angular_radius(p.sun_distance_m);
                    poses.push((t, t.vector(p.sun_dir), rho));
                }
                e[..world.bodies[0].mesh.len()].to_vec()
            })
            .collect();
        (values, poses)
    };
    let centroids = phobos.mesh.centroids.clone();
    let (without, _) = run(
        &World {
            bodies: vec![phobos.clone()],
        },
        &[("phobos", 401)],
    );
    let (with_mars, to_mars) = run(
        &World {
            bodies: vec![phobos, mars],
        },
        &[("phobos", 401), ("mars", 499)],
    );
    DiskEclipse {
        with_mars,
        without,
        to_mars,
        centroids,
        mars_radii_m,
    }
}

/// The share of a linearly limb-darkened disk (angular radius `rho` about `sun`) hidden
/// by the ellipsoid `radii` from `point`, by rays on a polar grid of the disk meeting the
/// quadric `|x / radii|² = 1`.
fn hidden_by_rays(point: DVec3, sun: DVec3, rho: f64, radii: DVec3) -> f64 {
    let e1 = sun.any_orthonormal_vector();
    let e2 = sun.cross(e1);
    let p = point / radii;
    let (mut hidden, mut total) = (0.0, 0.0);
    let n = 300;
    for i in 0..n {
        let r = (i as f64 + 0.5) / n as f64;
        let weight = r * (1.0 - LIMB_DARKENING * (1.0 - (1.0 - r * r).sqrt()));
        for j in 0..n {
            let a = (j as f64 + 0.5) / n as f64 * std::f64::consts::TAU;
            let dir = sun + rho * r * (a.cos() * e1 + a.sin() * e2);
            let d = dir / radii;
            let (b, c) = (p.dot(d), p.length_squared() - 1.0);
            total += weight;
            if b < 0.0 && b * b >= d.length_squared() * c {
                hidden += weight;
            }
        }
    }
    hidden / total
}

#[test]
fn a_disk_sun_behind_mars_darkens_phobos_in_cspices_full_and_any_windows() {
    // CSPICE's gfoclt (Sun and Mars as ellipsoids, seen from Phobos's centre, LT+S)
    // gives when the centre sees the Sun wholly or partly hidden. Facets lie up to 13 km
    // from the centre; the shadow's edge crosses the penumbra (about 57 km: 8,740 km to
    // Mars's limb times the Sun's 0.375°) in the 29 s of ingress, about 1.9 km/s, so a
    // facet sees an edge up to 7 s (LAG = 8 s) before or after the centre does.
    // The umbra is convex and holds the centre whenever it holds every facet, so the
    // all-dark spell lies inside FULL; each spell edge falls within one step (plus LAG
    // where the facets may lead or trail) of CSPICE's.
    let (full, any) = first_eclipse();
    let step = 10.0;
    let t0 = any.0 - 120.0;
    let n = ((any.1 + 120.0 - t0) / step) as usize;
    let times: Vec<f64> = (0..n).map(|k| t0 + step * k as f64).collect();
    let epochs: Vec<_> = times
        .iter()
        .map(|&t| hifitime::Epoch::from_tdb_seconds(t))
        .collect();
    let run = phobos_disk_eclipse(&epochs, None);
    let dark = |k: usize| run.with_mars[k].iter().all(|&e| e == 0.0);
    let dimmed = |k: usize| {
        run.with_mars[k]
            .iter()
            .zip(&run.without[k])
            .any(|(e, e0)| *e < e0 * (1.0 - 1e-12))
    };
    let span = |f: &dyn Fn(usize) -> bool| {
        let hits: Vec<f64> = (0..n).filter(|&k| f(k)).map(|k| times[k]).collect();
        (hits[0], hits[hits.len() - 1], hits.len())
    };
    let (dark_from, dark_to, dark_steps) = span(&dark);
    let (dim_from, dim_to, dim_steps) = span(&dimmed);
    println!(
        "all dark ET {dark_from} .. {dark_to} ({dark_steps} steps) vs FULL {full:?}; \
         dimmed {dim_from} .. {dim_to} ({dim_steps} steps) vs ANY {any:?}"
    );
    // Every step between the first and the last is dark (or dimmed): one spell each.
    assert_eq!(dark_steps as f64, (dark_to - dark_from) / step + 1.0);
    assert_eq!(dim_steps as f64, (dim_to - dim_from) / step + 1.0);
    const LAG: f64 = 8.0;
    let between = |t: f64, lo: f64, hi: f64| t >= lo && t <= hi;
    assert!(
        between(dark_from, full.0, full.0 + step + LAG),
        "dark from {dark_from}"
    );
    assert!(
        between(dark_to, full.1 - step - LAG, full.1),
        "dark until {dark_to}"
    );
    assert!(
        between(dim_from, any.0 - LAG, any.0 + step),
        "dimmed from {dim_from}"
    );
    assert!(
        between(dim_to, any.1 - step, any.1 + LAG),
        "dimmed until {dim_to}"
    );

    // Through ingress and egress, each facet's loss is the share of the disk Mars covers.
    let mut compared = 0;
    let mut worst: f64 = 0.0;
    for k in (0..n).filter(|&k| dimmed(k) && !dark(k)) {
        let (to_mars, sun, rho) = run.to_mars[k];
        for i in (0..run.centroids.len()).step_by(97) {
            let (e, e0) = (run.with_mars[k][i], run.without[k][i]);
            if e0 <= 0.0 {
                continue;
            }
            let at = to_mars.point(run.centroids[i]);
            let expected = 1.0 - hidden_by_rays(at, sun, rho, run.mars_radii_m);
            worst = worst.max((e / e0 - expected).abs());
            compared += 1;
        }
    }
    println!("{compared} facet-steps in penumbra, worst |share − rays| {worst:.2e}");
    assert!(compared >= 20, "{compared}");
    // The 300 × 300 polar grid of the disk places a cut to about 1/300 of a ring's
    // width (seen: 1.8e-4).
    assert!(worst < 1e-3, "{worst}");
}

#[test]
fn rays_through_a_disk_sun_to_a_mesh_mars_agree_with_the_closed_form() {
    // Through the first ingress at 2 s steps, Mars as a 20,480-facet mesh sampled by n
    // rays per facet against Mars as an ellipsoid. The mesh's chords sit up to 0.5 km
    // inside the ellipsoid: up to 0.025 of the disk where a share changes fastest (the
    // mean difference levels off at 0.012); n rays add a step of 1/n and a sampling
    // error of that order. The printed lines are the error-against-cost table of
    // docs/accuracy.md (`cargo test --release --test spice rays_through -- --nocapture`).
    let any = first_eclipse().1 .0;
    let epochs: Vec<_> = (0..24)
        .map(|k| hifitime::Epoch::from_tdb_seconds(any - 6.0 + 2.0 * k as f64))
        .collect();
    let closed = phobos_disk_eclipse(&epochs, None);
    for samples in [8, 32, 128, 512] {
        let started = std::time::Instant::now();
        let sampled = phobos_disk_eclipse(&epochs, Some(samples));
        let seconds = started.elapsed().as_secs_f64();
        let (mut worst, mut sum, mut partial) = (0.0f64, 0.0, 0);
        for k in 0..epochs.len() {
            for i in 0..closed.centroids.len() {
                let e0 = closed.without[k][i];
                let a = closed.with_mars[k][i] / e0;
                if e0 > 0.0 && a > 0.0 && a < 1.0 {
                    let b = sampled.with_mars[k][i] / e0;
                    partial += 1;
                    worst = worst.max((a - b).abs());
                    sum += (a - b).abs();
                }
            }
        }
        println!(
            "{samples:4} rays: {partial} facet-steps in penumbra, |closed − sampled| mean \
             {:.4} worst {worst:.4}; {seconds:.2} s for the run",
            sum / partial as f64
        );
        assert!(partial > 1000, "{partial}");
        assert!(worst < 0.03 + 1.5 / samples as f64, "{worst}");
    }
}

#[test]
fn the_earth_seen_from_a_smooth_lunar_site_rises_and_sets_where_cspice_says() {
    // 87.5° S, 5° W on the 1737.4 km Moon (MOON_ME), 2 m up, hourly through September
    // 2024: Earth's elevation against CSPICE's spkcpo, and its windows above 0 against
    // CSPICE's bisected crossings (tests/fixtures/spice/make_reference.py).
    let scene = spice_scene(
        &[
            "lsk/naif0012.tls",
            "pck/pck00011.tpc",
            "spk/de421.bsp",
            "pck/moon_pa_de421_1900-2050.bpc",
            "fk/moon_080317.tf",
        ],
        "start = \"2024-09-01T00:00:00 UTC\"\nstop = \"2024-10-01T00:00:00 UTC\"\nstep_s = 3600\n\
         [[body]]\nname = \"moon\"\nnaif_id = 301\nframe = \"MOON_ME\"\nellipsoid = { levels = 3 }\n\
         [[body]]\nname = \"earth\"\nnaif_id = 399\nellipsoid = { levels = 1 }\noutputs = false\n",
    );
    let prepared =
        slim::prepare::prepare(&scene, &Default::default(), &mut Default::default()).unwrap();
    let (world, states) = (&prepared.assembly.world, &prepared.states);
    let (lat, lon) = ((-87.5f64).to_radians(), (-5f64).to_radians());
    let surface = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin()) * 1737.4e3;
    let mesh = &world.bodies[0].mesh;
    let bvh = slim::trace::bvh::Bvh::build(mesh);
    let site = slim::panel::Site::new(mesh, &bvh, surface, 2.0).unwrap();
    let expected = rows("earth_from_haworth.csv");
    assert_eq!(states.len(), expected.len());
    let (mut t, mut elevation) = (Vec::new(), Vec::new());
    let mut worst: f64 = 0.0;
    for (state, row) in states.iter().zip(&expected) {
        let d = state.epoch.to_tdb_seconds() - num(row, "et_tdb_s");
        // hifitime's and CSPICE's TDB − TT series differ by a few microseconds.
        assert!(d.abs() < 1e-4, "epoch {} differs by {d} s", state.epoch);
        let seen = slim::sight::Sighting::of(&site, state, 0, 1);
        let cspice = num(row, "elevation_deg");
        worst = worst.max((seen.elevation.to_degrees() - cspice).abs());
        t.push(state.epoch.to_tdb_seconds());
        elevation.push(seen.elevation);
    }
    println!("Earth elevation: largest difference from CSPICE {worst:.2e}°");
    // The Sun-direction tests hold directions to 1e-6 rad; the Earth's from a point on
    // the surface inherits that.
    assert!(worst < 1e-6f64.to_degrees(), "{worst}°");

    // Windows of elevation above 0 (no terrain): the edges between hourly samples by the
    // straight line, within Δt²·max|ë|/(8|ė|) from the samples around each crossing.
    let windows = slim::sight::windows_above(&t, &elevation);
    let crossings = rows("earth_rise_set_haworth.csv");
    let edges: Vec<(bool, f64, bool)> = windows
        .iter()
        .flat_map(|w| {
            [
                (true, w.start_tdb_s, w.cut_at_start),
                (false, w.end_tdb_s, w.cut_at_end),
            ]
        })
        .filter(|(_, _, cut)| !cut)
        .collect();
    assert_eq!(edges.len(), crossings.len(), "{windows:?}");
    for ((rise, at, _), row) in edges.iter().zip(&crossings) {
        assert_eq!(*rise, row["kind"] == "rise");
        let exact = num(row, "et_tdb_s");
        let k = t.iter().position(|&x| x > exact).unwrap();
        let dt = t[k] - t[k - 1];
        let slope = ((elevation[k] - elevation[k - 1]) / dt).abs();
        let curvature = (k.saturating_sub(2)..(k + 2).min(t.len() - 1))
            .map(|j| (elevation[j + 1] - 2.0 * elevation[j] + elevation[j - 1]).abs() / (dt * dt))
            .fold(0.0, f64::max);
        // The curvature is taken from neighbouring samples: allow it to double in between.
        let bound = dt * dt * 2.0 * curvature / (8.0 * slope) + 1e-3;
        println!(
            "Earth {} at {exact}: slim {at} ({:+.1} s, bound {bound:.1} s)",
            row["kind"],
            at - exact
        );
        assert!(
            (at - exact).abs() <= bound,
            "{} s off, bound {bound} s",
            at - exact
        );
    }
    // Earth is up at the start and again at the end: both windows are cut by the month.
    assert!(windows.first().unwrap().cut_at_start && windows.last().unwrap().cut_at_end);
}
