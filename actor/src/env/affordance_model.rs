//! The actor's copy of the affordance U-Net: RGB-D in, one calibrated
//! probability plane per affordance out (sigmoid of logit / temperature).

use burn::prelude::*;
use nets::unet::AffordanceUnet;

/// The U-Net the actor infers with, and its calibration.
#[derive(Debug)]
pub struct AffordanceModel {
    net: AffordanceUnet,
    device: Device,
    affordances: usize,
    /// Temperature from the learner's calibration (1 = plain sigmoid).
    pub temperature: f32,
}

impl AffordanceModel {
    /// A freshly initialised network (before the learner's first weights).
    pub fn new(affordances: usize, device: &Device) -> Self {
        Self {
            net: AffordanceUnet::new(4, affordances, device),
            device: device.clone(),
            affordances,
            temperature: 1.0,
        }
    }

    /// Replaces the network (new weights from the learner).
    pub fn set_net(&mut self, net: AffordanceUnet) {
        self.net = net;
    }

    /// Loads safetensors weights from the learner; on error the current
    /// network stays.
    pub fn load_weights(&mut self, bytes: Vec<u8>) -> Result<(), nets::weights::WeightsError> {
        let mut net = AffordanceUnet::new(4, self.affordances, &self.device);
        nets::weights::load_safetensors(&mut net, bytes)?;
        self.net = net;
        Ok(())
    }

    /// Per affordance, the `h · w` probability plane of one frame.
    pub fn predict(&self, frame: &CameraFrame<'_>) -> Vec<Vec<f32>> {
        self.predict_batch(std::slice::from_ref(frame))
            .pop()
            .unwrap_or_default()
    }

    /// [`AffordanceModel::predict`] for several frames of one size, in one
    /// forward pass (batches are what keep a GPU busy).
    ///
    /// # Panics
    /// If the frames differ in size: an actor's environments share one task.
    pub fn predict_batch(&self, frames: &[CameraFrame<'_>]) -> Vec<Vec<Vec<f32>>> {
        let Some(first) = frames.first() else {
            return Vec::new();
        };
        let (height, width) = (first.height, first.width);
        assert!(
            frames
                .iter()
                .all(|f| (f.height, f.width) == (height, width)),
            "frames of one batch share a size"
        );
        let n = height * width;
        let mut input = Vec::with_capacity(frames.len() * 4 * n);
        for frame in frames {
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
        }
        let x = Tensor::<1>::from_floats(input.as_slice(), &self.device).reshape([
            frames.len(),
            4,
            height,
            width,
        ]);
        let logits: Vec<f32> = self
            .net
            .forward(x)
            .into_data()
            .try_to_vec()
            .expect("the U-Net returns f32 logits");
        let t = self.temperature.max(1e-3);
        let planes_per_frame = logits.len() / frames.len();
        logits
            .chunks(planes_per_frame)
            .map(|frame| {
                frame
                    .chunks(n)
                    .take(self.affordances)
                    .map(|plane| {
                        plane
                            .iter()
                            .map(|&l| 1.0 / (1.0 + (-l / t).exp()))
                            .collect()
                    })
                    .collect()
            })
            .collect()
    }
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
    fn a_batch_gives_each_frame_what_it_gets_alone() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let model = AffordanceModel::new(2, &device);
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
        // One pass over three frames (the GPU's way) against each alone.
        let one_pass = model.predict_batch(&frames);
        assert_eq!(one_pass.len(), 3);
        for (k, frame) in frames.iter().enumerate() {
            let alone = model.predict(frame);
            assert_eq!(alone.len(), 2);
            assert_eq!(alone[0].len(), h * w);
            for (a, b) in one_pass[k].iter().flatten().zip(alone.iter().flatten()) {
                assert!((a - b).abs() < 1e-5, "frame {k}: {a} vs {b}");
            }
        }
        assert!(one_pass[0] != one_pass[1]);
    }
}
