//! Reports drawn from a finished run, read back and checked against the run's tables and
//! the closed form.
//!
//! In: one small synthetic run — an icosphere of 1280 facets spinning under a Sun at
//! sub-solar latitude 20° (spin mode, 48 steps, PLY on), written with
//! `slim::run::run_scene` — and its report from `slim::report::write_report`; plus small
//! runs through the `slim` binary. Out: every figure exists, decodes as a PNG of the size
//! its figure states, SVGs are well formed; the plotted CDF equals the cdf table; the mean
//! map's pixels, inverted through the colour map, give the closed-form mean insolation by
//! latitude; requested facets are plotted; bad input fails with one line naming the folder;
//! `slim run --report` writes a self-contained index.html.

use arrow_array::{Array, Float64Array, StringArray, UInt32Array};
use glam::DVec3;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use slim::analytic::SphereLatitude;
use slim::mesh::generate::icosphere;
use slim::progress::Silent;
use slim::report::colormap::Colormap;
use slim::report::select::{FacetRef, LatLon};
use slim::report::{write_report, ReportOptions};
use slim::run::run_scene;
use slim::scene::Scene;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

#[path = "common/temp_dir.rs"]
mod temp_dir;
use temp_dir::{shared_dir, TempDir};

const LEVELS: u32 = 3; // 1280 facets
const STEPS: usize = 48;
const SUBSOLAR_DEG: f64 = 20.0;
const DISTANCE_AU: f64 = 1.0;
const FLUX_W_M2: f64 = 1361.0;

/// Writes the icosphere scene into `dir`; returns the scene path.
fn write_scene(dir: &Path) -> PathBuf {
    let mesh = icosphere(LEVELS, 1.0, DVec3::ZERO);
    let vertices = mesh
        .vertices
        .iter()
        .map(|v| format!("v {:?} {:?} {:?}", v.x, v.y, v.z));
    let faces = mesh
        .triangles
        .iter()
        .map(|t| format!("f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1));
    let obj: Vec<String> = vertices.chain(faces).collect();
    std::fs::write(dir.join("ball.obj"), obj.join("\n") + "\n").unwrap();
    let scene = format!(
        "[run]\nname = \"report-test\"\nbin_width_w_m2 = 20.0\n\n[output]\ncsv = false\nply = true\n\n\
         [ephemeris]\nmode = \"spin\"\ndistance_au = {DISTANCE_AU}\nsolar_constant_w_m2 = {FLUX_W_M2}\n\
         subsolar_latitude_deg = {SUBSOLAR_DEG}\nsteps_per_period = {STEPS}\n\n\
         [[body]]\nname = \"ball\"\nmesh = \"ball.obj\"\nunits = \"km\"\nspin_period_h = 6.0\n"
    );
    let path = dir.join("ball.toml");
    std::fs::write(&path, scene).unwrap();
    path
}

/// The shared run and its default report: (run folder, report folder).
fn shared() -> &'static (PathBuf, PathBuf) {
    static CELL: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    CELL.get_or_init(|| {
        let dir = shared_dir("report", "run");
        let scene = Scene::load(&write_scene(&dir)).expect("scene");
        let out = dir.join("out");
        run_scene(&scene, &out, &Default::default(), &Silent).expect("run");
        let report = write_report(&out, None, &ReportOptions::default()).expect("report");
        assert_eq!(report.dir, out.join("report"));
        (out, report.dir)
    })
}

/// A decoded PNG: width, height and RGB pixels.
struct Image {
    width: usize,
    height: usize,
    rgb: Vec<u8>,
}

impl Image {
    fn read(path: &Path) -> Image {
        let file = std::io::BufReader::new(std::fs::File::open(path).expect("open png"));
        let mut reader = png::Decoder::new(file).read_info().expect("png header");
        let mut buf = vec![0; reader.output_buffer_size().expect("png size")];
        let info = reader.next_frame(&mut buf).expect("png data");
        assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
        buf.truncate(info.buffer_size());
        Image {
            width: info.width as usize,
            height: info.height as usize,
            rgb: buf,
        }
    }

    fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).expect("read json")).expect("parse json")
}

/// Every (body, facet, threshold) → F of the run's cdf table.
fn cdf_table(run: &Path) -> HashMap<(String, u32, u64), f64> {
    let file = std::fs::File::open(run.join("cdf.parquet")).unwrap();
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .unwrap()
        .build()
        .unwrap();
    let mut table = HashMap::new();
    for batch in reader.map(|b| b.unwrap()) {
        let col = |n: &str| batch.column_by_name(n).unwrap().clone();
        let (body, facet, x, f) = (
            col("body"),
            col("facet"),
            col("irradiance_w_m2"),
            col("cdf"),
        );
        let body = body.as_any().downcast_ref::<StringArray>().unwrap();
        let facet = facet.as_any().downcast_ref::<UInt32Array>().unwrap();
        let x = x.as_any().downcast_ref::<Float64Array>().unwrap();
        let f = f.as_any().downcast_ref::<Float64Array>().unwrap();
        for r in 0..batch.num_rows() {
            table.insert(
                (
                    body.value(r).to_string(),
                    facet.value(r),
                    x.value(r).to_bits(),
                ),
                f.value(r),
            );
        }
    }
    table
}

/// The rows of `cdf_plot.csv` as (body, facet, role, x, F); roles are quoted.
fn plotted_cdf(report: &Path) -> Vec<(String, u32, String, f64, f64)> {
    let text = std::fs::read_to_string(report.join("cdf_plot.csv")).expect("cdf_plot.csv");
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("body,facet,role,latitude_deg,longitude_deg,irradiance_w_m2,cdf")
    );
    lines
        .map(|line| {
            let (head, role_and_rest) = line.split_once(",\"").expect("quoted role");
            let (role, rest) = role_and_rest.split_once("\",").expect("end of role");
            let (body, facet) = head.split_once(',').unwrap();
            let numbers: Vec<f64> = rest.split(',').map(|v| v.parse().unwrap()).collect();
            (
                body.to_string(),
                facet.parse().unwrap(),
                role.to_string(),
                numbers[2],
                numbers[3],
            )
        })
        .collect()
}

#[test]
fn report_files_exist_and_decode_at_their_stated_size() {
    let (_, report) = shared();
    let sized = [
        ("cdf", 960, 640),
        ("minmaxmean", 1100, 600),
        ("histograms", 900, 900),
    ];
    for (name, w, h) in sized {
        let image = Image::read(&report.join(format!("{name}.png")));
        assert_eq!((image.width, image.height), (w, h), "{name}.png");
        let svg = std::fs::read_to_string(report.join(format!("{name}.svg"))).unwrap();
        assert!(svg.trim_start().starts_with("<svg"), "{name}.svg starts");
        assert!(svg.trim_end().ends_with("</svg>"), "{name}.svg ends");
        assert_eq!(
            svg.matches('<').count(),
            svg.matches('>').count(),
            "{name}.svg brackets"
        );
        assert!(svg.contains(&format!("width=\"{w}\"")), "{name}.svg width");
    }
    for quantity in ["mean", "max", "lit_fraction", "time_above"] {
        let json = read_json(&report.join(format!("map_{quantity}.json")));
        let image = Image::read(&report.join(format!("map_{quantity}.png")));
        assert_eq!(
            image.width as u64,
            json["width"].as_u64().unwrap(),
            "{quantity}"
        );
        assert_eq!(
            image.height as u64,
            json["height"].as_u64().unwrap(),
            "{quantity}"
        );
        let values = json["bodies"][0]["values"].as_array().unwrap();
        assert_eq!(values.len(), 1280, "{quantity}: one value per facet");
    }
    let threshold = read_json(&report.join("map_time_above.json"))["threshold_used_w_m2"].as_f64();
    assert_eq!(
        threshold,
        Some(100.0),
        "bins of 20 W/m² hold 100 W/m² exactly"
    );
    for data in [
        "cdf_plot.csv",
        "minmaxmean.csv",
        "histograms.csv",
        "index.html",
    ] {
        assert!(report.join(data).is_file(), "{data}");
    }
}

#[test]
fn plotted_cdf_equals_the_run_cdf_table() {
    let (run, report) = shared();
    let table = cdf_table(run);
    let rows = plotted_cdf(report);
    let mut facets: Vec<(String, u32)> = rows.iter().map(|r| (r.0.clone(), r.1)).collect();
    facets.dedup();
    assert!(facets.len() >= 3, "a spread of facets: {facets:?}");
    let record = read_json(&run.join("run.json"));
    let thresholds = record["bins_w_m2"]["count"].as_u64().unwrap() as usize;
    assert_eq!(
        rows.len(),
        facets.len() * thresholds,
        "every threshold of every facet"
    );
    for (body, facet, role, x, f) in &rows {
        let expected = table.get(&(body.clone(), *facet, x.to_bits()));
        assert_eq!(expected, Some(f), "{body} #{facet} ({role}) at {x} W/m²");
    }
    let roles: Vec<&str> = rows.iter().map(|r| r.2.as_str()).collect();
    for role in [
        "brightest",
        "darkest lit",
        "median mean",
        "most polar",
        "most equatorial",
    ] {
        assert!(
            roles.iter().any(|r| r.contains(role)),
            "{role} in {roles:?}"
        );
    }
}

/// Tolerance argument for the map test. A pixel at latitude φ shows the facet covering
/// it; that facet's normal lies within the facet's angular radius of the pixel's direction
/// (level-3 icosphere: edges ≤ 8°, so circumradius < 5°; `NEIGHBOURHOOD_DEG` = 6° adds
/// margin), and with 48 steps its mean differs from the closed form at its own latitude by
/// at most ≈ 0.92·S/n² ≈ 0.55 W/m² (docs/accuracy.md table). So the true value lies in the closed
/// form's range over φ ± 6°, widened by 1 W/m². The colour then adds quantisation: half a
/// colour step for rounding plus one step because a few neighbouring 8-bit viridis entries
/// coincide (the nearest-colour search returns the first), i.e. 1.5 · range/255.
const NEIGHBOURHOOD_DEG: f64 = 6.0;

fn closed_form_range(lat_deg: f64) -> (f64, f64) {
    let mean =
        |d: f64| SphereLatitude::new(d.to_radians(), SUBSOLAR_DEG.to_radians(), FLUX_W_M2).mean();
    (0..=24)
        .map(|k| mean(lat_deg - NEIGHBOURHOOD_DEG + k as f64 * NEIGHBOURHOOD_DEG / 12.0))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), m| {
            (lo.min(m), hi.max(m))
        })
}

#[test]
fn mean_map_shows_the_closed_form_mean_by_latitude() {
    let (_, report) = shared();
    let json = read_json(&report.join("map_mean.json"));
    assert_eq!(json["colormap"], "viridis");
    let image = Image::read(&report.join("map_mean.png"));
    let (lo, hi) = (
        json["scale_min"].as_f64().unwrap(),
        json["scale_max"].as_f64().unwrap(),
    );
    let rect = &json["bodies"][0]["map"]["rect"];
    let get = |k: &str| rect[k].as_u64().unwrap() as usize;
    let (left, top, width, height) = (get("left"), get("top"), get("width"), get("height"));
    let tolerance = 1.5 * (hi - lo) / 255.0 + 1.0;
    for lat in [-60.0, -35.0, -10.0, 0.0, 15.0, 40.0, 65.0] {
        let (expect_lo, expect_hi) = closed_form_range(lat);
        for lon in [-150.0, -75.0, 10.0, 95.0, 170.0] {
            let x = left + (((lon + 180.0) / 360.0) * width as f64) as usize;
            let y = top + (((90.0 - lat) / 180.0) * height as f64) as usize;
            let index = Colormap::Viridis.nearest_index(image.pixel(x, y));
            let value = Colormap::value_of_index(lo, hi, index);
            assert!(
                value >= expect_lo - tolerance && value <= expect_hi + tolerance,
                "lat {lat}, lon {lon}: map shows {value:.1} W/m², closed form {expect_lo:.1}…{expect_hi:.1} (± {tolerance:.1})"
            );
        }
    }
}

#[test]
fn requested_facets_are_plotted_and_bad_requests_are_refused() {
    let (run, _) = shared();
    let out = TempDir::new("report", "requested");
    let options = ReportOptions {
        facets: vec!["ball:7".parse::<FacetRef>().unwrap()],
        near: vec!["30,-45".parse::<LatLon>().unwrap()],
        threshold_w_m2: 1e9,
        colormap: "cividis".parse().unwrap(),
        routes: Vec::new(),
    };
    write_report(run, Some(&out), &options).expect("report");
    let rows = plotted_cdf(&out);
    let near = rows
        .iter()
        .find(|r| r.2.contains("nearest"))
        .expect("near facet");
    assert!(rows
        .iter()
        .any(|r| r.1 == 7 && r.2.contains("--facet ball:7")));
    let line = std::fs::read_to_string(out.join("cdf_plot.csv")).unwrap();
    let near_line = line.lines().find(|l| l.contains("nearest")).unwrap();
    let fields: Vec<&str> = near_line.rsplitn(5, ',').collect();
    let (lat, lon): (f64, f64) = (fields[3].parse().unwrap(), fields[2].parse().unwrap());
    assert!(
        (lat - 30.0).abs() < 6.0 && (lon + 45.0).abs() < 8.0,
        "{near:?} at {lat}, {lon}"
    );
    let json = read_json(&out.join("map_time_above.json"));
    assert_eq!(json["colormap"], "cividis");
    assert!(
        json["threshold_used_w_m2"].as_f64().unwrap() < 1e9,
        "the largest threshold"
    );
    let bad = ReportOptions {
        facets: vec!["ball:1280".parse().unwrap()],
        ..ReportOptions::default()
    };
    let err = write_report(run, Some(&out), &bad).unwrap_err().to_string();
    assert!(err.contains("1280 facets"), "{err}");
    assert!("ball".parse::<FacetRef>().is_err() && "95,0".parse::<LatLon>().is_err());
}

/// A route file (as `slim route` writes it) along the equator from 80° W to 80° E is
/// drawn white over the map there and nowhere near the poles; a route on a body the run
/// does not have is an error naming the file.
#[test]
fn routes_are_drawn_on_their_bodys_map() {
    let (run, _) = shared();
    let out = TempDir::new("report", "route");
    let data = slim::output::read::RunData::read(run).unwrap();
    let centroids = &data.bodies[0].facets.centroid_m;
    let mut equator: Vec<(f64, usize)> = centroids
        .iter()
        .enumerate()
        .filter_map(|(i, c)| {
            let (lat, lon) = slim::output::read::lat_lon_deg(*c);
            (lat.abs() < 4.0 && lon.abs() < 80.0).then_some((lon, i))
        })
        .collect();
    equator.sort_by(|a, b| a.0.total_cmp(&b.0));
    let facets: Vec<usize> = equator.iter().map(|e| e.1).collect();
    let route = out.join("route.json");
    let write_route = |body: &str| {
        let json = serde_json::json!({"type": "Feature",
            "properties": {"body": body, "facets": facets}});
        std::fs::write(&route, json.to_string()).unwrap();
    };
    write_route("ball");
    let options = ReportOptions {
        routes: vec![route.clone()],
        ..ReportOptions::default()
    };
    write_report(run, Some(&out), &options).expect("report");
    let image = Image::read(&out.join("map_mean.png"));
    let json = read_json(&out.join("map_mean.json"));
    let rect = &json["bodies"][0]["map"]["rect"];
    let get = |k: &str| rect[k].as_u64().unwrap() as usize;
    let (left, top, width, height) = (get("left"), get("top"), get("width"), get("height"));
    let white_near = |lat: f64, lon: f64| {
        let x = left + ((lon + 180.0) / 360.0 * width as f64) as usize;
        let y = top + ((90.0 - lat) / 180.0 * height as f64) as usize;
        (y - 5..=y + 5).any(|y| image.pixel(x, y) == [255, 255, 255])
    };
    assert!(white_near(0.0, -40.0) && white_near(0.0, 0.0) && white_near(0.0, 40.0));
    assert!(!white_near(60.0, 0.0) && !white_near(0.0, 120.0));
    write_route("eros");
    let err = write_report(run, Some(&out), &options)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("route.json") && err.contains("'eros' is not in this run"),
        "{err}"
    );
}

#[test]
fn missing_tables_are_errors_naming_the_file() {
    let (run, _) = shared();
    let copy = TempDir::new("report", "missing");
    for name in ["run.json", "cdf.parquet", "geometry.parquet"] {
        std::fs::copy(run.join(name), copy.join(name)).unwrap();
    }
    let err = write_report(&copy, None, &ReportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("summary.parquet"), "{err}");
    std::fs::write(copy.join("summary.parquet"), b"not parquet").unwrap();
    let err = write_report(&copy, None, &ReportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("summary.parquet"), "{err}");
}

fn slim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slim"))
}

#[test]
fn report_on_a_folder_without_run_json_fails_with_one_line() {
    let dir = TempDir::new("report", "not-a-run");
    let out = slim().arg("report").arg(&*dir).output().unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains(&*dir.to_string_lossy()) && stderr.contains("run.json"),
        "{stderr}"
    );
    assert!(!dir.join("report").exists(), "nothing written");
}

#[test]
fn run_with_report_writes_a_self_contained_index() {
    let dir = TempDir::new("report", "cli");
    let scene = write_scene(&dir);
    let out = dir.join("out");
    let status = slim()
        .arg("run")
        .arg(&scene)
        .arg("-o")
        .arg(&out)
        .args(["--report", "--quiet"])
        .status()
        .unwrap();
    assert!(status.success());
    let report = out.join("report");
    let html = std::fs::read_to_string(report.join("index.html")).expect("index.html");
    assert!(
        !html.contains("http://") && !html.contains("https://"),
        "no network references"
    );
    for name in [
        "cdf",
        "minmaxmean",
        "histograms",
        "map_mean",
        "map_max",
        "map_lit_fraction",
        "map_time_above",
    ] {
        assert!(report.join(format!("{name}.png")).is_file(), "{name}.png");
        assert!(
            html.contains(&format!("href=\"{name}.png\"")),
            "{name} linked"
        );
    }
    for svg in ["cdf.svg", "minmaxmean.svg", "histograms.svg"] {
        assert!(html.contains(&format!("href=\"{svg}\"")), "{svg} linked");
    }
    assert_eq!(
        html.matches("src=\"data:image/png;base64,").count(),
        7,
        "every PNG embedded"
    );
    for section in [
        "Plan", "skipped", "Geometry", "Accuracy", "Timings", "Warnings", "Meshes",
    ] {
        assert!(html.contains(section), "{section}");
    }
}

#[test]
fn a_run_with_a_generated_ellipsoid_and_two_bodies_reports_on_the_first() {
    // A generated body has no mesh file (run.json: "mesh": null). The report must still
    // read the run, name the generated shape, and pick default CDF facets on the first
    // body (the body of interest), not on the larger occluder.
    let dir = TempDir::new("report", "ellipsoid");
    let scene = write_scene(&dir);
    let text = std::fs::read_to_string(&scene).unwrap()
        + "\n[[body]]\nname = \"big\"\nellipsoid = { radii_km = [5.0, 4.0, 3.0], levels = 2 }\n\
           position_km = [0.0, 40.0, 0.0]\n";
    std::fs::write(&scene, text).unwrap();
    let out = dir.join("out");
    run_scene(
        &Scene::load(&scene).unwrap(),
        &out,
        &Default::default(),
        &Silent,
    )
    .expect("run");
    let report = write_report(&out, None, &ReportOptions::default()).expect("report");
    let html = std::fs::read_to_string(report.dir.join("index.html")).unwrap();
    assert!(
        html.contains("ellipsoid 5 x 4 x 3 km, 320 facets"),
        "generated shape named"
    );
    let plotted = plotted_cdf(&report.dir);
    assert!(!plotted.is_empty());
    assert!(
        plotted.iter().all(|row| row.0 == "ball"),
        "default facets on the first body"
    );
}

#[test]
fn runs_with_scattered_light_map_each_part_of_the_light() {
    // A convex ball scatters nothing onto itself: its direct light read back must equal
    // the total and its scattered light be zero, facet by facet; the direct map spans the
    // total's range; with no planet there is no planet map.
    let dir = TempDir::new("report", "parts");
    let scene_path = write_scene(&dir);
    let text = std::fs::read_to_string(&scene_path).unwrap();
    std::fs::write(&scene_path, format!("{text}\n[scatter]\nalbedo = 0.1\n")).unwrap();
    let out = dir.join("out");
    run_scene(
        &Scene::load(&scene_path).unwrap(),
        &out,
        &Default::default(),
        &Silent,
    )
    .unwrap();
    let report = write_report(&out, None, &ReportOptions::default())
        .unwrap()
        .dir;
    let range = |name: &str| {
        let json = read_json(&report.join(format!("{name}.json")));
        (
            json["scale_min"].as_f64().unwrap(),
            json["scale_max"].as_f64().unwrap(),
        )
    };
    assert_eq!(range("map_direct_mean"), range("map_mean"));
    assert!(report.join("map_scattered_mean.png").is_file());
    assert!(!report.join("map_planet_mean.png").exists());
    let run = slim::output::read::RunData::read(&out).unwrap();
    let facets = &run.bodies[0].facets;
    let parts: Vec<&str> = facets.part_means_w_m2.iter().map(|p| p.0).collect();
    assert_eq!(parts, ["direct", "scattered"]);
    for k in 0..facets.len() {
        assert_eq!(facets.part_means_w_m2[0].1[k], facets.mean_w_m2[k]);
        assert_eq!(facets.part_means_w_m2[1].1[k], 0.0);
    }
}
