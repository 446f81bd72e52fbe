//! The learner's Adam: burn's, except where the parameters live on libtorch
//! (`gpu-torch`), where each parameter's update is a few libtorch
//! operations instead of burn's 13–15 (`libtorch`, which says why);
//! `settings` holds what both take.
//!
//! Its state is burn's `AdamState`, so an optimiser state saved with either
//! loads into the other, and checkpoints written before it still resume.
//! `AFX_ADAM=burn` has libtorch's tensors take burn's step too, to measure a
//! whole update against.

#[cfg(feature = "gpu-torch")]
mod libtorch;
mod settings;

use burn::optim::{AdamState, LearningRate, ModuleOptimizer, Optimizer};
use burn::prelude::*;

use settings::burns_adam;
pub use settings::AdamSettings;

/// Adam for one parameter at a time, as burn's optimisers are.
#[derive(Clone)]
pub struct Adam {
    /// Only read on libtorch.
    #[cfg_attr(not(feature = "gpu-torch"), allow(dead_code))]
    settings: AdamSettings,
    burn: burn::optim::Adam,
}

impl Adam {
    /// Adam with `settings`.
    pub fn new(settings: AdamSettings) -> Self {
        Self {
            settings,
            burn: burns_adam(&settings),
        }
    }

    /// The optimiser of a whole module (what a trainer holds), with
    /// `settings`.
    pub fn for_module(settings: AdamSettings) -> ModuleOptimizer {
        ModuleOptimizer::from(Self::new(settings))
    }
}

/// Whether libtorch's tensors get `libtorch`'s step: unless
/// `AFX_ADAM=burn` (burn's own operations, to measure a whole PPO update or
/// U-Net step against), read once.
#[cfg(feature = "gpu-torch")]
fn libtorch_steps_chosen() -> bool {
    static CHOSEN: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *CHOSEN.get_or_init(|| match std::env::var("AFX_ADAM").as_deref() {
        Err(_) | Ok("torch") => true,
        Ok("burn") => false,
        Ok(other) => {
            eprintln!("AFX_ADAM takes torch or burn, not {other:?}; using torch");
            true
        }
    })
}

impl Optimizer for Adam {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        #[cfg(feature = "gpu-torch")]
        if libtorch_steps_chosen() {
            if let Some((tensor, state)) =
                libtorch::adam_step(&self.settings, lr, &tensor, &grad, state.as_ref())
            {
                return (tensor, Some(state));
            }
        }
        self.burn.step(lr, tensor, grad, state)
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        burn::optim::Adam::to_device(state, device)
    }
}

#[cfg(test)]
mod tests {
    use burn::module::{Module, Param};
    use burn::optim::GradientsParams;

    use super::*;

    /// Two parameters of different ranks, so that states of both ranks are
    /// saved and loaded.
    #[derive(Module, Debug)]
    struct Pair {
        matrix: Param<Tensor<2>>,
        vector: Param<Tensor<1>>,
    }

    fn pair(device: &Device) -> Pair {
        let matrix = [0.5f32, -1.25, 2.0, 0.0, 3.5, -0.75];
        Pair {
            matrix: Param::from_tensor(Tensor::from_data(
                TensorData::new(matrix.to_vec(), [2, 3]),
                device,
            )),
            vector: Param::from_tensor(Tensor::from_floats([1.5, -0.25], device)),
        }
    }

    /// A loss whose gradients change from step to step.
    fn grads(net: &Pair, k: usize) -> GradientsParams {
        // Alternating signs: the moments, not the gradient alone, set each step.
        let w = (k + 1) as f32 * if k.is_multiple_of(2) { 1.0 } else { -0.5 };
        let loss = (net.matrix.val().powf_scalar(2.0).sum() * w)
            + (net.vector.val() * net.vector.val().mul_scalar(w).exp()).sum();
        GradientsParams::from_grads(loss.backward(), net)
    }

    fn floats(net: &Pair) -> Vec<f32> {
        let mut v: Vec<f32> = net.matrix.val().into_data().try_to_vec().unwrap();
        v.extend(net.vector.val().into_data().try_to_vec::<f32>().unwrap());
        v
    }

    const SETTINGS: AdamSettings = AdamSettings {
        beta_1: 0.9,
        beta_2: 0.999,
        epsilon: 1e-5,
        weight_decay: Some(1e-2),
    };

    /// Three steps of ours and of burn's Adam over a module on `device`;
    /// then each one's state saved and loaded into the other, and one more
    /// step each: the largest difference of the parameters at every step.
    fn ours_against_burns(device: &Device) -> Vec<f32> {
        let burns = || ModuleOptimizer::from(burns_adam(&SETTINGS));
        let (mut ours_opt, mut burn_opt) = (Adam::for_module(SETTINGS), burns());
        // One module twice: burn keys a saved state by the parameters' ids.
        let mut ours = pair(device);
        let mut theirs = ours.clone();
        let mut differences = Vec::new();
        let largest = |a: &Pair, b: &Pair| {
            (floats(a).iter().zip(floats(b)))
                .map(|(x, y)| (x - y).abs() / y.abs().max(1e-2))
                .fold(0.0, f32::max)
        };
        for k in 0..3 {
            ours = ours_opt.step(1e-2, ours.clone(), grads(&ours, k));
            theirs = burn_opt.step(1e-2, theirs.clone(), grads(&theirs, k));
            differences.push(largest(&ours, &theirs));
        }
        // Swap the states through their saved bytes: each continues the
        // other's optimisation.
        let ours_bytes = ours_opt.into_bytes().expect("our state saves");
        let burn_bytes = burn_opt.into_bytes().expect("burn's state saves");
        let mut ours_opt = Adam::for_module(SETTINGS)
            .from_bytes(burn_bytes)
            .expect("burn's state loads into ours");
        let mut burn_opt = burns()
            .from_bytes(ours_bytes)
            .expect("ours loads into burn's");
        ours = ours_opt.step(1e-2, ours.clone(), grads(&ours, 3));
        theirs = burn_opt.step(1e-2, theirs.clone(), grads(&theirs, 3));
        differences.push(largest(&ours, &theirs));
        differences
    }

    /// On the CPU backend ours is burn's, state and all.
    #[test]
    fn on_the_cpu_backend_it_is_burns_adam() {
        let differences = ours_against_burns(&Device::flex().autodiff());
        assert!(differences.iter().all(|&d| d == 0.0), "{differences:?}");
    }

    /// On libtorch ours takes its own operations and stays within float
    /// rounding of burn's, also after their saved states were swapped; a
    /// resumed step that started from fresh moments (a state that did not
    /// load) would differ by far more.
    #[cfg(feature = "gpu-torch")]
    #[test]
    #[allow(deprecated)]
    fn on_libtorch_it_follows_burns_adam_and_shares_its_state() {
        let differences = ours_against_burns(&Device::libtorch().autodiff());
        assert!(differences.iter().all(|&d| d < 1e-5), "{differences:?}");
    }
}
