//! `learner print-config`: every setting with its default, each under its
//! doc comment, so the printed file explains itself. The comments are the
//! settings' own doc comments (`documented`), so they cannot drift from the
//! code; a setting without one does not compile.

use documented::DocumentedFields;

use crate::config::{LearnerConfig, PolicyConfig, UnetConfig, ValidationConfig};

/// The doc comment of setting `key` in the table at `table` (`[]` for the
/// top level, `["task", "reward"]` for `[task.reward]`).
fn setting_doc(table: &[&str], key: &str) -> Option<&'static str> {
    match table {
        [] => LearnerConfig::get_field_docs(key),
        ["task"] => proto::TaskSpec::get_field_docs(key),
        ["task", "reward"] => proto::RewardWeights::get_field_docs(key),
        ["task", "selection"] => proto::SelectionRule::get_field_docs(key),
        ["task", "confidence"] => proto::ConfidenceRule::get_field_docs(key),
        ["task", "sphere"] => proto::SphereRule::get_field_docs(key),
        ["task", "map"] => proto::MapSettings::get_field_docs(key),
        ["policy"] => PolicyConfig::get_field_docs(key),
        ["policy", "ppo"] => training::ppo::PpoConfig::get_field_docs(key),
        ["unet"] => UnetConfig::get_field_docs(key),
        ["transport"] => transport::TransportConfig::get_field_docs(key),
        ["actors"] => proto::ActorSettings::get_field_docs(key),
        ["validation"] => ValidationConfig::get_field_docs(key),
        _ => return None,
    }
    .ok()
}

fn push_comment(out: &mut String, doc: &str) {
    for line in doc.lines() {
        out.push_str("# ");
        out.push_str(line.trim_end());
        out.push('\n');
    }
}

/// `config` as TOML, each table and setting under its doc comment.
pub fn documented_toml(config: &LearnerConfig) -> String {
    let mut out = String::from(
        "# The learner's settings and their defaults (`learner print-config`). A run's\n\
         # config.toml holds the same keys; `learner serve --config FILE` reads such a file\n\
         # (missing keys take these defaults) and `--set KEY=VALUE` sets one key.\n\n",
    );
    let mut table: Vec<String> = Vec::new();
    for line in config.to_toml().lines() {
        if let Some(header) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            table = header.split('.').map(str::to_string).collect();
            let path: Vec<&str> = table.iter().map(String::as_str).collect();
            if let Some((key, parent)) = path.split_last() {
                if let Some(doc) = setting_doc(parent, key) {
                    push_comment(&mut out, doc);
                }
            }
        } else if let Some((key, _)) = line.split_once(" = ") {
            let path: Vec<&str> = table.iter().map(String::as_str).collect();
            if let Some(doc) = setting_doc(&path, key.trim()) {
                push_comment(&mut out, doc);
            }
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_setting_is_printed_under_its_doc_and_the_text_reads_back() {
        let config = LearnerConfig::default();
        let text = documented_toml(&config);
        assert_eq!(
            toml::from_str::<LearnerConfig>(&text).unwrap(),
            config,
            "comments change nothing"
        );
        let lines: Vec<&str> = text.lines().collect();
        let mut settings = 0;
        for (i, line) in lines.iter().enumerate() {
            let is_setting = line
                .split_once(" = ")
                .is_some_and(|(k, _)| !k.starts_with('#') && !k.starts_with(' ') && !k.is_empty());
            let is_table = line.starts_with('[');
            if is_setting || is_table {
                settings += usize::from(is_setting);
                assert!(
                    i > 0 && lines[i - 1].starts_with("# "),
                    "{line:?} has no doc comment above it:\n{text}"
                );
            }
        }
        assert!(settings > 40, "only {settings} settings printed");
        assert!(text.contains("# Robot profile: a shipped name"), "{text}");
        assert!(text.contains("[actors]"));
    }
}
