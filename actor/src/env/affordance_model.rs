//! The actor's copy of the affordance U-Net: RGB-D in, one calibrated
//! probability plane per affordance out (sigmoid of logit / temperature).

use burn::prelude::*;
use nets::unet::AffordanceUnet;
use nets::unet_inference::UnetInference;

/// The U-Net the actor infers with, and its calibration.
#[derive(Debug)]
pub struct AffordanceModel {
    net: UnetInference,
    device: Device,
    affordances: usize,
    /// Temperature from the learner's calibration (1 = plain sigmoid).
    pub temperature: f32,
}

impl AffordanceModel {
    /// A freshly initialised network (before the learner's first weights).
    pub fn new(affordances: usize, device: &Device) -> Self {
        Self {
            net: UnetInference::new(AffordanceUnet::new(4, affordances, device), device),
            device: device.clone(),
            affordances,
            temperature: 1.0,
        }
    }

    /// Loads safetensors weights from the learner; on error the current
    /// network stays.
    pub fn load_weights(&mut self, bytes: Vec<u8>) -> Result<(), nets::weights::WeightsError> {
        *self = self.with_weights(bytes, self.temperature)?;
        Ok(())
    }

    /// A model like this one with the learner's safetensors weights and
    /// calibration `temperature`, built without touching this one: the
    /// environments go on inferring with it while the new one loads, and
    /// wait only for the swap.
    pub fn with_weights(
        &self,
        bytes: Vec<u8>,
        temperature: f32,
    ) -> Result<Self, nets::weights::WeightsError> {
        let mut net = AffordanceUnet::new(4, self.affordances, &self.device);
        nets::weights::load_safetensors(&mut net, bytes)?;
        Ok(Self {
            net: UnetInference::new(net, &self.device),
            device: self.device.clone(),
            affordances: self.affordances,
            temperature,
        })
    }

    /// Per affordance, the `h · w` probability plane of one frame.
    pub fn predict(&self, frame: &CameraFrame<'_>) -> Vec<Vec<f32>> {
        let input = network_input(frame);
        self.logits(&[&input], frame.height, frame.width)
            .pop()
            .map(|logits| logits.probabilities())
            .unwrap_or_default()
    }

    /// The network's output for `inputs` ([`network_input`]s of frames of
    /// `height · width`), in one forward pass on a GPU: the only part of a
    /// prediction that needs the model.
    pub(crate) fn logits(&self, inputs: &[&[f32]], height: usize, width: usize) -> Vec<Logits> {
        self.net
            .logits(inputs, height, width)
            .into_iter()
            .map(|values| Logits {
                values,
                pixels: height * width,
                affordances: self.affordances,
                temperature: self.temperature,
            })
            .collect()
    }
}

/// The U-Net's planes for an environment's camera `frame`, as its
/// observation takes them: none without a camera, an error for a frame with
/// no U-Net to see it.
pub fn planes_for(
    frame: Option<CameraFrame<'_>>,
    model: Option<&AffordanceModel>,
) -> anyhow::Result<Vec<Vec<f32>>> {
    match (frame, model) {
        (None, _) => Ok(Vec::new()),
        (Some(frame), Some(model)) => Ok(model.predict(&frame)),
        (Some(_), None) => anyhow::bail!("this environment's camera frames need the U-Net"),
    }
}

/// One frame's output of the U-Net, and its calibration.
#[derive(Debug)]
pub(crate) struct Logits {
    /// Planes of `pixels` logits, one per output channel.
    values: Vec<f32>,
    pixels: usize,
    affordances: usize,
    /// The learner's calibration when the logits were made.
    temperature: f32,
}

impl Logits {
    /// Per affordance, the calibrated probability plane (sigmoid of
    /// logit / temperature).
    pub(crate) fn probabilities(&self) -> Vec<Vec<f32>> {
        let t = self.temperature.max(1e-3);
        self.values
            .chunks(self.pixels.max(1))
            .take(self.affordances)
            .map(|plane| {
                plane
                    .iter()
                    .map(|&l| 1.0 / (1.0 + (-l / t).exp()))
                    .collect()
            })
            .collect()
    }
}

/// The U-Net's input for one frame: `[r, g, b, depth]` planes, colour in
/// 0..1, depth in metres with nothing seen as 0.
pub(crate) fn network_input(frame: &CameraFrame<'_>) -> Vec<f32> {
    let mut input = Vec::with_capacity(4 * frame.height * frame.width);
    for c in 0..3 {
        input.extend(
            frame
                .rgb
                .iter()
                .skip(c)
                .step_by(3)
                .map(|&b| f32::from(b) / 255.0),
        );
    }
    input.extend(
        frame
            .depth_m
            .iter()
            .map(|&d| if d.is_finite() { d.max(0.0) } else { 0.0 }),
    );
    input
}

/// One RGB-D camera frame as the U-Net reads it.
#[derive(Debug, Clone, Copy)]
pub struct CameraFrame<'a> {
    /// Interleaved RGB bytes, `height · width · 3`.
    pub rgb: &'a [u8],
    /// Depth in metres (non-finite = nothing seen), `height · width`.
    pub depth_m: &'a [f32],
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn burns_batch_gives_each_frame_what_the_cpu_path_gives_it_alone() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let net = AffordanceUnet::new(4, 2, &device);
        let cpu = AffordanceModel {
            net: UnetInference::Cpu(nets::unet_cpu::CpuUnet::from_network(&net)),
            device: device.clone(),
            affordances: 2,
            temperature: 0.7,
        };
        let model = AffordanceModel {
            net: UnetInference::Burn {
                net: Box::new(net),
                device: device.clone(),
            },
            device: device.clone(),
            affordances: 2,
            temperature: 0.7,
        };
        let (h, w) = (32, 32);
        let rgb: Vec<Vec<u8>> = (0..3)
            .map(|k| {
                (0..h * w * 3)
                    .map(|i| ((i * 31 + k * 77) % 256) as u8)
                    .collect()
            })
            .collect();
        let depth: Vec<Vec<f32>> = (0..3)
            .map(|k| {
                (0..h * w)
                    .map(|i| {
                        if i % 50 == k {
                            f32::NAN
                        } else {
                            0.5 + (i % 13) as f32 * 0.1
                        }
                    })
                    .collect()
            })
            .collect();
        let frames: Vec<CameraFrame<'_>> = (0..3)
            .map(|k| CameraFrame {
                rgb: &rgb[k],
                depth_m: &depth[k],
                height: h,
                width: w,
            })
            .collect();
        // One burn pass over three frames (the GPU's way, as the batching
        // thread makes it) against each frame alone through the CPU path.
        let inputs: Vec<Vec<f32>> = frames.iter().map(network_input).collect();
        let inputs: Vec<&[f32]> = inputs.iter().map(Vec::as_slice).collect();
        let one_pass: Vec<Vec<Vec<f32>>> = model
            .logits(&inputs, h, w)
            .iter()
            .map(Logits::probabilities)
            .collect();
        assert_eq!(one_pass.len(), 3);
        for (k, frame) in frames.iter().enumerate() {
            let alone = cpu.predict(frame);
            assert_eq!(alone.len(), 2);
            assert_eq!(alone[0].len(), h * w);
            for (a, b) in one_pass[k].iter().flatten().zip(alone.iter().flatten()) {
                assert!((a - b).abs() < 1e-5, "frame {k}: {a} vs {b}");
            }
        }
        assert!(one_pass[0] != one_pass[1]);
    }

    #[test]
    fn a_model_with_new_weights_leaves_the_one_in_use_as_it_was() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let (h, w) = (16, 16);
        let rgb: Vec<u8> = (0..h * w * 3).map(|i| ((i * 37) % 256) as u8).collect();
        let depth: Vec<f32> = (0..h * w).map(|i| 0.5 + (i % 11) as f32 * 0.1).collect();
        let frame = CameraFrame {
            rgb: &rgb,
            depth_m: &depth,
            height: h,
            width: w,
        };
        let in_use = AffordanceModel::new(2, &device);
        let before = in_use.predict(&frame);
        let learners = AffordanceUnet::new(4, 2, &device);
        let bytes = nets::weights::to_safetensors(&learners).unwrap();
        let fresh = in_use.with_weights(bytes.clone(), 0.5).unwrap();
        assert_eq!(
            in_use.predict(&frame),
            before,
            "the model in use is untouched"
        );
        assert_eq!(fresh.temperature, 0.5);
        // The new model infers with the learner's weights: as a model that
        // loaded them in place does.
        let mut loaded = AffordanceModel::new(2, &device);
        loaded.load_weights(bytes).unwrap();
        loaded.temperature = 0.5;
        assert_eq!(fresh.predict(&frame), loaded.predict(&frame));
        assert_ne!(fresh.predict(&frame), before);
    }
}
