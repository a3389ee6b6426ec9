//! Load test of `slim serve`: single-facet JSON queries on loopback, with no job running
//! and while a job computes.
//!
//! In: nothing (a temporary data folder with the shipped Itokawa meshes; the service runs
//! in this process on a free loopback port). Out: for each phase the number of queries,
//! throughput (queries/s) and latency percentiles p50/p99 (ms), printed as a Markdown
//! table; then the time of on-demand irradiance requests (3 places × 1,000 steps).
//! Bounded: each phase stops after `QUERIES` queries or `SECONDS` seconds.
//!
//! Run: `cargo run --release --example load_serve [-- CLIENTS]` (default 8 client threads,
//! each with its own keep-alive connection).

use slim::serve::{limits::Limits, Config};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

const QUERIES: usize = 200_000;
const SECONDS: f64 = 15.0;

fn main() {
    let clients: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(8);
    let data = data_dir();
    let port = free_port();
    let config = Config {
        data_dir: data.clone(),
        listen: format!("127.0.0.1:{port}").parse().unwrap(),
        token: None,
        protect_reads: false,
        workers: 1,
        job_threads: std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .saturating_sub(1)
            .max(1),
        limits: Limits::default(),
        executor: Default::default(),
    };
    std::thread::spawn(move || slim::serve::serve(config).expect("serve"));
    let base = format!("http://127.0.0.1:{port}");
    wait_up(&base);

    let small = submit(&base, &scene("itokawa_8.obj", 48));
    wait_state(&base, &small, |s| s == "succeeded");
    let url = |k: usize| format!("{base}/v1/jobs/{small}/facets?ids={}", k % 768);

    println!("| phase | clients | queries | seconds | queries/s | p50 ms | p99 ms |");
    println!("|---|---|---|---|---|---|---|");
    report("idle", clients, &load(clients, &url));

    let big = submit(&base, &scene("itokawa_32.obj", 100_000));
    wait_state(&base, &big, |s| s == "running");
    let busy = load(clients, &url);
    let job = get(&base, &format!("/v1/jobs/{big}"));
    report("job computing", clients, &busy);
    println!();
    on_demand(&base, &big);
    println!(
        "the job was still {} at the end ({} of {} steps); cores: {}",
        job["state"],
        job["progress"]["steps_done"],
        job["progress"]["steps_total"],
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    let _ = ureq::delete(&format!("{base}/v1/jobs/{big}")).call();
    // The cancelled job's thread removes its folder at its next step.
    let t0 = Instant::now();
    while data.join("jobs").join(&big).exists() && t0.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = std::fs::remove_dir_all(&data);
}

/// Times on-demand irradiance for 3 places × 1,000 steps of the running job's scene:
/// the first request builds the meshes and shadow grids, the later ones reuse them.
fn on_demand(base: &str, id: &str) {
    let request = r#"{"targets": [{"lat_deg": 0, "lon_deg": 0}, {"lat_deg": 45, "lon_deg": 90},
        {"lat_deg": -60, "lon_deg": 200}], "from_step": 0, "to_step": 1000}"#;
    let mut times = Vec::new();
    for _ in 0..4 {
        let t0 = Instant::now();
        let mut r = ureq::post(&format!("{base}/v1/jobs/{id}/irradiance"))
            .header("Content-Type", "application/json")
            .send(request)
            .expect("irradiance");
        assert_eq!(r.status(), 200);
        r.body_mut().read_to_string().unwrap();
        times.push(format!("{:.1}", t0.elapsed().as_secs_f64() * 1e3));
    }
    println!(
        "on-demand irradiance, 3 places × 1000 steps of itokawa_32 (while the job computes), ms: \
         first {} (builds the grids), then {}",
        times[0],
        times[1..].join(", ")
    );
}

/// Per query latency (s) and the phase's wall time (s).
struct Phase {
    latencies: Vec<f64>,
    wall_s: f64,
}

/// Runs `clients` threads issuing GETs until `QUERIES` are done or `SECONDS` pass.
fn load(clients: usize, url: &(dyn Fn(usize) -> String + Sync)) -> Phase {
    let issued = AtomicUsize::new(0);
    let t0 = Instant::now();
    let deadline = t0 + Duration::from_secs_f64(SECONDS);
    let latencies = std::thread::scope(|s| {
        let workers: Vec<_> = (0..clients)
            .map(|_| {
                s.spawn(|| {
                    let agent = ureq::Agent::new_with_defaults();
                    let mut times = Vec::new();
                    loop {
                        let k = issued.fetch_add(1, Ordering::Relaxed);
                        if k >= QUERIES || Instant::now() > deadline {
                            return times;
                        }
                        let q0 = Instant::now();
                        let mut r = agent.get(&url(k * 7919)).call().expect("query");
                        let body = r.body_mut().read_to_string().expect("answer");
                        assert!(body.starts_with("{\"body\""), "{body}");
                        times.push(q0.elapsed().as_secs_f64());
                    }
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().unwrap())
            .collect::<Vec<f64>>()
    });
    Phase {
        latencies,
        wall_s: t0.elapsed().as_secs_f64(),
    }
}

fn report(name: &str, clients: usize, phase: &Phase) {
    let mut sorted = phase.latencies.clone();
    sorted.sort_by(f64::total_cmp);
    let pct = |p: f64| sorted[((sorted.len() - 1) as f64 * p).round() as usize] * 1e3;
    println!(
        "| {name} | {clients} | {} | {:.1} | {:.0} | {:.2} | {:.2} |",
        sorted.len(),
        phase.wall_s,
        sorted.len() as f64 / phase.wall_s,
        pct(0.50),
        pct(0.99)
    );
}

/// A spin scene of one Itokawa mesh over `steps` steps of a 12 h period, with a point Sun
/// (as docs/performance.md's figures were taken).
fn scene(mesh: &str, steps: usize) -> String {
    format!(
        "[run]\nsun = \"point\"\n[output]\ncsv = false\nply = false\n[ephemeris]\nmode = \"spin\"\ndistance_au = 1.0\n\
         steps_per_period = {steps}\n[[body]]\nname = \"itokawa\"\nmesh = \"shapes/{mesh}\"\n\
         units = \"km\"\nspin_period_h = 12.0\n"
    )
}

fn data_dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("slim-load-serve-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("shapes")).unwrap();
    let shapes = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/shapes/itokawa");
    for mesh in ["itokawa_8.obj", "itokawa_32.obj"] {
        std::fs::copy(shapes.join(mesh), dir.join("shapes").join(mesh)).unwrap();
    }
    dir
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn get(base: &str, path: &str) -> serde_json::Value {
    let text = ureq::get(&format!("{base}{path}"))
        .call()
        .expect("GET")
        .body_mut()
        .read_to_string()
        .unwrap();
    serde_json::from_str(&text).unwrap()
}

fn wait_up(base: &str) {
    let t0 = Instant::now();
    while ureq::get(&format!("{base}/v1/jobs")).call().is_err() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the service did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn submit(base: &str, scene: &str) -> String {
    let text = ureq::post(&format!("{base}/v1/jobs"))
        .header("Content-Type", "application/toml")
        .send(scene)
        .expect("submit")
        .body_mut()
        .read_to_string()
        .unwrap();
    let job: serde_json::Value = serde_json::from_str(&text).unwrap();
    job["id"].as_str().expect("job id").to_string()
}

fn wait_state(base: &str, id: &str, done: impl Fn(&str) -> bool) {
    let t0 = Instant::now();
    loop {
        let job = get(base, &format!("/v1/jobs/{id}"));
        let state = job["state"].as_str().unwrap_or("");
        if done(state) {
            return;
        }
        assert!(
            matches!(state, "queued" | "running" | "succeeded"),
            "job {id}: {job}"
        );
        assert!(t0.elapsed() < Duration::from_secs(120), "job {id} is slow");
        std::thread::sleep(Duration::from_millis(20));
    }
}
