//! An exponential moving average of a network's weights over its training
//! steps (Polyak averaging, as "EMA" models in image classification and
//! diffusion): the U-Net trains on the few frames that show a successful
//! pick-up, so its weights swing from one step to the next and a
//! checkpoint's network is a draw among them (docs/ladder.md); the average
//! of the recent steps' weights does not swing.
//!
//! The average is debiased as Adam's moments are: after `t` steps it weighs
//! step `s` by `decay^(t - s)`, normalised over the steps taken, so its
//! first value is the first step's weights rather than a pull towards the
//! initial ones.

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;

/// The running average of a module's weights.
#[derive(Debug, Clone)]
pub struct WeightAverage<M> {
    average: M,
    decay: f64,
    /// `decay^steps`: what the debiasing needs of the steps taken.
    decay_power: f64,
}

impl<M: Module> WeightAverage<M> {
    /// An average that starts at `start`'s weights, counted as one step
    /// (further steps weigh the way they would after it). `decay` in
    /// `[0, 1)`: each step keeps `decay` of the average's weight.
    pub fn new(start: M, decay: f64) -> Self {
        Self {
            average: start,
            decay,
            decay_power: decay,
        }
    }

    /// An average restored from a checkpoint: its weights as they were,
    /// weighing further steps as a long-running average does.
    pub fn resumed(average: M, decay: f64) -> Self {
        Self {
            average,
            decay,
            decay_power: 0.0,
        }
    }

    /// Takes one step's weights into the average. `net` must have the
    /// average's structure (the network in training, without autodiff, on
    /// the average's device).
    pub fn update(&mut self, net: &M) {
        self.decay_power *= self.decay;
        // The share of the newest weights in the normalised average.
        let share = (1.0 - self.decay) / (1.0 - self.decay_power);
        let mut newest = Flattened::default();
        net.visit(&mut newest);
        let mut blend = Blend {
            newest: newest.values.into_iter(),
            share: share as f32,
        };
        self.average = self.average.clone().map(&mut blend);
    }

    /// The averaged weights.
    pub fn average(&self) -> &M {
        &self.average
    }
}

/// Every float parameter of a module, flattened, in the visiting order.
#[derive(Default)]
struct Flattened {
    values: Vec<Tensor<1>>,
}

impl ModuleVisitor for Flattened {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let value = param.val();
        let len = value.shape().num_elements();
        self.values.push(value.reshape([len]));
    }
}

/// Moves each parameter `share` of the way towards the newest weights.
struct Blend {
    newest: std::vec::IntoIter<Tensor<1>>,
    share: f32,
}

impl ModuleMapper for Blend {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some(newest) = self.newest.next() else {
            return param; // not reached: the two modules have one structure
        };
        let share = self.share;
        param.map(|average| {
            let newest = newest.reshape(average.dims());
            average.clone() + (newest - average) * share
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    fn with_weights(value: f32, device: &Device) -> Linear {
        LinearConfig::new(2, 3)
            .init(device)
            .map(&mut Fill { value })
    }

    struct Fill {
        value: f32,
    }

    impl ModuleMapper for Fill {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let value = self.value;
            param.map(|t| t.zeros_like() + value)
        }
    }

    fn values(net: &Linear) -> Vec<f32> {
        let mut flat = Flattened::default();
        net.visit(&mut flat);
        flat.values
            .into_iter()
            .flat_map(|t| t.into_data().try_to_vec::<f32>().expect("floats"))
            .collect()
    }

    #[test]
    fn the_average_weighs_each_step_by_its_decay_normalised_over_the_steps_taken() {
        let device = Device::flex();
        let decay = 0.5;
        let mut average = WeightAverage::new(with_weights(1.0, &device), decay);
        assert!(values(average.average()).iter().all(|&v| v == 1.0));
        average.update(&with_weights(4.0, &device));
        average.update(&with_weights(10.0, &device));
        // By hand: weights 0.25, 0.5, 1 for 1, 4, 10, over their sum 1.75.
        let expected = (0.25 * 1.0 + 0.5 * 4.0 + 1.0 * 10.0) / 1.75;
        for v in values(average.average()) {
            assert!((v - expected).abs() < 1e-5, "{v} against {expected}");
        }
    }

    #[test]
    fn a_resumed_average_moves_by_one_minus_the_decay_a_step() {
        let device = Device::flex();
        let mut average = WeightAverage::resumed(with_weights(2.0, &device), 0.9);
        average.update(&with_weights(12.0, &device));
        for v in values(average.average()) {
            assert!((v - 3.0).abs() < 1e-5, "{v}");
        }
    }
}
