//! What a run trains: the environment, the method, the affordances and the
//! image size. The learner and every actor read it from the run config's
//! `[task]` table and derive the policy's input layout and action count from
//! it here, in one place, so the two sides cannot disagree about shapes.

use serde::{Deserialize, Serialize};

use crate::method::{Method, Selection};
use crate::rules::{ConfidenceRule, MapSettings, SelectionRule, SphereRule};
use crate::ObsDtype;

/// What the robot can try on an object.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Affordance {
    /// Pick the object up.
    PickUp = 0,
    /// Push the object.
    Push = 1,
    /// A fake third affordance, compiled into this crate's own tests only
    /// (`third_affordance`): it proves that a new affordance is added here,
    /// in the task's definition, and crosses the wire with no change there.
    #[cfg(test)]
    Open = 2,
}

impl Affordance {
    /// How many there are.
    #[cfg(not(test))]
    pub const COUNT: usize = 2;
    /// How many there are (with the fake third of this crate's tests).
    #[cfg(test)]
    pub const COUNT: usize = 3;
    /// Every affordance, in index order.
    #[cfg(not(test))]
    pub const ALL: [Affordance; Self::COUNT] = [Affordance::PickUp, Affordance::Push];
    /// Every affordance, in index order (with the fake third of this crate's tests).
    #[cfg(test)]
    pub const ALL: [Affordance; Self::COUNT] =
        [Affordance::PickUp, Affordance::Push, Affordance::Open];

    /// Its code on the wire (and its index in per-affordance arrays).
    pub fn code(self) -> u32 {
        self as u32
    }

    /// The affordance with wire code `code`, if any.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|a| a.code() == code)
    }

    /// snake_case name, as in configs and metrics.
    pub fn as_str(self) -> &'static str {
        match self {
            Affordance::PickUp => "pick_up",
            Affordance::Push => "push",
            #[cfg(test)]
            Affordance::Open => "open",
        }
    }
}

/// Which environment the actors run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EnvKind {
    /// The simulator with map, U-Net and labeler: the real task.
    Sim,
    /// A deterministic contextual bandit: a wiring test fixture.
    BanditFixture,
}

/// Observation length of the bandit fixture (one-hot context).
pub const BANDIT_OBS_DIM: usize = 8;
/// Actions of the bandit fixture.
pub const BANDIT_ACTIONS: usize = 4;
/// Navigation actions of the simulator's action space.
pub const NAV_ACTIONS: usize = 5;
/// Moves of a held object (± 0.1 m along three axes).
pub const HAND_MOVES: usize = 6;
/// GRU hidden size of the methods without a map (IntExp: one layer of 512).
pub const DEFAULT_MEMORY_SIZE: usize = 512;

/// The α weights of the reward R = α1·R_nav + α2·R_int + α3·R_fail.
///
/// The paper leaves them as settings (1, 1, 1 unless tuning shows better:
/// [`RewardWeights::PAPER`]). The default is the tuned (0.25, 2, 0.05): in
/// these rooms about nine interactions in ten fail at first, and with the
/// paper's weights, or with only α1 or only α3 lowered, PPO learns to stop
/// trying them (docs/decisions/0001-reward-weights.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct RewardWeights {
    /// α1, navigation novelty.
    pub navigation: f32,
    /// α2, new successful interactions.
    pub interaction: f32,
    /// α3, failed actions (R_fail is −1, so a positive α3 penalises).
    pub failure: f32,
    /// α2 for successful pick-ups alone, in place of `interaction` (unset:
    /// `interaction`). Pick-ups succeed less often than pushes, so under one
    /// α2 policies learn to push (docs/notebook/2026-11-26-reproduction.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pick_up_interaction: Option<f32>,
    /// α2 for successful pushes alone, in place of `interaction` (unset:
    /// `interaction`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub push_interaction: Option<f32>,
    /// Reward for the first attempt of each affordance on an object
    /// instance whose outcome tells the affordance (a success, or a failure
    /// of the object itself): the outcome labels the object either way, so
    /// trying an untried object pays even when it fails. 0 is the paper's
    /// reward, which pays successes only.
    pub first_try: f32,
}

impl RewardWeights {
    /// The paper's weights, (1, 1, 1).
    pub const PAPER: Self = Self {
        navigation: 1.0,
        interaction: 1.0,
        failure: 1.0,
        pick_up_interaction: None,
        push_interaction: None,
        first_try: 0.0,
    };

    /// α2 for a success of `affordance`.
    pub fn interaction_for(&self, affordance: Affordance) -> f32 {
        let own = match affordance {
            Affordance::PickUp => self.pick_up_interaction,
            Affordance::Push => self.push_interaction,
            #[cfg(test)]
            Affordance::Open => None,
        };
        own.unwrap_or(self.interaction)
    }
}

impl Default for RewardWeights {
    fn default() -> Self {
        Self {
            navigation: 0.25,
            interaction: 2.0,
            failure: 0.05,
            pick_up_interaction: None,
            push_interaction: None,
            first_try: 0.0,
        }
    }
}

/// The run's task.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct TaskSpec {
    /// Environment of the actors.
    pub env: EnvKind,
    /// Method (what the state holds, how labels are made).
    pub method: Method,
    /// Affordances tried and learnt, each once, in plane order.
    pub affordances: Vec<Affordance>,
    /// Side of the camera images and of the 2-D maps, pixels (128 in the paper).
    pub image_size: usize,
    /// Steps per episode (600 in the paper).
    pub episode_steps: usize,
    /// Send only frames with both positive and negative labels (the paper's
    /// rule); off, every frame with any label is sent.
    pub balanced_frames: bool,
    /// Environment steps of the whole run (all actors) after which annotation
    /// by confidence starts (the paper's 400 000; method `ours` only).
    pub confidence_after_steps: u64,
    /// Label what the segmentation calls background (floor, walls) negative
    /// for every affordance, in every frame that gets labels (methods with
    /// segmentation: `ours`, `nomap-seg`). Unset: on for those methods, off
    /// for the others (see [`TaskSpec::labels_background`]). `false` is the
    /// paper's rule, which labels object masks only and leaves the network
    /// free to call the floor pushable.
    pub background_negative: Option<bool>,
    /// Object selection's filter of low-confidence objects (the paper gives
    /// no threshold): an object whose mean predicted probability for the
    /// affordance is below this loses its grid cell to any object above it;
    /// a cell with none above it takes the object rated highest.
    pub selection_confidence: f32,
    /// GRU hidden size of the methods without a map (512 as in IntExp).
    pub memory_size: usize,
    /// The reward's α weights (`[task.reward]`).
    pub reward: RewardWeights,
    /// Object selection's grid and most-centred object.
    pub selection: SelectionRule,
    /// Thresholds of annotation by confidence (`ours`).
    pub confidence: ConfidenceRule,
    /// The point labels of the methods without a map.
    pub sphere: SphereRule,
    /// The object-level map (`ours`).
    pub map: MapSettings,
}

impl Default for TaskSpec {
    fn default() -> Self {
        Self {
            env: EnvKind::Sim,
            method: Method::Ours,
            affordances: vec![Affordance::PickUp, Affordance::Push],
            image_size: 128,
            episode_steps: 600,
            balanced_frames: true,
            confidence_after_steps: 400_000,
            background_negative: None,
            selection_confidence: 0.05,
            memory_size: DEFAULT_MEMORY_SIZE,
            reward: RewardWeights::default(),
            selection: SelectionRule::default(),
            confidence: ConfidenceRule::default(),
            sphere: SphereRule::default(),
            map: MapSettings::default(),
        }
    }
}

/// Shapes of the policy's inputs: image-like inputs first, then vectors,
/// concatenated in this order in a rollout's flat observation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PolicyLayout {
    /// Channels of each image-like input, all `image_size` square.
    pub image_channels: Vec<usize>,
    /// Side of the image-like inputs.
    pub image_size: usize,
    /// Length of each vector input.
    pub vector_dims: Vec<usize>,
    /// Actions of the head.
    pub n_actions: usize,
    /// Element type on the wire: images in 0..1 travel as bytes.
    pub obs_dtype: ObsDtype,
    /// Hidden size of a GRU over the fused features (methods without a map), or `None`.
    pub gru_hidden: Option<usize>,
}

impl PolicyLayout {
    /// Elements of one flat observation.
    pub fn obs_len(&self) -> usize {
        self.input_widths().sum()
    }

    /// Elements of each input in one flat observation, in its order: every
    /// image (channels · side²), then every vector.
    pub fn input_widths(&self) -> impl Iterator<Item = usize> + '_ {
        let pixels = self.image_size * self.image_size;
        self.image_channels
            .iter()
            .map(move |&c| c * pixels)
            .chain(self.vector_dims.iter().copied())
    }
}

/// Why a task cannot run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TaskError {
    /// No affordance, or one listed twice.
    #[error("task.affordances must list pick_up and/or push, each once")]
    Affordances,
    /// The image is too small for the policy's convolutions or not a multiple of 16 (the U-Net halves it four times).
    #[error("task.image_size {0} must be a multiple of 16 and at least 48")]
    ImageSize(usize),
    /// No steps.
    #[error("task.episode_steps must be at least 1")]
    EpisodeSteps,
    /// A reward weight that is not a finite number.
    #[error("task.reward weights must be finite numbers")]
    RewardWeights,
    /// A GRU without units.
    #[error("task.memory_size must be at least 1 (the GRU of the methods without a map)")]
    MemorySize,
    /// Background labels asked of a method that segments nothing.
    #[error(
        "task.background_negative needs a method with segmentation (ours, nomap-seg), not {0}"
    )]
    BackgroundWithoutSegmentation(&'static str),
    /// A selection threshold that is not a probability.
    #[error("task.selection_confidence {0} must be a probability, between 0 and 1")]
    SelectionConfidence(f32),
    /// Cell ratings asked of a method without the grid.
    #[error("task.selection.ratings_in_state needs the grid selection (ours, nomap-seg, nomap-noseg), not {0}")]
    RatingsWithoutGrid(&'static str),
    /// A selection, label or map rule outside what it can mean.
    #[error(transparent)]
    Rule(#[from] crate::rules::RuleError),
}

impl TaskSpec {
    /// Checks that the task can run.
    pub fn validate(&self) -> Result<(), TaskError> {
        if self.env == EnvKind::BanditFixture {
            return Ok(());
        }
        let mut sorted = self.affordances.clone();
        sorted.sort_unstable();
        sorted.dedup();
        if self.affordances.is_empty() || sorted.len() != self.affordances.len() {
            return Err(TaskError::Affordances);
        }
        if self.image_size < 48 || !self.image_size.is_multiple_of(16) {
            return Err(TaskError::ImageSize(self.image_size));
        }
        if self.episode_steps == 0 {
            return Err(TaskError::EpisodeSteps);
        }
        let r = self.reward;
        if ![r.navigation, r.interaction, r.failure, r.first_try]
            .into_iter()
            .chain(r.pick_up_interaction)
            .chain(r.push_interaction)
            .all(|w| w.is_finite())
        {
            return Err(TaskError::RewardWeights);
        }
        if self.memory_size == 0 {
            return Err(TaskError::MemorySize);
        }
        if !(0.0..=1.0).contains(&self.selection_confidence) {
            return Err(TaskError::SelectionConfidence(self.selection_confidence));
        }
        if self.background_negative == Some(true) && !self.method.segments() {
            return Err(TaskError::BackgroundWithoutSegmentation(
                self.method.as_str(),
            ));
        }
        if self.selection.ratings_in_state && self.method.spec().selection != Selection::Grid {
            return Err(TaskError::RatingsWithoutGrid(self.method.as_str()));
        }
        crate::rules::validate_all(&self.selection, &self.confidence, &self.sphere, &self.map)?;
        Ok(())
    }

    /// Whether labelled frames get negative labels on the segmentation's
    /// background: as set, else wherever the method segments (push's pixel
    /// precision 0.13 → 0.60 with it: docs/decisions/0002-background-labels.md).
    pub fn labels_background(&self) -> bool {
        self.background_negative
            .unwrap_or_else(|| self.method.spec().segmentation)
    }

    /// Object-selection actions per affordance: a 3 × 3 grid, or for
    /// `intexp` one action on the most-centred object.
    pub fn selection_slots(&self) -> usize {
        self.method.spec().selection.slots()
    }

    /// Actions of the simulator's head: navigation, the selection slots per
    /// affordance, and drop plus hand moves when picking up is configured.
    pub fn n_actions(&self) -> usize {
        match self.env {
            EnvKind::BanditFixture => BANDIT_ACTIONS,
            EnvKind::Sim => {
                let pick = self.affordances.contains(&Affordance::PickUp);
                NAV_ACTIONS
                    + self.selection_slots() * self.affordances.len()
                    + usize::from(pick) * (1 + HAND_MOVES)
            }
        }
    }

    /// Length of the cell-ratings input: per affordance and selection slot
    /// the U-Net's mean probability over the offered object (0 unless
    /// `[task.selection] ratings_in_state`).
    pub fn ratings_len(&self) -> usize {
        if self.selection.ratings_in_state {
            self.selection_slots() * self.affordances.len()
        } else {
            0
        }
    }

    /// Whether the method keeps an object-level map (only `ours`); the
    /// others remember through a GRU.
    pub fn uses_map(&self) -> bool {
        self.method.spec().map
    }

    /// Channels of the camera input. `ours`: RGB, distance, and per
    /// affordance the U-Net's probability and the interacted (success,
    /// failure) masks from the map; without a map: RGB, distance and the
    /// probabilities; `intexp`: RGB and the probabilities.
    pub fn camera_channels(&self) -> usize {
        self.method.spec().camera_channels(self.affordances.len())
    }

    /// Channels of each 2-D map (0 without a map; [`crate::MethodSpec::map_channels`]).
    pub fn map_channels(&self) -> usize {
        self.method.spec().map_channels(self.affordances.len())
    }

    /// Length of the action-history input (0 without one; [`crate::MethodSpec::history_len`]).
    pub fn history_len(&self) -> usize {
        self.method.spec().history_len(self.n_actions())
    }

    /// The policy's input layout.
    pub fn layout(&self) -> PolicyLayout {
        match self.env {
            EnvKind::BanditFixture => PolicyLayout {
                image_channels: Vec::new(),
                image_size: 0,
                vector_dims: vec![BANDIT_OBS_DIM],
                n_actions: BANDIT_ACTIONS,
                obs_dtype: ObsDtype::F32,
                gru_hidden: None,
            },
            EnvKind::Sim => {
                // The camera; with a map its global (10 m) and local (2 m)
                // maps. The history if the method has it; the inventory
                // (what the hand holds) always; the cells' ratings if set.
                let spec = self.method.spec();
                let mut image_channels = vec![self.camera_channels()];
                if spec.map {
                    image_channels.extend([self.map_channels(), self.map_channels()]);
                }
                let mut vector_dims = Vec::new();
                if spec.history {
                    vector_dims.push(self.history_len());
                }
                vector_dims.push(1);
                if self.ratings_len() > 0 {
                    vector_dims.push(self.ratings_len());
                }
                PolicyLayout {
                    image_channels,
                    image_size: self.image_size,
                    vector_dims,
                    n_actions: self.n_actions(),
                    obs_dtype: ObsDtype::U8,
                    gru_hidden: (!self.uses_map()).then_some(self.memory_size),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_affordance_can_have_its_own_interaction_weight_and_it_must_be_finite() {
        let task: TaskSpec =
            toml::from_str("[reward]\npick_up_interaction = 4.0\n").expect("a task");
        assert_eq!(task.reward.interaction_for(Affordance::PickUp), 4.0);
        assert_eq!(task.reward.interaction_for(Affordance::Push), 2.0);
        task.validate().unwrap();
        let nan: TaskSpec = toml::from_str("[reward]\npush_interaction = nan\n").expect("a task");
        assert_eq!(nan.validate(), Err(TaskError::RewardWeights));
        let text = toml::to_string(&TaskSpec::default()).unwrap();
        assert!(
            !text.contains("pick_up_interaction"),
            "unset stays unwritten: {text}"
        );
    }

    #[test]
    fn action_counts_follow_the_paper() {
        let task = |affordances: Vec<Affordance>| TaskSpec {
            affordances,
            ..TaskSpec::default()
        };
        assert_eq!(task(vec![Affordance::PickUp]).n_actions(), 21);
        assert_eq!(task(vec![Affordance::Push]).n_actions(), 14);
        assert_eq!(
            task(vec![Affordance::PickUp, Affordance::Push]).n_actions(),
            30
        );
        let layout = task(vec![Affordance::PickUp]).layout();
        assert_eq!(layout.image_channels, vec![7, 5, 5]);
        assert_eq!(layout.vector_dims, vec![5 * 23, 1]);
        assert_eq!(layout.obs_len(), 17 * 128 * 128 + 116);
    }

    #[test]
    fn bad_tasks_are_refused_with_the_key_to_fix() {
        let ok = TaskSpec::default();
        assert_eq!(ok.validate(), Ok(()));
        let twice = TaskSpec {
            affordances: vec![Affordance::Push, Affordance::Push],
            ..ok.clone()
        };
        assert!(twice
            .validate()
            .unwrap_err()
            .to_string()
            .contains("task.affordances"));
        let small = TaskSpec {
            image_size: 40,
            ..ok.clone()
        };
        assert!(small
            .validate()
            .unwrap_err()
            .to_string()
            .contains("task.image_size"));
        let background = TaskSpec {
            method: Method::NomapNoseg,
            background_negative: Some(true),
            ..ok.clone()
        };
        assert!(background
            .validate()
            .unwrap_err()
            .to_string()
            .contains("task.background_negative"));
        for threshold in [f32::NAN, -0.1, 1.5] {
            let selection = TaskSpec {
                selection_confidence: threshold,
                ..ok.clone()
            };
            assert!(selection
                .validate()
                .unwrap_err()
                .to_string()
                .contains("task.selection_confidence"));
        }
        let gru = TaskSpec {
            memory_size: 0,
            ..ok
        };
        assert!(gru
            .validate()
            .unwrap_err()
            .to_string()
            .contains("task.memory_size"));
    }

    #[test]
    fn cell_ratings_add_one_input_per_cell_and_affordance_and_need_the_grid() {
        let with_ratings = |method| TaskSpec {
            method,
            selection: SelectionRule {
                ratings_in_state: true,
                ..SelectionRule::default()
            },
            ..TaskSpec::default()
        };
        let ours = with_ratings(Method::Ours);
        ours.validate().unwrap();
        let plain = TaskSpec::default().layout().vector_dims;
        let mut expected = plain.clone();
        expected.push(crate::GRID_CELLS * ours.affordances.len());
        assert_eq!(ours.layout().vector_dims, expected);
        assert_eq!(TaskSpec::default().ratings_len(), 0);
        let intexp = with_ratings(Method::Intexp);
        assert!(intexp
            .validate()
            .unwrap_err()
            .to_string()
            .contains("ratings_in_state"));
    }

    #[test]
    fn methods_without_a_map_see_less_and_remember_through_a_gru() {
        let task = |method| TaskSpec {
            method,
            affordances: vec![Affordance::PickUp],
            ..TaskSpec::default()
        };
        let ours = task(Method::Ours).layout();
        assert_eq!(ours.gru_hidden, None);
        let seg = task(Method::NomapSeg).layout();
        assert_eq!(seg.image_channels, vec![5]);
        assert_eq!(seg.vector_dims, vec![5 * 23, 1]);
        assert_eq!(seg.gru_hidden, Some(512));
        assert_eq!(task(Method::NomapNoseg).layout(), seg);
        let intexp = task(Method::Intexp).layout();
        assert_eq!(intexp.image_channels, vec![4]);
        assert_eq!(intexp.vector_dims, vec![1]);
        // 5 navigation, 1 centred pick up, drop, 6 hand moves.
        assert_eq!(intexp.n_actions, 13);
        for method in [Method::NomapSeg, Method::NomapNoseg, Method::Intexp] {
            assert_eq!(task(method).validate(), Ok(()));
        }
    }

    #[test]
    fn background_labels_default_on_where_the_method_segments_and_follow_an_explicit_setting() {
        let task = |method, background_negative| TaskSpec {
            method,
            background_negative,
            ..TaskSpec::default()
        };
        for (method, segments) in [
            (Method::Ours, true),
            (Method::NomapSeg, true),
            (Method::NomapNoseg, false),
            (Method::Intexp, false),
        ] {
            assert_eq!(
                task(method, None).labels_background(),
                segments,
                "{method:?}"
            );
            assert!(!task(method, Some(false)).labels_background(), "{method:?}");
        }
        assert!(task(Method::NomapSeg, Some(true)).labels_background());
    }
}
