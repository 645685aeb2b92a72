//! The crate's layout (ARCHITECTURE.md): its top-level modules import one another without a
//! circle, `run` (plain data) imports none of them, the outputs never fly a run, and only
//! `main` ends the process.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).expect("src") {
        let path = entry.expect("an entry").path();
        if path.is_dir() {
            out.extend(files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out
}

/// The top-level module a file of `src/` belongs to (`output/plots/top.rs` -> `output`).
fn module_of(path: &Path) -> String {
    let rel = path.strip_prefix(src()).expect("under src");
    let first = rel.components().next().expect("a component").as_os_str().to_string_lossy().to_string();
    first.trim_end_matches(".rs").to_string()
}

/// The crate's modules each module names (`crate::x`, or `super::x` from a module's root file
/// for none: `super` stays inside the module), comments left out.
fn imports() -> BTreeMap<String, BTreeSet<String>> {
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for path in files(&src()) {
        let module = module_of(&path);
        let text = std::fs::read_to_string(&path).expect("a source file");
        let used = graph.entry(module.clone()).or_default();
        for line in text.lines().map(str::trim).filter(|l| !l.starts_with("//")) {
            for (i, _) in line.match_indices("crate::") {
                let rest = &line[i + "crate::".len()..];
                let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if !name.is_empty() && name != module {
                    used.insert(name);
                }
            }
        }
    }
    graph
}

#[test]
fn no_module_imports_one_that_imports_it_back() {
    let graph = imports();
    // Depth-first search for a circle, reporting it.
    fn visit(
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
            if let Some(circle) = visit(next, graph, path, done) {
                return Some(circle);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    for node in graph.keys() {
        if let Some(circle) = visit(node, &graph, &mut Vec::new(), &mut done) {
            panic!("an import circle: {}", circle.join(" -> "));
        }
    }
    assert!(graph.len() >= 8, "the modules were not found: {graph:?}");
}

#[test]
fn run_is_plain_data_and_outputs_never_fly() {
    let graph = imports();
    let run: Vec<_> = graph["run"].iter().filter(|m| *m != "scenario_file").collect();
    assert!(run.is_empty(), "run imports {run:?}");
    for flying in ["drive", "fly", "commands", "sweep", "falsification", "shrink"] {
        assert!(!graph["output"].contains(flying), "output imports {flying}");
    }
    for above in ["output", "fly", "commands", "sweep", "falsification", "shrink", "cli"] {
        assert!(!graph["drive"].contains(above), "drive imports {above}");
    }
}

#[test]
fn only_main_ends_the_process() {
    for path in files(&src()) {
        let text = std::fs::read_to_string(&path).expect("a source file");
        if path.ends_with("main.rs") {
            continue;
        }
        assert!(!text.contains("process::exit"), "{} calls process::exit", path.display());
    }
}
