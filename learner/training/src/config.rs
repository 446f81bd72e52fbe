//! The training settings of the two networks, as the learner's config
//! nests them (`[policy]`, `[unet]`): what [`crate::ppo_batcher`] and
//! [`crate::affordance_learner`] read, with their defaults.

use nets::unet::ClassBalance;
use serde::{Deserialize, Serialize};

use crate::ppo::PpoConfig;

/// Episodes whose steps the U-Net's trainer may owe at once: enough for
/// every environment of a large actor ending its episode together (32 at
/// the paper's scale), bounded so that a trainer that cannot keep up does
/// not train on after its frames have long moved on (debt beyond it is
/// forgiven).
pub const MAX_OWED_EPISODES: usize = 64;

/// The policy's training: PPO's own settings (`[policy.ppo]`) and how the
/// learner batches steps for it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct PolicyConfig {
    /// Environment steps (from any actors) per update. The paper used 8
    /// actors × 600 steps; the default fits a 2-core machine's memory and
    /// time at 128 × 128 (each step's observation is ~0.4 MB as floats).
    pub batch_steps: usize,
    /// Batches of steps that may wait for the PPO thread while it updates.
    /// Beyond them the oldest steps are discarded and counted
    /// (`rollout_steps_discarded`), which bounds the policy lag of what is
    /// trained when the learner cannot keep up with the actors.
    pub queue_batches: usize,
    /// The run's seed: initial weights of both networks, minibatch
    /// shuffling and the dataset split.
    pub seed: u64,
    /// Where PPO trains when not where the U-Net does (the learner's
    /// `device`): `cpu` keeps the small policy on the CPU's own training
    /// path (on every core of the rayon pool) while the U-Net trains on the
    /// GPU.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    /// PPO's settings (the paper's, i.e. IntExp's, values by default).
    /// Configs written before 2026-11-29 held them in `[policy]` itself;
    /// such files (a resumed run's config.toml) and `--set policy.KEY`
    /// are read as before.
    pub ppo: PpoConfig,
}

/// Affordance U-Net training on the global dataset of labelled frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct UnetConfig {
    /// Adam learning rate.
    pub learning_rate: f64,
    /// L2 weight decay.
    pub weight_decay: f32,
    /// Frames per gradient step.
    pub batch_frames: usize,
    /// Gradient steps owed for each episode whose frames arrive, paid in
    /// rounds of this many steps (each gated on validation), however many
    /// episodes arrive together (an actor's environments end theirs at
    /// once); a trainer that cannot keep up trains without pause. Before
    /// 2026-11-29 a round took these steps however many episodes it
    /// followed, so the U-Net took about two steps per episode, at 64 px on
    /// 2 cores as at the paper's scale on a GPU
    /// (docs/decisions/0013-unet-steps-per-episode.md). 16 since 2026-11-29
    /// (8 before): per pixel the network learns pick up and push better
    /// (docs/ladder.md, "Sixteen steps an episode").
    pub steps_per_episode: usize,
    /// Episodes whose steps the U-Net may owe before the actors wait: while
    /// it owes more, every actor pauses (the weights it is sent say so)
    /// until the U-Net has caught up, so that it trains its
    /// `steps_per_episode` for every episode on a machine too small for
    /// both (docs/decisions/0013-unet-steps-per-episode.md). 0 never holds
    /// the actors back: a U-Net that cannot keep up then trains fewer
    /// steps per episode.
    pub hold_actors_beyond_episodes: usize,
    /// A training frame leaves the dataset after this many uses (the paper's 35).
    pub max_uses: u32,
    /// Frames held at most; the oldest go first.
    pub max_frames: usize,
    /// Frames with positive labels of an affordance that has positives in
    /// fewer than this share of the training frames are the last that
    /// `max_frames` drops (they still leave after `max_uses`); 0 drops
    /// every frame oldest first. Successful pick-ups are rare (a few dozen
    /// in 10 k steps at 64 px) and get rarer as the policy tries less, so
    /// the newest frames alone hold only the last few of them
    /// (docs/ladder.md, "An average of the recent weights"). Off by default:
    /// at 0.25 it kept a quarter of the training frames with pick-up
    /// positives, and both seeds run ranked objects worse than without it
    /// (docs/ladder.md, "Rare positives kept").
    pub rare_positive_share: f64,
    /// Hold out whole episodes: every frame of an episode goes to the split
    /// its episode draws (with `validation_fraction` and `test_fraction`),
    /// so that the gate and the temperature judge the network on episodes
    /// it never trained on, and the validation frames the gate compares are
    /// spread over the held-out episodes rather than the newest. Off (each
    /// frame draws its own split; the paper splits "the newly generated
    /// dataset" of each episode, which allows either) until whole runs are
    /// measured: with frames drawn one by one, a validation frame's
    /// neighbours in its episode are training frames, so the gate cannot
    /// see a network learning its training rooms by heart (docs/ladder.md,
    /// "Whole episodes held out").
    pub split_by_episode: bool,
    /// Share of new frames that go to validation.
    pub validation_fraction: f64,
    /// Share of new frames that go to test.
    pub test_fraction: f64,
    /// Newest validation frames the gate compares the networks on.
    pub max_validation_frames: usize,
    /// Frames the validation and the test split each keep; older ones move
    /// to training (without a cap, held-out frames pile up while training
    /// frames leave after their uses).
    pub max_held_out_frames: usize,
    /// How each affordance plane's loss weighs positive labels against
    /// negative ones: "classes" (positives and negatives half each, so 0.5
    /// means as likely as not) or "pixels" (the paper's: every labelled
    /// pixel alike, so probabilities follow the labels' share of positives,
    /// 2 to 5 in 1 000 pick-up pixels), or `{ positive-share = A }`
    /// (positives A of it, negatives the rest). The validation gate and the
    /// temperature weigh them the same way
    /// (docs/decisions/0011-class-balanced-loss.md).
    pub class_balance: ClassBalance,
    /// Mirror each training frame left to right (its labels with it) with
    /// probability one half each time a batch takes it: the same rooms seen
    /// from the other side, so that more gradient steps on the few frames
    /// that show a successful pick-up teach what a pickable object looks
    /// like rather than those frames. On by default since 2026-11-29: over
    /// three seeds it kept pick up's pixels and ranked objects better
    /// (docs/decisions/0014-mirrored-training-frames.md); the paper mentions
    /// no augmentation (`configs/paper.toml` turns it off).
    pub mirror_frames: bool,
    /// Gate and deploy an average of the U-Net's recent weights rather than
    /// its latest: each gradient step keeps this share of the average and
    /// adds the rest of the step's weights (0.999 averages over about the
    /// last thousand steps; 0 deploys the latest weights). The average
    /// does not swing from one step to the next the way the weights of a
    /// network trained on a few positive frames do
    /// (`training::weight_average`). Off by default: over three seeds at
    /// 0.999 it ranked objects a little better and drew pixels a little
    /// worse, every range overlapping (docs/ladder.md, "An average of the
    /// recent weights").
    pub weight_average: f64,
    /// A batch normalisation between each of the U-Net's 3 × 3 convolutions
    /// and its ReLU while it trains; the gate, the actors and the
    /// checkpoint's deployed weights get the network with each
    /// normalisation folded into its convolution (`nets::unet`), so nothing
    /// outside training changes. Off until whole runs over seeds decide: an
    /// offline prototype learnt pick up two to four times better per step
    /// (docs/notebook/2026-12-01-unet-batch-norm.md). On libtorch such a
    /// network trains with burn's operations, not the one-operation pass
    /// (`training::unet_train_torch`).
    pub batch_norm: bool,
}

impl Default for PolicyConfig {
    /// PPO's own defaults (`training::ppo::PpoConfig`, written once there)
    /// and the learner's batching.
    fn default() -> Self {
        Self {
            batch_steps: 128,
            queue_batches: 2,
            seed: 0,
            device: None,
            ppo: PpoConfig::default(),
        }
    }
}

impl Default for UnetConfig {
    fn default() -> Self {
        Self {
            learning_rate: 1e-3,
            weight_decay: 1e-4,
            batch_frames: 8,
            steps_per_episode: 16,
            hold_actors_beyond_episodes: 8,
            max_uses: 35,
            max_frames: 4_000,
            rare_positive_share: 0.0,
            split_by_episode: false,
            validation_fraction: 0.15,
            test_fraction: 0.15,
            max_validation_frames: 64,
            max_held_out_frames: 256,
            class_balance: ClassBalance::default(),
            mirror_frames: true,
            weight_average: 0.0,
            batch_norm: false,
        }
    }
}
