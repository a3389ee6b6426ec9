//! Scene input: a job request body turned into a checked scene and its plan.
//!
//! In: the request body — scene TOML (`application/toml`, `text/plain`), the same scene
//! as a JSON object (`application/json`, same keys and nesting as the TOML), or
//! `{"scene_file": "scenes/NAME.toml"}` naming a catalogue scene. Out: the scene's TOML
//! text, the path it is parsed as, and the [`Plan`] (facets, steps), with every limit
//! checked and every file the scene names resolved inside the data folder.
//!
//! A submitted scene is read as if it were the file `DIR/ID.toml`: its mesh and kernel
//! paths are relative to the data folder. A catalogue scene is read from where it lies,
//! exactly as `slim run` reads it.

use super::catalogue::{check_joined, resolve};
use super::limits::Limits;
use super::reply::{ApiError, ApiResult};
use crate::error::Error;
use crate::plan::Plan;
use crate::prepare::{generated_facets, prepare};
use crate::progress::Timings;
use crate::scene::Scene;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// A scene as submitted: its TOML text and the path it is parsed as.
#[derive(Debug, Clone)]
pub struct SceneText {
    pub toml: String,
    pub parse_path: PathBuf,
}

impl SceneText {
    /// The scene, parsed; errors name the key path, with the data folder left out.
    pub fn parse(&self, dir: &Path) -> ApiResult<Scene> {
        Scene::parse(&self.parse_path, &self.toml, self.toml.clone().into_bytes())
            .map_err(|e| bad_scene(dir, &e))
    }
}

/// A library error about the scene as a 422 answer, paths shown relative to `dir`.
pub fn bad_scene(dir: &Path, e: &crate::Error) -> ApiError {
    let prefix = format!("{}/", dir.display());
    ApiError::unprocessable("bad_scene", e.to_string().replace(&prefix, ""))
}

/// Reads a request body as scene text (`id` names a submitted scene's virtual file).
pub fn scene_text(
    dir: &Path,
    id: &str,
    content_type: Option<&str>,
    body: &[u8],
) -> ApiResult<SceneText> {
    let media = content_type
        .map(|c| {
            c.split(';')
                .next()
                .unwrap_or("")
                .trim()
                .to_ascii_lowercase()
        })
        .unwrap_or_default();
    let submitted = dir.join(format!("{id}.toml"));
    match media.as_str() {
        "application/json" => {
            let value: Value = serde_json::from_slice(body).map_err(|e| {
                ApiError::bad_request("malformed_body", format!("the body is not JSON: {e}"))
            })?;
            let Value::Object(map) = value else {
                return Err(ApiError::bad_request(
                    "malformed_body",
                    "the body must be a JSON object: a scene, or {\"scene_file\": \"scenes/...\"}",
                ));
            };
            if let Some(file) = map.get("scene_file") {
                return catalogue_scene(dir, file, map.len());
            }
            Ok(SceneText {
                toml: toml_text(&map)?,
                parse_path: submitted,
            })
        }
        "" | "application/toml" | "text/plain" | "text/x-toml" => {
            let toml = std::str::from_utf8(body)
                .map_err(|e| ApiError::bad_request("malformed_body", format!("not UTF-8: {e}")))?;
            Ok(SceneText {
                toml: toml.to_string(),
                parse_path: submitted,
            })
        }
        other => Err(ApiError::new(
            axum::http::StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            format!("content type '{other}': send application/json or application/toml"),
        )),
    }
}

fn catalogue_scene(dir: &Path, file: &Value, keys: usize) -> ApiResult<SceneText> {
    let (Value::String(name), 1) = (file, keys) else {
        return Err(ApiError::bad_request(
            "malformed_body",
            "write {\"scene_file\": \"scenes/NAME.toml\"} with nothing else",
        ));
    };
    let path = resolve(dir, name)?;
    let toml = std::fs::read_to_string(&path)
        .map_err(|e| ApiError::unprocessable("bad_scene", format!("scene_file '{name}': {e}")))?;
    Ok(SceneText {
        toml,
        parse_path: path,
    })
}

/// The JSON scene as TOML: one `key = value` line per top-level key, nested tables and
/// arrays written inline, so the TOML reader checks it with the same key paths.
fn toml_text(map: &serde_json::Map<String, Value>) -> ApiResult<String> {
    let mut out = String::new();
    for (key, value) in map {
        out.push_str(&format!("{} = {}\n", quoted(key), toml_value(key, value)?));
    }
    Ok(out)
}

fn toml_value(key: &str, value: &Value) -> ApiResult<String> {
    Ok(match value {
        Value::Null => {
            return Err(ApiError::unprocessable(
                "bad_scene",
                format!("{key}: null is not a value; leave the key out instead"),
            ))
        }
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => n.to_string(),
        Value::String(s) => quoted(s),
        Value::Array(items) => {
            let items: ApiResult<Vec<String>> = items.iter().map(|v| toml_value(key, v)).collect();
            format!("[{}]", items?.join(", "))
        }
        Value::Object(map) => {
            let items: ApiResult<Vec<String>> = map
                .iter()
                .map(|(k, v)| Ok(format!("{} = {}", quoted(k), toml_value(k, v)?)))
                .collect();
            format!("{{{}}}", items?.join(", "))
        }
    })
}

/// A TOML basic string: JSON's string escapes are a subset of TOML's.
fn quoted(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

/// A scene that passed every check: its run name and plan.
#[derive(Debug, Clone)]
pub struct Planned {
    pub name: String,
    pub plan: Plan,
}

/// Parses the scene, checks its files and limits, loads its shapes and returns its plan
/// with the memory estimate. Counts the scene states by itself (bodies, steps, generated
/// facets) are checked before anything is read or built. Blocking (reads meshes and
/// kernels).
pub fn plan(dir: &Path, text: &SceneText, limits: &Limits) -> ApiResult<Planned> {
    let scene = text.parse(dir)?;
    check_files(dir, &scene)?;
    if scene.run.cache_dir.is_some() {
        // A scene must not choose where the service writes: it keeps its own cache.
        return Err(ApiError::unprocessable(
            "bad_scene",
            "run.cache_dir is not accepted here: the service keeps its own horizon-map cache",
        ));
    }
    check_counts(&scene, limits)?;
    let prepared =
        prepare(&scene, &limits.job_budget(), &mut Timings::default()).map_err(|e| match e {
            Error::OverBudget(msg) => ApiError::unprocessable("limit_exceeded", msg),
            e => bad_scene(dir, &e),
        })?;
    let facets = prepared.assembly.world.facet_count();
    if facets > limits.max_facets {
        return Err(over_limit("facets", facets, limits.max_facets));
    }
    Ok(Planned {
        plan: prepared.plan,
        name: scene.name,
    })
}

/// Every file the scene names ([`Scene::input_files`]) must be a file inside the data
/// folder.
pub fn check_files(dir: &Path, scene: &Scene) -> ApiResult<()> {
    for (key, path) in scene.input_files() {
        check_joined(dir, &key, path)?;
    }
    Ok(())
}

/// The counts a scene gives before anything is built: bodies, steps and the facets of
/// generated ellipsoids.
fn check_counts(scene: &Scene, limits: &Limits) -> ApiResult<()> {
    let bodies = scene.bodies.len();
    if bodies > limits.max_bodies {
        return Err(over_limit("bodies", bodies, limits.max_bodies));
    }
    let steps = scene.step_count();
    if steps > limits.max_steps as f64 {
        return Err(over_limit("steps", steps.ceil() as usize, limits.max_steps));
    }
    let generated = generated_facets(scene);
    if generated > limits.max_facets as f64 {
        return Err(over_limit("facets", generated as usize, limits.max_facets));
    }
    Ok(())
}

fn over_limit(what: &str, n: usize, max: usize) -> ApiError {
    ApiError::unprocessable(
        "limit_exceeded",
        format!("the scene has {n} {what}; this service allows at most {max} per job"),
    )
}
