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
//! `nomap-seg`, a 0.2 m sphere for `nomap-noseg` and `intexp`).

use std::time::{Duration, Instant};

use anyhow::Context;
use mapper::{Affordance, Map, MapConfig, ObjectId, Outcome as MapOutcome, Pose};
use nalgebra::Point2;
use proto::{FrameBatch, Method, StatField};
use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::agent::{Failure, Simulator};
use sim::profile::RobotProfile;
use sim::randomise::randomise;
use sim::raycast::Frame;
use sim::renderer::Renderer;
use sim::scene::OrientedBox;
use sim::scenes::SceneSource;

use crate::env::actions::{
    cell_targets, centred_target, ActionSpace, CellTargets, PolicyAction, Selection, SelectionRule,
    Target,
};
use crate::env::affordance_model::{AffordanceModel, CameraFrame};
use crate::env::reward::{RewardTracker, RewardWeights, StepEvent};
use crate::env::state::{build_state, ActionHistory, State, StateConfig, StateInputs};
use crate::labeler::{
    apply_confidence_labels, confidence_labels, frame_batch, label_background_negative, map_labels,
    segment_labels, sphere_labels, ConfidenceRule, EpisodeFrame, InteractionPoint, SphereRule,
};
use crate::mapping::{class_image, instance_classes, intrinsics, map_frame};
use crate::metrics::{annotation_rates, ground_truth_planes, map_id_consistency, score_frame};
use crate::recording::{
    write_episode, EpisodeRecord, FrameRecord, MapLayout, MapPlanesRecord, ObjectRecord, StepRecord,
};

/// Settings of the environment.
#[derive(Debug, Clone)]
pub struct SimEnvConfig {
    /// What the state holds and how labels are made.
    pub method: Method,
    /// Affordances tried and labelled, in plane order.
    pub affordances: Vec<Affordance>,
    /// Steps per episode (600 in the paper).
    pub episode_steps: usize,
    /// Reward weights.
    pub reward: RewardWeights,
    /// Object selection.
    pub selection: SelectionRule,
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
    /// The paper's settings of `method` for `affordances`.
    pub fn paper(method: Method, affordances: &[Affordance]) -> Self {
        Self {
            method,
            affordances: affordances.to_vec(),
            episode_steps: 600,
            reward: RewardWeights::default(),
            selection: SelectionRule::default(),
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
        self.method == Method::Ours
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
}

/// Which episodes go to MCAP files, and where.
#[derive(Debug, Clone)]
struct Recording {
    dir: std::path::PathBuf,
    /// File-name prefix (the actor's).
    prefix: String,
    /// Every how many episodes one is recorded.
    every: u64,
}

impl Recording {
    /// The file for episode `id` ending at the run's `global_steps`: named
    /// by both, and never one that exists (a restarted actor counts its
    /// episodes from 0 again).
    fn path(&self, global_steps: u64, id: u64) -> std::path::PathBuf {
        let stem = format!("{}step{global_steps:09}_episode{id:06}", self.prefix);
        let mut path = self.dir.join(format!("{stem}.mcap"));
        let mut n = 1;
        while path.exists() {
            n += 1;
            path = self.dir.join(format!("{stem}_{n}.mcap"));
        }
        path
    }
}

/// One frame's map planes as the policy saw them, kept for a recording.
struct RecordedMapPlanes {
    /// x, y (metres), heading (radians).
    agent: (f32, f32, f32),
    global: Vec<f32>,
    local: Vec<f32>,
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
    map: Map,
    reward: RewardTracker,
    history: ActionHistory,
    visited: Vec<Point2<f32>>,
    frames: Vec<EpisodeFrame>,
    targets: CellTargets,
    /// Methods without a map: every interaction as a point on its object.
    points: Vec<InteractionPoint>,
    /// Methods without a map: every scene object's pose in every frame.
    object_poses: Vec<Vec<Pose>>,
    steps: usize,
    scene_index: u64,
    /// The object in the hand: its map id and its box when it was picked up.
    in_hand: Option<(ObjectId, OrientedBox)>,
    /// Ground truth per scene object and affordance (plane order).
    truth: Vec<Vec<bool>>,
    /// The simulator's instance ids of every frame (object index + 1).
    truth_ids: Vec<Vec<u32>>,
    /// The class of every instance id ([`instance_classes`]), for the map.
    classes: Vec<u16>,
    /// Wall-clock time of every frame, nanoseconds since the Unix epoch.
    stamps: Vec<u64>,
    /// What every step did, for recordings.
    step_log: Vec<StepRecord>,
    /// The policy's map planes of every frame, for recordings (methods
    /// with a map; empty when not recording).
    map_planes: Vec<RecordedMapPlanes>,
    /// The U-Net's calibrated probabilities of every frame, one byte per
    /// pixel and affordance (planes in order), for annotation by confidence.
    probabilities: Vec<Vec<u8>>,
    /// Per affordance: sums and counts of the U-Net's frame IoU and object accuracy.
    scores: Vec<ScoreSums>,
    /// Interactions tried and those that succeeded, per affordance
    /// (indexed by `Affordance as usize`).
    attempts: [u32; Affordance::ALL.len()],
    successes: [u32; Affordance::ALL.len()],
    /// Interactions that failed because the object was beyond reach, and
    /// because it does not afford the action
    /// ([`Failure::object_does_not_afford`]), per
    /// affordance like `attempts`.
    out_of_reach: [u32; Affordance::ALL.len()],
    unafforded: [u32; Affordance::ALL.len()],
    /// Interactable scene objects an interaction succeeded on.
    interacted: std::collections::BTreeSet<usize>,
    episode_return: f32,
}

/// The point an interaction leaves on its target (methods without a map):
/// the aimed pixel back-projected with the last frame's depth, in the
/// object's frame as it was in that frame. `None` where the pixel saw nothing.
fn interaction_point(
    episode: &Episode,
    affordances: &[Affordance],
    affordance: Affordance,
    target: &Target,
    k: &mapper::Intrinsics,
) -> Option<InteractionPoint> {
    let frame = episode.frames.last()?;
    let object = (target.object as usize).checked_sub(1)?;
    let pose = episode.object_poses.last()?.get(object)?;
    let z = *frame.depth_m.get(target.v * k.width + target.u)?;
    if !(z.is_finite() && z > 0.0) {
        return None;
    }
    let p_world = frame.t_world_camera * k.back_project(target.u as f32, target.v as f32, z);
    Some(InteractionPoint {
        object,
        affordance: affordances.iter().position(|&a| a == affordance)?,
        success: false,
        p_object: pose.inverse() * p_world,
    })
}

/// Running sums of per-frame scores.
#[derive(Debug, Clone, Copy, Default)]
struct ScoreSums {
    iou: f64,
    iou_frames: u32,
    accuracy: f64,
    accuracy_frames: u32,
}

/// What an episode leaves behind: labelled frames for the learner and the
/// paper's per-episode metrics against the simulator's ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeSummary {
    /// The labelled frames (balanced ones only, if so configured).
    pub frames: FrameBatch,
    /// Metrics, means over the configured affordances where per affordance.
    pub stats: Vec<(StatField, f32)>,
}

impl SimEnv {
    /// An environment drawing rooms from `source`.
    pub fn new(
        config: SimEnvConfig,
        source: SceneSource,
        profile: RobotProfile,
        renderer: Renderer,
    ) -> Self {
        let space = ActionSpace::new(&config.affordances, Selection::of(config.method));
        let state_config = StateConfig {
            image_size: profile.image_size,
            map_cells: profile.image_size,
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
        }
    }

    /// Records every `every`-th episode (by id) from now on to
    /// `dir/{prefix}step{run steps:09}_episode{id:06}.mcap`, the run's
    /// steps being those the learner last reported ([`SimEnv::set_global_steps`]).
    pub fn record_to(&mut self, dir: std::path::PathBuf, prefix: String, every: u64) {
        self.recording = Some(Recording {
            dir,
            prefix,
            every: every.max(1),
        });
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
    pub fn scene_index(&self) -> u64 {
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
    pub fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()> {
        let (scene_index, scene) = self.source.pick(seed);
        let mut rng = StdRng::seed_from_u64(seed);
        let (sim, _) = randomise(&scene, &self.profile, &mut rng)
            .with_context(|| format!("setting up an episode in {}", scene.name))?;
        let start = sim.agent();
        let truth = ground_truth_planes(sim.scene(), &self.profile, &self.config.affordances);
        let classes = instance_classes(sim.scene().objects.iter().map(|o| o.object_type.as_str()));
        self.episode = Some(Episode {
            pending: None,
            truth,
            classes,
            truth_ids: Vec::new(),
            probabilities: Vec::new(),
            stamps: Vec::new(),
            step_log: Vec::new(),
            map_planes: Vec::new(),
            scores: vec![ScoreSums::default(); self.config.affordances.len()],
            attempts: Default::default(),
            successes: Default::default(),
            out_of_reach: [0; Affordance::ALL.len()],
            unafforded: [0; Affordance::ALL.len()],
            interacted: Default::default(),
            episode_return: 0.0,
            reward: RewardTracker::new(self.config.reward, start),
            visited: vec![Point2::new(start.x, start.y)],
            sim,
            map: Map::new(self.config.map),
            history: ActionHistory::default(),
            frames: Vec::new(),
            targets: CellTargets::default(),
            points: Vec::new(),
            object_poses: Vec::new(),
            steps: 0,
            scene_index,
            in_hand: None,
        });
        self.timings = StepTimings::default();
        self.capture()
    }

    /// Applies action `index` of the action space; the next frame is
    /// rendered and mapped, and waits for [`SimEnv::observe`].
    pub fn begin_step(&mut self, index: usize) -> anyhow::Result<ActionOutcome> {
        let action = self.space.get(index).with_context(|| {
            format!(
                "action {index} is outside the action space ({})",
                self.space.len()
            )
        })?;
        let episode = self.episode.as_mut().context("step before reset")?;
        anyhow::ensure!(
            episode.pending.is_none(),
            "step before the last frame was observed"
        );
        let started = Instant::now();
        let dropped = episode.sim.held();
        let interaction = match action {
            PolicyAction::Select { affordance, cell } => episode
                .targets
                .target(affordance, cell)
                .map(|t| (affordance, t)),
            _ => None,
        };
        // Without a map, the interaction leaves a point on the target object,
        // taken where the object is before the action moves it.
        let point = match interaction {
            Some((affordance, target)) if !self.config.uses_map() => {
                let k = intrinsics(&episode.sim.camera());
                interaction_point(episode, &self.config.affordances, affordance, &target, &k)
            }
            _ => None,
        };
        let boxes_before: Vec<OrientedBox> = match action {
            PolicyAction::Select {
                affordance: Affordance::PickUp,
                ..
            } => episode
                .sim
                .scene()
                .objects
                .iter()
                .map(|o| o.bounds)
                .collect(),
            _ => Vec::new(),
        };
        let outcome = match self.space.to_sim(action, &episode.targets) {
            Some(sim_action) => episode.sim.apply(sim_action),
            None => sim::agent::Outcome {
                success: false,
                failure: Some(Failure::NothingThere),
            },
        };
        // The interaction's outcome goes onto the map object that was
        // selected (or, without a map, onto its point).
        let mut interacted_instance = None;
        let evidence = tells_the_affordance(&outcome);
        if let Some(mut point) = point.filter(|_| evidence) {
            point.success = outcome.success;
            episode.points.push(point);
        }
        if let Some((affordance, Target { object, .. })) = interaction {
            interacted_instance = Some((affordance, object as usize));
            episode.attempts[affordance as usize] += 1;
            episode.successes[affordance as usize] += u32::from(outcome.success);
            if let Some(failure) = &outcome.failure {
                let kind = affordance as usize;
                episode.out_of_reach[kind] +=
                    u32::from(matches!(failure, Failure::OutOfReach { .. }));
                episode.unafforded[kind] += u32::from(failure.object_does_not_afford());
            }
        }
        if let Some((affordance, Target { object, .. })) =
            interaction.filter(|_| self.config.uses_map() && evidence)
        {
            let id = ObjectId(object);
            let result = if outcome.success {
                MapOutcome::Success
            } else {
                MapOutcome::Failure
            };
            // Only ids of the frame's objects are selectable, so the object
            // exists; labels of objects the map deletes later stay with it.
            let _ = episode.map.record_interaction(id, affordance, result);
            if outcome.success && affordance == Affordance::Push {
                // The map tracks the pushed object from the next frame on,
                // looking along the push (the camera's heading) for it.
                let yaw = episode.sim.agent().yaw_deg.to_radians();
                let along = nalgebra::Vector3::new(yaw.cos(), yaw.sin(), 0.0);
                let _ = episode.map.notify_pushed(id, along);
            }
            if outcome.success && affordance == Affordance::PickUp {
                // The map keeps the object, unseen, until it is put down.
                if let Some(index) = episode.sim.held() {
                    if episode.map.hold(id).is_ok() {
                        episode.in_hand = Some((id, boxes_before[index]));
                    }
                }
            }
        }
        if let (
            Some(sim::agent::Action::PickUp { u, v } | sim::agent::Action::Push { u, v }),
            true,
        ) = (self.space.to_sim(action, &episode.targets), outcome.success)
        {
            let width = self.profile.image_size;
            let instance = episode
                .truth_ids
                .last()
                .and_then(|ids| ids.get(v * width + u).copied())
                .unwrap_or(0);
            if instance > 0 {
                episode.interacted.insert(instance as usize - 1);
            }
        }
        if action == PolicyAction::Drop && outcome.success {
            if let (Some((id, before)), Some(index)) = (episode.in_hand.take(), dropped) {
                let after = episode.sim.scene().objects[index].bounds;
                let pose = |b: &OrientedBox| Pose::from_parts(b.center.coords.into(), b.rotation);
                let _ = episode
                    .map
                    .release(id, pose(&after) * pose(&before).inverse());
            }
        }
        let agent = episode.sim.agent();
        let reward = episode.reward.reward(&StepEvent {
            agent,
            success: outcome.success,
            interaction: interacted_instance,
        });
        episode.episode_return += reward;
        if self.recording.is_some() {
            episode.step_log.push(StepRecord {
                action: index,
                action_name: format!("{action:?}"),
                reward,
                success: outcome.success,
                failure: outcome
                    .failure
                    .as_ref()
                    .map(|f| format!("{f:?}"))
                    .unwrap_or_default(),
                agent: (agent.x, agent.y, agent.yaw_deg),
            });
        }
        episode.visited.push(Point2::new(agent.x, agent.y));
        episode
            .history
            .push(index, outcome.success, reward, self.state_config.history);
        episode.steps += 1;
        let done = episode.steps >= self.config.episode_steps;
        let sim_time = started.elapsed();
        self.capture()?;
        self.timings.sim = sim_time;
        Ok(ActionOutcome {
            reward,
            success: outcome.success,
            failure: outcome.failure,
            done,
        })
    }

    /// Renders the agent's view and integrates it into the map; the frame
    /// then waits for the U-Net ([`SimEnv::camera_frame`], [`SimEnv::observe`]).
    fn capture(&mut self) -> anyhow::Result<()> {
        let episode = self.episode.as_mut().context("capture before reset")?;
        let t0 = Instant::now();
        let frame: Frame = episode.sim.render(&mut self.renderer)?;
        let camera = episode.sim.camera();
        let t1 = Instant::now();
        // The frame's objects: map ids, or the segmentation without a map.
        let map_ids = if self.config.uses_map() {
            episode
                .map
                .integrate(&map_frame(
                    &camera,
                    &frame,
                    &class_image(&frame.ids, &episode.classes),
                ))
                .context("integrating the frame into the map")?
        } else {
            episode.object_poses.push(
                episode
                    .sim
                    .scene()
                    .objects
                    .iter()
                    .map(|o| Pose::from_parts(o.bounds.center.coords.into(), o.bounds.rotation))
                    .collect(),
            );
            frame.ids.clone()
        };
        let t2 = Instant::now();
        let map_stages = if self.config.uses_map() {
            episode.map.last_timings()
        } else {
            mapper::IntegrateTimings::default()
        };
        episode.pending = Some(Captured { frame, map_ids });
        self.timings = StepTimings {
            sim: Duration::ZERO,
            render: t1 - t0,
            map: t2 - t1,
            map_stages,
            unet: Duration::ZERO,
            state: Duration::ZERO,
        };
        Ok(())
    }

    /// The frame of the reset or step begun, for the U-Net; `None` before a
    /// reset or once observed.
    pub fn camera_frame(&self) -> Option<CameraFrame<'_>> {
        let frame = &self.episode.as_ref()?.pending.as_ref()?.frame;
        Some(CameraFrame {
            rgb: &frame.rgb,
            depth_m: &frame.depth_m,
            height: frame.height,
            width: frame.width,
        })
    }

    /// Completes the reset or step begun: scores the U-Net's `probabilities`
    /// (per affordance, a plane for [`SimEnv::camera_frame`]) against the
    /// ground truth, chooses the interaction targets and builds the state.
    pub fn observe(&mut self, probabilities: Vec<Vec<f32>>) -> anyhow::Result<SimObservation> {
        let episode = self.episode.as_mut().context("observe before reset")?;
        let Captured { frame, map_ids } = episode
            .pending
            .take()
            .context("observe twice, or before a reset or step")?;
        anyhow::ensure!(
            probabilities.len() == self.config.affordances.len()
                && probabilities
                    .iter()
                    .all(|p| p.len() == frame.height * frame.width),
            "the U-Net gave {} planes for {} affordances at {} × {} px",
            probabilities.len(),
            self.config.affordances.len(),
            frame.height,
            frame.width
        );
        let t3 = Instant::now();
        for (plane, (probabilities, sums)) in
            probabilities.iter().zip(&mut episode.scores).enumerate()
        {
            let truth = &episode.truth;
            let affords = |id: u32| truth.get(id as usize - 1).is_some_and(|t| t[plane]);
            let scores = score_frame(probabilities, &frame.ids, &affords);
            if let Some(iou) = scores.iou {
                sums.iou += f64::from(iou);
                sums.iou_frames += 1;
            }
            if let Some(accuracy) = scores.object_accuracy {
                sums.accuracy += f64::from(accuracy);
                sums.accuracy_frames += 1;
            }
        }
        // The agent has not moved since the frame was captured.
        let camera = episode.sim.camera();
        let k = intrinsics(&camera);
        let agent = episode.sim.agent();
        let holding = episode.sim.held().is_some();
        episode.targets = match Selection::of(self.config.method) {
            Selection::Grid => cell_targets(
                &map_ids,
                frame.width,
                &self.config.affordances,
                Some(&probabilities),
                &self.config.selection,
            ),
            Selection::Centred => centred_target(
                &map_ids,
                frame.width,
                &self.config.affordances,
                &self.config.selection,
            ),
        };
        let state = build_state(
            &self.state_config,
            &StateInputs {
                rgb: &frame.rgb,
                depth_m: &frame.depth_m,
                map_ids: &map_ids,
                t_world_camera: &camera.t_world_camera,
                intrinsics: &k,
                agent: (agent.x, agent.y, agent.yaw_deg.to_radians()),
                floor_z: episode.sim.scene().floor_top_m,
                reach_m: self.profile.reach_m,
                visited: &episode.visited,
                probabilities: &probabilities,
                map: self.config.uses_map().then_some(&episode.map),
                history: &episode.history,
                holding,
            },
        );
        if self.recording.is_some() && !state.global_map.is_empty() {
            episode.map_planes.push(RecordedMapPlanes {
                agent: (agent.x, agent.y, agent.yaw_deg.to_radians()),
                global: state.global_map.clone(),
                local: state.local_map.clone(),
            });
        }
        let mask = self.space.mask(holding, &episode.targets);
        episode.truth_ids.push(frame.ids);
        episode.stamps.push(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64),
        );
        episode.probabilities.push(
            probabilities
                .iter()
                .flatten()
                .map(|&p| proto::unit_to_byte(p))
                .collect(),
        );
        episode.frames.push(EpisodeFrame {
            rgb: frame.rgb,
            depth_m: frame.depth_m,
            map_ids,
            t_world_camera: camera.t_world_camera,
        });
        self.timings.state = t3.elapsed();
        Ok(SimObservation { state, mask })
    }

    /// Ends the episode: its labelled frames for the learner (interaction
    /// labels through the map, also for objects it merged or dropped, or
    /// point labels without a map) and its metrics against the simulator's
    /// ground truth; recorded too, if asked.
    pub fn finish_episode(&mut self, episode_id: u64) -> anyhow::Result<EpisodeSummary> {
        let confidence = self.annotates_by_confidence();
        let mut episode = self.episode.take().context("finish before reset")?;
        if confidence {
            self.annotate_by_confidence(&mut episode)?;
        }
        let k = intrinsics(&episode.sim.camera());
        let mut labels = self.labels(&episode, &k);
        if self.config.background_negative && self.config.method.segments() {
            label_background_negative(&mut labels, &episode.truth_ids);
        }
        if let Some(recording) = self
            .recording
            .as_ref()
            .filter(|r| episode_id.is_multiple_of(r.every))
        {
            let path = recording.path(self.global_steps, episode_id);
            self.record(&episode, &labels, &k, &path).with_context(|| {
                format!(
                    "recording the episode (--record {})",
                    recording.dir.display()
                )
            })?;
        }
        Ok(EpisodeSummary {
            stats: episode_stats(
                &episode,
                &labels,
                k.pixels(),
                self.config.uses_map(),
                &self.config.affordances,
            ),
            frames: frame_batch(
                episode_id,
                &k,
                &episode.frames,
                &labels,
                self.config.affordances.len(),
                self.config.balanced_frames,
            ),
        })
    }

    /// Stores on the map a confidence label for every untouched object the
    /// calibrated U-Net is sure about over the episode's frames.
    fn annotate_by_confidence(&self, episode: &mut Episode) -> anyhow::Result<()> {
        let pixels = self.profile.image_size * self.profile.image_size;
        for (plane, &affordance) in self.config.affordances.iter().enumerate() {
            let planes: Vec<Vec<f32>> = episode
                .probabilities
                .iter()
                .map(|p| {
                    p[plane * pixels..(plane + 1) * pixels]
                        .iter()
                        .map(|&b| proto::byte_to_unit(b))
                        .collect()
                })
                .collect();
            let decided = confidence_labels(
                &episode.map,
                &episode.frames,
                &planes,
                affordance,
                &self.config.confidence,
            );
            apply_confidence_labels(&mut episode.map, affordance, &decided)
                .context("storing confidence labels on the map")?;
        }
        Ok(())
    }

    /// Every frame's label planes, made the method's way.
    fn labels(&self, episode: &Episode, k: &mapper::Intrinsics) -> Vec<Vec<u8>> {
        let planes = self.config.affordances.len();
        let poses = &episode.object_poses;
        let pose_of = |frame: usize, object: usize| poses[frame][object];
        match self.config.method {
            Method::Ours => map_labels(&episode.map, &episode.frames, &self.config.affordances),
            Method::NomapSeg => segment_labels(
                &episode.frames,
                k,
                &episode.points,
                planes,
                &pose_of,
                &self.config.sphere,
            ),
            Method::NomapNoseg | Method::Intexp => sphere_labels(
                &episode.frames,
                k,
                &episode.points,
                planes,
                &pose_of,
                &self.config.sphere,
            ),
        }
    }

    /// Writes the episode to an MCAP file at `path`.
    fn record(
        &self,
        episode: &Episode,
        labels: &[Vec<u8>],
        k: &mapper::Intrinsics,
        path: &std::path::Path,
    ) -> anyhow::Result<()> {
        let records: Vec<FrameRecord<'_>> = (0..episode.frames.len())
            .map(|i| {
                let frame = &episode.frames[i];
                FrameRecord {
                    stamp_ns: episode.stamps[i],
                    rgb: &frame.rgb,
                    depth_m: &frame.depth_m,
                    instance_ids: &episode.truth_ids[i],
                    map_ids: &frame.map_ids,
                    labels: &labels[i],
                    predictions: &episode.probabilities[i],
                    t_world_camera: &frame.t_world_camera,
                    map_planes: episode.map_planes.get(i).map(|p| MapPlanesRecord {
                        agent: p.agent,
                        global: &p.global,
                        local: &p.local,
                    }),
                }
            })
            .collect();
        let with_map = !episode.map_planes.is_empty();
        let layout = MapLayout {
            plane_names: self.state_config.map_plane_names(),
            cells: self.state_config.map_cells,
            extents_m: [
                self.state_config.global_extent_m,
                self.state_config.local_extent_m,
            ],
            floor_z: episode.sim.scene().floor_top_m,
        };
        let objects = if with_map {
            self.object_records(&episode.map)?
        } else {
            Vec::new()
        };
        write_episode(
            path,
            &EpisodeRecord {
                intrinsics: k,
                affordances: &self.config.affordances,
                frames: &records,
                steps: &episode.step_log,
                map_layout: with_map.then_some(&layout),
                objects: &objects,
            },
        )?;
        Ok(())
    }

    /// The map's objects with their meshes and labels, for a recording.
    fn object_records(&self, map: &Map) -> anyhow::Result<Vec<ObjectRecord>> {
        map.objects()
            .values()
            .map(|object| {
                let mesh = map
                    .object_mesh(object.id)
                    .context("meshing a map object for the recording")?;
                let mut metadata = vec![(
                    "class".to_owned(),
                    object
                        .class()
                        .map_or_else(|| "unknown".to_owned(), |c| c.to_string()),
                )];
                for &a in &self.config.affordances {
                    let label = match object.labels.label(a) {
                        Some(true) => "positive",
                        Some(false) => "negative",
                        None => "unknown",
                    };
                    metadata.push((a.as_str().to_owned(), label.to_owned()));
                }
                Ok(ObjectRecord {
                    id: object.id.0,
                    mesh,
                    metadata,
                })
            })
            .collect()
    }
}

/// Whether an interaction's outcome says anything about its object's
/// affordance, so that labels may follow from it: a success, or a failure of
/// the object itself. An arm that never reached the object (beyond reach, no
/// room to lift it, nothing under the pixel) learnt nothing about it; the
/// robot knows this from its own arm, and labelling such objects negative
/// taught the U-Net that reachable pickupable objects cannot be picked up
/// (56 % of a trained policy's failed pick-ups were beyond reach).
fn tells_the_affordance(outcome: &sim::agent::Outcome) -> bool {
    outcome.success
        || outcome
            .failure
            .as_ref()
            .is_some_and(Failure::object_does_not_afford)
}

/// A sum of per-frame scores over its `frames`, as their mean; `None`
/// without frames.
fn per_frame(sum: f64, frames: u32) -> Option<f32> {
    (frames > 0).then(|| (sum / f64::from(frames)) as f32)
}

/// The paper's per-episode metrics against the simulator's ground truth:
/// return, interaction success rate (and why attempts failed),
/// interacted object rate, both
/// annotation rates of `labels`, the U-Net's mean IoU and object
/// accuracy over the episode's frames (means over affordances), and, for
/// methods with a map (`uses_map`), how consistently it re-identified the
/// scene's objects.
fn episode_stats(
    episode: &Episode,
    labels: &[Vec<u8>],
    pixels: usize,
    uses_map: bool,
    affordances: &[Affordance],
) -> Vec<(StatField, f32)> {
    let planes = episode.scores.len();
    // Annotation rates of the labels over every frame of the episode.
    let (mut positive, mut negative) = (0.0f64, 0.0f64);
    for (frame_labels, ids) in labels.iter().zip(&episode.truth_ids) {
        for (plane, plane_labels) in frame_labels.chunks(pixels).enumerate() {
            let truth = &episode.truth;
            let affords = |id: u32| truth.get(id as usize - 1).is_some_and(|t| t[plane]);
            let (p, n) = annotation_rates(plane_labels, ids, &affords);
            positive += f64::from(p);
            negative += f64::from(n);
        }
    }
    let rated = (episode.truth_ids.len() * planes).max(1) as f64;
    let interactable = episode
        .truth
        .iter()
        .filter(|t| t.iter().any(|&x| x))
        .count();
    let interacted = episode
        .interacted
        .iter()
        .filter(|&&i| episode.truth.get(i).is_some_and(|t| t.iter().any(|&x| x)))
        .count();
    let mean = |f: fn(&ScoreSums) -> (f64, u32)| -> Option<f32> {
        let (sum, n) = episode
            .scores
            .iter()
            .map(f)
            .fold((0.0, 0), |(s, c), (x, k)| (s + x, c + k));
        per_frame(sum, n)
    };
    let attempts: u32 = episode.attempts.iter().sum();
    let successes: u32 = episode.successes.iter().sum();
    let mut stats = vec![
        (StatField::EpisodeReturn, episode.episode_return),
        (
            StatField::InteractionSuccessRate,
            successes as f32 / attempts.max(1) as f32,
        ),
        (
            StatField::InteractionAttemptRate,
            attempts as f32 / episode.steps.max(1) as f32,
        ),
        (
            StatField::InteractedObjectRate,
            interacted as f32 / interactable.max(1) as f32,
        ),
        (
            StatField::InteractableAnnotationRate,
            (positive / rated) as f32,
        ),
        (
            StatField::NonInteractableAnnotationRate,
            (negative / rated) as f32,
        ),
    ];
    if attempts > 0 {
        let attempts = attempts as f32;
        stats.push((
            StatField::InteractionOutOfReachRate,
            episode.out_of_reach.iter().sum::<u32>() as f32 / attempts,
        ));
        stats.push((
            StatField::InteractionUnaffordedRate,
            episode.unafforded.iter().sum::<u32>() as f32 / attempts,
        ));
    }
    for &affordance in affordances {
        let kind = affordance as usize;
        let (attempts, successes) = (episode.attempts[kind], episode.successes[kind]);
        let [attempt_rate, success_rate, out_of_reach_rate, unafforded_rate] = match affordance {
            Affordance::PickUp => [
                StatField::PickUpAttemptRate,
                StatField::PickUpSuccessRate,
                StatField::PickUpOutOfReachRate,
                StatField::PickUpUnaffordedRate,
            ],
            Affordance::Push => [
                StatField::PushAttemptRate,
                StatField::PushSuccessRate,
                StatField::PushOutOfReachRate,
                StatField::PushUnaffordedRate,
            ],
        };
        stats.push((attempt_rate, attempts as f32 / episode.steps.max(1) as f32));
        if attempts > 0 {
            let share = |n: u32| n as f32 / attempts as f32;
            stats.push((success_rate, share(successes)));
            stats.push((out_of_reach_rate, share(episode.out_of_reach[kind])));
            stats.push((unafforded_rate, share(episode.unafforded[kind])));
        }
    }
    if let Some(iou) = mean(|s| (s.iou, s.iou_frames)) {
        stats.push((StatField::AffordanceIou, iou));
    }
    if let Some(accuracy) = mean(|s| (s.accuracy, s.accuracy_frames)) {
        stats.push((StatField::ObjectAccuracy, accuracy));
    }
    for (&affordance, sums) in affordances.iter().zip(&episode.scores) {
        let (iou, accuracy) = match affordance {
            Affordance::PickUp => (StatField::PickUpIou, StatField::PickUpObjectAccuracy),
            Affordance::Push => (StatField::PushIou, StatField::PushObjectAccuracy),
        };
        stats.extend(per_frame(sums.iou, sums.iou_frames).map(|v| (iou, v)));
        stats.extend(per_frame(sums.accuracy, sums.accuracy_frames).map(|v| (accuracy, v)));
    }
    if uses_map {
        let frames = episode
            .truth_ids
            .iter()
            .zip(&episode.frames)
            .map(|(truth, frame)| (truth.as_slice(), frame.map_ids.as_slice()));
        let current = |id: u32| episode.map.current_id(ObjectId(id)).0;
        if let Some(consistency) = map_id_consistency(frames, current) {
            stats.push((StatField::MapIdConsistency, consistency));
        }
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_successes_and_failures_of_the_object_itself_make_labels() {
        let failed = |failure| sim::agent::Outcome {
            success: false,
            failure: Some(failure),
        };
        let succeeded = sim::agent::Outcome {
            success: true,
            failure: None,
        };
        assert!(tells_the_affordance(&succeeded));
        for evidence in [
            Failure::NotPickupable,
            Failure::TooHeavy { mass_kg: 30.0 },
            Failure::TooWide { width_m: 0.5 },
            Failure::NotPushable,
            Failure::DidNotMove { moved_m: 0.01 },
        ] {
            assert!(
                tells_the_affordance(&failed(evidence.clone())),
                "{evidence:?}"
            );
        }
        for no_evidence in [
            Failure::OutOfReach { distance_m: 1.4 },
            Failure::NothingThere,
            Failure::NoRoom {
                blocked_by: "Shelf".into(),
            },
        ] {
            assert!(
                !tells_the_affordance(&failed(no_evidence.clone())),
                "{no_evidence:?}"
            );
        }
    }
}
