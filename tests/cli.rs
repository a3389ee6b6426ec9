//! The `slim` command, run as a process.
//!
//! In: small scenes in temporary folders (the shipped Itokawa 8-level mesh, non-convex, so
//! shadow rays are traced) and broken inputs. Out: exit codes, one-line errors that name
//! the file, quiet and non-terminal output without progress-bar escapes, and results that
//! do not depend on the number of threads.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

#[path = "common/temp_dir.rs"]
mod temp_dir;
use temp_dir::TempDir;

// ---------------------------------------------------------------------------------------
// Helpers

fn itokawa() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/shapes/itokawa/itokawa_8.obj")
}

/// A spin scene over the shipped Itokawa mesh (768 facets, non-convex), 24 steps.
fn write_scene(dir: &TempDir, name: &str) -> PathBuf {
    let text = format!(
        "[output]\ncsv = true\nply = true\nhistory = true\n\n\
         [ephemeris]\nmode = \"spin\"\ndistance_au = 1.1\nsubsolar_latitude_deg = 15.0\nsteps_per_period = 24\n\n\
         [[body]]\nname = \"itokawa\"\nmesh = {:?}\nunits = \"km\"\nspin_period_h = 12.13\n",
        itokawa().display().to_string()
    );
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn slim(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_slim"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run slim")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Asserts a failure: non-zero exit, nothing on stdout, stderr exactly one line starting
/// with "slim: error:" and containing every needle. Returns the line.
#[track_caller]
fn assert_one_line_error(out: &Output, needles: &[&str]) -> String {
    let stderr = text(&out.stderr);
    assert!(!out.status.success(), "succeeded; stderr: {stderr}");
    assert_eq!(out.status.code(), Some(1), "exit code; stderr: {stderr}");
    assert!(out.stdout.is_empty(), "stdout: {}", text(&out.stdout));
    assert!(
        stderr.ends_with('\n'),
        "stderr not a terminated line: {stderr:?}"
    );
    assert_eq!(
        stderr.lines().count(),
        1,
        "stderr is not one line: {stderr:?}"
    );
    assert!(stderr.starts_with("slim: error:"), "{stderr:?}");
    for n in needles {
        assert!(
            stderr.contains(n),
            "stderr does not mention {n:?}: {stderr:?}"
        );
    }
    stderr.trim_end().to_string()
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 temp path")
}

// ---------------------------------------------------------------------------------------
// slim run

/// The summary table as this build writes it: Parquet, or CSV alone without Parquet.
const SUMMARY_TABLE: &str = if cfg!(feature = "parquet") {
    "summary.parquet"
} else {
    "summary.csv"
};

#[test]
fn run_succeeds_writes_run_json_and_draws_no_bar_when_not_a_terminal() {
    let dir = TempDir::new("cli", "run-ok");
    let scene = write_scene(&dir, "ito.toml");
    let out_dir = dir.join("out");
    let out = slim(
        &["run", s(&scene), "-o", s(&out_dir), "--threads", "1"],
        &dir.0,
    );
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "failed: {stderr}");
    assert!(out_dir.join("run.json").is_file());
    assert!(out_dir.join(SUMMARY_TABLE).is_file());
    assert!(out_dir.join("itokawa.ply").is_file());
    assert!(
        !stderr.contains('\r'),
        "carriage return in stderr: {stderr:?}"
    );
    assert!(
        !stderr.contains("\x1b["),
        "escape codes in stderr: {stderr:?}"
    );
    assert!(stderr.contains("plan:"), "the plan is shown: {stderr}");
    assert!(stderr.contains("768 facets"), "{stderr}");
    assert!(stderr.contains("wrote "), "{stderr}");
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("run.json")).unwrap()).unwrap();
    assert_eq!(record["threads"].as_u64(), Some(1));
    assert!(
        record["counts"]["shadowed"].as_u64().unwrap() > 0,
        "non-convex mesh: facets shadowed by their own body"
    );
}

/// A spin of three whole periods: the plan says the later periods repeat the first, and
/// the closing line that its ray count covers every step although only the first
/// period's rays were traced; one period alone says neither.
#[test]
fn a_repeating_spin_says_so_in_the_plan_and_in_its_closing_line() {
    let dir = TempDir::new("cli", "repeats");
    let base = std::fs::read_to_string(write_scene(&dir, "ito.toml")).unwrap();
    let scene = dir.join("three.toml");
    let three = base.replace(
        "steps_per_period = 24\n",
        "steps_per_period = 24\nperiods = 3\n",
    );
    std::fs::write(&scene, three).unwrap();
    let out = slim(&["run", s(&scene), "-o", s(&dir.join("three"))], &dir.0);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("repeats every 24 steps"), "{stderr}");
    assert!(
        stderr.contains("72 steps") && stderr.contains("counted over every step"),
        "{stderr}"
    );
    let one = slim(
        &["run", s(&dir.join("ito.toml")), "-o", s(&dir.join("one"))],
        &dir.0,
    );
    let stderr = text(&one.stderr);
    assert!(one.status.success(), "{stderr}");
    assert!(
        !stderr.contains("repeated steps") && !stderr.contains("counted over"),
        "{stderr}"
    );
}

/// Hourly steps of a spin that does not repeat exactly (4.02 turns in 48 steps): the Sun
/// comes back within 0.2° every 12 steps, and the plan says that the rays start from the
/// blockers met there, and counts them in its memory; one turn in 24 steps (15° apart,
/// nothing nearer) says neither.
#[test]
fn the_plan_says_when_rays_recall_the_blockers_of_a_spin_before() {
    let dir = TempDir::new("cli", "recall");
    let base = std::fs::read_to_string(write_scene(&dir, "ito.toml")).unwrap();
    let run = "[run]\nsun = \"point\"\ntracer = \"bvh\"\ncache_dir = \"cache\"\n\n";
    let hourly = base.replace(
        "steps_per_period = 24\n",
        "steps_per_period = 12\nperiods = 4.02\n",
    );
    for (name, scene, recalls) in [("hourly", hourly, true), ("one", base, false)] {
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, format!("{run}{scene}")).unwrap();
        let out = slim(&["run", s(&path), "-o", s(&dir.join(name))], &dir.0);
        let stderr = text(&out.stderr);
        assert!(out.status.success(), "{stderr}");
        let says = stderr.contains("rays start from the blockers met 12 steps before")
            && stderr.contains("remembered blockers");
        assert_eq!(says, recalls, "{name}: {stderr}");
        assert_eq!(
            stderr.contains("rays start from"),
            recalls,
            "{name}: {stderr}"
        );
    }
}

/// A body whose own shadows come from a horizon map says so in the plan's self-shadowing
/// line, with the rays the map leaves, instead of promising a ray per facet.
#[test]
fn the_plan_says_when_a_horizon_map_decides_a_bodys_own_shadows() {
    let dir = TempDir::new("cli", "plan-map");
    let base = std::fs::read_to_string(write_scene(&dir, "ito.toml")).unwrap();
    for (mode, says) in [
        ("exact", "only where the map is not certain"),
        ("approximate", "without rays"),
    ] {
        let scene = dir.join(format!("{mode}.toml"));
        let run = format!(
            "[run]\nsun = \"point\"\nshadows = \"horizon\"\nhorizon_mode = \"{mode}\"\n\
             cache_dir = \"cache\"\n\n"
        );
        std::fs::write(&scene, run + &base).unwrap();
        let out_dir = dir.join(mode);
        let out = slim(&["run", s(&scene), "-o", s(&out_dir), "-q"], &dir.0);
        assert!(out.status.success(), "{mode}: {}", text(&out.stderr));
        let record: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out_dir.join("run.json")).unwrap()).unwrap();
        let decisions = record["plan"]["decisions"].as_array().unwrap();
        let own = decisions
            .iter()
            .find(|d| d["stage"] == "self-shadowing of 'itokawa'")
            .expect("a self-shadowing decision")["reason"]
            .as_str()
            .unwrap();
        assert!(
            own.contains("horizon map") && own.contains(says),
            "{mode}: {own}"
        );
        assert!(!own.contains("ray per facet"), "{mode}: {own}");
    }
}

#[test]
fn quiet_run_prints_nothing() {
    let dir = TempDir::new("cli", "quiet");
    let scene = write_scene(&dir, "ito.toml");
    let out_dir = dir.join("out");
    let out = slim(&["run", s(&scene), "-o", s(&out_dir), "--quiet"], &dir.0);
    assert!(out.status.success(), "failed: {}", text(&out.stderr));
    assert!(out.stdout.is_empty(), "stdout: {:?}", text(&out.stdout));
    assert!(out.stderr.is_empty(), "stderr: {:?}", text(&out.stderr));
    assert!(out_dir.join("run.json").is_file());
}

#[test]
fn default_output_folder_is_results_slash_scene_name_in_the_working_directory() {
    let dir = TempDir::new("cli", "default-out");
    let scene = write_scene(&dir, "my-run.toml");
    let out = slim(&["run", "my-run.toml", "-q"], &dir.0);
    assert!(out.status.success(), "failed: {}", text(&out.stderr));
    assert!(dir.join("results/my-run/run.json").is_file());
    drop(scene);
}

#[test]
fn results_do_not_depend_on_the_number_of_threads() {
    let dir = TempDir::new("cli", "threads");
    let scene = write_scene(&dir, "ito.toml");
    let one = dir.join("one");
    let two = dir.join("two");
    for (out_dir, n) in [(&one, "1"), (&two, "2")] {
        let out = slim(
            &["run", s(&scene), "-o", s(out_dir), "--threads", n, "-q"],
            &dir.0,
        );
        assert!(
            out.status.success(),
            "--threads {n} failed: {}",
            text(&out.stderr)
        );
    }
    for name in [
        "summary.csv",
        "cdf.csv",
        "history.csv",
        "geometry.csv",
        SUMMARY_TABLE,
        "itokawa.ply",
    ] {
        let a = std::fs::read(one.join(name)).unwrap();
        let b = std::fs::read(two.join(name)).unwrap();
        assert!(a == b, "{name} differs between --threads 1 and --threads 2");
    }
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(two.join("run.json")).unwrap()).unwrap();
    assert_eq!(record["threads"].as_u64(), Some(2));
}

/// A build without Parquet writes its tables as CSV even where the scene asks for none,
/// and no Parquet file.
#[cfg(not(feature = "parquet"))]
#[test]
fn without_parquet_every_table_is_written_as_csv() {
    let dir = TempDir::new("cli", "lean");
    let scene = write_scene(&dir, "ito.toml");
    let toml = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(&scene, toml.replace("csv = true", "csv = false")).unwrap();
    let out_dir = dir.join("out");
    let out = slim(&["run", s(&scene), "-o", s(&out_dir), "-q"], &dir.0);
    assert!(out.status.success(), "failed: {}", text(&out.stderr));
    for name in ["summary.csv", "cdf.csv", "geometry.csv", "history.csv"] {
        assert!(out_dir.join(name).is_file(), "{name} is missing");
    }
    let parquet = std::fs::read_dir(&out_dir)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().extension() == Some("parquet".as_ref()))
        .count();
    assert_eq!(parquet, 0);
}

// ---------------------------------------------------------------------------------------
// slim run: errors

#[test]
fn missing_scene_file_is_a_one_line_error_naming_it() {
    let dir = TempDir::new("cli", "missing-scene");
    let out = slim(&["run", "nowhere.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["nowhere.toml"]);
    assert!(
        !dir.join("out").exists(),
        "no output folder for a scene that does not load"
    );
}

#[test]
fn unknown_scene_key_is_a_one_line_error_naming_file_and_key() {
    let dir = TempDir::new("cli", "bad-scene");
    let scene = write_scene(&dir, "bad.toml");
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("spin_period_h", "spin_perod_h");
    std::fs::write(&scene, text).unwrap();
    let out = slim(&["run", "bad.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["bad.toml", "body[0]", "spin_perod_h"]);
}

#[test]
fn toml_syntax_error_is_a_one_line_error_with_the_line() {
    let dir = TempDir::new("cli", "syntax");
    let scene = write_scene(&dir, "syntax.toml");
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("distance_au = 1.1", "distance_au = = 1.1");
    std::fs::write(&scene, text).unwrap();
    let out = slim(&["run", "syntax.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["syntax.toml", "line 8"]);
}

#[test]
fn broken_mesh_is_a_one_line_error_naming_the_mesh() {
    let dir = TempDir::new("cli", "broken-mesh");
    std::fs::write(
        dir.join("broken.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    )
    .unwrap();
    let scene = "[ephemeris]\nmode = \"fixed\"\n[[ephemeris.sun]]\ndirection = [1, 0, 0]\nflux_w_m2 = 100\n\n\
                 [[body]]\nname = \"x\"\nmesh = \"broken.obj\"\nunits = \"m\"\n";
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    let out = slim(&["run", "scene.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["broken.obj"]);
    assert!(!dir.join("out/run.json").exists());
}

#[test]
fn missing_mesh_is_a_one_line_error_naming_the_mesh() {
    let dir = TempDir::new("cli", "missing-mesh");
    let scene = "[ephemeris]\nmode = \"fixed\"\n[[ephemeris.sun]]\ndirection = [1, 0, 0]\nflux_w_m2 = 100\n\n\
                 [[body]]\nname = \"x\"\nmesh = \"absent.obj\"\nunits = \"m\"\n";
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    let out = slim(&["run", "scene.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["absent.obj"]);
}

#[test]
fn zero_threads_is_a_one_line_error() {
    let dir = TempDir::new("cli", "zero-threads");
    let scene = write_scene(&dir, "ito.toml");
    let out = slim(&["run", s(&scene), "-o", "out", "--threads", "0"], &dir.0);
    assert_one_line_error(&out, &["--threads"]);
    assert!(!dir.join("out").exists());
}

/// Absurd numbers that would make the CDF's bin count overflow are refused with the key
/// to change (they used to panic: "chunk_size must not be zero").
#[test]
fn absurd_bins_and_fluxes_are_one_line_errors_naming_the_bin_width() {
    let dir = TempDir::new("cli", "absurd-bins");
    let scene = write_scene(&dir, "ito.toml");
    let toml = std::fs::read_to_string(&scene).unwrap();
    let cases = [
        format!("[run]\nbin_width_w_m2 = 1e-300\n{toml}"),
        toml.replace("[ephemeris]", "[ephemeris]\nsolar_constant_w_m2 = 1e308"),
        "[ephemeris]\nmode = \"fixed\"\n[[ephemeris.sun]]\ndirection = [1, 0, 0]\n\
         flux_w_m2 = 1e308\n\n[[body]]\nname = \"rock\"\nunits = \"km\"\nmesh = "
            .to_string()
            + &format!("{:?}\n", itokawa().display().to_string()),
    ];
    for (k, case) in cases.iter().enumerate() {
        let path = dir.join(format!("absurd{k}.toml"));
        std::fs::write(&path, case).unwrap();
        let out = slim(&["run", s(&path), "-o", "out", "-q"], &dir.0);
        assert_one_line_error(&out, &["run.bin_width_w_m2", "at most 1000000"]);
        assert!(!dir.join("out/run.json").exists());
    }
}

/// A run whose estimate is above `--max-memory` is refused before it starts, naming the
/// estimate, the limit, the largest part and the key that shrinks it; the results of the
/// earlier run in the same folder stay as they were (a failing scene used to clear them
/// first). The plan in `run.json` carries the estimate.
#[test]
fn a_run_above_its_memory_limit_is_refused_and_the_earlier_results_stay() {
    let dir = TempDir::new("cli", "budget");
    let scene = write_scene(&dir, "ito.toml");
    assert!(slim(&["run", s(&scene), "-o", "out", "-q"], &dir.0)
        .status
        .success());
    let record = std::fs::read_to_string(dir.join("out/run.json")).unwrap();
    assert!(
        record.contains("\"memory\"") && record.contains("statistics"),
        "{record}"
    );
    let summary = std::fs::read(dir.join("out/summary.csv")).unwrap();
    // 0.002 W/m² bins up to ~1,100 W/m²: 768 facets × 560,000 counts, about 1.7 GB.
    let fine = dir.join("fine.toml");
    let toml = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(&fine, format!("[run]\nbin_width_w_m2 = 0.002\n{toml}")).unwrap();
    let out = slim(
        &["run", s(&fine), "-o", "out", "-q", "--max-memory", "64M"],
        &dir.0,
    );
    assert_one_line_error(
        &out,
        &[
            "64.0 MiB",
            "--max-memory",
            "statistics",
            "run.bin_width_w_m2",
        ],
    );
    assert_eq!(std::fs::read(dir.join("out/summary.csv")).unwrap(), summary);
    assert!(dir.join("out/run.json").exists());
    let out = slim(&["run", s(&fine), "--max-memory", "lots"], &dir.0);
    assert_one_line_error(&out, &["--max-memory", "'lots' is not a size"]);
}

/// A file in the output folder that no run.json of slim lists is never overwritten: here
/// the input mesh itself, named like the body's result PLY, with `-o` pointing at the
/// mesh's folder (it used to be replaced by the result and deleted by the next run).
#[test]
fn a_file_slim_did_not_write_is_never_overwritten() {
    let dir = TempDir::new("cli", "foreign");
    let mesh = dir.join("itokawa.ply");
    let original = b"ply\nformat ascii 1.0\nthis is the user's own file\n";
    std::fs::write(&mesh, original).unwrap();
    let scene = write_scene(&dir, "ito.toml");
    let out = slim(&["run", s(&scene), "-o", s(&dir.0), "-q"], &dir.0);
    assert_one_line_error(&out, &["itokawa.ply", "does not overwrite"]);
    assert_eq!(std::fs::read(&mesh).unwrap(), original);
    assert!(!dir.join("run.json").exists());
}

/// The files a run writes are exactly the ones `output::file_names` predicts, which is the
/// list checked for foreign files before a run starts.
#[test]
fn the_predicted_output_names_are_the_files_a_run_writes() {
    let dir = TempDir::new("cli", "names");
    let scene = write_scene(&dir, "ito.toml");
    let out_dir = dir.join("out");
    let out = slim(&["run", s(&scene), "-o", s(&out_dir), "-q"], &dir.0);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("run.json")).unwrap()).unwrap();
    let mut written: Vec<String> = record["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .filter(|n| n != "run.json")
        .collect();
    let mut predicted = slim::output::file_names(true, true, true, &["itokawa"]);
    written.sort();
    predicted.sort();
    assert_eq!(written, predicted);
}

/// An absurd thread count is refused before any thread is spawned (it used to spawn
/// threads without end), with the largest count this machine allows.
#[test]
fn a_huge_thread_count_is_a_one_line_error() {
    let dir = TempDir::new("cli", "huge-threads");
    let scene = write_scene(&dir, "ito.toml");
    let out = slim(
        &["run", s(&scene), "-o", "out", "--threads", "100000"],
        &dir.0,
    );
    let line = assert_one_line_error(&out, &["--threads 100000", "give 1 to"]);
    assert!(line.contains("per core"), "{line}");
    assert!(!dir.join("out").exists());
}

/// A mistyped argument or subcommand is one line and exit code 1, as every other error
/// (clap's own message was several lines and exit code 2); help still prints and exits 0.
#[test]
fn command_line_mistakes_are_one_line_errors_with_the_usage() {
    let dir = TempDir::new("cli", "usage");
    let line = assert_one_line_error(&slim(&["run", "--bogus"], &dir.0), &["--bogus"]);
    assert!(line.contains("usage: slim run"), "{line}");
    assert_one_line_error(&slim(&["frobnicate"], &dir.0), &["frobnicate", "--help"]);
    assert_one_line_error(&slim(&[], &dir.0), &["--help"]);
    assert_one_line_error(&slim(&["info"], &dir.0), &["MESH"]);
    let help = slim(&["run", "--help"], &dir.0);
    assert!(help.status.success());
    assert!(text(&help.stdout).contains("--threads"));
}

// ---------------------------------------------------------------------------------------
// slim info

/// `slim info MESH | head -1`: a reader that closes the pipe early ends slim quietly
/// (it used to panic on the broken pipe).
#[test]
fn info_into_a_closed_pipe_ends_quietly() {
    let dir = TempDir::new("cli", "pipe");
    let mut child = Command::new(env!("CARGO_BIN_EXE_slim"))
        .args(["info", s(&itokawa())])
        .current_dir(&dir.0)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run slim");
    // Close the reading end before slim has read its mesh, let alone printed.
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("slim ends");
    let stderr = text(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(out.status.success(), "exit {:?}: {stderr}", out.status);
    assert!(stderr.is_empty(), "{stderr}");
}

#[test]
fn info_reports_facets_and_vertices() {
    let dir = TempDir::new("cli", "info");
    let out = slim(&["info", s(&itokawa())], &dir.0);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "failed: {}", text(&out.stderr));
    assert!(stdout.contains("itokawa_8.obj"), "{stdout}");
    assert!(stdout.contains("768 facets"), "{stdout}");
    assert!(stdout.contains("386 vertices"), "{stdout}");
}

/// The three extents of the "size: X x Y x Z m" line.
fn extents(stdout: &str) -> [f64; 3] {
    let line = stdout
        .lines()
        .find(|l| l.trim_start().starts_with("size:"))
        .expect("size line");
    let dims = line.trim_start().trim_start_matches("size:");
    let dims = &dims[..dims.find(" m").expect("unit")];
    let v: Vec<f64> = dims
        .split(" x ")
        .map(|x| x.trim().parse().expect("number"))
        .collect();
    [v[0], v[1], v[2]]
}

#[test]
fn info_units_scale_the_report() {
    let dir = TempDir::new("cli", "info-units");
    let km = slim(&["info", s(&itokawa())], &dir.0);
    let m = slim(&["info", "--units", "m", s(&itokawa())], &dir.0);
    assert!(km.status.success() && m.status.success());
    let (km, m) = (extents(&text(&km.stdout)), extents(&text(&m.stdout)));
    for i in 0..3 {
        // Itokawa is ~535 × 294 × 209 m: in km units the size is hundreds of metres.
        assert!(km[i] > 100.0 && km[i] < 1000.0, "{km:?}");
        assert!((km[i] / 1000.0 - m[i]).abs() <= 0.1, "km {km:?} vs m {m:?}");
    }
}

#[test]
fn info_on_a_missing_file_is_a_one_line_error() {
    let dir = TempDir::new("cli", "info-missing");
    let out = slim(&["info", "no-such-mesh.obj"], &dir.0);
    assert_one_line_error(&out, &["no-such-mesh.obj"]);
}

#[test]
fn info_on_a_broken_file_is_a_one_line_error_with_the_line() {
    let dir = TempDir::new("cli", "info-broken");
    std::fs::write(
        dir.join("bad.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n",
    )
    .unwrap();
    let out = slim(&["info", "bad.obj"], &dir.0);
    assert_one_line_error(&out, &["bad.obj", "line 3"]);
}

/// Raw control bytes from a bad file are shown as escapes: they neither drive the terminal
/// nor break the one-line error (they used to be echoed as they were).
#[test]
fn control_bytes_of_a_bad_file_are_escaped_in_the_error() {
    let dir = TempDir::new("cli", "info-control");
    std::fs::write(
        dir.join("bad.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 \x1b[2J\x07zero\nf 1 2 3\n",
    )
    .unwrap();
    let out = slim(&["info", "bad.obj"], &dir.0);
    let line = assert_one_line_error(&out, &["bad.obj", "line 3", "\\u{1b}[2J\\u{7}zero"]);
    assert!(!line.contains('\x1b') && !line.contains('\x07'), "{line:?}");
}

#[test]
fn unknown_ephemeris_key_is_a_one_line_error_naming_the_key() {
    let dir = TempDir::new("cli", "bad-ephemeris");
    let scene = write_scene(&dir, "eph.toml");
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("steps_per_period", "steps_per_perod");
    std::fs::write(&scene, text).unwrap();
    let out = slim(&["run", "eph.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["eph.toml", "ephemeris", "steps_per_perod"]);
}

#[test]
fn missing_body_key_is_a_one_line_error_naming_the_key() {
    let dir = TempDir::new("cli", "missing-body-key");
    let scene = write_scene(&dir, "nokey.toml");
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("units = \"km\"\n", "");
    std::fs::write(&scene, text).unwrap();
    let out = slim(&["run", "nokey.toml", "-o", "out"], &dir.0);
    assert_one_line_error(&out, &["nokey.toml", "body[0]", "units"]);
}

/// `slim place` answers the service's place query on a scene file: the facet series equals
/// the run's history, and a panel at a height comes with it.
#[cfg(feature = "serve")]
#[test]
fn place_answers_a_query_on_a_scene_file_and_refuses_places_off_the_mesh() {
    let dir = TempDir::new("cli", "place");
    write_scene(&dir, "s.toml");
    let query = dir.join("q.json");
    std::fs::write(
        &query,
        r#"{"targets": [{"facet": 100, "height_m": 1.5, "panel": {"mount": "sun_tracking"}}]}"#,
    )
    .unwrap();
    let out = slim(&["place", "s.toml", "q.json", "-o", "a.json"], &dir.0);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let answer: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("a.json")).unwrap()).unwrap();
    let series = &answer["series"][0];
    assert_eq!(series["facet"], 100);
    assert_eq!(series["irradiance_w_m2"].as_array().unwrap().len(), 24);
    assert_eq!(series["panel"]["power_w"].as_array().unwrap().len(), 24);
    // The same facet's values as `slim run` writes them in its history.
    let run = slim(&["run", "s.toml", "-o", "out", "--quiet"], &dir.0);
    assert!(run.status.success(), "{}", text(&run.stderr));
    let (header, rows) = read_csv_rows(&dir.join("out/history.csv"));
    let (facet, value) = (
        header.iter().position(|h| h == "facet").unwrap(),
        header.iter().position(|h| h == "irradiance_w_m2").unwrap(),
    );
    let history: Vec<f64> = rows
        .iter()
        .filter(|r| r[facet] == "100")
        .map(|r| r[value].parse().unwrap())
        .collect();
    let placed: Vec<f64> = serde_json::from_value(series["irradiance_w_m2"].clone()).unwrap();
    assert_eq!(placed, history);
    // Far off the mesh: one line naming the distance.
    std::fs::write(&query, r#"{"targets": [{"point_m": [1e7, 0, 0]}]}"#).unwrap();
    let out = slim(&["place", "s.toml", "q.json"], &dir.0);
    assert_one_line_error(&out, &["from the nearest facet", "off_mesh"]);
}

/// A CSV file's header and rows (no quoting: slim's numeric tables need none).
#[cfg(feature = "serve")]
fn read_csv_rows(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let split = |l: &str| l.split(',').map(str::to_string).collect::<Vec<_>>();
    let header = split(lines.next().unwrap());
    (header, lines.map(split).collect())
}

/// `slim route` plans a drive on a scene file. Its energy, recomputed here leg by leg
/// from the run's own history (the deck panel's η·A·E, each quantum at its step's
/// light, a drive at the mean of its two facets), equals the route's; walking the plan's
/// facets as waypoints with its departures gives the same route; a request with both a
/// goal and waypoints is a one-line error naming the request file.
#[cfg(feature = "serve")]
#[test]
fn route_plans_on_a_scene_file_with_the_runs_own_light() {
    let dir = TempDir::new("cli", "route");
    write_scene(&dir, "s.toml");
    let rover = r#""rover": {"speed_m_s": 0.05, "max_slope_deg": 89,
        "panel": {"area_m2": 2, "efficiency": 0.25},
        "battery": {"capacity_wh": 200, "initial_wh": 120, "min_charge_wh": 20},
        "idle_load_w": 5, "drive_load_w": 30}"#;
    let request = dir.join("r.json");
    std::fs::write(
        &request,
        format!(r#"{{"from": {{"facet": 100}}, "to": {{"facet": 400}}, {rover}}}"#),
    )
    .unwrap();
    let out = slim(
        &["route", "s.toml", "r.json", "-o", "plan.json", "-q"],
        &dir.0,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("plan.json")).unwrap()).unwrap();
    assert_eq!(plan["type"], "Feature");
    assert_eq!(plan["geometry"]["type"], "LineString");
    let p = &plan["properties"];
    let facets: Vec<u32> = serde_json::from_value(p["facets"].clone()).unwrap();
    assert_eq!((facets[0], *facets.last().unwrap()), (100, 400));
    assert_eq!(
        plan["geometry"]["coordinates"].as_array().unwrap().len(),
        facets.len()
    );
    assert_eq!(p["feasible"], true);
    assert!(p["min_charge_wh"].as_f64().unwrap() >= 20.0);

    // The energy from the run's history.
    let run = slim(&["run", "s.toml", "-o", "out", "--quiet"], &dir.0);
    assert!(run.status.success(), "{}", text(&run.stderr));
    let (header, rows) = read_csv_rows(&dir.join("out/history.csv"));
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (step, facet, value) = (col("step"), col("facet"), col("irradiance_w_m2"));
    let light = |k: usize, f: u64| -> f64 {
        let row = rows
            .iter()
            .find(|r| r[step] == k.to_string() && r[facet] == f.to_string())
            .unwrap();
        row[value].parse().unwrap()
    };
    let t0 = p["arrive_tdb_s"][0].as_f64().unwrap();
    let (tau, substeps) = (
        p["quantum_s"].as_f64().unwrap(),
        p["substeps"].as_u64().unwrap(),
    );
    let mut energy_wh = 0.0;
    for leg in p["legs"].as_array().unwrap() {
        let (a, b) = (
            leg["from_facet"].as_u64().unwrap(),
            leg["to_facet"].as_u64().unwrap(),
        );
        let first = ((leg["start_tdb_s"].as_f64().unwrap() - t0) / tau).round() as u64;
        let last = ((leg["end_tdb_s"].as_f64().unwrap() - t0) / tau).round() as u64;
        for q in first..last {
            let k = (q / substeps) as usize;
            energy_wh += 0.25 * 2.0 * 0.5 * (light(k, a) + light(k, b)) * tau / 3600.0;
        }
    }
    let routed = p["energy_wh"].as_f64().unwrap();
    assert!(
        (energy_wh - routed).abs() <= 1e-4 * routed.max(1.0),
        "{energy_wh} vs {routed}"
    );

    // The plan's facets as waypoints, leaving each when the plan does.
    let departures: Vec<f64> = p["legs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| l["kind"] == "drive")
        .map(|l| l["start_tdb_s"].as_f64().unwrap())
        .collect();
    let waypoints: Vec<String> = facets
        .iter()
        .enumerate()
        .map(|(i, f)| match departures.get(i) {
            Some(t) => format!(r#"{{"facet": {f}, "depart_tdb_s": {t}}}"#),
            None => format!(r#"{{"facet": {f}}}"#),
        })
        .collect();
    std::fs::write(
        &request,
        format!(r#"{{"waypoints": [{}], {rover}}}"#, waypoints.join(",")),
    )
    .unwrap();
    let out = slim(
        &["route", "s.toml", "r.json", "-o", "walk.json", "-q"],
        &dir.0,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let walked: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("walk.json")).unwrap()).unwrap();
    let w = &walked["properties"];
    assert_eq!(w["mode"], "evaluate");
    for key in ["facets", "energy_wh", "charge_wh", "distance_m", "dark_s"] {
        assert_eq!(w[key], p[key], "{key}");
    }

    // A goal and waypoints at once.
    std::fs::write(
        &request,
        format!(r#"{{"to": {{"facet": 4}}, "waypoints": [], {rover}}}"#),
    )
    .unwrap();
    let out = slim(&["route", "s.toml", "r.json"], &dir.0);
    assert_one_line_error(&out, &["either from and to", "bad_route"]);
}

/// With scattering on, a panel over a sunlit plain gets the light the plain scatters:
/// under a Sun at elevation e every facet has radiosity B = ρ·S·sin e, and a panel h
/// above an infinite plain, tilted β from facing up, receives B·(1 − cos β)/2 from it.
/// The panels here face away from the Sun (no direct light): vertical (1/2), tilted 60°
/// (1/4) and facing down (1). The plain, 2 km wide, misses at most 2h/L of form factor
/// beyond its inscribed disk (L = 1 km), and the facets the answer leaves out at most
/// its `left_out`.
#[cfg(feature = "serve")]
#[test]
fn place_adds_the_light_a_sunlit_plain_scatters_onto_a_panel() {
    let dir = TempDir::new("cli", "place-terrain");
    // The plain at x = 1,000 km facing +x, 40 × 40 squares of 50 m; from the place, up
    // is +x, north +z and east +y.
    let (n, side, radius) = (40, 50.0, 1.0e6);
    let mut obj = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (y, z) = (-1000.0 + side * i as f64, -1000.0 + side * j as f64);
            obj += &format!("v {radius} {y} {z}\n");
        }
    }
    let at = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            obj += &format!("f {} {} {}\n", at(i, j), at(i + 1, j), at(i + 1, j + 1));
            obj += &format!("f {} {} {}\n", at(i, j), at(i + 1, j + 1), at(i, j + 1));
        }
    }
    std::fs::write(dir.join("plain.obj"), obj).unwrap();
    let (e, flux, albedo, h) = (30f64.to_radians(), 1000.0, 0.1, 1.0);
    // The Sun at elevation e toward the east.
    let scene = format!(
        "[ephemeris]\nmode = \"fixed\"\n[[ephemeris.sun]]\ndirection = [{}, {}, 0]\n\
         flux_w_m2 = {flux}\n\n[scatter]\nalbedo = {albedo}\n\n[[body]]\nname = \"plain\"\n\
         mesh = \"plain.obj\"\nunits = \"m\"\n",
        e.sin(),
        e.cos()
    );
    std::fs::write(dir.join("s.toml"), scene).unwrap();
    let target = |tilt: f64| {
        serde_json::json!({"point_m": [radius, 3.7, -11.2], "height_m": h,
            "panel": {"mount": "fixed", "tilt_deg": tilt, "azimuth_deg": 270}})
    };
    let tilts = [90.0, 60.0, 180.0];
    let query = serde_json::json!({"targets": tilts.map(target)});
    std::fs::write(dir.join("q.json"), query.to_string()).unwrap();
    let out = slim(&["place", "s.toml", "q.json", "-o", "a.json"], &dir.0);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let answer: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("a.json")).unwrap()).unwrap();
    let b = albedo * flux * e.sin();
    for (k, tilt) in tilts.into_iter().enumerate() {
        let panel = &answer["series"][k]["panel"];
        let terrain = &panel["scattered"];
        let got = terrain["irradiance_w_m2"][0].as_f64().unwrap();
        assert_eq!(
            panel["irradiance_w_m2"][0].as_f64().unwrap(),
            got,
            "no direct light"
        );
        let want = b * (1.0 - tilt.to_radians().cos()) / 2.0;
        let bound = b * (2.0 * h / 1000.0 + terrain["left_out"].as_f64().unwrap());
        assert!(bound < 0.02 * b, "{terrain}");
        assert!(
            got <= want && want - got <= bound,
            "tilt {tilt}: {got} vs {want}"
        );
    }
}

/// Another body's shadow falls on a panel: a 300 m moon 2 km beyond the panel, right on
/// its line to the Sun, hides the Sun at the first step (the ray runs through the moon's
/// centre); at the second the Sun stands 45° up and the ray passes 2 km from it. The
/// same with the Sun as a disk (0.53° wide at 1 AU, the moon 17° wide from the panel).
#[cfg(feature = "serve")]
#[test]
fn other_bodies_shadow_panels() {
    let dir = TempDir::new("cli", "panel-eclipse");
    for sun in ["point", "disk"] {
        let scene = format!(
            "[run]\nsun = \"{sun}\"\n\n[output]\nhistory = false\n\n\
             [ephemeris]\nmode = \"fixed\"\n\n\
             [[ephemeris.sun]]\ndirection = [1.0, 0.0, 0.0]\ndistance_au = 1.0\n\n\
             [[ephemeris.sun]]\ndirection = [1.0, 0.0, 1.0]\ndistance_au = 1.0\n\n\
             [[body]]\nname = \"ground\"\nellipsoid = {{ radii_km = [1.0, 1.0, 1.0], levels = 4 }}\n\n\
             [[body]]\nname = \"moon\"\nellipsoid = {{ radii_km = [0.3, 0.3, 0.3], levels = 3 }}\n\
             position_km = [3.0, 0.0, 0.0]\noutputs = false\n"
        );
        std::fs::write(dir.join("s.toml"), scene).unwrap();
        std::fs::write(
            dir.join("q.json"),
            r#"{"targets": [{"lat_deg": 0, "lon_deg": 0, "height_m": 2,
                "panel": {"mount": "sun_tracking"}}]}"#,
        )
        .unwrap();
        let out = slim(&["place", "s.toml", "q.json", "-o", "a.json"], &dir.0);
        assert!(out.status.success(), "{sun}: {}", text(&out.stderr));
        let answer: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("a.json")).unwrap()).unwrap();
        let panel = &answer["series"][0]["panel"];
        let visible: Vec<f64> = serde_json::from_value(panel["sun_visible"].clone()).unwrap();
        let irradiance: Vec<f64> =
            serde_json::from_value(panel["irradiance_w_m2"].clone()).unwrap();
        assert_eq!(visible[0], 0.0, "{sun}: {panel}");
        assert_eq!(irradiance[0], 0.0, "{sun}: {panel}");
        assert!(visible[1] > 0.999, "{sun}: {panel}");
        assert!((irradiance[1] - 1361.0).abs() < 1.5, "{sun}: {panel}");
    }
}

/// A route on a scene whose mesh is missing is one line naming the mesh's whole path; a
/// bad rover is refused before the scene is read.
#[cfg(feature = "serve")]
#[test]
fn route_errors_name_the_mesh_and_the_bad_field() {
    let dir = TempDir::new("cli", "route-errors");
    let missing = dir.join("sub/missing.obj");
    std::fs::write(
        dir.join("s.toml"),
        format!(
            "[ephemeris]\nmode = \"spin\"\ndistance_au = 1.0\nsteps_per_period = 4\n\n\
             [[body]]\nname = \"b\"\nmesh = {:?}\nunits = \"km\"\nspin_period_h = 1.0\n",
            missing.display().to_string()
        ),
    )
    .unwrap();
    let rover = r#""rover": {"speed_m_s": 0.1, "battery": {"capacity_wh": 10}}"#;
    std::fs::write(
        dir.join("r.json"),
        format!(r#"{{"from": {{"facet": 1}}, "to": {{"facet": 2}}, {rover}}}"#),
    )
    .unwrap();
    let out = slim(&["route", "s.toml", "r.json"], &dir.0);
    assert_one_line_error(&out, &[&missing.display().to_string(), "bad_scene"]);
    std::fs::write(
        dir.join("r.json"),
        r#"{"from": {"facet": 1}, "to": {"facet": 2},
            "rover": {"speed_m_s": 0, "battery": {"capacity_wh": 10}}}"#,
    )
    .unwrap();
    let out = slim(&["route", "s.toml", "r.json"], &dir.0);
    assert_one_line_error(&out, &["rover.speed_m_s", "bad_route"]);
}

/// The BVH's horizon bound goes to the scene's cache folder and is read back by the next
/// run (same results); `slim cache` lists it and deletes it once unused.
#[test]
fn a_runs_bound_is_cached_listed_and_pruned() {
    let dir = TempDir::new("cli", "cache");
    let scene = write_scene(&dir, "s.toml");
    let body = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(
        &scene,
        format!("[run]\ntracer = \"bvh\"\ncache_dir = \"cache\"\n\n{body}"),
    )
    .unwrap();
    let first = slim(&["run", "s.toml", "-o", "first"], &dir.0);
    assert!(first.status.success(), "{}", text(&first.stderr));
    let listed = slim(&["cache", "--dir", "cache"], &dir.0);
    let listing = text(&listed.stdout);
    assert!(listed.status.success(), "{}", text(&listed.stderr));
    assert!(
        listing.contains(": 1 file,") && listing.contains("horizon-bound "),
        "{listing}"
    );
    let second = slim(&["run", "s.toml", "-o", "second"], &dir.0);
    assert!(
        text(&second.stderr).contains("the horizon bound read from the cache"),
        "{}",
        text(&second.stderr)
    );
    for file in ["summary.csv", "cdf.csv"] {
        assert_eq!(
            std::fs::read(dir.join("first").join(file)).unwrap(),
            std::fs::read(dir.join("second").join(file)).unwrap(),
            "{file}"
        );
    }
    // run.json says where each run's bound came from.
    let source = |run: &str| {
        let record: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(run).join("run.json")).unwrap())
                .unwrap();
        let bounds = record["horizon_bounds"].as_array().expect("bounds").clone();
        assert_eq!(bounds.len(), 1, "{bounds:?}");
        bounds[0]["source"].as_str().unwrap().to_string()
    };
    assert_eq!(
        (source("first"), source("second")),
        ("built".into(), "cache".into())
    );
    let kept = slim(&["cache", "--dir", "cache", "--prune-unused", "1"], &dir.0);
    assert!(text(&kept.stdout).contains("deleted 0 files"));
    let pruned = slim(&["cache", "--dir", "cache", "--prune-unused", "0"], &dir.0);
    assert!(
        text(&pruned.stdout).contains("deleted 1 file,"),
        "{}",
        text(&pruned.stdout)
    );
    assert_eq!(std::fs::read_dir(dir.join("cache")).unwrap().count(), 0);
}
