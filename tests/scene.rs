//! Scene files: loading, path resolution and every validation error.
//!
//! In: the shipped example scene and small scene texts (parsed as if read from a file in a
//! made-up folder), plus a few real files in a temporary directory (non-UTF-8, missing).
//! Out: every error names the scene file and the offending key (or line), and says what is
//! wrong — not only where.

use slim::scene::{EphemerisSection, Scene};
use std::path::Path;

#[path = "common/temp_dir.rs"]
mod temp_dir;
use temp_dir::TempDir;

// ---------------------------------------------------------------------------------------
// Helpers

/// The path the test scenes pretend to be read from.
const SCENE_PATH: &str = "/nonexistent/scenes/test-scene.toml";

/// A valid spin-mode scene with one body.
const SPIN: &str = r#"[run]
bin_width_w_m2 = 10.0

[output]
csv = true

[ephemeris]
mode = "spin"
distance_au = 1.5
steps_per_period = 24

[[body]]
name = "rock"
mesh = "rock.obj"
units = "km"
spin_period_h = 5.0
"#;

/// A valid fixed-mode scene with one body and two suns.
const FIXED: &str = r#"[ephemeris]
mode = "fixed"
step_s = 60.0

[[ephemeris.sun]]
direction = [1.0, 0.0, 0.0]
flux_w_m2 = 1000.0

[[ephemeris.sun]]
direction = [0.0, 1.0, 0.0]
distance_au = 2.0

[[body]]
name = "rock"
mesh = "rock.obj"
units = "m"
"#;

fn parse(text: &str) -> slim::Result<Scene> {
    Scene::parse(Path::new(SCENE_PATH), text, text.as_bytes().to_vec())
}

/// `text` with `from` replaced by `to`; panics if `from` is not in `text` (a typo in a
/// test must not silently test the valid scene).
fn edit(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "test scene has no {from:?}");
    text.replacen(from, to, 1)
}

/// The error's Display; panics if the scene is accepted.
fn error_of(text: &str) -> String {
    match parse(text) {
        Ok(_) => panic!("scene accepted, expected an error:\n{text}"),
        Err(e) => e.to_string(),
    }
}

/// Asserts that `text` is rejected with an error naming the scene file and every needle.
#[track_caller]
fn assert_rejected(text: &str, needles: &[&str]) {
    let msg = error_of(text);
    assert!(
        msg.contains("test-scene.toml"),
        "error does not name the scene file: {msg}"
    );
    for n in needles {
        assert!(msg.contains(n), "error does not mention {n:?}: {msg}");
    }
    assert!(!msg.contains('\n'), "error is not one line: {msg:?}");
}

// ---------------------------------------------------------------------------------------
// Valid scenes

#[test]
fn shipped_phobos_scene_loads_with_mesh_relative_to_scene_folder() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("data/phobos-spin.toml");
    let scene = Scene::load(&path).expect("shipped scene loads");
    assert_eq!(scene.name, "phobos-spin");
    assert_eq!(scene.bodies.len(), 1);
    assert_eq!(scene.bodies[0].name, "phobos");
    assert_eq!(
        scene.bodies[0].mesh.as_deref().unwrap(),
        root.join("data/shapes/phobos/m1phobos.obj")
    );
    assert!(
        scene.bodies[0].mesh.as_deref().unwrap().is_file(),
        "resolved mesh path exists"
    );
    assert_eq!(scene.source, std::fs::read(&path).unwrap());
    match &scene.ephemeris {
        EphemerisSection::Spin(s) => {
            assert_eq!(s.distance_au, 1.52);
            assert_eq!(s.steps_per_period, 360);
            assert_eq!(s.periods, 1.0);
        }
        other => panic!("expected spin mode, got {other:?}"),
    }
    assert_eq!(scene.bodies[0].spin_period_h, Some(7.65));
}

#[test]
fn shipped_scene_resolves_mesh_from_a_relative_scene_path() {
    // Relative scene path (as typed on a command line): the mesh path stays relative to
    // the current directory through the scene's folder.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("data/phobos-spin.toml")).unwrap();
    let scene = Scene::parse(
        Path::new("data/phobos-spin.toml"),
        &text,
        text.clone().into_bytes(),
    )
    .expect("parses");
    assert_eq!(
        scene.bodies[0].mesh.as_deref().unwrap(),
        Path::new("data/shapes/phobos/m1phobos.obj")
    );
}

#[test]
fn mesh_paths_resolve_relative_to_scene_folder_and_absolute_paths_stay() {
    let scene = parse(SPIN).expect("valid");
    assert_eq!(
        scene.bodies[0].mesh.as_deref().unwrap(),
        Path::new("/nonexistent/scenes/rock.obj")
    );
    let text = edit(SPIN, "mesh = \"rock.obj\"", "mesh = \"../shapes/rock.obj\"");
    let scene = parse(&text).expect("valid");
    assert_eq!(
        scene.bodies[0].mesh.as_deref().unwrap(),
        Path::new("/nonexistent/scenes/../shapes/rock.obj")
    );
    let text = edit(
        SPIN,
        "mesh = \"rock.obj\"",
        "mesh = \"/elsewhere/rock.obj\"",
    );
    let scene = parse(&text).expect("valid");
    assert_eq!(
        scene.bodies[0].mesh.as_deref().unwrap(),
        Path::new("/elsewhere/rock.obj")
    );
}

#[test]
fn defaults_and_name_from_file_stem() {
    let scene = parse(FIXED).expect("valid");
    assert_eq!(scene.name, "test-scene");
    assert_eq!(scene.run.bin_width_w_m2, 10.0);
    assert!(scene.output.csv && scene.output.ply && !scene.output.history);
    match &scene.ephemeris {
        EphemerisSection::Fixed(f) => {
            assert_eq!(f.sun.len(), 2);
            assert_eq!(f.solar_constant_w_m2, slim::SOLAR_CONSTANT_W_M2);
        }
        other => panic!("expected fixed mode, got {other:?}"),
    }
    let j2000 = hifitime::Epoch::from_gregorian_hms(2000, 1, 1, 12, 0, 0, hifitime::TimeScale::TDB);
    assert_eq!(scene.start, j2000);
    let named = edit(SPIN, "[run]\n", "[run]\nname = \"custom\"\n");
    assert_eq!(parse(&named).unwrap().name, "custom");
}

#[test]
fn valid_optional_keys_are_accepted() {
    let text = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nperiods = 2.5\nobliquity_deg = 25.0\nsolar_longitude_deg = 90.0\n\
         solar_constant_w_m2 = 1360.8\nstart = \"2018-06-10T00:00:00 UTC\"",
    );
    let text = edit(
        &text,
        "spin_period_h = 5.0",
        "spin_period_h = 5.0\nformat = \"obj\"\norient = \"outward\"\n\
         position_km = [1.0, 2.0, 3.0]\ninitial_rotation_deg = 30.0",
    );
    let text = edit(
        &text,
        "bin_width_w_m2 = 10.0",
        "bin_width_w_m2 = 5.0\ntracer = \"grid\"",
    );
    let text = edit(
        &text,
        "csv = true",
        "csv = false\nply = false\nhistory = true",
    );
    let scene = parse(&text).unwrap_or_else(|e| panic!("valid scene rejected: {e}"));
    assert!(!scene.output.csv && !scene.output.ply && scene.output.history);
    assert_eq!(scene.bodies[0].position_km, [1.0, 2.0, 3.0]);
    let start = hifitime::Epoch::from_gregorian_utc_at_midnight(2018, 6, 10);
    assert_eq!(scene.start, start);
}

// ---------------------------------------------------------------------------------------
// Unknown keys: rejected with their path and name

#[test]
fn unknown_top_level_key_is_rejected_with_its_name() {
    assert_rejected(&format!("bogus_key = 1\n{SPIN}"), &["bogus_key"]);
}

#[test]
fn unknown_key_in_run_is_rejected_with_its_path() {
    assert_rejected(
        &edit(SPIN, "bin_width_w_m2", "bin_widht_w_m2"),
        &["run.bin_widht_w_m2"],
    );
}

#[test]
fn unknown_key_in_output_is_rejected_with_its_path() {
    assert_rejected(&edit(SPIN, "csv = true", "cvs = true"), &["output.cvs"]);
}

#[test]
fn unknown_key_in_body_is_rejected_with_its_path() {
    assert_rejected(
        &edit(SPIN, "spin_period_h", "spin_perod_h"),
        &["body[0]", "spin_perod_h"],
    );
    let two =
        format!("{SPIN}\n[[body]]\nname = \"b\"\nmesh = \"b.obj\"\nunits = \"m\"\ncolour = 1\n");
    assert_rejected(&two, &["body[1]", "colour"]);
}

#[test]
fn unknown_key_in_spin_ephemeris_is_rejected_with_its_name() {
    // The ephemeris is an internally tagged enum; the path may stop at `ephemeris`, but
    // the user must still be told which key is unknown.
    assert_rejected(
        &edit(SPIN, "steps_per_period", "steps_per_perod"),
        &["ephemeris", "steps_per_perod"],
    );
}

#[test]
fn unknown_key_in_fixed_ephemeris_is_rejected_with_its_name() {
    assert_rejected(&edit(FIXED, "step_s", "stepp_s"), &["ephemeris", "stepp_s"]);
}

#[test]
fn unknown_key_in_fixed_sun_is_rejected_with_its_name() {
    let text = edit(
        FIXED,
        "flux_w_m2 = 1000.0",
        "flux_w_m2 = 1000.0\ncolour = \"yellow\"",
    );
    assert_rejected(&text, &["ephemeris", "colour"]);
}

#[test]
fn unknown_ephemeris_mode_is_rejected_naming_the_mode() {
    assert_rejected(
        &edit(SPIN, "mode = \"spin\"", "mode = \"orbit\""),
        &["ephemeris", "orbit"],
    );
}

// ---------------------------------------------------------------------------------------
// Missing keys and wrong types

#[test]
fn missing_body_units_is_reported_by_name() {
    assert_rejected(&edit(SPIN, "units = \"km\"\n", ""), &["body[0]", "units"]);
}

#[test]
fn missing_body_mesh_is_reported_by_name() {
    assert_rejected(
        &edit(SPIN, "mesh = \"rock.obj\"\n", ""),
        &["body[0]", "mesh"],
    );
}

#[test]
fn missing_body_name_is_reported_by_name() {
    assert_rejected(&edit(SPIN, "name = \"rock\"\n", ""), &["body[0]", "name"]);
}

#[test]
fn missing_distance_au_in_spin_mode_is_reported_by_name() {
    assert_rejected(
        &edit(SPIN, "distance_au = 1.5\n", ""),
        &["ephemeris", "distance_au"],
    );
}

#[test]
fn missing_spin_period_of_first_body_in_spin_mode() {
    assert_rejected(
        &edit(SPIN, "spin_period_h = 5.0\n", ""),
        &["body[0].spin_period_h"],
    );
    // A second body without a spin period is fine (not rotating).
    let two = format!("{SPIN}\n[[body]]\nname = \"b\"\nmesh = \"b.obj\"\nunits = \"m\"\n");
    parse(&two).expect("second body may omit spin_period_h");
}

#[test]
fn missing_ephemeris_mode_and_section() {
    assert_rejected(&edit(SPIN, "mode = \"spin\"\n", ""), &["ephemeris", "mode"]);
    let no_ephemeris = "[[body]]\nname = \"a\"\nmesh = \"a.obj\"\nunits = \"m\"\n";
    assert_rejected(no_ephemeris, &["ephemeris"]);
}

#[test]
fn wrong_type_of_units_is_reported_with_path() {
    assert_rejected(
        &edit(SPIN, "units = \"km\"", "units = 3"),
        &["body[0].units"],
    );
    assert_rejected(
        &edit(SPIN, "units = \"km\"", "units = \"miles\""),
        &["body[0].units", "miles"],
    );
}

#[test]
fn wrong_type_in_run_and_output_is_reported_with_path() {
    assert_rejected(
        &edit(SPIN, "bin_width_w_m2 = 10.0", "bin_width_w_m2 = \"ten\""),
        &["run.bin_width_w_m2"],
    );
    assert_rejected(&edit(SPIN, "csv = true", "csv = \"yes\""), &["output.csv"]);
    assert_rejected(
        &edit(SPIN, "spin_period_h = 5.0", "spin_period_h = \"5h\""),
        &["body[0].spin_period_h"],
    );
    assert_rejected(
        &edit(
            SPIN,
            "spin_period_h = 5.0",
            "spin_period_h = 5.0\nposition_km = [1.0, 2.0]",
        ),
        &["body[0].position_km"],
    );
}

#[test]
fn wrong_type_in_ephemeris_names_the_key() {
    assert_rejected(
        &edit(SPIN, "distance_au = 1.5", "distance_au = \"far\""),
        &["ephemeris", "distance_au"],
    );
    assert_rejected(
        &edit(SPIN, "steps_per_period = 24", "steps_per_period = -24"),
        &["ephemeris", "steps_per_period"],
    );
}

#[test]
fn body_must_be_an_array_of_tables() {
    let text = edit(SPIN, "[[body]]", "[body]");
    assert_rejected(&text, &["body"]);
}

// ---------------------------------------------------------------------------------------
// Values out of range

#[test]
fn nonpositive_and_nonfinite_numbers_are_rejected_with_their_key() {
    for bad in ["0.0", "-1.5", "nan", "inf", "-inf"] {
        assert_rejected(
            &edit(SPIN, "distance_au = 1.5", &format!("distance_au = {bad}")),
            &["ephemeris.distance_au"],
        );
        assert_rejected(
            &edit(
                SPIN,
                "spin_period_h = 5.0",
                &format!("spin_period_h = {bad}"),
            ),
            &["body[0].spin_period_h"],
        );
        assert_rejected(
            &edit(
                SPIN,
                "bin_width_w_m2 = 10.0",
                &format!("bin_width_w_m2 = {bad}"),
            ),
            &["run.bin_width_w_m2"],
        );
        assert_rejected(
            &edit(
                SPIN,
                "steps_per_period = 24",
                &format!("steps_per_period = 24\nperiods = {bad}"),
            ),
            &["ephemeris.periods"],
        );
        assert_rejected(
            &edit(
                SPIN,
                "steps_per_period = 24",
                &format!("steps_per_period = 24\nsolar_constant_w_m2 = {bad}"),
            ),
            &["ephemeris.solar_constant_w_m2"],
        );
        assert_rejected(
            &edit(FIXED, "step_s = 60.0", &format!("step_s = {bad}")),
            &["ephemeris.step_s"],
        );
        assert_rejected(
            &edit(FIXED, "distance_au = 2.0", &format!("distance_au = {bad}")),
            &["ephemeris.sun[1].distance_au"],
        );
    }
}

#[test]
fn zero_steps_per_period_is_rejected() {
    assert_rejected(
        &edit(SPIN, "steps_per_period = 24", "steps_per_period = 0"),
        &["ephemeris.steps_per_period"],
    );
}

#[test]
fn nonfinite_position_and_rotation_are_rejected() {
    let text = edit(
        SPIN,
        "spin_period_h = 5.0",
        "spin_period_h = 5.0\nposition_km = [0.0, nan, 0.0]",
    );
    assert_rejected(&text, &["body[0].position_km"]);
    let text = edit(
        SPIN,
        "spin_period_h = 5.0",
        "spin_period_h = 5.0\ninitial_rotation_deg = inf",
    );
    assert_rejected(&text, &["body[0].initial_rotation_deg"]);
}

#[test]
fn sun_flux_must_be_finite_and_not_negative() {
    for bad in ["-1.0", "nan", "inf"] {
        let text = edit(FIXED, "flux_w_m2 = 1000.0", &format!("flux_w_m2 = {bad}"));
        assert_rejected(&text, &["ephemeris.sun[0].flux_w_m2"]);
    }
    // Zero flux (a step in eclipse) is allowed.
    parse(&edit(FIXED, "flux_w_m2 = 1000.0", "flux_w_m2 = 0.0")).expect("zero flux is valid");
}

#[test]
fn subsolar_latitude_out_of_range_is_rejected() {
    for bad in ["90.5", "-91", "nan", "inf"] {
        let text = edit(
            SPIN,
            "steps_per_period = 24",
            &format!("steps_per_period = 24\nsubsolar_latitude_deg = {bad}"),
        );
        assert_rejected(&text, &["ephemeris.subsolar_latitude_deg"]);
    }
    for good in ["90", "-90", "0", "45.5"] {
        let text = edit(
            SPIN,
            "steps_per_period = 24",
            &format!("steps_per_period = 24\nsubsolar_latitude_deg = {good}"),
        );
        parse(&text).unwrap_or_else(|e| panic!("latitude {good} rejected: {e}"));
    }
}

#[test]
fn obliquity_needs_solar_longitude_and_excludes_subsolar_latitude() {
    let only_obliquity = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nobliquity_deg = 20.0",
    );
    assert_rejected(
        &only_obliquity,
        &["ephemeris", "obliquity_deg", "solar_longitude_deg"],
    );
    let only_longitude = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nsolar_longitude_deg = 20.0",
    );
    assert_rejected(&only_longitude, &["ephemeris", "solar_longitude_deg"]);
    let both = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nobliquity_deg = 20.0\nsolar_longitude_deg = 10.0\nsubsolar_latitude_deg = 3.0",
    );
    assert_rejected(&both, &["ephemeris", "subsolar_latitude_deg"]);
    let nan = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nobliquity_deg = nan\nsolar_longitude_deg = 10.0",
    );
    assert_rejected(&nan, &["ephemeris"]);
}

#[test]
fn duplicate_and_empty_body_names_are_rejected() {
    let two = format!("{SPIN}\n[[body]]\nname = \"rock\"\nmesh = \"b.obj\"\nunits = \"m\"\n");
    assert_rejected(&two, &["body[1].name", "rock"]);
    assert_rejected(
        &edit(SPIN, "name = \"rock\"", "name = \"  \""),
        &["body[0].name"],
    );
}

#[test]
fn empty_body_list_is_rejected() {
    let text = format!("body = []\n{}", &SPIN[..SPIN.find("[[body]]").unwrap()]);
    assert_rejected(&text, &["body"]);
    // No [[body]] at all: also an error naming `body`.
    let none = &SPIN[..SPIN.find("[[body]]").unwrap()];
    assert_rejected(none, &["body"]);
}

#[test]
fn fixed_mode_without_suns_is_rejected() {
    let empty = "[ephemeris]\nmode = \"fixed\"\nsun = []\n\n[[body]]\nname = \"a\"\nmesh = \"a.obj\"\nunits = \"m\"\n";
    assert_rejected(empty, &["ephemeris.sun"]);
    let missing = "[ephemeris]\nmode = \"fixed\"\n\n[[body]]\nname = \"a\"\nmesh = \"a.obj\"\nunits = \"m\"\n";
    assert_rejected(missing, &["ephemeris", "sun"]);
}

#[test]
fn sun_needs_exactly_one_of_distance_and_flux() {
    let both = edit(
        FIXED,
        "flux_w_m2 = 1000.0",
        "flux_w_m2 = 1000.0\ndistance_au = 1.0",
    );
    assert_rejected(&both, &["ephemeris.sun[0]", "distance_au", "flux_w_m2"]);
    let neither = edit(FIXED, "flux_w_m2 = 1000.0\n", "");
    assert_rejected(&neither, &["ephemeris.sun[0]", "distance_au", "flux_w_m2"]);
}

#[test]
fn zero_or_nonfinite_sun_direction_is_rejected() {
    for bad in ["[0.0, 0.0, 0.0]", "[nan, 0.0, 1.0]", "[inf, 0.0, 0.0]"] {
        let text = edit(
            FIXED,
            "direction = [0.0, 1.0, 0.0]",
            &format!("direction = {bad}"),
        );
        assert_rejected(&text, &["ephemeris.sun[1].direction"]);
    }
}

#[test]
fn bad_epoch_is_rejected_naming_start() {
    let text = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nstart = \"next tuesday\"",
    );
    assert_rejected(&text, &["ephemeris.start"]);
    let text = edit(
        FIXED,
        "step_s = 60.0",
        "step_s = 60.0\nstart = \"2018-13-45T99:00:00 UTC\"",
    );
    assert_rejected(&text, &["ephemeris.start"]);
}

// ---------------------------------------------------------------------------------------
// The deserializer's message reaches the user

#[test]
fn scene_errors_say_what_is_wrong_not_only_where() {
    // An unknown key: the message should say it is unknown (not only the location).
    let msg = error_of(&edit(SPIN, "csv = true", "cvs = true"));
    assert!(msg.contains("unknown field"), "no reason given: {msg}");
    // A missing key: the message names the missing key.
    let msg = error_of(&edit(SPIN, "units = \"km\"\n", ""));
    assert!(
        msg.contains("missing field") && msg.contains("units"),
        "no reason given: {msg}"
    );
    // A wrong type: the message says what was expected.
    let msg = error_of(&edit(SPIN, "csv = true", "csv = \"yes\""));
    assert!(
        msg.contains("invalid type") || msg.contains("expected"),
        "no reason given: {msg}"
    );
}

// ---------------------------------------------------------------------------------------
// TOML syntax errors

fn syntax_error_line(text: &str) -> String {
    let msg = error_of(text);
    assert!(msg.contains("test-scene.toml"), "no file: {msg}");
    msg
}

#[test]
fn toml_syntax_errors_report_the_right_line() {
    // Replace lines of SPIN (1-based) by broken ones; the error must name that line.
    let lines: Vec<&str> = SPIN.lines().collect();
    for (line_no, broken) in [
        (1, "[run"),
        (2, "bin_width_w_m2 = = 10.0"),
        (8, "distance_au = 1.5.3"),
        (12, "name = \"rock"),
        (15, "spin_period_h = "),
    ] {
        let mut l = lines.clone();
        l[line_no - 1] = broken;
        let text = l.join("\n") + "\n";
        let msg = syntax_error_line(&text);
        assert!(
            msg.contains(&format!("line {line_no}:")),
            "expected line {line_no}: {msg}"
        );
    }
}

#[test]
fn duplicate_key_reports_the_line_of_the_second_key() {
    let text = edit(
        SPIN,
        "distance_au = 1.5",
        "distance_au = 1.5\ndistance_au = 2.0",
    );
    let msg = syntax_error_line(&text);
    assert!(msg.contains("line 10:"), "expected line 10: {msg}");
}

#[test]
fn syntax_error_on_last_line_without_newline() {
    let text = format!("{SPIN}extra = [1, 2");
    let n = SPIN.lines().count() + 1;
    let msg = syntax_error_line(&text);
    assert!(
        msg.contains(&format!("line {n}")),
        "expected line {n}: {msg}"
    );
}

// ---------------------------------------------------------------------------------------
// Files

#[test]
fn non_utf8_scene_file_is_rejected_naming_the_file() {
    let dir = TempDir::new("scene", "non-utf8");
    let path = dir.0.join("latin1.toml");
    let mut bytes = SPIN.as_bytes().to_vec();
    bytes.extend_from_slice(b"# caf\xe9\n");
    std::fs::write(&path, bytes).unwrap();
    let msg = Scene::load(&path)
        .expect_err("non-UTF-8 rejected")
        .to_string();
    assert!(msg.contains("latin1.toml"), "{msg}");
    assert!(msg.contains("UTF-8"), "{msg}");
}

#[test]
fn missing_scene_file_is_reported_naming_the_file() {
    let dir = TempDir::new("scene", "missing");
    let path = dir.0.join("nowhere.toml");
    let msg = Scene::load(&path).expect_err("missing file").to_string();
    assert!(msg.contains("nowhere.toml"), "{msg}");
    assert!(
        msg.to_lowercase().contains("no such file") || msg.contains("not found"),
        "{msg}"
    );
}

#[test]
fn loaded_scene_keeps_its_bytes_and_path() {
    let dir = TempDir::new("scene", "bytes");
    let path = dir.0.join("keep.toml");
    std::fs::write(&path, FIXED).unwrap();
    let scene = Scene::load(&path).expect("loads");
    assert_eq!(scene.source, FIXED.as_bytes());
    assert_eq!(scene.path, path);
    assert_eq!(scene.name, "keep");
    assert_eq!(
        scene.bodies[0].mesh.as_deref().unwrap(),
        dir.0.join("rock.obj")
    );
}

// ---------------------------------------------------------------------------------------
// SPICE-mode placement: kernels, a named frame, a synthetic orbit or a fixed offset

/// A valid SPICE-mode scene: a kernel body, and a moonlet on a synthetic orbit.
const SPICE: &str = r#"[ephemeris]
mode = "spice"
kernels = ["k/naif0012.tls"]
start = "2018-06-10T00:00:00 UTC"
stop = "2018-06-10T01:00:00 UTC"
step_s = 600

[[body]]
name = "primary"
naif_id = 401
frame = "IAU_PHOBOS"
ellipsoid = { levels = 1 }

[[body]]
name = "moonlet"
ellipsoid = { radii_km = [0.1, 0.1, 0.1], levels = 1 }
orbit = { radius_km = 1.2, period_h = 11.9, pole_ra_deg = 310, pole_dec_deg = -81 }
"#;

#[test]
fn spice_bodies_take_a_frame_or_a_synthetic_orbit() {
    let scene = parse(SPICE).unwrap();
    assert_eq!(scene.bodies[0].frame.as_deref(), Some("IAU_PHOBOS"));
    let orbit = scene.bodies[1].orbit.as_ref().unwrap();
    assert_eq!((orbit.radius_km, orbit.phase_deg), (1.2, 0.0));
    let fixed = edit(
        SPICE,
        "orbit = { radius_km = 1.2, period_h = 11.9, pole_ra_deg = 310, pole_dec_deg = -81 }",
        "position_km = [1.2, 0.0, 0.0]",
    );
    assert!(parse(&fixed).is_ok());
}

#[test]
fn spice_placement_mistakes_are_rejected_with_their_keys() {
    let orbit =
        "orbit = { radius_km = 1.2, period_h = 11.9, pole_ra_deg = 310, pole_dec_deg = -81 }";
    assert_rejected(
        &edit(SPICE, orbit, "position_km = [0.0, 0.0, 0.0]"),
        &["body[1].naif_id", "orbit", "position_km"],
    );
    assert_rejected(
        &edit(SPICE, orbit, &format!("naif_id = 402\n{orbit}")),
        &["body[1].orbit", "not both"],
    );
    assert_rejected(
        &edit(SPICE, "period_h = 11.9", "period_h = 0"),
        &["body[1].orbit.period_h"],
    );
    assert_rejected(
        &edit(SPICE, "radius_km = 1.2", "radius_km = -1"),
        &["body[1].orbit.radius_km"],
    );
    assert_rejected(
        &edit(SPICE, orbit, &format!("{orbit}\nframe = \"MOON_ME\"")),
        &["body[1].frame", "naif_id"],
    );
    assert_rejected(
        &edit(
            &edit(SPICE, "naif_id = 401\n", ""),
            "ellipsoid = { levels = 1 }",
            "ellipsoid = { radii_km = [13, 11, 9], levels = 1 }",
        ),
        &["body[0].naif_id", "first body"],
    );
    assert_rejected(
        &edit(SPICE, "orbit = { radius_km = 1.2", "orbit = { radius = 1.2"),
        &["body[1].orbit", "radius"],
    );
}

#[test]
fn frames_and_orbits_are_refused_outside_spice_mode() {
    assert_rejected(
        &edit(
            SPIN,
            "spin_period_h = 5.0",
            "spin_period_h = 5.0\nframe = \"MOON_ME\"",
        ),
        &["body[0].frame", "spice mode"],
    );
    assert_rejected(
        &edit(
            SPIN,
            "spin_period_h = 5.0",
            "spin_period_h = 5.0\norbit = { radius_km = 1.0, period_h = 2.0 }",
        ),
        &["body[0].orbit", "spice mode"],
    );
}

#[test]
fn stereographic_terrain_needs_a_mesh_file_and_a_positive_radius() {
    let terrain = edit(
        SPIN,
        "units = \"km\"",
        "units = \"km\"\nstereographic = { pole = \"south\", radius_km = 1737.4 }",
    );
    assert!(parse(&terrain).is_ok());
    assert_rejected(
        &edit(&terrain, "radius_km = 1737.4", "radius_km = 0"),
        &["body[0].stereographic.radius_km"],
    );
    assert_rejected(
        &edit(&terrain, "pole = \"south\"", "pole = \"east\""),
        &["body[0].stereographic.pole", "east"],
    );
    let ellipsoid = edit(
        &terrain,
        "mesh = \"rock.obj\"\nunits = \"km\"",
        "ellipsoid = { radii_km = [1, 1, 1] }",
    );
    assert_rejected(&ellipsoid, &["body[0].stereographic", "mesh files only"]);
}

/// A scene file saved with a UTF-8 byte-order mark loads like the same file without it
/// (the TOML reader skips the mark itself; this guards it).
#[test]
fn a_byte_order_mark_before_the_scene_is_ignored() {
    let dir = std::env::temp_dir().join(format!("slim-scene-bom-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bom.toml");
    std::fs::write(&path, format!("\u{feff}{SPIN}")).unwrap();
    let scene = Scene::load(&path);
    std::fs::remove_dir_all(&dir).unwrap();
    let scene = scene.expect("a scene with a byte-order mark loads");
    assert_eq!(scene.bodies[0].name, "rock");
    assert_eq!(scene.run.bin_width_w_m2, 10.0);
}

// ---------------------------------------------------------------------------------------
// Runs that could never finish are refused before anything is allocated

/// The hardening issue's absurd step counts: each used to be accepted and abort on memory
/// within seconds; each is now refused naming the key that sets the steps.
#[test]
fn absurd_step_counts_are_refused_naming_the_key() {
    let spin_steps = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 1000000000",
    );
    assert_rejected(&spin_steps, &["ephemeris.steps_per_period", "1e9 steps"]);
    let spin_periods = edit(
        SPIN,
        "steps_per_period = 24",
        "steps_per_period = 24\nperiods = 1e30",
    );
    assert_rejected(&spin_periods, &["ephemeris.periods", "at most 1e12 s"]);
    let window = edit(SPICE, "step_s = 600", "step_s = 1e-9");
    assert_rejected(&window, &["ephemeris.step_s", "3.6e12 steps"]);
    let spins = edit(
        SPICE,
        "stop = \"2018-06-10T01:00:00 UTC\"\nstep_s = 600",
        "spins = 1e12",
    );
    assert_rejected(&spins, &["ephemeris.spins", "3.6e14 steps"]);
    // A century of hourly steps is fine.
    let century = edit(
        SPICE,
        "stop = \"2018-06-10T01:00:00 UTC\"",
        "stop = \"2118-06-10T01:00:00 UTC\"",
    );
    parse(&edit(&century, "step_s = 600", "step_s = 3600")).expect("876,600 steps");
}

/// Every step checks every pair of bodies: a scene of a thousand bodies is refused.
#[test]
fn too_many_bodies_are_refused() {
    let header = SPIN.split("[[body]]").next().unwrap();
    let bodies = |n: usize| -> String {
        (0..n)
            .map(|i| {
                format!(
                    "\n[[body]]\nname = \"b{i}\"\nspin_period_h = 5.0\n\
                     ellipsoid = {{ radii_km = [1, 1, 1], levels = 0 }}\n"
                )
            })
            .collect()
    };
    assert_rejected(
        &(header.to_string() + &bodies(65)),
        &["body", "65 bodies; at most 64"],
    );
    parse(&(header.to_string() + &bodies(64))).expect("64 bodies are allowed");
}

/// A run whose epochs would leave any calendar (a spin period of 1e308 h used to panic in
/// the epoch arithmetic, found by fuzzing planned requests) is refused naming the key.
#[test]
fn a_run_spanning_beyond_any_calendar_is_refused() {
    let spin = edit(SPIN, "spin_period_h = 5.0", "spin_period_h = 1e308");
    assert_rejected(&spin, &["body[0].spin_period_h", "at most 1e12 s"]);
    let fixed = edit(FIXED, "step_s = 60.0", "step_s = 1e300");
    assert_rejected(&fixed, &["ephemeris.step_s", "at most 1e12 s"]);
    parse(&edit(SPIN, "spin_period_h = 5.0", "spin_period_h = 8760.0")).expect("a year");
}

#[test]
fn shadow_and_sun_keys_are_checked_with_the_key_named() {
    let with = |keys: &str| edit(SPIN, "[run]\n", &format!("[run]\n{keys}\n"));
    let ok = parse(&with("shadows = \"horizon\"\nhorizon_mode = \"approximate\"\nsun = \"disk\"\nlimb_darkening = 0.6\nhorizon_azimuths = 64"))
        .expect("valid shadow keys");
    assert_eq!(ok.shadows().azimuths, 64);
    parse(&with("sun = \"disk\"\nshadows = \"rays\"")).expect("a disk Sun with rays");
    assert_rejected(
        &with("horizon_azimuths = 3"),
        &["run.horizon_azimuths", "8..=4096"],
    );
    assert_rejected(&with("limb_darkening = 1.5"), &["run.limb_darkening"]);
    assert_rejected(&with("shadows = \"sometimes\""), &["shadows"]);
    assert_rejected(&with("sun_samples = 0"), &["run.sun_samples", "1..=1024"]);
    assert_eq!(
        parse(&with("sun_samples = 64"))
            .unwrap()
            .shadows()
            .sun_samples,
        64
    );
}

#[test]
fn surroundings_resolve_beside_the_scene_and_only_surround_mesh_files() {
    let with = edit(
        SPIN,
        "units = \"km\"\n",
        "units = \"km\"\nsurroundings = { mesh = \"around.obj\", units = \"m\" }\n",
    );
    let scene = parse(&with).expect("surroundings accepted");
    let files: Vec<(String, &Path)> = scene.input_files();
    assert!(files.contains(&(
        "body[0].surroundings.mesh".to_string(),
        Path::new("/nonexistent/scenes/around.obj")
    )));
    assert_rejected(
        &edit(&with, "units = \"m\" }", "}"),
        &["body[0].surroundings", "units"],
    );
    let ellipsoid = edit(
        &with,
        "mesh = \"rock.obj\"\nunits = \"km\"",
        "ellipsoid = { radii_km = [1.0, 1.0, 1.0] }",
    );
    assert_rejected(&ellipsoid, &["body[0].surroundings", "terrain patch"]);
}

#[test]
fn a_scene_needs_a_body_with_outputs() {
    let occluder = edit(
        SPIN,
        "units = \"km\"\n",
        "units = \"km\"\noutputs = false\n",
    );
    assert_rejected(&occluder, &["body", "outputs = false", "no statistics"]);
}

#[test]
fn every_shipped_scene_loads() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let mut scenes = 0;
    for entry in std::fs::read_dir(&data).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
            for (key, file) in scene.input_files() {
                assert!(
                    file.is_file(),
                    "{}: {key} {}",
                    path.display(),
                    file.display()
                );
            }
            scenes += 1;
        }
    }
    assert!(scenes >= 5, "{scenes} scenes");
}

/// A disk Sun's angular size comes from its distance: a fixed Sun given only by its flux
/// has none, and is refused with the key to give instead.
#[test]
fn a_disk_sun_needs_the_distance_of_fixed_suns() {
    let disk = format!("[run]\nsun = \"disk\"\n\n{FIXED}");
    assert_rejected(&disk, &["ephemeris.sun[0].flux_w_m2", "distance_au"]);
    let point = format!("[run]\nsun = \"point\"\n\n{FIXED}");
    parse(&point).expect("a point Sun needs no distance");
}

/// Left out, the Sun is a disk wherever its distance is known at every step (spin, and
/// fixed Suns given by their distance), and a point where one is given by its flux alone;
/// a scene that names it gets what it names.
#[test]
fn the_sun_is_a_disk_by_default_wherever_its_distance_is_known() {
    use slim::horizon::SunShape;
    let sun = |text: &str| parse(text).expect("valid scene").sun();
    assert_eq!(sun(SPIN), SunShape::Disk);
    assert_eq!(sun(FIXED), SunShape::Point);
    let by_distance = FIXED.replace("flux_w_m2 = 1000.0", "distance_au = 1.0");
    assert_eq!(sun(&by_distance), SunShape::Disk);
    let point = SPIN.replace("[run]\n", "[run]\nsun = \"point\"\n");
    assert_eq!(sun(&point), SunShape::Point);
    assert_eq!(parse(&point).unwrap().shadows().sun, SunShape::Point);
    assert_eq!(parse(SPIN).unwrap().shadows().sun, SunShape::Disk);
}
