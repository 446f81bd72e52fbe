//! The validation gate: a trained U-Net replaces the deployed one only if its
//! loss on the newest validation frames is lower.
//!
//! Why a module: a round of U-Net training ends with the gate, and on 2
//! cores the gate and the temperature refit took a quarter of the U-Net
//! thread's time (on an H200 a round took seconds around 0.3 s of gradient
//! steps; docs/notebook/2026-12-01-gate-scores-kept.md): both networks ran
//! on every gate frame, and a replacement ran the new network over them once
//! more for its temperature. The deployed network changes only when it is replaced, and
//! the gate's frames only as new episodes arrive, so [`Gate`] keeps the
//! deployed network's score per frame and computes it only for frames it has
//! not scored; after a replacement the candidate's scores are the deployed
//! network's. The candidate's logits come back with the decision, for the
//! temperature refit on the same frames.

use std::sync::Arc;

use burn::prelude::Device;
use nets::unet::{AffordanceUnet, ClassBalance};
use nets::unet_inference::UnetInference;

use crate::affordance::{score_frames, Evaluation, FrameScore, LabelledFrame};

/// The outcome of comparing a candidate network with the deployed one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GateDecision {
    /// True if the candidate should replace the deployed network.
    pub replace: bool,
    /// The candidate on the gate's frames.
    pub candidate: Evaluation,
    /// The deployed network on the same frames.
    pub deployed: Evaluation,
}

/// A gate's decision with the candidate's logits on each of its frames
/// (`[affordances, h, w]`, row-major, in the frames' order).
pub struct GateOutcome {
    /// The decision.
    pub decision: GateDecision,
    /// The candidate's logits per frame.
    pub candidate_logits: Vec<Vec<f32>>,
}

/// The gate with the deployed network's scores kept between rounds.
///
/// Its scores belong to the network it last judged as deployed: call
/// [`Gate::forget`] whenever the deployed network is set by other means (a
/// restored checkpoint).
#[derive(Default)]
pub struct Gate {
    /// The deployed network's score per frame it has scored (frames held,
    /// so that a frame's address names it while it is here).
    deployed_scores: Vec<(Arc<LabelledFrame>, FrameScore)>,
}

impl Gate {
    /// Forgets the deployed network's scores (it was replaced from outside).
    pub fn forget(&mut self) {
        self.deployed_scores.clear();
    }

    /// Scores `candidate` on every one of `frames` and `deployed` on those it
    /// has no score for, and decides: the candidate replaces the deployed
    /// network only if its mean masked BCE + Dice loss is lower. With no
    /// frames nothing is replaced (there is no evidence). On a replacement
    /// the candidate's scores are kept as the deployed network's.
    pub fn decide(
        &mut self,
        candidate: &AffordanceUnet,
        deployed: &AffordanceUnet,
        frames: &[Arc<LabelledFrame>],
        balance: ClassBalance,
        device: &Device,
    ) -> GateOutcome {
        let refs: Vec<&LabelledFrame> = frames.iter().map(|f| f.as_ref()).collect();
        let candidate_net = UnetInference::new(candidate.clone(), device);
        let (candidate_scores, candidate_logits) = score_frames(&candidate_net, &refs, balance);
        let known: Vec<Option<FrameScore>> = frames
            .iter()
            .map(|frame| {
                self.deployed_scores
                    .iter()
                    .find(|(seen, _)| Arc::ptr_eq(seen, frame))
                    .map(|(_, score)| *score)
            })
            .collect();
        let unscored: Vec<&LabelledFrame> = refs
            .iter()
            .zip(&known)
            .filter(|(_, score)| score.is_none())
            .map(|(frame, _)| *frame)
            .collect();
        let mut fresh = if unscored.is_empty() {
            Vec::new()
        } else {
            let deployed_net = UnetInference::new(deployed.clone(), device);
            score_frames(&deployed_net, &unscored, balance).0
        }
        .into_iter();
        let deployed_scores: Vec<FrameScore> = known
            .into_iter()
            .map(|score| {
                score.unwrap_or_else(|| fresh.next().expect("one score per unscored frame"))
            })
            .collect();
        let (candidate_score, deployed_score) = (
            Evaluation::from_scores(&candidate_scores),
            Evaluation::from_scores(&deployed_scores),
        );
        let decision = GateDecision {
            replace: !frames.is_empty() && candidate_score.loss < deployed_score.loss,
            candidate: candidate_score,
            deployed: deployed_score,
        };
        let kept = if decision.replace {
            candidate_scores
        } else {
            deployed_scores
        };
        self.deployed_scores = frames.iter().cloned().zip(kept).collect();
        GateOutcome {
            decision,
            candidate_logits,
        }
    }
}

/// The gate once, with nothing kept: both networks on `frames`.
pub fn validation_gate(
    candidate: &AffordanceUnet,
    deployed: &AffordanceUnet,
    frames: &[Arc<LabelledFrame>],
    balance: ClassBalance,
    device: &Device,
) -> GateDecision {
    Gate::default()
        .decide(candidate, deployed, frames, balance, device)
        .decision
}
