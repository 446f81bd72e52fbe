//! How the runs differ from the paper, in words the results page prints:
//! the scale, the reward, the labels, the baselines, the test set and every
//! setting that `configs/paper.toml` sets otherwise.

use std::fmt::Write as _;

use super::Comparison;

pub(super) fn differences(out: &mut String, comparison: &Comparison) {
    let m = &comparison.manifest;
    let _ = writeln!(
        out,
        "## How these runs differ from the paper\n\n\
         - **Simulator**: this project's own (iTHOR rooms' metadata, rapier physics, its own \
         renderer and robot profile), not AI2-THOR; pick up and push succeed by its rules \
         (`actor/sim/src/affordances.rs`). The paper's numbers are a reference for the methods' order, not values to \
         match.\n\
         - **Scale**: `{}`, {} steps per run; the paper trained at 128 px with 600-step \
         episodes for about 1 M steps (8 parallel environments).\n\
         - **Reward**: {}\n\
         - **Both affordances in one run** (one U-Net plane and one set of selection actions \
         each); the paper trained one affordance per run.\n\
         - **Background labels**: `ours` and `nomap-seg` also label what the segmentation calls \
         floor and wall negative; the paper did not. `ours-paper-labels` (when run) is `ours` \
         under the paper's rule (`background_negative = false`), comparable with the baselines \
         that cannot have background labels.\n\
         - **No-map baselines** (`nomap-seg`, `nomap-noseg`) keep a GRU memory of 512 instead of \
         the map; their segments are the simulator's instance masks (the paper's NoMap+Seg used \
         segmentation too).\n\
         - **IntExp** is this project's reimplementation inside the same framework, not \
         Nagarajan et al.'s code: the same PPO, U-Net, reward and action space as the others; \
         its state is RGB, affordances and inventory with a GRU memory; it selects the \
         most-centred object and labels 0.2 m spheres around interaction points (IntExp(PT)), \
         as does `nomap-noseg`.\n\
         - **Test set**: Table 1's views are random reachable poses (objects on at least 10 % \
         of the image) rather than the paper's 611 manually steered frames; Table 2 tries every \
         object from the nearest position that reaches it, and judges objects no position \
         reaches by the simulator's rules (the paper placed the robot in front of each of its \
         236 objects).\n\
         - **Settings that differ from `configs/paper.toml`** (the paper's method as written; \
         the reasons are in docs/decisions/): {}.\n",
        m.local_options,
        m.steps,
        reward_line(comparison.first_config.as_deref()),
        settings_line(comparison.first_config.as_deref())
    );
}

/// When the `ours` runs' confidence labels started, if they did.
pub(super) fn confidence_line(after_steps: u64, steps: u64) -> String {
    if after_steps >= steps {
        return "off (`deploy/reproduce.sh --confidence-fraction off`): while the network \
                over-calls, labels by confidence cost the ranking (docs/ladder.md), so the \
                evaluated `ours` networks learnt from interaction labels alone"
            .to_string();
    }
    format!(
        "from step {after_steps} ({:.0} % of the budget: the paper switches them on at 400 k \
         steps of its ~1 M, so every evaluated `ours` network has both of its labelling \
         mechanisms)",
        100.0 * after_steps as f64 / steps.max(1) as f64
    )
}

/// The first run's settings that `configs/paper.toml` sets otherwise.
fn settings_line(config: Option<&str>) -> String {
    match config.and_then(super::paper_settings::differences_from_paper) {
        None => "unknown (the first run has no readable config.toml)".to_string(),
        Some(lines) if lines.is_empty() => "none".to_string(),
        Some(lines) => lines.join("; "),
    }
}

/// The reward weights the runs trained with, as the first run's
/// `config.toml` says (every run of a comparison shares its task).
fn reward_line(config: Option<&str>) -> String {
    let weights = config
        .and_then(|text| text.parse::<toml::Table>().ok())
        .and_then(|table| table.get("task")?.get("reward").cloned())
        .and_then(|reward| reward.try_into::<proto::RewardWeights>().ok());
    let Some(w) = weights else {
        return "the runs' weights are unknown (the first run has no readable config.toml)"
            .to_string();
    };
    let mut line = format!(
        "weights α = ({}, {}, {}) for every method",
        w.navigation, w.interaction, w.failure
    );
    if let Some(a) = w.pick_up_interaction {
        line += &format!(", α2 = {a} for pick-ups");
    }
    if let Some(a) = w.push_interaction {
        line += &format!(", α2 = {a} for pushes");
    }
    if w.first_try != 0.0 {
        line += &format!(", {} for each first try that labels an object", w.first_try);
    }
    if w == proto::RewardWeights::PAPER {
        line += " (the paper's)";
    } else {
        line += ", not the paper's (1, 1, 1) (docs/decisions/0001-reward-weights.md: with the \
                 paper's the policy stopped interacting here)";
    }
    line + "."
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reward_line_says_what_the_runs_trained_with() {
        let config = "seed = 1\n[task]\nmethod = \"ours\"\n[task.reward]\nnavigation = 0.1\n\
                      interaction = 2.0\nfailure = 0.05\n";
        let line = reward_line(Some(config));
        assert!(
            line.starts_with("weights α = (0.1, 2, 0.05) for every method, not the paper's"),
            "{line}"
        );
        let paper = "[task.reward]\nnavigation = 1.0\ninteraction = 1.0\nfailure = 1.0\n";
        assert!(reward_line(Some(paper)).ends_with("(the paper's)."));
        let split = "[task.reward]\nnavigation = 0.25\ninteraction = 2.0\nfailure = 0.05\n\
                     pick_up_interaction = 6.0\n";
        assert!(reward_line(Some(split)).contains(", α2 = 6 for pick-ups"));
        let first_try = "[task.reward]\nfirst_try = 0.5\n";
        assert!(reward_line(Some(first_try)).contains(", 0.5 for each first try that labels"));
        assert!(reward_line(None).contains("unknown"));
        assert!(reward_line(Some("not toml [")).contains("unknown"));
    }
}
