//! The documentation cannot point at what is not there: every repository
//! path named in a Markdown file or in a code comment exists, every relative
//! Markdown link resolves, every Markdown file a comment names by itself
//! exists somewhere in the repository, and the README stays a front page.
//! Files moved or renamed without their mentions fail here, not in a
//! reader's hands.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The repository's root.
fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// Whether a directory holds nothing the repository tracks: build outputs,
/// runs, hidden tool state (`.ci` is tracked).
fn skipped(name: &str) -> bool {
    (name.starts_with('.') && name != ".ci") || ["target", "runs"].contains(&name)
}

/// Every file under `dir`, skipping what [`skipped`] names.
fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir)
        .expect("readable directory")
        .flatten()
    {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if path.is_dir() {
            if !skipped(&name) {
                files(&path, out);
            }
        } else {
            out.push(path);
        }
    }
}

/// The repository's top-level directories: a path naming one of them first
/// is a repository path.
fn top_level(repo: &Path) -> Vec<String> {
    std::fs::read_dir(repo)
        .expect("readable root")
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| !skipped(name))
        .collect()
}

/// The text a file says to readers: all of a Markdown file, the comment
/// lines of code, scripts and configs.
fn prose(path: &Path) -> Option<String> {
    let ext = path.extension()?.to_str()?;
    let text = std::fs::read_to_string(path).ok()?;
    let comment = match ext {
        "md" => return Some(text),
        "rs" => "//",
        "sh" | "toml" | "py" | "yml" => "#",
        _ => return None,
    };
    let lines: Vec<&str> = text
        .lines()
        .filter(|l| l.trim_start().starts_with(comment))
        .collect();
    Some(lines.join("\n"))
}

fn path_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || "_-./".contains(c)
}

/// Every maximal run of path characters in `text` that starts at a word
/// boundary with one of `roots` followed by `/`, without its trailing dots
/// and slashes; templates (`<run>`, `*`, `{a,b}`) are left out.
fn repository_paths(text: &str, roots: &[String]) -> Vec<String> {
    let mut found = Vec::new();
    let chars: Vec<(usize, char)> = text.char_indices().collect();
    for (i, &(at, c)) in chars.iter().enumerate() {
        if i > 0 && path_char(chars[i - 1].1) || !path_char(c) {
            continue;
        }
        let end = chars[i..]
            .iter()
            .find(|(_, c)| !path_char(*c))
            .map_or(text.len(), |&(e, _)| e);
        let token = text[at..end].trim_end_matches(['.', '/']);
        let Some((first, _)) = token.split_once('/') else {
            continue;
        };
        let template = text[end..].starts_with(['<', '*', '{']);
        if roots.iter().any(|r| r == first) && !template {
            found.push(token.to_string());
        }
    }
    found
}

/// Whether `token` is a Cargo feature of a crate at the repository's top
/// (`nets/gpu-torch`), which reads like a path and is none.
fn cargo_feature(repo: &Path, token: &str) -> bool {
    let Some((krate, feature)) = token.split_once('/') else {
        return false;
    };
    let Ok(manifest) = std::fs::read_to_string(repo.join(krate).join("Cargo.toml")) else {
        return false;
    };
    let features = manifest.split("\n[features]").nth(1).unwrap_or("");
    let features = features.split("\n[").next().unwrap_or("");
    features
        .lines()
        .any(|l| l.split('=').next().is_some_and(|k| k.trim() == feature))
}

#[test]
fn every_repository_path_named_in_docs_and_comments_exists() {
    let repo = repo();
    let roots = top_level(&repo);
    let mut all = Vec::new();
    files(&repo, &mut all);
    let mut missing = BTreeSet::new();
    for file in &all {
        let Some(text) = prose(file) else { continue };
        for path in repository_paths(&text, &roots) {
            if !repo.join(&path).exists() && !cargo_feature(&repo, &path) {
                let from = file.strip_prefix(&repo).unwrap().display().to_string();
                missing.insert(format!("{from}: {path}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "paths named that do not exist (move the mention with the file):\n{}",
        missing.into_iter().collect::<Vec<_>>().join("\n")
    );
}

#[test]
fn every_relative_markdown_link_resolves() {
    let repo = repo();
    let mut all = Vec::new();
    files(&repo, &mut all);
    let mut broken = BTreeSet::new();
    for file in all
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "md"))
    {
        let text = std::fs::read_to_string(file).expect("readable Markdown");
        for (at, _) in text.match_indices("](") {
            let rest = &text[at + 2..];
            let Some(end) = rest.find(')') else { continue };
            let target = rest[..end].split('#').next().unwrap_or("");
            if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let dir = file.parent().expect("a file's directory");
            if !dir.join(target).exists() {
                let from = file.strip_prefix(&repo).unwrap().display().to_string();
                broken.insert(format!("{from}: ({target})"));
            }
        }
    }
    assert!(
        broken.is_empty(),
        "Markdown links to nothing:\n{}",
        broken.into_iter().collect::<Vec<_>>().join("\n")
    );
}

#[test]
fn every_markdown_file_a_comment_names_exists() {
    let repo = repo();
    let mut all = Vec::new();
    files(&repo, &mut all);
    let names: BTreeSet<String> = all
        .iter()
        .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    let mut missing = BTreeSet::new();
    for file in all
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e != "md"))
    {
        let Some(text) = prose(file) else { continue };
        for word in text.split(|c: char| !path_char(c)) {
            let word = word.trim_end_matches('.');
            let name = word.rsplit('/').next().unwrap_or(word);
            if name.len() > 3 && name.ends_with(".md") && !names.contains(name) {
                let from = file.strip_prefix(&repo).unwrap().display().to_string();
                missing.insert(format!("{from}: {word}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "Markdown files named in comments that the repository does not hold (its \
         rationale belongs in docs/):\n{}",
        missing.into_iter().collect::<Vec<_>>().join("\n")
    );
}

#[test]
fn the_readme_is_a_front_page() {
    let readme = std::fs::read_to_string(repo().join("README.md")).expect("README.md");
    let lines = readme.lines().count();
    assert!(
        lines <= 250,
        "README.md has {lines} lines: keep it a front page (what it is, run, test, where \
         next) and move the rest to docs/"
    );
}

#[test]
fn the_path_finder_finds_paths_and_leaves_templates() {
    let roots = vec!["docs".to_string(), "actor".to_string()];
    let text = "see docs/a.md, `actor/src/x.rs`. Not xdocs/b.md nor runs/c; \
                docs/notebook/ and actor/<crate> and docs/*.md";
    assert_eq!(
        repository_paths(text, &roots),
        ["docs/a.md", "actor/src/x.rs", "docs/notebook"]
    );
}
