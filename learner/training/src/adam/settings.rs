//! Adam's settings, and burn's Adam made from them: what the trainers'
//! optimiser and its libtorch step both read.

use burn::optim::decay::WeightDecayConfig;
use burn::optim::AdamConfig;

/// Adam's settings, as burn's `AdamConfig` names them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamSettings {
    /// Decay of the first moment.
    pub beta_1: f32,
    /// Decay of the second moment.
    pub beta_2: f32,
    /// Added to the second moment's root (scaled by its bias correction,
    /// as burn does).
    pub epsilon: f32,
    /// L2 penalty added to the gradient, if any.
    pub weight_decay: Option<f32>,
}

impl Default for AdamSettings {
    /// burn's defaults: betas 0.9 and 0.999, epsilon 1e-5, no weight decay.
    fn default() -> Self {
        Self {
            beta_1: 0.9,
            beta_2: 0.999,
            epsilon: 1e-5,
            weight_decay: None,
        }
    }
}

/// burn's Adam with `settings`.
pub(super) fn burns_adam(settings: &AdamSettings) -> burn::optim::Adam {
    AdamConfig::new()
        .with_beta_1(settings.beta_1)
        .with_beta_2(settings.beta_2)
        .with_epsilon(settings.epsilon)
        .with_weight_decay(settings.weight_decay.map(WeightDecayConfig::new))
        .build()
}
