//! Shards and merge, run as processes: `slim run --shard K/N` then `slim merge` must
//! write every file of one `slim run` byte for byte, for time parts N = 1, 2, 3, 7 and 4
//! facet parts, on Phobos with Mars (SPICE, other bodies' shadows, history, CSV, PLY) and
//! on a body with scattered light, Mars's planet-shine (whose weights are reused from
//! step to step) and two spectral bands. Broken sets of parts are refused with errors
//! that name the folder and what is wrong.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "common/temp_dir.rs"]
mod temp_dir;
use temp_dir::TempDir;

fn data(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(path)
        .display()
        .to_string()
}

/// Phobos and Mars from the shipped kernels over one Phobos orbit in `steps` steps,
/// with `extra` TOML (bodies, scatter, bands) after the ephemeris.
fn phobos_scene(dir: &TempDir, name: &str, steps: usize, mesh: &str, extra: &str) -> PathBuf {
    let kernels = [
        "kernels/lsk/naif0012.tls",
        "kernels/pck/pck00011.tpc",
        "kernels/spk/mar085_subset_2018-06/mar085.bsp",
        "kernels/spk/mar085_subset_2018-06/de430.bsp",
    ]
    .map(|k| format!("{:?}", data(k)))
    .join(", ");
    let text = format!(
        "[run]\nname = \"{name}\"\ncache_dir = {cache:?}\n\n\
         [output]\ncsv = true\nply = true\nhistory = true\n\n\
         [ephemeris]\nmode = \"spice\"\nkernels = [{kernels}]\n\
         start = \"2018-06-10T00:00:00 UTC\"\nspins = 1\nsteps_per_spin = {steps}\n\n\
         {extra}\n\
         [[body]]\nname = \"phobos\"\nnaif_id = 401\nmesh = {mesh:?}\nunits = \"km\"\n\n\
         [[body]]\nname = \"mars\"\nnaif_id = 499\nellipsoid = {{ levels = 3 }}\n\
         outputs = false\nalbedo = 0.25\n",
        cache = dir.join("cache").display().to_string(),
        mesh = data(mesh),
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

fn slim(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_slim"))
        .args(args)
        .arg("--quiet")
        .output()
        .expect("run slim")
}

fn ok(args: &[&str]) {
    let out = slim(args);
    assert!(
        out.status.success(),
        "slim {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn fails(args: &[&str]) -> String {
    let out = slim(args);
    assert!(!out.status.success(), "slim {args:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs `scene` in `n` parts by `by` into `dir/by-n/K`, merges them into `dir/by-n/merged`.
fn run_in_parts(scene: &Path, dir: &TempDir, n: usize, by: &str) -> PathBuf {
    let root = dir.join(format!("{by}-{n}"));
    let mut parts = Vec::new();
    // Run the parts out of order: a part does not depend on the others.
    for k in (1..=n).rev() {
        let part = root.join(k.to_string());
        ok(&[
            "run",
            s(scene),
            "--shard",
            &format!("{k}/{n}"),
            "--by",
            by,
            "-o",
            s(&part),
        ]);
        parts.push(part);
    }
    let merged = root.join("merged");
    let mut args = vec!["merge"];
    args.extend(parts.iter().map(|p| s(p)));
    args.extend(["-o", s(&merged)]);
    ok(&args);
    merged
}

/// Every file of `one` but run.json is in `merged` with the same bytes, and nothing else
/// is; run.json agrees on everything that describes the result.
fn assert_identical(one: &Path, merged: &Path, what: &str) {
    let names = |d: &Path| {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        v.sort();
        v
    };
    assert_eq!(names(one), names(merged), "{what}: the files");
    for name in names(one) {
        if name == "run.json" {
            continue;
        }
        let (a, b) = (
            std::fs::read(one.join(&name)).unwrap(),
            std::fs::read(merged.join(&name)).unwrap(),
        );
        assert!(
            a == b,
            "{what}: {name} differs ({} against {} bytes)",
            a.len(),
            b.len()
        );
    }
    let record = |d: &Path| -> Value {
        let mut v: Value =
            serde_json::from_slice(&std::fs::read(d.join("run.json")).unwrap()).unwrap();
        let o = v.as_object_mut().unwrap();
        for work in ["timings_s", "threads", "merged_from"] {
            o.remove(work);
        }
        // A part reads from the cache what a single run built.
        if let Some(bounds) = o.get_mut("horizon_bounds") {
            for b in bounds.as_array_mut().unwrap() {
                let b = b.as_object_mut().unwrap();
                b.remove("build_s");
                b.remove("source");
            }
        }
        if let Some(ff) = o.get_mut("scatter").and_then(|s| s.get_mut("form_factors")) {
            for f in ff.as_array_mut().unwrap() {
                let f = f.as_object_mut().unwrap();
                f.remove("build_s");
                f.remove("source");
            }
        }
        v
    };
    assert_eq!(record(one), record(merged), "{what}: run.json");
    let merged_from =
        &serde_json::from_slice::<Value>(&std::fs::read(merged.join("run.json")).unwrap()).unwrap()
            ["merged_from"];
    assert!(
        merged_from["parts"].as_u64().unwrap() >= 1,
        "{what}: {merged_from}"
    );
}

#[test]
fn parts_by_time_and_by_facet_merge_into_the_files_of_one_run() {
    let dir = TempDir::new("shards", "direct");
    let scene = phobos_scene(&dir, "phobos", 28, "shapes/phobos/m1phobos.obj", "");
    let one = dir.join("one");
    ok(&["run", s(&scene), "-o", s(&one)]);
    for n in [1, 2, 3, 7] {
        let merged = run_in_parts(&scene, &dir, n, "time");
        assert_identical(&one, &merged, &format!("{n} time parts"));
    }
    let merged = run_in_parts(&scene, &dir, 4, "facets");
    assert_identical(&one, &merged, "4 facet parts");
}

/// A spin of four whole periods repeats its first one, and each part of it computes the
/// first period it covers and hands that light on: the merged files must still be one
/// run's byte for byte, and the counts in run.json (every step's, however many were
/// computed) the same.
#[test]
fn parts_of_a_spin_that_repeats_merge_into_the_files_of_one_run() {
    let dir = TempDir::new("shards", "repeats");
    let text = format!(
        "[run]\nname = \"repeats\"\ntracer = \"bvh\"\ncache_dir = {cache:?}\n\n\
         [output]\ncsv = true\nply = true\nhistory = true\n\n\
         [ephemeris]\nmode = \"spin\"\ndistance_au = 1.52\nsubsolar_latitude_deg = 20.0\n\
         steps_per_period = 6\nperiods = 4\n\n\
         [[body]]\nname = \"phobos\"\nmesh = {mesh:?}\nunits = \"km\"\nspin_period_h = 7.65\n",
        mesh = data("shapes/phobos/m1phobos.obj"),
        cache = dir.join("cache").display().to_string(),
    );
    let scene = dir.join("repeats.toml");
    std::fs::write(&scene, text).unwrap();
    let one = dir.join("one");
    ok(&["run", s(&scene), "-o", s(&one)]);
    let plan = std::fs::read_to_string(one.join("run.json")).unwrap();
    assert!(plan.contains("repeats every 6 steps"), "{plan}");
    for n in [2, 3, 5] {
        let merged = run_in_parts(&scene, &dir, n, "time");
        assert_identical(
            &one,
            &merged,
            &format!("{n} time parts of a repeating spin"),
        );
    }
}

#[test]
fn parts_with_scattered_light_planet_shine_and_bands_merge_exactly() {
    let dir = TempDir::new("shards", "scatter");
    // Itokawa's 3,072-facet shape in Phobos's place keeps the form factors small; Mars's
    // planet-shine weights are kept while it moves less than planet_reuse, so a time part
    // must start from the weights one run would hold (Scatter::prime).
    let extra = "[scatter]\nalbedo = 0.3\n\n\
                 [[band]]\nname = \"blue\"\nsolar_constant_w_m2 = 400.0\n\n\
                 [[band]]\nname = \"red\"\nsolar_constant_w_m2 = 961.0\n";
    let scene = phobos_scene(&dir, "scatter", 21, "shapes/itokawa/itokawa_16.obj", extra);
    let one = dir.join("one");
    ok(&["run", s(&scene), "-o", s(&one)]);
    let record: Value =
        serde_json::from_slice(&std::fs::read(one.join("run.json")).unwrap()).unwrap();
    let scatter = &record["scatter"];
    assert!(
        scatter["planet_weights_reused"].as_u64().unwrap() > 0
            && scatter["planet_weights_built"].as_u64().unwrap() > 0,
        "the test needs weights both built and reused: {scatter}"
    );
    for n in [3, 7] {
        let merged = run_in_parts(&scene, &dir, n, "time");
        assert_identical(
            &one,
            &merged,
            &format!("{n} time parts with scattered light"),
        );
    }
    let merged = run_in_parts(&scene, &dir, 4, "facets");
    assert_identical(&one, &merged, "4 facet parts with scattered light");
}

#[test]
fn broken_sets_of_parts_are_refused_naming_the_folder() {
    let dir = TempDir::new("shards", "broken");
    let scene = phobos_scene(&dir, "small", 6, "shapes/itokawa/itokawa_8.obj", "");
    let part = |k: usize, n: usize| {
        let p = dir.join(format!("p{k}of{n}"));
        ok(&[
            "run",
            s(&scene),
            "--shard",
            &format!("{k}/{n}"),
            "-o",
            s(&p),
        ]);
        p
    };
    let (p1, p2, p3) = (part(1, 3), part(2, 3), part(3, 3));
    let out = dir.join("out");
    let e = fails(&["merge", s(&p1), s(&p3), "-o", s(&out)]);
    assert!(e.contains("lack part 2/3"), "{e}");
    let e = fails(&["merge", s(&p1), s(&p2), s(&p3), s(&p1), "-o", s(&out)]);
    assert!(e.contains("holds part 1/3"), "{e}");
    let other = part(2, 2);
    let e = fails(&["merge", s(&p1), s(&other), s(&p3), "-o", s(&out)]);
    assert!(e.contains("number of parts") && e.contains("p2of2"), "{e}");
    let whole = dir.join("whole");
    ok(&["run", s(&scene), "-o", s(&whole)]);
    let e = fails(&["merge", s(&whole), "-o", s(&out)]);
    assert!(e.contains("is not a part") && e.contains("whole"), "{e}");
    // A flipped byte in a part's statistics.
    let file = p2.join("part.bin");
    let mut bytes = std::fs::read(&file).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x10;
    std::fs::write(&file, &bytes).unwrap();
    let e = fails(&["merge", s(&p1), s(&p2), s(&p3), "-o", s(&out)]);
    assert!(
        e.contains("p2of3/part.bin") && e.contains("checksum"),
        "{e}"
    );
    assert!(
        !out.join("run.json").exists(),
        "a failed merge leaves no run.json"
    );
    // The scene edited after the parts ran.
    let text = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(
        &scene,
        text.replace("steps_per_spin = 6", "steps_per_spin = 7"),
    )
    .unwrap();
    let e = fails(&["merge", s(&p1), s(&p2), s(&p3), "-o", s(&out)]);
    assert!(
        e.contains("small.toml") && e.contains("is not the scene the parts ran"),
        "{e}"
    );
    // Parts that cannot be.
    for bad in ["0/3", "4/3", "three"] {
        let e = fails(&["run", s(&scene), "--shard", bad, "-o", s(&out)]);
        assert!(e.contains("--shard"), "{bad}: {e}");
    }
    let e = fails(&["run", s(&scene), "--shard", "1/9", "-o", s(&out)]);
    assert!(e.contains("at most") && e.contains("parts"), "{e}");
}

#[test]
fn slurm_scripts_are_written_and_a_dry_run_estimates_a_part_without_writing() {
    let dir = TempDir::new("shards", "slurm");
    let scene = phobos_scene(&dir, "small", 40, "shapes/itokawa/itokawa_8.obj", "");
    let batch = dir.join("batch");
    let out = Command::new(env!("CARGO_BIN_EXE_slim"))
        .args([
            "slurm",
            s(&scene),
            "--shards",
            "4",
            "--dry-run",
            "--probe-steps",
            "5",
            "-o",
            s(&batch),
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("4 parts by time") && text.contains("probe of 5 steps"),
        "{text}"
    );
    assert!(
        text.contains("10 steps ×") && text.contains("GiB planned"),
        "{text}"
    );
    assert!(text.contains("#SBATCH --array=1-4"), "{text}");
    assert!(!batch.exists(), "a dry run writes nothing");
    ok(&[
        "slurm",
        s(&scene),
        "--shards",
        "3",
        "--by",
        "facets",
        "--partition",
        "short",
        "-o",
        s(&batch),
    ]);
    let parts = std::fs::read_to_string(batch.join("slurm/parts.sh")).unwrap();
    assert!(
        parts.contains("--by facets") && parts.contains("#SBATCH --partition=short"),
        "{parts}"
    );
    assert!(
        batch.join("slurm/logs").is_dir(),
        "Slurm needs the log folder to exist"
    );
    let merge = std::fs::read_to_string(batch.join("slurm/merge.sh")).unwrap();
    assert!(
        merge.contains("parts/3'") && !merge.contains("parts/4'"),
        "{merge}"
    );
}
