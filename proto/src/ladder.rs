//! The label ladder's dataset (`actor --dataset`, `learner train-unet`): an
//! `ours` run's frames, each with three label sources side by side, so that
//! the U-Net can be trained offline on each one and the rung where the
//! pick-up signal is lost found (`docs/ladder.md`).
//!
//! A dataset directory holds the run's `config.toml` (the task, the U-Net's
//! settings) and `episodes/*.frames`: each file one episode's frames as an
//! encoded [`crate::FrameBatch`] message whose planes are rung-major: for
//! rung `r` (in [`LabelRung::ALL`]'s order) and affordance `a` of the task's
//! `A`, plane `r · A + a`.

use std::ops::Range;

/// The dataset's directory of episode files.
pub const DATASET_EPISODES_DIR: &str = "episodes";
/// The extension of an episode file.
pub const DATASET_EPISODE_EXTENSION: &str = "frames";

/// One label source of the ladder, from the most to the least informed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum LabelRung {
    /// L0: the simulator's ground truth for every object in view (and the
    /// background negative, as the run labels it): what the network could
    /// learn from these frames at best.
    GroundTruth,
    /// L1: ground truth only for the objects the agent tried (every
    /// attempt, also those beyond reach), spread over each such map
    /// object's pixels in every frame as the labeler spreads outcomes:
    /// perfect outcomes on the objects the policy chose.
    TriedTruth,
    /// L2: the run's own labels, exactly as its labeler sent them.
    Run,
}

impl LabelRung {
    /// Every rung, in plane order.
    pub const ALL: [Self; 3] = [Self::GroundTruth, Self::TriedTruth, Self::Run];

    /// The rung's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::GroundTruth => "ground-truth",
            Self::TriedTruth => "tried-truth",
            Self::Run => "run",
        }
    }

    /// The rung's short name (L0, L1, L2).
    pub fn short(self) -> &'static str {
        match self {
            Self::GroundTruth => "L0",
            Self::TriedTruth => "L1",
            Self::Run => "L2",
        }
    }

    /// The rung's planes among a dataset frame's, for a task of
    /// `affordances` affordances.
    pub fn planes(self, affordances: usize) -> Range<usize> {
        let r = self as usize;
        r * affordances..(r + 1) * affordances
    }
}

impl std::fmt::Display for LabelRung {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for LabelRung {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|r| r.name() == s || r.short().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                format!(
                    "unknown label source '{s}': ground-truth (L0), tried-truth (L1) or run (L2)"
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rungs_parse_by_name_and_short_name_and_own_disjoint_planes() {
        for rung in LabelRung::ALL {
            assert_eq!(rung.name().parse::<LabelRung>(), Ok(rung));
            assert_eq!(rung.short().to_lowercase().parse::<LabelRung>(), Ok(rung));
        }
        assert!("l3".parse::<LabelRung>().is_err());
        assert_eq!(LabelRung::GroundTruth.planes(2), 0..2);
        assert_eq!(LabelRung::TriedTruth.planes(2), 2..4);
        assert_eq!(LabelRung::Run.planes(2), 4..6);
    }
}
