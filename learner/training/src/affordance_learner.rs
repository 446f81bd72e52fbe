//! Affordance learning in the learner: every episode's labelled frames join
//! the global dataset (split into train / validation / test), the U-Net
//! trains on the training split, and the trained network replaces the one
//! the actors use only when it beats it on validation.

use crate::affordance::{Evaluation, LabelledFrame, UnetTrainer, UnetTrainingConfig, UNKNOWN};
use crate::dataset::{AffordanceDataset, DatasetConfig};
use crate::gate::{Gate, GateOutcome};
use crate::optimizer_state::{OptimizerState, OptimizerStateError};
use crate::temperature::fit_weighted_temperature;
use crate::weight_average::WeightAverage;
use burn::prelude::*;
use nets::unet::AffordanceUnet;
use nets::weights::{load_safetensors, to_safetensors, WeightsError};
use proto::{FrameBatchView, LABEL_UNKNOWN};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

use crate::config::UnetConfig;

/// Why an episode's frames were refused.
#[derive(Debug, thiserror::Error)]
pub enum FramesError {
    /// Another number of affordance planes than the run's task.
    #[error("frames carry {got} affordance planes; this run's task has {expected} (is the actor using the learner's config.toml?)")]
    Affordances {
        /// Planes in the message.
        got: u32,
        /// Planes of the task.
        expected: usize,
    },
    /// Images of another size than the run's task: the U-Net trains on
    /// batches of one size.
    #[error("frames are {height} × {width} pixels; this run's task has {expected} × {expected} (is the actor using the learner's config.toml?)")]
    Size {
        /// Height in the message.
        height: u32,
        /// Width in the message.
        width: u32,
        /// Side of the task's images.
        expected: usize,
    },
}

/// Why the U-Net's training state could not be saved or restored.
#[derive(Debug, thiserror::Error)]
pub enum TrainingStateError {
    /// The network in training could not be written or read.
    #[error("U-Net weights: {0}")]
    Weights(#[from] WeightsError),
    /// Adam's state could not be captured or does not fit the network.
    #[error("U-Net optimiser: {0}")]
    Optimizer(#[from] OptimizerStateError),
}

/// The U-Net in training and its Adam state: with these in a checkpoint,
/// a resumed run continues U-Net training where it stopped instead of
/// restarting it from the deployed network with a fresh Adam.
#[derive(Debug, Clone)]
pub struct UnetTrainingState {
    /// The network in training (safetensors), which may differ from the
    /// deployed one: it has not passed the validation gate (yet).
    pub candidate: Vec<u8>,
    /// Its optimiser's state.
    pub optimizer: OptimizerState,
    /// The average of its recent weights (safetensors), when the run
    /// averages them (`[unet] weight_average`).
    pub average: Option<Vec<u8>>,
}

/// What one round of U-Net training did.
#[derive(Debug, Clone, Serialize)]
pub struct UnetRound {
    /// Gradient steps the round took.
    pub steps: usize,
    /// Mean training loss (masked BCE + Dice) of the round's steps.
    pub train_loss: f32,
    /// The trained network on validation.
    pub candidate_loss: f32,
    /// The trained network's IoU on validation.
    pub candidate_iou: f32,
    /// The deployed network on the same frames.
    pub deployed_loss: f32,
    /// The deployed network's IoU on validation.
    pub deployed_iou: f32,
    /// Whether the trained network now replaces the deployed one.
    pub replaced: bool,
    /// Temperature of the deployed network, fitted on validation when it was replaced.
    pub temperature: f32,
    /// Frames in the dataset: train, validation, test.
    pub frames: (usize, usize, usize),
    /// Training frames with a positive label, per affordance.
    pub positive_frames: Vec<usize>,
    /// Where the round's time went.
    pub seconds: RoundSeconds,
}

/// Wall-clock seconds of a round's parts: what keeps the U-Net trainer
/// behind its actors when its gradient steps are cheap (a GPU's).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RoundSeconds {
    /// Sampling and mirroring the batches and the gradient steps.
    pub training: f64,
    /// The validation gate: both networks on the newest validation frames.
    pub gate: f64,
    /// Refitting the temperature of a network that replaced the deployed one.
    pub temperature: f64,
}

impl RoundSeconds {
    /// Adds `other`'s seconds part by part (a sum over rounds).
    pub fn add(&mut self, other: &RoundSeconds) {
        self.training += other.training;
        self.gate += other.gate;
        self.temperature += other.temperature;
    }
}

/// The U-Net being trained, the deployed one, and the dataset.
pub struct AffordanceLearner {
    trainer: UnetTrainer,
    /// The average of the trained weights, which the gate compares with
    /// the deployed network instead of the latest weights.
    average: Option<WeightAverage<AffordanceUnet>>,
    deployed: AffordanceUnet,
    /// The validation gate, with the deployed network's scores kept.
    gate: Gate,
    dataset: AffordanceDataset,
    settings: UnetConfig,
    affordances: usize,
    device: Device,
    rng: StdRng,
    temperature: f32,
}

/// An episode's frames in the U-Net's layout: planar RGB in 0..1 and depth.
pub fn labelled_frames(view: &FrameBatchView<'_>) -> Vec<LabelledFrame> {
    let (h, w) = (view.height as usize, view.width as usize);
    let pixels = h * w;
    let planes = view.n_affordances as usize;
    let depth = view.depth_m.to_vec();
    (0..view.n_frames as usize)
        .map(|f| {
            let rgb = &view.rgb[3 * pixels * f..3 * pixels * (f + 1)];
            let mut rgbd = Vec::with_capacity(4 * pixels);
            for c in 0..3 {
                rgbd.extend(rgb.iter().skip(c).step_by(3).map(|&b| f32::from(b) / 255.0));
            }
            rgbd.extend_from_slice(&depth[pixels * f..pixels * (f + 1)]);
            let labels = view.labels[planes * pixels * f..planes * pixels * (f + 1)]
                .iter()
                .map(|&l| if l == LABEL_UNKNOWN { UNKNOWN } else { l })
                .collect();
            LabelledFrame {
                size: [h, w],
                rgbd,
                labels,
            }
        })
        .collect()
}

/// An episode's frames converted, after checking they have the task's
/// `affordances` planes and `image_size` square images.
pub fn checked_frames(
    view: &FrameBatchView<'_>,
    affordances: usize,
    image_size: usize,
) -> Result<Vec<LabelledFrame>, FramesError> {
    if view.n_affordances as usize != affordances {
        return Err(FramesError::Affordances {
            got: view.n_affordances,
            expected: affordances,
        });
    }
    if view.height as usize != image_size || view.width as usize != image_size {
        return Err(FramesError::Size {
            height: view.height,
            width: view.width,
            expected: image_size,
        });
    }
    Ok(labelled_frames(view))
}

/// The network in training as the gate, the average and the actors take
/// it: on `device` without autodiff, normalisations folded in.
fn trained(trainer: &UnetTrainer, device: &Device) -> AffordanceUnet {
    trainer.inference_net(device).folded()
}

impl AffordanceLearner {
    /// A fresh U-Net for `affordances` planes, trained on `device`.
    pub fn new(affordances: usize, settings: &UnetConfig, seed: u64, device: &Device) -> Self {
        let net = Self::trainee(AffordanceUnet::new(4, affordances, device), settings);
        let deployed = net.folded();
        Self {
            trainer: UnetTrainer::new(net, Self::training(settings), device),
            average: Self::average_from(&deployed, settings),
            deployed,
            gate: Gate::default(),
            dataset: AffordanceDataset::new(DatasetConfig {
                max_uses: settings.max_uses,
                max_frames: settings.max_frames,
                validation_fraction: settings.validation_fraction,
                test_fraction: settings.test_fraction,
                max_held_out: settings.max_held_out_frames,
                rare_positive_share: settings.rare_positive_share,
                split_by_episode: settings.split_by_episode,
            }),
            settings: settings.clone(),
            affordances,
            device: device.clone(),
            rng: StdRng::seed_from_u64(seed ^ 0x05ee_da11),
            temperature: 1.0,
        }
    }

    /// `net` as it trains: with fresh batch normalisations when the run
    /// asks for them (`[unet] batch_norm`).
    fn trainee(net: AffordanceUnet, settings: &UnetConfig) -> AffordanceUnet {
        if settings.batch_norm {
            net.with_batch_norm()
        } else {
            net
        }
    }

    /// A fresh average starting at `net`, when the run averages weights.
    fn average_from(
        net: &AffordanceUnet,
        settings: &UnetConfig,
    ) -> Option<WeightAverage<AffordanceUnet>> {
        (settings.weight_average > 0.0)
            .then(|| WeightAverage::new(net.clone(), settings.weight_average))
    }

    fn training(settings: &UnetConfig) -> UnetTrainingConfig {
        UnetTrainingConfig {
            learning_rate: settings.learning_rate,
            weight_decay: settings.weight_decay,
            class_balance: settings.class_balance,
        }
    }

    /// Adds an episode's frames (keyed by `episode`, unique over actors).
    pub fn add_episode(&mut self, episode: u64, frames: Vec<LabelledFrame>) {
        self.dataset.add_episode(episode, frames, &mut self.rng);
    }

    /// Whether the gate takes an average of the recent weights (`[unet]
    /// weight_average`) rather than the latest.
    pub fn averages_weights(&self) -> bool {
        self.average.is_some()
    }

    /// Gradient steps owed for each episode that arrives (`[unet]
    /// steps_per_episode`).
    pub fn steps_per_episode(&self) -> usize {
        self.settings.steps_per_episode
    }

    /// Trains `steps` gradient steps on the training split, then gates the
    /// result on validation; `None` without training frames.
    pub fn train_round(&mut self, steps: usize) -> Option<UnetRound> {
        let mut seconds = RoundSeconds::default();
        let started = Instant::now();
        let mut losses = Vec::new();
        for _ in 0..steps {
            let batch = self
                .dataset
                .sample_train(self.settings.batch_frames, &mut self.rng);
            if batch.is_empty() {
                break;
            }
            let mirrored: Vec<Option<LabelledFrame>> = batch
                .iter()
                .map(|f| {
                    let mirror = self.settings.mirror_frames && self.rng.random_bool(0.5);
                    mirror.then(|| f.mirrored())
                })
                .collect();
            let refs: Vec<&LabelledFrame> = batch
                .iter()
                .zip(&mirrored)
                .map(|(f, m)| m.as_ref().unwrap_or(f))
                .collect();
            losses.push(self.trainer.step(&refs));
            if let Some(average) = &mut self.average {
                average.update(&trained(&self.trainer, &self.device));
            }
        }
        if losses.is_empty() {
            return None;
        }
        seconds.training = started.elapsed().as_secs_f64();
        let started = Instant::now();
        let candidate = match &self.average {
            Some(average) => average.average().clone(),
            None => trained(&self.trainer, &self.device),
        };
        let frames = self
            .dataset
            .gate_frames(self.settings.max_validation_frames);
        let GateOutcome {
            decision: gate,
            candidate_logits,
        } = self.gate.decide(
            &candidate,
            &self.deployed,
            &frames,
            self.settings.class_balance,
            &self.device,
        );
        seconds.gate = started.elapsed().as_secs_f64();
        if gate.replace {
            let started = Instant::now();
            self.temperature = self.fit_temperature(&frames, &candidate_logits);
            seconds.temperature = started.elapsed().as_secs_f64();
            self.deployed = candidate;
        }
        let Evaluation { loss, iou, .. } = gate.candidate;
        Some(UnetRound {
            steps: losses.len(),
            train_loss: losses.iter().sum::<f32>() / losses.len() as f32,
            candidate_loss: loss,
            candidate_iou: iou,
            deployed_loss: gate.deployed.loss,
            deployed_iou: gate.deployed.iou,
            replaced: gate.replace,
            temperature: self.temperature,
            frames: self.dataset.sizes(),
            positive_frames: self.dataset.positive_frames(self.affordances),
            seconds,
        })
    }

    /// Temperature scaling of a network on the gate's frames' labelled
    /// pixels, from its logits on them (the gate's), so that the actors'
    /// confidence labels rest on calibrated probabilities; with balanced
    /// classes, each plane's classes weigh half, as in training.
    fn fit_temperature(&self, frames: &[Arc<LabelledFrame>], frame_logits: &[Vec<f32>]) -> f32 {
        // Per plane: logits and labels of its labelled pixels.
        let mut planes = vec![(Vec::new(), Vec::new()); self.affordances];
        for (frame, predicted) in frames.iter().zip(frame_logits) {
            let pixels = frame.size[0] * frame.size[1];
            for (plane, (logits, labels)) in planes.iter_mut().enumerate() {
                let range = plane * pixels..(plane + 1) * pixels;
                for (&l, &label) in predicted[range.clone()].iter().zip(&frame.labels[range]) {
                    if label != UNKNOWN {
                        logits.push(l);
                        labels.push(label == 1);
                    }
                }
            }
        }
        let (mut logits, mut labels, mut weights) = (Vec::new(), Vec::new(), Vec::new());
        for (plane_logits, plane_labels) in planes {
            let positives = plane_labels.iter().filter(|&&y| y).count();
            let negatives = plane_labels.len() - positives;
            let weight = |y: bool| match self.settings.class_balance.positive_share() {
                None => 1.0,
                Some(share) if y => share / positives as f32,
                Some(share) => (1.0 - share) / negatives as f32,
            };
            weights.extend(plane_labels.iter().map(|&y| weight(y)));
            logits.extend(plane_logits);
            labels.extend(plane_labels);
        }
        fit_weighted_temperature(&logits, &labels, &weights)
    }

    /// The deployed network's calibration temperature.
    pub fn temperature(&self) -> f32 {
        self.temperature
    }

    /// The deployed network's weights (what the actors should use).
    pub fn deployed_weights(&self) -> Result<Vec<u8>, WeightsError> {
        to_safetensors(&self.deployed)
    }

    /// The network in training and its optimiser's state, for a checkpoint.
    pub fn training_state(&self) -> Result<UnetTrainingState, TrainingStateError> {
        Ok(UnetTrainingState {
            candidate: to_safetensors(&self.trainer.inference_net(&self.device))?,
            optimizer: self.trainer.optimizer_state()?,
            average: match &self.average {
                Some(average) => Some(to_safetensors(average.average())?),
                None => None,
            },
        })
    }

    /// Continues training from a saved network in training and its
    /// optimiser's state (after [`AffordanceLearner::restore`]). On error
    /// nothing changes.
    pub fn restore_training(
        &mut self,
        state: &UnetTrainingState,
    ) -> Result<(), TrainingStateError> {
        let mut net = Self::trainee(
            AffordanceUnet::new(4, self.affordances, &self.device),
            &self.settings,
        );
        load_safetensors(&mut net, state.candidate.clone())?;
        let mut trainer =
            UnetTrainer::new(net.clone(), Self::training(&self.settings), &self.device);
        trainer.restore_optimizer(&state.optimizer)?;
        let average = match (&state.average, self.settings.weight_average > 0.0) {
            (Some(bytes), true) => {
                let mut average = AffordanceUnet::new(4, self.affordances, &self.device);
                load_safetensors(&mut average, bytes.clone())?;
                Some(WeightAverage::resumed(
                    average,
                    self.settings.weight_average,
                ))
            }
            // Saved without an average: it starts at the saved weights.
            _ => Self::average_from(&net.folded(), &self.settings),
        };
        self.trainer = trainer;
        self.average = average;
        Ok(())
    }

    /// Continues from saved deployed weights and temperature (training
    /// restarts from them, with a fresh optimiser and, with `[unet]
    /// batch_norm`, fresh normalisations, unless
    /// [`AffordanceLearner::restore_training`] follows).
    pub fn restore(&mut self, bytes: Vec<u8>, temperature: f32) -> Result<(), WeightsError> {
        self.temperature = temperature;
        let mut net = AffordanceUnet::new(4, self.affordances, &self.device);
        load_safetensors(&mut net, bytes)?;
        self.trainer = UnetTrainer::new(
            Self::trainee(net.clone(), &self.settings),
            Self::training(&self.settings),
            &self.device,
        );
        self.average = Self::average_from(&net, &self.settings);
        self.deployed = net;
        self.gate.forget();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::{decode, encode, FrameBatch, Limits, Message, MessageHeader};

    fn frames_of(size: u32, affordances: u32) -> Vec<u8> {
        let pixels = (size * size) as usize;
        let batch = FrameBatch {
            episode_id: 7,
            height: size,
            width: size,
            n_affordances: affordances,
            depth_m: vec![1.5; pixels],
            rgb: vec![128; 3 * pixels],
            labels: vec![LABEL_UNKNOWN; affordances as usize * pixels],
        };
        encode(&batch, MessageHeader::default())
    }

    fn check(bytes: &[u8]) -> Result<Vec<LabelledFrame>, FramesError> {
        let limits = Limits {
            max_actors: 4,
            max_payload_len: 1 << 24,
        };
        match decode(bytes, &limits).expect("a valid message") {
            (_, Message::Frames(view)) => checked_frames(&view, 2, 64),
            (_, other) => panic!("not frames: {other:?}"),
        }
    }

    #[test]
    fn a_round_takes_the_steps_asked_for_once_there_are_frames() {
        let settings = UnetConfig {
            steps_per_episode: 2,
            batch_frames: 1,
            validation_fraction: 0.0,
            test_fraction: 0.0,
            ..UnetConfig::default()
        };
        let device = Device::flex();
        let mut learner = AffordanceLearner::new(1, &settings, 1, &device);
        assert!(learner.train_round(2).is_none(), "nothing to train on yet");
        let frame = LabelledFrame {
            size: [16, 16],
            rgbd: vec![0.5; 4 * 256],
            labels: vec![1; 256],
        };
        for episode in 0..3 {
            learner.add_episode(episode, vec![frame.clone()]);
        }
        assert_eq!(learner.train_round(6).map(|r| r.steps), Some(6));
        assert_eq!(learner.steps_per_episode(), 2);
    }

    /// Every parameter's values, in the visiting order.
    struct Values(Vec<f32>);

    impl burn::module::ModuleVisitor for Values {
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            self.0
                .extend(param.val().into_data().try_to_vec::<f32>().expect("floats"));
        }
    }

    #[test]
    fn an_averaging_learner_gates_its_average_and_keeps_it_through_a_checkpoint() {
        let settings = |weight_average| UnetConfig {
            batch_frames: 1,
            validation_fraction: 0.0,
            test_fraction: 0.0,
            weight_average,
            ..UnetConfig::default()
        };
        let device = Device::flex();
        let frame = LabelledFrame {
            size: [16, 16],
            rgbd: vec![0.5; 4 * 256],
            labels: vec![1; 256],
        };
        let trained = |weight_average| {
            let mut learner = AffordanceLearner::new(1, &settings(weight_average), 1, &device);
            learner.add_episode(0, vec![frame.clone()]);
            learner.train_round(3).expect("frames to train on");
            learner
        };
        let plain = trained(0.0);
        assert!(plain.training_state().unwrap().average.is_none());

        let averaging = trained(0.9);
        let state = averaging.training_state().unwrap();
        let average = state.average.clone().expect("the average in the state");

        let mut resumed = AffordanceLearner::new(1, &settings(0.9), 2, &device);
        resumed.restore_training(&state).unwrap();
        let again = resumed.training_state().unwrap();
        let weights = |bytes: &Vec<u8>| {
            let mut net = AffordanceUnet::new(4, 1, &device);
            load_safetensors(&mut net, bytes.clone()).unwrap();
            let mut values = Values(Vec::new());
            net.visit(&mut values);
            values.0
        };
        assert!(
            weights(again.average.as_ref().unwrap()) == weights(&average),
            "the average restored"
        );
        assert!(
            weights(&again.candidate) == weights(&state.candidate),
            "the latest weights restored"
        );
        assert!(weights(&average) != weights(&state.candidate));
    }

    #[test]
    fn a_normalising_learner_deploys_plain_weights_and_checkpoints_its_statistics() {
        let settings = |batch_norm| UnetConfig {
            batch_frames: 2,
            validation_fraction: 0.0,
            test_fraction: 0.0,
            batch_norm,
            ..UnetConfig::default()
        };
        let device = Device::flex();
        // Frames that differ, so that the batches' statistics move the
        // running ones.
        let frame = |shade: f32| LabelledFrame {
            size: [16, 16],
            rgbd: (0..4 * 256).map(|i| shade + (i % 7) as f32 * 0.1).collect(),
            labels: (0..256).map(|i| u8::from(i % 3 == 0)).collect(),
        };
        let mut learner = AffordanceLearner::new(1, &settings(true), 1, &device);
        learner.add_episode(0, vec![frame(0.1), frame(0.6), frame(0.3)]);
        learner.train_round(4).expect("frames to train on");

        // The actors' network is a plain one.
        let mut plain = AffordanceUnet::new(4, 1, &device);
        load_safetensors(&mut plain, learner.deployed_weights().unwrap())
            .expect("the deployed weights fit a plain network");
        // The network in training keeps its normalisations, running
        // statistics included, and a resumed learner takes them back.
        let state = learner.training_state().unwrap();
        // (Built apart: a clone shares its running statistics.)
        let fresh = AffordanceUnet::new(4, 1, &device).with_batch_norm();
        let mut normalised = AffordanceUnet::new(4, 1, &device).with_batch_norm();
        load_safetensors(&mut normalised, state.candidate.clone())
            .expect("the candidate holds its normalisations");
        // The tensors alone (a file's header may list them in any order).
        let tensors = |bytes: &[u8], name: &str| nets::weights::unbundle(bytes, name).unwrap();
        let statistic = "down.0.first_norm.running_mean";
        assert!(
            tensors(&state.candidate, statistic)
                != tensors(&to_safetensors(&fresh).unwrap(), statistic),
            "the running statistics moved in training and were saved"
        );
        let mut resumed = AffordanceLearner::new(1, &settings(true), 2, &device);
        resumed.restore_training(&state).unwrap();
        let again = resumed.training_state().unwrap().candidate;
        assert!(tensors(&again, "") == tensors(&state.candidate, ""));
        // A run without them refuses the state rather than drop them.
        let mut other = AffordanceLearner::new(1, &settings(false), 2, &device);
        assert!(other.restore_training(&state).is_err());
    }

    #[test]
    fn frames_of_the_task_are_taken_and_others_refused_with_the_reason() {
        let taken = check(&frames_of(64, 2)).expect("the task's frames");
        assert_eq!(taken.len(), 1);
        assert_eq!(taken[0].size, [64, 64]);
        assert!(taken[0].labels.iter().all(|&l| l == UNKNOWN));

        let err = check(&frames_of(128, 2)).unwrap_err();
        assert!(
            err.to_string().contains("128 × 128 pixels") && err.to_string().contains("64 × 64"),
            "{err}"
        );
        let err = check(&frames_of(64, 1)).unwrap_err();
        assert!(err.to_string().contains("1 affordance planes"), "{err}");
    }
}
