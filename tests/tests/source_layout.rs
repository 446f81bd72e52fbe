//! The source tree stays readable in small pieces. No two source files of a
//! crate import each other, directly or in a loop: modules form layers, so
//! each can be read (and changed) knowing only the ones below it. A file's
//! imports are its `crate::…` and `super::…` paths outside comments and
//! outside its `#[cfg(test)]` tail; a path counts as naming the longest
//! module it starts with. And no source file holds more than
//! [`MAX_LINES_BEFORE_TESTS`] lines before its `#[cfg(test)]` tail: a file
//! that grows past it holds more than one job, and small modules with one
//! job each are how this tree is kept.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Every `src/` directory of the workspace's crates.
fn crate_sources(repo: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![repo.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if dir != repo && (name.starts_with('.') || ["target", "runs", "fuzz"].contains(&name)) {
            continue;
        }
        if dir.join("Cargo.toml").is_file() && dir.join("src").is_dir() {
            found.push(dir.join("src"));
        }
        for entry in std::fs::read_dir(&dir)
            .expect("readable directory")
            .flatten()
        {
            if entry.file_type().is_ok_and(|t| t.is_dir()) && entry.file_name() != "src" {
                stack.push(entry.path());
            }
        }
    }
    found.sort();
    found
}

/// The module path of a source file (`a::b` for `src/a/b.rs` or `src/a/b/mod.rs`).
fn module_of(src: &Path, file: &Path) -> String {
    let rel = file
        .strip_prefix(src)
        .expect("under src")
        .with_extension("");
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("lib" | "main" | "mod")
    ) {
        parts.pop();
    }
    parts.join("::")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir)
        .expect("readable directory")
        .flatten()
    {
        let path = entry.path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The code of a file without comments and without its test module.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|line| line.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The identifiers path following each occurrence of `prefix`.
fn paths_after<'a>(code: &'a str, prefix: &'a str) -> impl Iterator<Item = Vec<&'a str>> + 'a {
    code.match_indices(prefix).map(move |(at, _)| {
        let rest = &code[at + prefix.len()..];
        let end = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'))
            .unwrap_or(rest.len());
        rest[..end].split("::").filter(|p| !p.is_empty()).collect()
    })
}

/// Module → the modules of the same crate it imports.
fn import_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeMap<String, PathBuf> = files
        .iter()
        .map(|f| (module_of(src, f), f.clone()))
        .collect();
    let mut graph = BTreeMap::new();
    for (module, file) in &modules {
        let code = code(&std::fs::read_to_string(file).expect("readable source"));
        let parent: Vec<&str> = module.split("::").filter(|p| !p.is_empty()).collect();
        let parent = &parent[..parent.len().saturating_sub(1)];
        let mut imports = BTreeSet::new();
        let candidates = paths_after(&code, "crate::")
            .map(|p| p.iter().map(|s| s.to_string()).collect::<Vec<_>>())
            .chain(paths_after(&code, "super::").map(|p| {
                parent
                    .iter()
                    .map(|s| s.to_string())
                    .chain(p.iter().map(|s| s.to_string()))
                    .collect()
            }));
        for path in candidates {
            let named = (1..=path.len())
                .rev()
                .map(|k| path[..k].join("::"))
                .find(|m| modules.contains_key(m));
            if let Some(named) = named {
                let related = named == *module
                    || module.starts_with(&format!("{named}::"))
                    || named.starts_with(&format!("{module}::"));
                if !related {
                    imports.insert(named);
                }
            }
        }
        graph.insert(module.clone(), imports);
    }
    graph
}

/// A loop of imports, if there is one.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        Open,
        Done,
    }
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        marks: &mut BTreeMap<String, Mark>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        marks.insert(node.to_string(), Mark::Open);
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            match marks.get(next) {
                Some(Mark::Open) => {
                    let start = path.iter().position(|p| p == next).expect("on the path");
                    let mut cycle = path[start..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Some(Mark::Done) => {}
                None => {
                    if let Some(cycle) = visit(next, graph, marks, path) {
                        return Some(cycle);
                    }
                }
            }
        }
        path.pop();
        marks.insert(node.to_string(), Mark::Done);
        None
    }
    let mut marks = BTreeMap::new();
    for node in graph.keys() {
        if !marks.contains_key(node) {
            if let Some(cycle) = visit(node, graph, &mut marks, &mut Vec::new()) {
                return Some(cycle);
            }
        }
    }
    None
}

#[test]
fn no_two_files_of_a_crate_import_each_other() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let sources = crate_sources(&repo);
    assert!(sources.len() >= 9, "found the crates: {sources:?}");
    let cycles: Vec<String> = sources
        .iter()
        .filter_map(|src| {
            find_cycle(&import_graph(src)).map(|c| format!("{}: {}", src.display(), c.join(" → ")))
        })
        .collect();
    assert!(cycles.is_empty(), "import loops:\n{}", cycles.join("\n"));
}

#[test]
fn the_check_finds_a_loop_of_three() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec!["a"]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    let cycle = find_cycle(&graph).expect("a loop");
    assert_eq!(cycle.len(), 4, "{cycle:?}");
    let mut without = graph.clone();
    without.get_mut("c").unwrap().clear();
    assert_eq!(find_cycle(&without), None);
}

/// The most lines a crate's source file may hold before its tests.
const MAX_LINES_BEFORE_TESTS: usize = 600;

/// Lines of a file before its `#[cfg(test)]` tail (all of them without one).
fn lines_before_tests(text: &str) -> usize {
    text.lines()
        .take_while(|line| line.trim() != "#[cfg(test)]")
        .count()
}

#[test]
fn no_source_file_grows_past_its_limit_before_its_tests() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut too_long = Vec::new();
    let mut files = 0;
    for src in crate_sources(&repo) {
        let mut paths = Vec::new();
        rust_files(&src, &mut paths);
        for path in paths {
            files += 1;
            let text = std::fs::read_to_string(&path).expect("readable source");
            let lines = lines_before_tests(&text);
            if lines > MAX_LINES_BEFORE_TESTS {
                too_long.push(format!("{} ({lines} lines)", path.display()));
            }
        }
    }
    assert!(files > 100, "found only {files} source files");
    assert!(
        too_long.is_empty(),
        "over {MAX_LINES_BEFORE_TESTS} lines before their tests (split each by job): {too_long:?}"
    );
}

#[test]
fn lines_before_tests_stop_at_the_test_module() {
    let text = "fn a() {}\n\nfn b() {}\n#[cfg(test)]\nmod tests {\n}\n";
    assert_eq!(lines_before_tests(text), 3);
    assert_eq!(lines_before_tests("fn a() {}\nfn b() {}\n"), 2);
}
