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
        let m = DMat3::from_cols_array(&[
            num(&row, "m00"),
            num(&row, "m10"),
            num(&row, "m20"),
            num(&row, "m01"),
            num(&row, "m11"),
            num(&row, "m21"),
            num(&row, "m02"),
            num(&row, "m12"),
            num(&row, "m22"),
        ]);
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

fn case_kernels(case: &str) -> Option<Vec<&'static str>> {
    let mut k = PCK.to_vec();
    match case {
        "phobos" | "mars" => k.extend([
            "spk/mar085_subset_2018-06/mar085.bsp",
            "spk/mar085_subset_2018-06/de430.bsp",
        ]),
        "moon_iau" => k.push("spk/de421.bsp"),
        "vesta" => k.extend(["spk/de421.bsp", "spk/sb_vesta_nav_120628.bsp"]),
        _ => return None,
    }
    Some(k)
}

fn case_body(case: &str) -> i32 {
    match case {
        "phobos" => 401,
        "mars" => 499,
        "moon_iau" => 301,
        "vesta" => 2000004,
        _ => unreachable!(),
    }
}

#[test]
fn sun_directions_match_cspice_for_every_aberration() {
    let fixture = rows("sun_directions.csv");
    let mut report = Vec::new();
    for case in ["phobos", "mars", "moon_iau", "vesta"] {
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
            let body = SpiceBody::new(&kernels, case, case_body(case)).unwrap();
            let eph = SpiceEphemeris::new(
                kernels,
                vec![body],
                epochs,
                1.0,
                parse_aberration(abcorr).unwrap(),
                1361.0,
            );
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
    let eph = SpiceEphemeris::new(kernels, vec![body], vec![epoch], 1.0, None, 1361.0);
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
    let eph = SpiceEphemeris::new(kernels, vec![body], vec![epoch], 1.0, None, 1361.0);
    let e = eph.state(0).unwrap_err().to_string();
    assert!(
        e.contains("2000433") && e.contains("provide") && e.contains("401"),
        "{e}"
    );
}

/// Phobos's lit facets at each epoch, with Mars (a PCK-sized ellipsoid) as occluder.
fn phobos_lit_facets(epochs: Vec<hifitime::Epoch>) -> Vec<usize> {
    use slim::illum::Direct;
    use slim::mesh::{generate::ellipsoid, read_mesh, LengthUnit, Mesh};
    use slim::world::{Body, World};
    let kernels = kernels(&case_kernels("phobos").unwrap());
    let mars_radii = kernels.radii_km(499).expect("pck00011 has Mars radii");
    let bodies = vec![
        SpiceBody::new(&kernels, "phobos", 401).unwrap(),
        SpiceBody::new(&kernels, "mars", 499).unwrap(),
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
    );
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
    let eclipses = rows("phobos_eclipses.csv");
    let first = |kind: &str| {
        let r = eclipses.iter().find(|r| r["type"] == kind).unwrap();
        (num(r, "start_et_tdb_s"), num(r, "stop_et_tdb_s"))
    };
    let (full, any) = (first("FULL"), first("ANY"));
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
