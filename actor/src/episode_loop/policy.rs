//! The broadcast policy an actor acts with: loading it from a checked
//! weights message, and the forward passes that pick each environment's
//! action (the CPU's own pass, or burn's, batched or one per environment).

use std::sync::Arc;

use anyhow::Context;
use burn::prelude::*;
use nets::policy::{CpuPolicy, CpuPolicyStep, PolicyInput, PolicyLayout, PolicyNet};
use nets::sample;
use nets::weights::{load_safetensors, unbundle};
use proto::{
    WEIGHTS_META_ENV_STEPS, WEIGHTS_META_HOLD, WEIGHTS_META_TEMPERATURE, WEIGHTS_POLICY_PREFIX,
    WEIGHTS_UNET_PREFIX,
};
use rayon::prelude::*;
use transport::{ActorPorts, ReceivedMessage};

use crate::env::affordance_model::AffordanceModel;
use crate::env::Observation;
use crate::sampling::env_threads::PolicyPass;
use crate::sampling::Inference;

/// The broadcast policy the actor acts with.
pub(super) struct Policy {
    pub(super) net: PolicyNet,
    /// The same weights for the CPU's own pass (`nets::policy::CpuPolicy`),
    /// used on every device where the policy has one (shared with the
    /// environments' threads, which run it too).
    pub(super) cpu: Option<Arc<CpuPolicy>>,
    pub(super) layout: PolicyLayout,
    pub(super) policy_version: u64,
    pub(super) unet_version: u64,
    /// The run's environment steps over all actors when the learner sent
    /// these weights, if it said.
    pub(super) env_steps: Option<u64>,
    /// The learner said to wait for its U-Net ([`proto::WEIGHTS_META_HOLD`]).
    pub(super) hold: bool,
}

/// What one weights message holds for the actor: the policy, and the
/// U-Net when the message carries one of another version than the
/// current policy's.
pub(super) struct LoadedWeights {
    pub(super) policy: Policy,
    /// The new U-Net (calibration included), for the caller to swap in.
    pub(super) unet: Option<AffordanceModel>,
}

/// Loads a weights message once `ports` has checked it (layout, size, the
/// run key's signature): the policy always, a new U-Net (built like `model`,
/// which stays untouched) when the message carries one of another version
/// than `current`'s.
pub(super) fn load_weights(
    ports: &ActorPorts,
    message: &ReceivedMessage,
    layout: &PolicyLayout,
    model: Option<&AffordanceModel>,
    device: &Device,
    current: Option<&Policy>,
) -> anyhow::Result<LoadedWeights> {
    let (header, weights) = ports
        .check_weights(message)
        .context("invalid weights on the weights service")?;
    let mut net = PolicyNet::new(layout, device);
    let policy_bytes = unbundle(weights.bytes(), WEIGHTS_POLICY_PREFIX)
        .context("the learner's weights hold no policy")?;
    load_safetensors(&mut net, policy_bytes).context(
        "the learner's policy does not fit this actor's task (start the actor with the learner's config.toml: --config RUN_DIR/config.toml)",
    )?;
    let metadata = nets::weights::metadata(weights.bytes()).unwrap_or_default();
    let number = |key: &str| metadata.get(key).and_then(|v| v.parse::<f64>().ok());
    let env_steps = number(WEIGHTS_META_ENV_STEPS).map(|steps| steps as u64);
    let has_unet = weights
        .tensors()
        .names()
        .iter()
        .any(|n| n.starts_with(WEIGHTS_UNET_PREFIX));
    let unet_changed = current.is_none_or(|p| p.unet_version != header.unet_version);
    let mut unet = None;
    if let (true, true, Some(model)) = (has_unet, unet_changed, model) {
        let temperature = number(WEIGHTS_META_TEMPERATURE).unwrap_or(1.0) as f32;
        let bytes = unbundle(weights.bytes(), WEIGHTS_UNET_PREFIX)?;
        unet = Some(
            model
                .with_weights(bytes, temperature)
                .context("loading the learner's U-Net")?,
        );
        tracing::info!(
            "actor: loaded U-Net version {} (temperature {temperature:.3})",
            header.unet_version
        );
    }
    // The policy is small (about 15 MFLOP a pass at 64 px): on a GPU, burn's
    // pass is bound by its per-operation overhead, so the CPU's own pass
    // serves every device (docs/decisions/0007-policy-pass-on-the-cpu.md).
    let cpu = CpuPolicy::from_network(&net, layout).map(Arc::new);
    let policy = Policy {
        net,
        cpu,
        layout: layout.clone(),
        policy_version: header.policy_version,
        unet_version: header.unet_version,
        env_steps,
        hold: metadata.contains_key(WEIGHTS_META_HOLD),
    };
    Ok(LoadedWeights { policy, unet })
}

/// What the policy chose for one environment at one step.
pub(super) struct Acted {
    pub(super) action: u32,
    pub(super) log_prob: f32,
    /// The critic's value of the observation.
    pub(super) value: f32,
    /// The GRU state after this step (policies with memory).
    pub(super) hidden: Option<Vec<f32>>,
}

/// The policy's output for one environment's observation.
pub(super) struct PolicyStep {
    /// Log-probabilities of the actions, −∞ where masked.
    log_probs: Vec<f32>,
    /// The critic's value.
    pub(super) value: f32,
    /// The GRU state after the step (policies with memory).
    hidden: Option<Vec<f32>>,
}

/// The policy over several environments' observations, each with its
/// recurrent state before this step (`None` = zeros, an episode's start):
/// one per observation and thread where the policy has the CPU's own pass
/// or runs on a CPU device, else one batched forward pass.
pub(super) fn forward_batch(
    policy: &Policy,
    inputs: &[(&Observation, Option<&[f32]>)],
    device: &Device,
    inference: Inference,
) -> anyhow::Result<Vec<PolicyStep>> {
    let per_observation = policy.cpu.is_some() || inference == Inference::PerEnvironment;
    if inputs.len() > 1 && per_observation {
        return inputs
            .par_iter()
            .map(|input| forward(policy, std::slice::from_ref(input), device))
            .collect::<anyhow::Result<Vec<_>>>()
            .map(|steps| steps.into_iter().flatten().collect());
    }
    forward(policy, inputs, device)
}

/// One forward pass of the policy over `inputs` (see [`forward_batch`]).
fn forward(
    policy: &Policy,
    inputs: &[(&Observation, Option<&[f32]>)],
    device: &Device,
) -> anyhow::Result<Vec<PolicyStep>> {
    if let Some(cpu) = &policy.cpu {
        return Ok(inputs
            .iter()
            .map(|(observation, hidden)| {
                let step = observation.cpu_pass(cpu, *hidden);
                step_of_cpu_pass(step, observation)
            })
            .collect());
    }
    let n = inputs.len();
    let mut features: Vec<f32> = Vec::with_capacity(n * policy.layout.obs_len());
    for (observation, _) in inputs {
        features.extend_from_slice(&observation.values.floats());
    }
    let masks: Vec<u8> = inputs
        .iter()
        .flat_map(|(o, _)| o.action_mask.iter().copied())
        .collect();
    let hidden = policy.layout.gru_hidden.map(|size| {
        let values: Vec<f32> = inputs
            .iter()
            .flat_map(|(_, h)| hidden_values(&policy.layout, *h))
            .collect();
        Tensor::<1>::from_floats(values.as_slice(), device).reshape([n, size])
    });
    let out = policy.net.forward(
        &PolicyInput::from_flat(&policy.layout, &features, &masks, n, device),
        hidden,
    );
    let read = |t: Tensor<1>| -> anyhow::Result<Vec<f32>> {
        t.into_data()
            .try_to_vec()
            .map_err(|e| anyhow::anyhow!("reading the policy's output: {e:?}"))
    };
    let log_probs = read(out.log_probs.reshape([-1]))?;
    let values = read(out.values)?;
    let hidden = out.hidden.map(|h| read(h.reshape([-1]))).transpose()?;
    let n_actions = policy.layout.n_actions;
    Ok((0..n)
        .map(|i| {
            let lp = masked(
                log_probs[i * n_actions..(i + 1) * n_actions].to_vec(),
                &inputs[i].0.action_mask,
            );
            let h = hidden.as_ref().map(|h| {
                let size = h.len() / n;
                h[i * size..(i + 1) * size].to_vec()
            });
            PolicyStep {
                log_probs: lp,
                value: values[i],
                hidden: h,
            }
        })
        .collect())
}

/// The step the CPU's pass gave for `observation`.
fn step_of_cpu_pass(step: CpuPolicyStep, observation: &Observation) -> PolicyStep {
    PolicyStep {
        log_probs: masked(step.log_probs, &observation.action_mask),
        value: step.value,
        hidden: step.hidden,
    }
}

/// The step an environment's thread found for `observation` with its
/// `pass`, if that pass was made by `policy` (not one that new weights
/// have replaced since).
pub(super) fn step_of_thread_pass(
    policy: &Policy,
    observation: &Observation,
    pass: PolicyPass,
) -> Option<PolicyStep> {
    (pass.version == policy.policy_version).then(|| step_of_cpu_pass(pass.step, observation))
}

/// `log_probs` with −∞ for the actions `mask` forbids.
fn masked(mut log_probs: Vec<f32>, mask: &[u8]) -> Vec<f32> {
    for (lp, &allowed) in log_probs.iter_mut().zip(mask) {
        if allowed == 0 {
            *lp = f32::NEG_INFINITY;
        }
    }
    log_probs
}

/// One action per policy step, sampled as the `uniforms` decide.
pub(super) fn choose(steps: Vec<PolicyStep>, uniforms: &[f32]) -> anyhow::Result<Vec<Acted>> {
    anyhow::ensure!(
        steps.len() == uniforms.len(),
        "{} policy steps for {} draws",
        steps.len(),
        uniforms.len()
    );
    steps
        .into_iter()
        .zip(uniforms)
        .map(|(step, &uniform)| {
            let (action, log_prob) =
                sample(&step.log_probs, uniform).context("the environment allowed no action")?;
            Ok(Acted {
                action,
                log_prob,
                value: step.value,
                hidden: step.hidden,
            })
        })
        .collect()
}

/// The recurrent state as the chunk carries it: zeros before an episode's
/// first step, nothing for a policy without memory.
pub(super) fn hidden_values(layout: &PolicyLayout, hidden: Option<&[f32]>) -> Vec<f32> {
    match (layout.gru_hidden, hidden) {
        (None, _) => Vec::new(),
        (Some(size), None) => vec![0.0; size],
        (Some(_), Some(h)) => h.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::ObsDtype;

    /// A small policy with a GRU of 8: one 2-channel image of 64 px, a
    /// vector of 5, 4 actions.
    fn small_gru_layout() -> PolicyLayout {
        PolicyLayout {
            image_channels: vec![2],
            image_size: 64,
            vector_dims: vec![5],
            n_actions: 4,
            obs_dtype: ObsDtype::F32,
            gru_hidden: Some(8),
        }
    }

    #[test]
    fn one_batched_forward_equals_a_forward_per_environment() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let layout = small_gru_layout();
        let policy = Policy {
            net: PolicyNet::new(&layout, &device),
            cpu: None,
            layout: layout.clone(),
            policy_version: 1,
            unet_version: 0,
            env_steps: None,
            hold: false,
        };
        let observations: Vec<Observation> = (0..3)
            .map(|k| {
                Observation::of_floats(
                    (0..layout.obs_len())
                        .map(|i| ((i * 7 + k * 13) % 17) as f32 / 17.0)
                        .collect(),
                    (0..4).map(|a| u8::from(a != k)).collect(),
                )
            })
            .collect();
        // An episode's start (zeros) beside two running recurrent states.
        let hidden = [
            None,
            Some((0..8).map(|i| i as f32 / 8.0 - 0.5).collect::<Vec<f32>>()),
            Some(vec![0.3; 8]),
        ];
        let inputs: Vec<_> = observations
            .iter()
            .zip(&hidden)
            .map(|(o, h)| (o, h.as_deref()))
            .collect();
        // One pass over the batch (as on a GPU) against one per environment.
        let batched = forward(&policy, &inputs, &device).unwrap();
        assert_eq!(batched.len(), 3);
        let threaded = forward_batch(&policy, &inputs, &device, Inference::PerEnvironment).unwrap();
        assert_eq!(threaded.len(), 3);
        let close = |a: f32, b: f32| (a == b) || (a - b).abs() < 1e-5;
        for (k, (input, together)) in inputs.iter().zip(&batched).enumerate() {
            let alone = forward(&policy, std::slice::from_ref(input), &device)
                .unwrap()
                .remove(0);
            assert_eq!(
                threaded[k].log_probs, alone.log_probs,
                "threads keep the order"
            );
            assert!(close(together.value, alone.value), "value of {k}");
            assert_eq!(together.log_probs[k], f32::NEG_INFINITY, "masked action");
            assert!(
                together
                    .log_probs
                    .iter()
                    .zip(&alone.log_probs)
                    .all(|(&a, &b)| close(a, b)),
                "log-probabilities of {k}: {:?} vs {:?}",
                together.log_probs,
                alone.log_probs
            );
            let (t, a) = (
                together.hidden.as_ref().unwrap(),
                alone.hidden.as_ref().unwrap(),
            );
            assert_eq!(t.len(), 8);
            assert!(t.iter().zip(a).all(|(&x, &y)| close(x, y)), "state of {k}");
        }
        // The recurrent state matters: another state, another output.
        assert!(batched[1].hidden != batched[2].hidden);
    }

    #[test]
    fn the_cpu_pass_acts_as_burns_pass_does() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        for gru_hidden in [None, Some(8)] {
            let layout = PolicyLayout {
                image_channels: vec![3, 2],
                image_size: 64,
                vector_dims: vec![5, 1],
                n_actions: 6,
                obs_dtype: ObsDtype::U8,
                gru_hidden,
            };
            let net = PolicyNet::new(&layout, &device);
            let cpu = CpuPolicy::from_network(&net, &layout).map(Arc::new);
            assert!(
                cpu.is_some(),
                "{gru_hidden:?}: the policy gets the CPU pass"
            );
            let policy = |cpu: Option<Arc<CpuPolicy>>| Policy {
                net: net.clone(),
                cpu,
                layout: layout.clone(),
                policy_version: 1,
                unet_version: 0,
                env_steps: None,
                hold: false,
            };
            let (with_cpu, burn_only) = (policy(cpu), policy(None));
            let observations: Vec<Observation> = (0..2)
                .map(|k| {
                    Observation::of_floats(
                        (0..layout.obs_len())
                            .map(|i| ((i * 11 + k * 5) % 19) as f32 / 19.0)
                            .collect(),
                        (0..6).map(|a| u8::from(a != 2 * k + 1)).collect(),
                    )
                })
                .collect();
            // An episode's start beside a running recurrent state.
            let running: Vec<f32> = (0..8).map(|i| i as f32 / 8.0 - 0.4).collect();
            let states = [None, gru_hidden.map(|_| running.as_slice())];
            let inputs: Vec<_> = observations.iter().zip(states).collect();
            let fast = forward(&with_cpu, &inputs, &device).unwrap();
            let reference = forward(&burn_only, &inputs, &device).unwrap();
            let close = |x: f32, y: f32| x == y || (x - y).abs() < 1e-5;
            for (k, (f, r)) in fast.iter().zip(&reference).enumerate() {
                assert_eq!(f.log_probs[2 * k + 1], f32::NEG_INFINITY, "masked action");
                assert!(close(f.value, r.value), "value of {k}");
                for (a, (&x, &y)) in f.log_probs.iter().zip(&r.log_probs).enumerate() {
                    assert!(close(x, y), "action {a} of {k}: {x} vs {y}");
                }
                match (&f.hidden, &r.hidden) {
                    (None, None) => assert!(gru_hidden.is_none()),
                    (Some(x), Some(y)) => {
                        assert_eq!(x.len(), 8);
                        assert!(x.iter().zip(y).all(|(&x, &y)| close(x, y)), "state of {k}");
                    }
                    _ => panic!("{gru_hidden:?}: one pass gave a state, the other not"),
                }
            }
        }
    }

    #[test]
    fn a_threads_pass_counts_only_when_made_by_the_current_policy() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let layout = small_gru_layout();
        let net = PolicyNet::new(&layout, &device);
        let policy = Policy {
            cpu: CpuPolicy::from_network(&net, &layout).map(Arc::new),
            net,
            layout: layout.clone(),
            policy_version: 3,
            unet_version: 0,
            env_steps: None,
            hold: false,
        };
        let observation = Observation::of_floats(
            (0..layout.obs_len())
                .map(|i| (i % 7) as f32 / 7.0)
                .collect(),
            vec![1, 0, 1, 1],
        );
        let state: Vec<f32> = (0..8).map(|i| i as f32 / 10.0).collect();
        let cpu = policy.cpu.as_ref().unwrap();
        let pass = |version| PolicyPass {
            version,
            step: observation.cpu_pass(cpu, Some(&state)),
        };
        let here = forward(&policy, &[(&observation, Some(&state))], &device).unwrap();
        let taken = step_of_thread_pass(&policy, &observation, pass(3)).expect("current policy");
        assert_eq!(taken.log_probs, here[0].log_probs);
        assert_eq!(taken.log_probs[1], f32::NEG_INFINITY, "masked as here");
        assert_eq!(
            (taken.value, &taken.hidden),
            (here[0].value, &here[0].hidden)
        );
        assert!(
            step_of_thread_pass(&policy, &observation, pass(2)).is_none(),
            "stale"
        );
    }
}
