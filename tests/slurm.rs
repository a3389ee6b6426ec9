//! `slim slurm --submit` on a real Slurm: the shipped Phobos example as 4 parts in an
//! array job plus the merge job, compared byte for byte with `slim run`. Needs a running
//! Slurm: `.ci/slurm/up` installs Debian's Slurm and munge and starts a one-node cluster
//! on this machine; CI runs it with `cargo test --test slurm -- --ignored`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn slim(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_slim"))
        .args(args)
        .output()
        .expect("run slim");
    assert!(
        out.status.success(),
        "slim {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("slim-slurm-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
#[ignore = "needs a Slurm cluster: run .ci/slurm/up first (CI does)"]
fn the_phobos_example_in_four_slurm_parts_equals_one_run() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/phobos.toml");
    let scene = scene.to_str().unwrap();
    let (one, batch) = (folder("one"), folder("batch"));
    slim(&["run", scene, "-o", one.to_str().unwrap(), "--quiet"]);
    slim(&[
        "slurm",
        scene,
        "--shards",
        "4",
        "-o",
        batch.to_str().unwrap(),
        "--submit",
    ]);
    let t0 = Instant::now();
    let merged = batch.join("run.json");
    while !merged.is_file() {
        let logs = batch.join("slurm/logs");
        assert!(
            t0.elapsed() < Duration::from_secs(600),
            "no merged run after 10 minutes; logs in {}",
            logs.display()
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    for entry in std::fs::read_dir(&one).unwrap() {
        let name = entry.unwrap().file_name();
        if name == "run.json" {
            continue;
        }
        let a = std::fs::read(one.join(&name)).unwrap();
        let b = std::fs::read(batch.join(&name)).unwrap();
        assert!(a == b, "{name:?} differs from slim run's");
    }
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&merged).unwrap()).unwrap();
    assert_eq!(record["merged_from"]["parts"], 4);
    for k in 1..=4 {
        assert!(batch.join(format!("slurm/logs/part-{k}.out")).is_file());
    }
    let _ = std::fs::remove_dir_all(&one);
    let _ = std::fs::remove_dir_all(&batch);
}
