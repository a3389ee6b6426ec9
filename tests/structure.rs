//! The module structure: the library's top-level modules (the pipeline stages and their
//! helpers) form no import circle, nor do the files of any one folder. Read from the
//! source text: every `crate::NAME` a file under `src/NAME2` mentions outside comments is
//! an edge NAME2 → NAME; within a folder, every `super::NAME` or `crate::FOLDER::NAME`
//! naming a sibling file. A circle would mean two stages (or two files of one) that
//! cannot be understood, tested or built (Cargo features) one without the other.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

#[path = "common/imports.rs"]
mod imports;
use imports::names_after;

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file below `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The top-level module a file belongs to (`scene/schema.rs` → `scene`), or none for the
/// crate roots and the binary's command line.
fn module_of(file: &Path) -> Option<String> {
    let relative = file.strip_prefix(src()).unwrap();
    let first = relative.components().next()?.as_os_str().to_str()?;
    let name = first.trim_end_matches(".rs");
    (!matches!(name, "lib" | "main" | "cli")).then(|| name.to_string())
}

/// Module → the other top-level modules it names.
fn module_graph() -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let modules: BTreeSet<String> = files.iter().filter_map(|f| module_of(f)).collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in &files {
        let Some(from) = module_of(file) else {
            continue;
        };
        let text = std::fs::read_to_string(file).unwrap();
        let edges = graph.entry(from.clone()).or_default();
        for to in names_after(&text, "crate::") {
            if to != from && modules.contains(&to) {
                edges.insert(to);
            }
        }
    }
    graph
}

/// Per folder below `src` (as a module path, `ephemeris::spice`): each file (its stem;
/// the folder's `mod.rs`, its face, left out) → the sibling files its code names, unit
/// tests and comments left out.
fn file_graphs() -> BTreeMap<String, BTreeMap<String, BTreeSet<String>>> {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let stem = |f: &Path| f.file_stem().unwrap().to_str().unwrap().to_string();
    let mut graphs: BTreeMap<String, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for file in &files {
        let folder = file.parent().unwrap();
        let Ok(relative) = folder.strip_prefix(src()) else {
            continue;
        };
        if relative.as_os_str().is_empty() || stem(file) == "mod" {
            continue;
        }
        let path: Vec<&str> = relative.iter().map(|c| c.to_str().unwrap()).collect();
        let siblings: BTreeSet<String> = files
            .iter()
            .filter(|f| f.parent() == Some(folder) && stem(f) != "mod")
            .map(|f| stem(f))
            .collect();
        let text = std::fs::read_to_string(file).unwrap();
        let code = text.split("#[cfg(test)]\nmod tests").next().unwrap();
        let from = stem(file);
        let named = names_after(code, "super::")
            .into_iter()
            .chain(names_after(code, &format!("crate::{}::", path.join("::"))));
        let edges: BTreeSet<String> = named
            .filter(|to| *to != from && siblings.contains(to))
            .collect();
        graphs
            .entry(path.join("::"))
            .or_default()
            .insert(from, edges);
    }
    graphs
}

/// A circle through `node`, if the depth-first walk from it finds one.
fn circle_from(
    node: &str,
    graph: &BTreeMap<String, BTreeSet<String>>,
    path: &mut Vec<String>,
    done: &mut BTreeSet<String>,
) -> Option<Vec<String>> {
    if let Some(at) = path.iter().position(|n| n == node) {
        let mut circle = path[at..].to_vec();
        circle.push(node.to_string());
        return Some(circle);
    }
    if done.contains(node) {
        return None;
    }
    path.push(node.to_string());
    for next in graph.get(node).into_iter().flatten() {
        if let Some(circle) = circle_from(next, graph, path, done) {
            return Some(circle);
        }
    }
    path.pop();
    done.insert(node.to_string());
    None
}

#[test]
fn the_top_level_modules_import_no_circle() {
    let graph = module_graph();
    assert!(graph.len() > 20, "read {} modules", graph.len());
    // The edges are read, not only the modules: the horizon stage builds on the tree.
    assert!(graph["horizon"].contains("trace"), "{:?}", graph["horizon"]);
    let mut done = BTreeSet::new();
    for node in graph.keys() {
        let circle = circle_from(node, &graph, &mut Vec::new(), &mut done);
        assert!(
            circle.is_none(),
            "import circle: {}",
            circle.unwrap().join(" → ")
        );
    }
}

#[test]
fn the_files_of_each_folder_import_no_circle() {
    let graphs = file_graphs();
    assert!(graphs.len() > 10, "read {} folders", graphs.len());
    // The reading sees the edges it must: the horizon map's build uses the outlines.
    assert!(graphs["horizon"]["map"].contains("outline"));
    for (folder, graph) in &graphs {
        let mut done = BTreeSet::new();
        for node in graph.keys() {
            let circle = circle_from(node, graph, &mut Vec::new(), &mut done);
            assert!(
                circle.is_none(),
                "import circle in src/{}: {}",
                folder.replace("::", "/"),
                circle.unwrap().join(" → ")
            );
        }
    }
}

#[test]
fn the_scene_names_no_stage_that_runs() {
    let graph = module_graph();
    let scene = &graph["scene"];
    for stage in [
        "prepare", "simulate", "run", "scatter", "render", "fit", "output", "serve", "report",
        "plan", "bands", "illum",
    ] {
        assert!(!scene.contains(stage), "scene imports {stage}: {scene:?}");
    }
}

#[test]
fn the_circle_finder_finds_a_planted_circle() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec!["a"]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    let circle = circle_from("d", &graph, &mut Vec::new(), &mut BTreeSet::new()).unwrap();
    assert_eq!(circle, ["a", "b", "c", "a"]);
}
