//! Where a comparison's settings differ from the paper's method as written
//! (`configs/paper.toml`), so that the results page names every default of
//! this project that the paper did not have (the class-balanced loss, the
//! mirrored frames, selection within reach, …) instead of leaving the reader
//! to diff two config files.

use std::fmt::Write;

/// The paper's settings, as the repository holds them.
const PAPER_CONFIG: &str = include_str!("../../../configs/paper.toml");

/// One line per setting of `configs/paper.toml` that `run_config` (a run's
/// `config.toml`) sets otherwise or leaves to its default, as
/// `` `section.key = run value` (the paper's: value) ``, sorted by section
/// and key. `None` if `run_config` is not TOML.
pub(crate) fn differences_from_paper(run_config: &str) -> Option<Vec<String>> {
    let paper: toml::Table = PAPER_CONFIG
        .parse()
        .expect("configs/paper.toml is TOML (a unit test reads it)");
    let run: toml::Table = run_config.parse().ok()?;
    let mut lines = Vec::new();
    compare("", &paper, Some(&run), &mut lines);
    Some(lines)
}

fn compare(prefix: &str, paper: &toml::Table, run: Option<&toml::Table>, lines: &mut Vec<String>) {
    for (key, paper_value) in paper {
        let path = format!("{prefix}{key}");
        let run_value = run.and_then(|r| r.get(key));
        if let toml::Value::Table(paper_table) = paper_value {
            let run_table = run_value.and_then(toml::Value::as_table);
            compare(&format!("{path}."), paper_table, run_table, lines);
            continue;
        }
        let mut line = String::new();
        match run_value {
            Some(v) if same(v, paper_value) => continue,
            Some(v) => {
                let _ = write!(line, "`{path} = {v}`");
            }
            None => {
                let _ = write!(line, "`{path}` unset (the method's default)");
            }
        }
        let _ = write!(line, " (the paper's: {paper_value})");
        lines.push(line);
    }
}

/// Equal as settings: an integer and a float of the same value are the same number.
fn same(a: &toml::Value, b: &toml::Value) -> bool {
    let number = |v: &toml::Value| match v {
        toml::Value::Integer(i) => Some(*i as f64),
        toml::Value::Float(f) => Some(*f),
        _ => None,
    };
    match (number(a), number(b)) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_papers_own_settings_differ_in_nothing() {
        assert_eq!(differences_from_paper(PAPER_CONFIG), Some(Vec::new()));
    }

    #[test]
    fn each_setting_set_otherwise_or_left_unset_is_named_with_the_papers_value() {
        let mut run: toml::Table = PAPER_CONFIG.parse().unwrap();
        let unet = run["unet"].as_table_mut().unwrap();
        unet.insert("class_balance".into(), "classes".into());
        unet.insert("mirror_frames".into(), true.into());
        let task = run["task"].as_table_mut().unwrap();
        task.remove("background_negative");
        // The same number written as an integer is no difference.
        task["reward"]
            .as_table_mut()
            .unwrap()
            .insert("navigation".into(), 1.into());
        let lines = differences_from_paper(&toml::to_string(&run).unwrap()).unwrap();
        assert_eq!(
            lines,
            [
                "`task.background_negative` unset (the method's default) (the paper's: false)",
                "`unet.class_balance = \"classes\"` (the paper's: \"pixels\")",
                "`unet.mirror_frames = true` (the paper's: false)",
            ]
        );
        assert_eq!(differences_from_paper("not toml ["), None);
    }
}
