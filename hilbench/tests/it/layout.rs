//! The crate's layout (ARCHITECTURE.md): its top-level modules import one another without a
//! circle, `run` (plain data) imports none of them, the outputs never fly a run, the flags
//! import nothing they configure, and only `main` ends the process; and in every crate of the
//! workspace no file imports one that imports it back.

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
fn the_flags_import_nothing_they_configure() {
    // ripgrep's shape: the flags sit below everything; commands turn them into what flies.
    let graph = imports();
    for above in ["drive", "sweep", "falsification", "fly", "shrink", "output", "commands"] {
        assert!(!graph["cli"].contains(above), "cli imports {above}");
    }
}

/// A file's module path in its crate (`src/sweep/stats.rs` -> `["sweep", "stats"]`, a
/// `mod.rs`, `lib.rs` or `main.rs` its folder's).
fn module_path(src: &Path, path: &Path) -> Vec<String> {
    let rel = path.strip_prefix(src).expect("under src").with_extension("");
    let mut parts: Vec<String> =
        rel.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    if matches!(parts.last().map(String::as_str), Some("mod" | "lib" | "main")) {
        parts.pop();
    }
    parts
}

/// The paths a file's code names (`crate::a::b`, `super::a`, `use crate::a::{b, c}`), resolved
/// to module paths, from `base` (the module `super` is relative to); its tests left out.
fn named_paths(text: &str, base: &[String]) -> Vec<Vec<String>> {
    let code = text.split("#[cfg(test)]\nmod tests").next().unwrap_or_default();
    let ident = |s: &str| -> Vec<String> {
        let mut out = Vec::new();
        for part in s.split("::") {
            let name: String = part.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
            if name.is_empty()
                || name.len() != part.len()
                || !name.starts_with(|c: char| c.is_ascii_lowercase())
            {
                if !name.is_empty() && name.starts_with(|c: char| c.is_ascii_lowercase()) {
                    out.push(name);
                }
                break;
            }
            out.push(name);
        }
        out
    };
    let mut named = Vec::new();
    for line in code.lines().map(str::trim).filter(|l| !l.starts_with("//")) {
        let mut rest = line;
        while let Some(i) = rest.find(['c', 's']) {
            let tail = &rest[i..];
            let boundary = i == 0 || !rest[..i].ends_with(|c: char| c.is_ascii_alphanumeric() || c == '_');
            let (root, after) = if boundary && tail.starts_with("crate::") {
                (Vec::new(), &tail["crate::".len()..])
            } else if boundary && tail.starts_with("super::") {
                let mut after = tail;
                let mut up = 0;
                while let Some(a) = after.strip_prefix("super::") {
                    after = a;
                    up += 1;
                }
                (base[..base.len().saturating_sub(up)].to_vec(), after)
            } else {
                rest = &tail[1..];
                continue;
            };
            let mut path = root.clone();
            path.extend(ident(after));
            named.push(path.clone());
            // `use crate::a::{b, c::d}`: each name in the braces too.
            let prefix_len: usize = after.find('{').unwrap_or(usize::MAX);
            let head = after.get(..prefix_len).unwrap_or_default();
            if head.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':')
                && let Some(inner) = after.get(prefix_len + 1..).and_then(|s| s.split('}').next())
            {
                let mut b = root;
                b.extend(ident(head));
                for item in inner.split(',') {
                    let mut p = b.clone();
                    p.extend(ident(item.trim()));
                    named.push(p);
                }
            }
            rest = after;
        }
    }
    named
}

#[test]
fn no_file_of_any_crate_imports_a_file_that_imports_it_back() {
    // A file and its folder's module (parent and child) may name each other; two files that
    // are not, never: an item that both need is in the wrong one.
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut crates = 0;
    let mut circles = Vec::new();
    let mut entries: Vec<PathBuf> =
        std::fs::read_dir(&root).expect("the workspace").map(|e| e.expect("an entry").path()).collect();
    entries.sort();
    for dir in entries.into_iter().filter(|d| d.join("Cargo.toml").is_file() && d.join("src").is_dir()) {
        crates += 1;
        let src = dir.join("src");
        let modules: BTreeMap<Vec<String>, PathBuf> =
            files(&src).into_iter().map(|p| (module_path(&src, &p), p)).collect();
        let mut edges: BTreeMap<&Vec<String>, BTreeSet<&Vec<String>>> = BTreeMap::new();
        for (module, path) in &modules {
            let text = std::fs::read_to_string(path).expect("a source file");
            let is_folder =
                matches!(path.file_name().and_then(|n| n.to_str()), Some("mod.rs" | "lib.rs" | "main.rs"));
            let base =
                if is_folder { module.clone() } else { module[..module.len().saturating_sub(1)].to_vec() };
            let out = edges.entry(module).or_default();
            for named in named_paths(&text, &base) {
                // The longest prefix that is a file's module.
                let Some(target) =
                    (0..=named.len()).rev().find_map(|k| modules.get_key_value(&named[..k]).map(|(m, _)| m))
                else {
                    continue;
                };
                let related = target.starts_with(module) || module.starts_with(target);
                if !related {
                    out.insert(target);
                }
            }
        }
        // A circle: a file reached again from itself.
        for start in edges.keys() {
            let mut stack = vec![(*start, vec![(*start).clone()])];
            let mut seen = BTreeSet::new();
            while let Some((at, trail)) = stack.pop() {
                for next in edges.get(at).into_iter().flatten() {
                    if next == start {
                        let mut names: Vec<String> = trail.iter().map(|m| m.join("::")).collect();
                        names.push(start.join("::"));
                        circles.push(format!(
                            "{}: {}",
                            dir.file_name().unwrap_or_default().to_string_lossy(),
                            names.join(" -> ")
                        ));
                    } else if seen.insert(*next) {
                        let mut t = trail.clone();
                        t.push((*next).clone());
                        stack.push((*next, t));
                    }
                }
            }
        }
    }
    assert!(crates >= 10, "the workspace's crates were not found ({crates})");
    assert!(circles.is_empty(), "files that import each other:\n{}", circles.join("\n"));
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
