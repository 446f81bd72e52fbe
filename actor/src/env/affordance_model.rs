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

    /// Per affordance, the `h · w` probability plane for an RGB-D frame
    /// (`rgb` interleaved bytes, `depth_m` metres).
    pub fn predict(
        &self,
        rgb: &[u8],
        depth_m: &[f32],
        height: usize,
        width: usize,
    ) -> Vec<Vec<f32>> {
        let n = height * width;
        let mut input = Vec::with_capacity(4 * n);
        for c in 0..3 {
            input.extend(rgb.iter().skip(c).step_by(3).map(|&b| f32::from(b) / 255.0));
        }
        input.extend(
            depth_m
                .iter()
                .map(|&d| if d.is_finite() { d.max(0.0) } else { 0.0 }),
        );
        let x =
            Tensor::<1>::from_floats(input.as_slice(), &self.device).reshape([1, 4, height, width]);
        let logits: Vec<f32> = self
            .net
            .forward(x)
            .into_data()
            .try_to_vec()
            .expect("the U-Net returns f32 logits");
        let t = self.temperature.max(1e-3);
        logits
            .chunks(n)
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
