//! Training and evaluating the affordance U-Net on labelled frames.

use crate::adam::{Adam, AdamSettings};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use nets::unet::{masked_bce_dice, AffordanceUnet, ClassBalance};
use nets::unet_inference::UnetInference;

use crate::optimizer_state::{OptimizerState, OptimizerStateError};

/// The U-Net's logits for a training step: on libtorch the whole pass as
/// one operation with libtorch's backward (`unet_train_torch`), else its
/// forward pass.
fn logits(net: &AffordanceUnet, x: Tensor<4>) -> Tensor<4> {
    #[cfg(feature = "gpu-torch")]
    return crate::unet_train_torch::logits(net, x);
    #[cfg(not(feature = "gpu-torch"))]
    net.forward(x)
}

/// Label value of a pixel no interaction or annotation says anything about.
pub const UNKNOWN: u8 = 255;

/// One RGB-D frame with per-pixel labels for each affordance.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelledFrame {
    /// Height and width, pixels.
    pub size: [usize; 2],
    /// `[4, h, w]`: red, green, blue in 0..1, then depth in metres.
    pub rgbd: Vec<f32>,
    /// `[affordances, h, w]`: 1 = affords, 0 = does not, [`UNKNOWN`].
    pub labels: Vec<u8>,
}

impl LabelledFrame {
    /// Number of affordances labelled.
    pub fn affordances(&self) -> usize {
        self.labels.len() / (self.size[0] * self.size[1])
    }

    /// The frame mirrored left to right: every plane's rows reversed, the
    /// labels with the image.
    pub fn mirrored(&self) -> LabelledFrame {
        LabelledFrame {
            size: self.size,
            rgbd: rows_reversed(&self.rgbd, self.size[1]),
            labels: rows_reversed(&self.labels, self.size[1]),
        }
    }
}

/// `planes` (rows of `width` values) with every row reversed.
fn rows_reversed<T: Copy>(planes: &[T], width: usize) -> Vec<T> {
    planes
        .chunks(width)
        .flat_map(|row| row.iter().rev().copied())
        .collect()
}

/// Settings of U-Net training.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnetTrainingConfig {
    /// Adam learning rate.
    pub learning_rate: f64,
    /// L2 weight decay.
    pub weight_decay: f32,
    /// How the loss weighs positive labels against negative ones.
    pub class_balance: ClassBalance,
}

impl Default for UnetTrainingConfig {
    fn default() -> Self {
        Self {
            learning_rate: 1e-3,
            weight_decay: 1e-4,
            class_balance: ClassBalance::default(),
        }
    }
}

/// Stacks frames into `(rgbd [b, 4, h, w], labels [b, a, h, w], known [b, a, h, w])`.
pub fn batch_tensors(
    frames: &[&LabelledFrame],
    device: &Device,
) -> (Tensor<4>, Tensor<4>, Tensor<4>) {
    let [h, w] = frames[0].size;
    let rgbd: Vec<f32> = frames.iter().flat_map(|f| f.rgbd.iter().copied()).collect();
    let x = Tensor::<1>::from_floats(rgbd.as_slice(), device).reshape([frames.len(), 4, h, w]);
    let (labels, known) = label_tensors(frames, device);
    (x, labels, known)
}

/// `(labels [b, a, h, w], known [b, a, h, w])` of [`batch_tensors`], for a
/// loss whose logits come from elsewhere.
fn label_tensors(frames: &[&LabelledFrame], device: &Device) -> (Tensor<4>, Tensor<4>) {
    let [h, w] = frames[0].size;
    let shape = [frames.len(), frames[0].affordances(), h, w];
    let plane = |value: fn(u8) -> bool| {
        let v: Vec<f32> = frames
            .iter()
            .flat_map(|f| f.labels.iter().map(move |&l| f32::from(u8::from(value(l)))))
            .collect();
        Tensor::<1>::from_floats(v.as_slice(), device).reshape(shape)
    };
    (plane(|l| l == 1), plane(|l| l != UNKNOWN))
}

/// Trains a U-Net with Adam (weight decay) on the masked BCE + Dice loss.
pub struct UnetTrainer {
    /// The network being trained (autodiff device).
    pub net: AffordanceUnet,
    optimizer: ModuleOptimizer,
    config: UnetTrainingConfig,
    device: Device,
}

impl UnetTrainer {
    /// Trains `net` on `device` (made autodiff here).
    pub fn new(net: AffordanceUnet, config: UnetTrainingConfig, device: &Device) -> Self {
        let device = device.clone().autodiff();
        Self {
            net: net.fork(&device).train(),
            optimizer: adam(&config),
            config,
            device,
        }
    }

    /// Adam's state, for a checkpoint (with [`UnetTrainer::inference_net`]'s weights).
    pub fn optimizer_state(&self) -> Result<OptimizerState, OptimizerStateError> {
        OptimizerState::capture(&self.optimizer, &self.net)
    }

    /// Continues from a saved Adam state (after the weights were restored).
    /// On error nothing changes.
    pub fn restore_optimizer(&mut self, state: &OptimizerState) -> Result<(), OptimizerStateError> {
        let (net, optimizer) = state.restore(self.net.clone(), adam(&self.config))?;
        self.net = net;
        self.optimizer = optimizer;
        Ok(())
    }

    /// One gradient step on `frames`; returns the loss before the step.
    pub fn step(&mut self, frames: &[&LabelledFrame]) -> f32 {
        let (x, y, known) = batch_tensors(frames, &self.device);
        let loss = masked_bce_dice(logits(&self.net, x), y, known, self.config.class_balance);
        let value = loss.clone();
        let grads = GradientsParams::from_grads(loss.backward(), &self.net);
        self.net = self
            .optimizer
            .step(self.config.learning_rate, self.net.clone(), grads);
        // Read back last: on a GPU, reading the loss before the backward
        // pass made this thread wait for the forward pass before it could
        // queue a single backward or optimiser kernel (as PPO's update
        // reads its statistics once, after its minibatches).
        value.into_scalar::<f32>()
    }

    /// The network without autodiff, for inference on `device`.
    pub fn inference_net(&self, device: &Device) -> AffordanceUnet {
        self.net.valid().to_device(device)
    }
}

/// A fresh Adam with `config`'s weight decay.
fn adam(config: &UnetTrainingConfig) -> ModuleOptimizer {
    Adam::for_module(AdamSettings {
        weight_decay: Some(config.weight_decay),
        ..AdamSettings::default()
    })
}

/// Logits `[affordances, h, w]` of one frame, row-major.
pub fn predict_logits(net: &UnetInference, frame: &LabelledFrame) -> Vec<f32> {
    let [h, w] = frame.size;
    net.logits(&[&frame.rgbd], h, w)
        .pop()
        .expect("one image in, one out")
}

/// How well a network does on labelled frames.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Evaluation {
    /// Mean masked BCE + Dice loss over the frames (lower is better).
    pub loss: f32,
    /// IoU of `logit > 0` with the positive labels, over labelled pixels.
    pub iou: f32,
    /// Labelled pixels counted.
    pub labelled_pixels: usize,
}

impl Evaluation {
    /// The evaluation over frames from each frame's score, in order (the
    /// losses summed in that order, so the same scores give the same
    /// figures however they were gathered).
    pub fn from_scores<'a>(scores: impl IntoIterator<Item = &'a FrameScore>) -> Self {
        let (mut loss, mut inter, mut union, mut labelled, mut frames) =
            (0.0f64, 0usize, 0usize, 0usize, 0usize);
        for score in scores {
            loss += score.loss;
            inter += score.intersection;
            union += score.union;
            labelled += score.labelled;
            frames += 1;
        }
        Self {
            loss: (loss / frames.max(1) as f64) as f32,
            iou: if union == 0 {
                1.0
            } else {
                inter as f32 / union as f32
            },
            labelled_pixels: labelled,
        }
    }
}

/// One frame's part of an [`Evaluation`]: its loss and its labelled
/// pixels' counts. Kept per frame, a network's scores on frames it has
/// already seen need not be computed again (the validation gate's deployed
/// network, `gate`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameScore {
    /// Masked BCE + Dice loss of the frame.
    pub loss: f64,
    /// Labelled pixels both predicted (`logit > 0`) and labelled positive.
    pub intersection: usize,
    /// Labelled pixels predicted or labelled positive.
    pub union: usize,
    /// Labelled pixels.
    pub labelled: usize,
}

/// Frames a network takes at once when it scores many (the gate's, an
/// evaluation's): on a GPU a batch of 8 costs about twice one frame
/// (docs/performance.md), on the CPU the frames run one by one either way.
pub const SCORING_BATCH: usize = 8;

/// Each of `frames` (of one size) scored under `net`, with its logits
/// (`[affordances, h, w]`, row-major), the frames taken in batches of
/// [`SCORING_BATCH`].
pub fn score_frames(
    net: &UnetInference,
    frames: &[&LabelledFrame],
    balance: ClassBalance,
) -> (Vec<FrameScore>, Vec<Vec<f32>>) {
    let logits: Vec<Vec<f32>> = frames
        .chunks(SCORING_BATCH)
        .flat_map(|batch| {
            let [h, w] = batch[0].size;
            let images: Vec<&[f32]> = batch.iter().map(|f| f.rgbd.as_slice()).collect();
            net.logits(&images, h, w)
        })
        .collect();
    let scores = frames
        .iter()
        .zip(&logits)
        .map(|(frame, logits)| score_logits(frame, logits, balance))
        .collect();
    (scores, logits)
}

/// Scores one frame (see [`FrameScore`]) from a network's `logits` on it.
/// The loss is taken on the CPU: one frame's loss is cheap there, and on
/// a GPU each would be a round trip.
fn score_logits(frame: &LabelledFrame, logits: &[f32], balance: ClassBalance) -> FrameScore {
    let cpu = Device::flex();
    let (y, known) = label_tensors(&[frame], &cpu);
    let tensor = Tensor::<1>::from_floats(logits, &cpu).reshape(y.dims());
    let mut score = FrameScore {
        loss: f64::from(masked_bce_dice(tensor, y, known, balance).into_scalar::<f32>()),
        ..FrameScore::default()
    };
    for (&l, &label) in logits.iter().zip(&frame.labels) {
        if label == UNKNOWN {
            continue;
        }
        score.labelled += 1;
        let (p, t) = (l > 0.0, label == 1);
        score.intersection += usize::from(p && t);
        score.union += usize::from(p || t);
    }
    score
}

/// Evaluates `net` (inference on `device`) on `frames`, the loss weighing
/// the classes by `balance` as training does.
pub fn evaluate(
    net: &AffordanceUnet,
    frames: &[&LabelledFrame],
    balance: ClassBalance,
    device: &Device,
) -> Evaluation {
    let inference = UnetInference::new(net.clone(), device);
    // A batch at a time, so that memory stays flat however many frames.
    let scores: Vec<FrameScore> = frames
        .chunks(SCORING_BATCH)
        .flat_map(|batch| score_frames(&inference, batch, balance).0)
        .collect();
    Evaluation::from_scores(&scores)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mirrored_frame_has_each_row_reversed_in_every_plane_labels_with_it() {
        // 2 × 3 pixels, 4 image planes and 2 label planes, each value its
        // own: (plane, row, column) read back from where it lands.
        let (h, w) = (2, 3);
        let frame = LabelledFrame {
            size: [h, w],
            rgbd: (0..4 * h * w).map(|i| i as f32).collect(),
            labels: (0..2 * h * w).map(|i| i as u8).collect(),
        };
        let mirrored = frame.mirrored();
        for plane in 0..4 {
            for row in 0..h {
                for col in 0..w {
                    let at = |c: usize| (plane * h + row) * w + c;
                    assert_eq!(mirrored.rgbd[at(col)], frame.rgbd[at(w - 1 - col)]);
                    if plane < 2 {
                        assert_eq!(mirrored.labels[at(col)], frame.labels[at(w - 1 - col)]);
                    }
                }
            }
        }
        assert_ne!(mirrored.rgbd, frame.rgbd);
        let back = mirrored.mirrored();
        assert_eq!((back.rgbd, back.labels), (frame.rgbd, frame.labels));
    }
}
