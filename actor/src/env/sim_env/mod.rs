//! The simulator environment of the four methods. For `ours` each step goes
//! simulator → map integration → U-Net inference → state → (policy,
//! outside) → action. A step comes in two halves around the U-Net
//! ([`SimEnv::begin_step`], then [`SimEnv::observe`] with its
//! probabilities), so that an actor running several environments infers
//! their frames in one batch; at the end of an episode the labeler turns the map's
//! interaction records into labelled frames for the learner. A picked-up
//! object is held in the map (kept, unseen) and released where the
//! simulator put it down.
//!
//! The methods without a map skip the map: objects are the simulator's
//! segmentation, each interaction leaves a 3-D point on its object, and the
//! labels come from those points (the whole segment under the point for
//! `nomap-seg`, a 0.2 m sphere for `nomap-noseg` and `intexp`). Which of the
//! two an episode keeps is its [`ObjectMemory`]; its metrics accumulate in
//! an [`EpisodeMetrics`]; a recording, when asked for, observes it.
//!
//! This file holds the settings, the episode's working state and resets;
//! `step` the first half of a step, `observation` the second (capture and
//! observe), `episode_end` the labels and metrics of a finished episode,
//! `recorder` its recording.

use std::time::{Duration, Instant};

use anyhow::Context;
use mapper::{Affordance, MapConfig};
use nalgebra::Point2;
use proto::{
    ConfidenceRule, FrameBatch, Method, SelectionRule, SphereRule, StatKey, TaskSpec, TypeTries,
};
use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::agent::{Failure, Simulator};
use sim::profile::RobotProfile;
use sim::randomise::randomise;
use sim::raycast::Frame;
use sim::renderer::Renderer;
use sim::scenes::SceneSource;

use crate::env::actions::{
    cell_targets, centred_target, ActionSpace, CellTargets, PolicyAction, Selection,
};
use crate::env::affordance_model::{AffordanceModel, CameraFrame};
use crate::env::episode_metrics::EpisodeMetrics;
use crate::env::object_memory::{object_memory, Interaction, MemoryRules, ObjectMemory};
use crate::env::reach::{beyond_reach_hidden, horizontal_distances};
use crate::env::reward::{RewardTracker, RewardWeights, StepEvent};
use crate::env::state::{build_state, ActionHistory, State, StateConfig, StateInputs};
use crate::frame_scores::ground_truth_planes;
use crate::labeler::{frame_batch, label_background_negative, EpisodeFrame};
use crate::mapping::{instance_classes, intrinsics};
use crate::recording::StepRecord;

mod dataset;
mod episode_end;
mod observation;
mod recorder;
mod step;

use dataset::DatasetRecording;
use recorder::{EpisodeRecorder, Recording};

/// Settings of the environment.
#[derive(Debug, Clone)]
pub struct SimEnvConfig {
    /// What the state holds and how labels are made.
    pub method: Method,
    /// Affordances tried and labelled, in plane order.
    pub affordances: Vec<Affordance>,
    /// Steps per episode (600 in the paper).
    pub episode_steps: usize,
    /// Side of the camera's square images, pixels (the run's
    /// `[task] image_size`; 128 in the paper).
    pub image_size: usize,
    /// Reward weights.
    pub reward: RewardWeights,
    /// Object selection's grid and most-centred object.
    pub selection: SelectionRule,
    /// Objects the U-Net rates below this lose their grid cell to any rated
    /// above it (the task's `selection_confidence`).
    pub selection_confidence: f32,
    /// The map.
    pub map: MapConfig,
    /// Send only frames with both label classes.
    pub balanced_frames: bool,
    /// Label the segmentation's background negative ([`proto::TaskSpec::background_negative`]).
    pub background_negative: bool,
    /// Annotate by confidence once the run has taken this many steps (all
    /// actors); `None`: never.
    pub confidence_after_steps: Option<u64>,
    /// The thresholds of annotation by confidence.
    pub confidence: ConfidenceRule,
    /// The point labels of the methods without a map.
    pub sphere: SphereRule,
}

impl SimEnvConfig {
    /// The settings a run's task gives its environments: every one of them
    /// from the task, so all actors of a run (and an evaluation of it) step
    /// alike.
    pub fn from_task(task: &TaskSpec) -> Self {
        Self {
            method: task.method,
            affordances: task.affordances.clone(),
            episode_steps: task.episode_steps,
            image_size: task.image_size,
            reward: task.reward,
            selection: task.selection,
            selection_confidence: task.selection_confidence,
            map: MapConfig::from_settings(task.map),
            balanced_frames: task.balanced_frames,
            background_negative: task.labels_background(),
            confidence_after_steps: Some(task.confidence_after_steps),
            confidence: task.confidence,
            sphere: task.sphere,
        }
    }

    /// The paper's settings of `method` for `affordances`.
    pub fn paper(method: Method, affordances: &[Affordance]) -> Self {
        Self {
            method,
            affordances: affordances.to_vec(),
            episode_steps: 600,
            image_size: 128,
            reward: RewardWeights::default(),
            selection: SelectionRule::default(),
            selection_confidence: TaskSpec::default().selection_confidence,
            map: MapConfig::default(),
            balanced_frames: true,
            background_negative: false,
            confidence_after_steps: Some(400_000),
            confidence: ConfidenceRule::default(),
            sphere: SphereRule::default(),
        }
    }

    /// Whether the method keeps the object-level map.
    fn uses_map(&self) -> bool {
        self.method.spec().map
    }

    /// The rules the episode's object memory labels by.
    fn memory_rules(&self) -> MemoryRules {
        MemoryRules {
            map: self.map,
            confidence: self.confidence,
            sphere: self.sphere,
        }
    }
}

/// What the policy gets after a reset or a step.
#[derive(Debug, Clone, PartialEq)]
pub struct SimObservation {
    /// The state.
    pub state: State,
    /// One byte per action, 1 = allowed.
    pub mask: Vec<u8>,
}

/// What an action did, known before the next observation.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionOutcome {
    /// The reward.
    pub reward: f32,
    /// Whether the action succeeded.
    pub success: bool,
    /// Why not.
    pub failure: Option<Failure>,
    /// True when the episode's step budget is used up.
    pub done: bool,
}

/// Where a step's time went.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepTimings {
    /// Simulator action.
    pub sim: Duration,
    /// Rendering.
    pub render: Duration,
    /// Map integration.
    pub map: Duration,
    /// The map's own split of `map` (zero without a map).
    pub map_stages: mapper::IntegrateTimings,
    /// U-Net inference.
    pub unet: Duration,
    /// State building, targets and mask.
    pub state: Duration,
}

/// The environment.
pub struct SimEnv {
    config: SimEnvConfig,
    source: SceneSource,
    profile: RobotProfile,
    renderer: Renderer,
    space: ActionSpace,
    state_config: StateConfig,
    episode: Option<Episode>,
    timings: StepTimings,
    global_steps: u64,
    /// Where episodes are recorded, if they are.
    recording: Option<Recording>,
    /// Where the label ladder's dataset goes, if it is written.
    dataset: Option<DatasetRecording>,
}

/// A frame rendered (and integrated into the map) that waits for the
/// U-Net's probabilities before it becomes an observation.
struct Captured {
    frame: Frame,
    map_ids: Vec<u32>,
}

/// One episode's working state.
struct Episode {
    /// The frame of the reset or step begun, until [`SimEnv::observe`].
    pending: Option<Captured>,
    sim: Simulator,
    /// The map, or interaction points without one.
    memory: Box<dyn ObjectMemory>,
    reward: RewardTracker,
    history: ActionHistory,
    visited: Vec<Point2<f32>>,
    frames: Vec<EpisodeFrame>,
    targets: CellTargets,
    steps: usize,
    scene_index: u64,
    /// The U-Net's calibrated probabilities of every frame, one byte per
    /// pixel and affordance (planes in order), for annotation by confidence
    /// and recordings.
    probabilities: Vec<Vec<u8>>,
    metrics: EpisodeMetrics,
    /// What a recording needs besides, when episodes are recorded.
    recorder: Option<EpisodeRecorder>,
}

/// What an episode leaves behind: labelled frames for the learner and the
/// paper's per-episode metrics against the simulator's ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeSummary {
    /// The labelled frames (balanced ones only, if so configured).
    pub frames: FrameBatch,
    /// Metrics, means over the configured affordances where per affordance.
    pub stats: Vec<(StatKey, f32)>,
    /// Interactions by object type.
    pub tries: Vec<TypeTries>,
}

impl SimEnv {
    /// An environment drawing rooms from `source`.
    pub fn new(
        config: SimEnvConfig,
        source: SceneSource,
        profile: RobotProfile,
        renderer: Renderer,
    ) -> Self {
        let space = ActionSpace::new(&config.affordances, config.method.spec().selection);
        let state_config = StateConfig {
            image_size: config.image_size,
            map_cells: config.image_size,
            ratings_len: if config.selection.ratings_in_state {
                config.method.spec().selection.slots() * config.affordances.len()
            } else {
                0
            },
            ..StateConfig::paper(config.method, &config.affordances, space.len())
        };
        Self {
            config,
            source,
            profile,
            renderer,
            space,
            state_config,
            episode: None,
            timings: StepTimings::default(),
            global_steps: 0,
            recording: None,
            dataset: None,
        }
    }

    /// The run's steps over all actors (from the learner): annotation by
    /// confidence starts when they reach the configured number.
    pub fn set_global_steps(&mut self, steps: u64) {
        self.global_steps = steps;
    }

    /// Whether episodes now end with annotation by confidence (`ours` only).
    pub fn annotates_by_confidence(&self) -> bool {
        self.config.uses_map()
            && self
                .config
                .confidence_after_steps
                .is_some_and(|after| self.global_steps >= after)
    }

    /// The action space.
    pub fn action_space(&self) -> &ActionSpace {
        &self.space
    }

    /// The state's layout.
    pub fn state_config(&self) -> &StateConfig {
        &self.state_config
    }

    /// Time spent in the last step (or reset), by stage.
    pub fn last_timings(&self) -> StepTimings {
        self.timings
    }

    /// Index of the current room in the scene source.
    pub(crate) fn scene_index(&self) -> u64 {
        self.episode.as_ref().map_or(0, |e| e.scene_index)
    }

    /// The simulator of the running episode.
    pub fn simulator(&self) -> Option<&Simulator> {
        self.episode.as_ref().map(|e| &e.sim)
    }

    /// Starts an episode (a room picked and randomised by `seed`) and
    /// observes its first frame with `model`.
    pub fn reset(&mut self, seed: u64, model: &AffordanceModel) -> anyhow::Result<SimObservation> {
        self.begin_reset(seed)?;
        self.observe_with(model)
    }

    /// Applies action `index` of the action space and observes the next
    /// frame with `model`.
    pub fn step(
        &mut self,
        index: usize,
        model: &AffordanceModel,
    ) -> anyhow::Result<(ActionOutcome, SimObservation)> {
        let outcome = self.begin_step(index)?;
        Ok((outcome, self.observe_with(model)?))
    }

    /// [`SimEnv::observe`] with `model`'s probabilities for the pending frame.
    fn observe_with(&mut self, model: &AffordanceModel) -> anyhow::Result<SimObservation> {
        let started = Instant::now();
        let probabilities = self
            .camera_frame()
            .map(|frame| model.predict(&frame))
            .context("observe before reset or step")?;
        let unet = started.elapsed();
        let observation = self.observe(probabilities)?;
        self.timings.unet = unet;
        Ok(observation)
    }

    /// Starts an episode: a room picked and randomised by `seed`; its first
    /// frame is rendered and mapped, and waits for [`SimEnv::observe`].
    pub(crate) fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()> {
        let (scene_index, scene) = self.source.pick(seed);
        let mut rng = StdRng::seed_from_u64(seed);
        let (sim, _) = randomise(&scene, &self.profile, self.config.image_size, &mut rng)
            .with_context(|| format!("setting up an episode in {}", scene.name))?;
        let start = sim.agent();
        let truth = ground_truth_planes(sim.scene(), &self.profile, &self.config.affordances);
        let classes = instance_classes(sim.scene().objects.iter().map(|o| o.object_type.as_str()));
        self.episode = Some(Episode {
            pending: None,
            memory: object_memory(
                &self.config.method.spec(),
                &self.config.memory_rules(),
                &self.config.affordances,
                classes,
            ),
            probabilities: Vec::new(),
            metrics: EpisodeMetrics::new(
                truth,
                sim.scene()
                    .objects
                    .iter()
                    .map(|o| o.object_type.clone())
                    .collect(),
                &self.config.affordances,
            ),
            recorder: self.recording.as_ref().map(|_| EpisodeRecorder::default()),
            reward: RewardTracker::new(self.config.reward, start),
            visited: vec![Point2::new(start.x, start.y)],
            sim,
            history: ActionHistory::default(),
            frames: Vec::new(),
            targets: CellTargets::default(),
            steps: 0,
            scene_index,
        });
        self.timings = StepTimings::default();
        self.capture()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_environment_takes_every_rule_from_the_task() {
        let task = TaskSpec {
            selection_confidence: 0.2,
            selection: SelectionRule {
                centre_fraction: 0.5,
                min_pixels: 4,
                within_reach: false,
                prefer: proto::CellPreference::MostProbable,
                ratings_in_state: true,
            },
            confidence: ConfidenceRule {
                positive_above: 0.8,
                negative_below: 0.3,
                min_pixels: 7,
            },
            sphere: SphereRule {
                radius_m: 0.3,
                occlusion_tolerance_m: 0.05,
            },
            map: proto::MapSettings {
                voxel_size_m: 0.05,
                max_misses: 4,
                segmentation: proto::MapSegmentation::Geometric,
                ..proto::MapSettings::default()
            },
            ..TaskSpec::default()
        };
        task.validate().unwrap();
        let config = SimEnvConfig::from_task(&task);
        assert_eq!(config.selection, task.selection);
        assert_eq!(config.selection_confidence, 0.2);
        assert_eq!(config.confidence, task.confidence);
        assert_eq!(config.sphere, task.sphere);
        assert_eq!(config.map, MapConfig::from_settings(task.map));
        assert_eq!(config.map.settings.voxel_size_m, 0.05);
        assert_eq!(config.map.settings.max_misses, 4);
        assert!(matches!(
            config.map.segmentation(),
            mapper::Segmentation::Geometric(_)
        ));
        assert_eq!(
            config.map.integration().free_space_margin_m,
            0.05,
            "derived from the voxel size"
        );
        let defaults = SimEnvConfig::from_task(&TaskSpec::default());
        assert_eq!(defaults.map, MapConfig::default());
        assert_eq!(defaults.selection, SelectionRule::default());
    }
}
