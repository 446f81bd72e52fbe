//! The run's seed decides the networks' initial weights. A test binary of
//! its own: the CPU backend's random generator is global to the process,
//! and tests running beside this one would draw from it.

use learner::config::LearnerConfig;
use learner::service::Trainers;

/// Both networks' initial weights (safetensors bytes) for `seed`.
fn initial_weights(seed: u64) -> (Vec<u8>, Vec<u8>) {
    let mut config = LearnerConfig::default();
    config.policy.seed = seed;
    let device =
        nets::device::open_device(nets::device::DeviceChoice::Cpu).expect("the CPU device");
    let trainers = Trainers::new(&config, &device, &device);
    let policy = trainers.policy.weights().expect("policy weights");
    let unet = trainers
        .affordance
        .expect("the default task trains a U-Net")
        .deployed_weights()
        .expect("U-Net weights");
    (policy, unet)
}

#[test]
fn runs_with_one_seed_start_from_the_same_weights_and_other_seeds_do_not() {
    let first = initial_weights(3);
    let again = initial_weights(3);
    let other = initial_weights(4);
    assert!(
        same_tensors(&first.0, &again.0),
        "seed 3 gave two different initial policies"
    );
    assert!(
        same_tensors(&first.1, &again.1),
        "seed 3 gave two different initial U-Nets"
    );
    assert!(
        !same_tensors(&first.0, &other.0),
        "seeds 3 and 4 gave the same initial policy"
    );
    assert!(
        !same_tensors(&first.1, &other.1),
        "seeds 3 and 4 gave the same initial U-Net"
    );
}

/// The same tensors under the same names (the files' byte layouts may
/// differ: the order of tensors in a file is not fixed).
fn same_tensors(x: &[u8], y: &[u8]) -> bool {
    let a = safetensors::SafeTensors::deserialize(x).expect("valid safetensors");
    let b = safetensors::SafeTensors::deserialize(y).expect("valid safetensors");
    let mut names = a.names();
    names.sort();
    let mut other = b.names();
    other.sort();
    names == other
        && names
            .iter()
            .all(|n| a.tensor(n).expect("listed").data() == b.tensor(n).expect("listed").data())
}
