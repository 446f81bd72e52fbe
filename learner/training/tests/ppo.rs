//! PPO against references and on small tasks: the loss pieces against a
//! plain-f64 computation, a masked contextual bandit, and a cue-recall task
//! that needs the GRU's memory. Random policies fail the same thresholds.

use burn::prelude::*;
use burn::tensor::{Bool, Int};
use nets::policy::{ObsDtype, PolicyInput, PolicyLayout, PolicyNet};
use nets::weights::{load_safetensors, to_safetensors};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use training::gae::gae;
use training::optimizer_state::OptimizerState;
use training::ppo::{mask_tensor, ppo_loss, LossTerms, Ppo, PpoBatch, PpoConfig, Sequences};

fn cpu() -> Device {
    Device::flex()
}

#[test]
fn loss_pieces_match_an_f64_reference() {
    let device = cpu();
    let mut rng = StdRng::seed_from_u64(7);
    let (b, a) = (12, 5);
    let logits: Vec<f32> = (0..b * a).map(|_| rng.random_range(-2.0..2.0)).collect();
    let allowed: Vec<bool> = (0..b * a)
        .map(|i| i % a != (i / a) % a || i % 7 == 0)
        .collect();
    // Masked log-softmax in f64.
    let mut lp64 = vec![f64::NEG_INFINITY; b * a];
    for r in 0..b {
        let row: Vec<usize> = (0..a).filter(|&j| allowed[r * a + j]).collect();
        let max = row
            .iter()
            .map(|&j| f64::from(logits[r * a + j]))
            .fold(f64::MIN, f64::max);
        let z: f64 = row
            .iter()
            .map(|&j| (f64::from(logits[r * a + j]) - max).exp())
            .sum();
        for &j in &row {
            lp64[r * a + j] = f64::from(logits[r * a + j]) - max - z.ln();
        }
    }
    let actions: Vec<usize> = (0..b)
        .map(|r| {
            (0..a)
                .find(|&j| allowed[r * a + (j + r) % a])
                .map(|j| (j + r) % a)
                .unwrap()
        })
        .collect();
    let old_lp: Vec<f32> = actions
        .iter()
        .enumerate()
        .map(|(r, &j)| lp64[r * a + j] as f32 + rng.random_range(-0.4..0.4))
        .collect();
    let values: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let old_values: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let advantages: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let returns: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let config = PpoConfig::default();

    let masked_logits = Tensor::<1>::from_floats(logits.as_slice(), &device)
        .reshape([b, a])
        .mask_fill(
            mask_tensor(&allowed, a, &device).bool_not(),
            nets::policy::MASKED_LOGIT,
        );
    let log_probs = burn::tensor::activation::log_softmax(masked_logits, 1);
    let t = |v: &[f32]| Tensor::<1>::from_floats(v, &device);
    let (_, terms) = ppo_loss(
        log_probs,
        t(&values),
        Tensor::<1, Int>::from_ints(
            actions
                .iter()
                .map(|&x| x as i64)
                .collect::<Vec<_>>()
                .as_slice(),
            &device,
        ),
        t(&old_lp),
        t(&old_values),
        t(&advantages),
        t(&returns),
        &config,
    );
    let terms = LossTerms::read(terms);

    let eps = f64::from(config.clip);
    let (mut pg, mut vl, mut ent, mut kl, mut cf) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for r in 0..b {
        let new = lp64[r * a + actions[r]];
        let log_ratio = new - f64::from(old_lp[r]);
        let ratio = log_ratio.exp();
        let adv = f64::from(advantages[r]);
        pg += (-adv * ratio).max(-adv * ratio.clamp(1.0 - eps, 1.0 + eps));
        let (v, ov, ret) = (
            f64::from(values[r]),
            f64::from(old_values[r]),
            f64::from(returns[r]),
        );
        let clipped = ov + (v - ov).clamp(-eps, eps);
        vl += 0.5 * (v - ret).powi(2).max((clipped - ret).powi(2));
        ent -= (0..a)
            .filter(|&j| allowed[r * a + j])
            .map(|j| lp64[r * a + j].exp() * lp64[r * a + j])
            .sum::<f64>();
        kl += (ratio - 1.0) - log_ratio;
        cf += f64::from(u8::from((ratio - 1.0).abs() > eps));
    }
    let n = b as f64;
    for (name, got, want) in [
        ("policy", terms.policy, pg / n),
        ("value", terms.value, vl / n),
        ("entropy", terms.entropy, ent / n),
        ("approx_kl", terms.approx_kl, kl / n),
        ("clip_fraction", terms.clip_fraction, cf / n),
    ] {
        assert!(
            (f64::from(got) - want).abs() < 1e-5,
            "{name}: burn {got}, reference {want}"
        );
    }
}

/// Samples one action per row from `[rows, actions]` log-probabilities.
fn sample_rows(log_probs: &Tensor<2>, rng: &mut StdRng) -> (Vec<u32>, Vec<f32>) {
    let [rows, a] = log_probs.dims();
    let lp: Vec<f32> = log_probs.clone().into_data().try_to_vec().unwrap();
    (0..rows)
        .map(|r| {
            let row: Vec<f32> = lp[r * a..(r + 1) * a]
                .iter()
                .map(|&x| if x < -1e8 { f32::NEG_INFINITY } else { x })
                .collect();
            nets::sample(&row, rng.random()).expect("an allowed action")
        })
        .unzip()
}

fn vectors(rows: &[Vec<f32>], device: &Device) -> Tensor<2> {
    let dim = rows[0].len();
    let flat: Vec<f32> = rows.iter().flatten().copied().collect();
    Tensor::<1>::from_floats(flat.as_slice(), device).reshape([rows.len(), dim])
}

/// Masked contextual bandit: context c ∈ 0..4 shown one-hot; action c pays 1;
/// one wrong action is masked at random each step.
struct Bandit {
    context: usize,
    masked: usize,
}

impl Bandit {
    fn draw(rng: &mut StdRng) -> Self {
        let context = rng.random_range(0..4);
        let masked = (context + rng.random_range(1..4)) % 4;
        Self { context, masked }
    }
    fn observation(&self) -> Vec<f32> {
        (0..4)
            .map(|i| f32::from(u8::from(i == self.context)))
            .collect()
    }
    fn allowed(&self) -> Vec<bool> {
        (0..4).map(|i| i != self.masked).collect()
    }
}

/// The policy's input for a batch of bandit draws.
fn bandit_input(envs: &[Bandit], device: &Device) -> PolicyInput {
    let obs: Vec<Vec<f32>> = envs.iter().map(Bandit::observation).collect();
    let allowed: Vec<bool> = envs.iter().flat_map(Bandit::allowed).collect();
    PolicyInput {
        images: vec![],
        vectors: vec![vectors(&obs, device)],
        mask: mask_tensor(&allowed, 4, device),
    }
}

fn bandit_net(device: &Device) -> PolicyNet {
    PolicyNet::new(
        &PolicyLayout {
            image_channels: vec![],
            image_size: 0,
            vector_dims: vec![4],
            n_actions: 4,
            obs_dtype: ObsDtype::F32,
            gru_hidden: None,
        },
        device,
    )
}

/// Mean reward of `net` (on `device`) over `n` fresh bandit draws (`None`:
/// uniformly random allowed actions).
fn bandit_score(net: Option<&PolicyNet>, n: usize, rng: &mut StdRng, device: &Device) -> f32 {
    let envs: Vec<Bandit> = (0..n).map(|_| Bandit::draw(rng)).collect();
    let actions: Vec<u32> = match net {
        Some(net) => {
            let input = bandit_input(&envs, device);
            sample_rows(&net.forward(&input, None).log_probs, rng).0
        }
        None => envs
            .iter()
            .map(|e| {
                let allowed: Vec<u32> = (0..4).filter(|&i| i != e.masked as u32).collect();
                allowed[rng.random_range(0..3)]
            })
            .collect(),
    };
    envs.iter()
        .zip(&actions)
        .filter(|(e, &a)| a as usize == e.context)
        .count() as f32
        / n as f32
}

/// One batch of 128 bandit steps played by `net` (on `device`, policy version
/// `version`).
fn bandit_batch(net: &PolicyNet, version: u64, rng: &mut StdRng, device: &Device) -> PpoBatch {
    let envs: Vec<Bandit> = (0..128).map(|_| Bandit::draw(rng)).collect();
    let input = bandit_input(&envs, device);
    let out = net.forward(&input, None);
    let (actions, log_probs) = sample_rows(&out.log_probs, rng);
    let values: Vec<f32> = out.values.into_data().try_to_vec().unwrap();
    let rewards: Vec<f32> = envs
        .iter()
        .zip(&actions)
        .map(|(e, &a)| f32::from(u8::from(a as usize == e.context)))
        .collect();
    let (advantages, returns) = gae(&rewards, &values, &[true; 128], 0.0, 0.99, 0.95);
    PpoBatch {
        input,
        actions,
        behaviour_log_probs: log_probs,
        values,
        advantages,
        returns,
        policy_versions: vec![version; 128],
        sequences: None,
    }
}

#[test]
fn ppo_solves_a_masked_contextual_bandit_and_random_does_not() {
    solves_the_bandit_on(&cpu());
}

/// The same on libtorch, where the optimiser and the gradient clipping take
/// libtorch's own calls (`training::adam`, `training::libtorch_ops`).
#[cfg(feature = "gpu-torch")]
#[test]
#[allow(deprecated)]
fn ppo_solves_the_bandit_on_libtorch_too() {
    solves_the_bandit_on(&Device::libtorch());
}

fn solves_the_bandit_on(device: &Device) {
    let device = device.clone();
    let mut rng = StdRng::seed_from_u64(1);
    let config = PpoConfig {
        learning_rate: 3e-3,
        ..PpoConfig::default()
    };
    let mut ppo = Ppo::new(bandit_net(&device), config, &device);
    let threshold = 0.9;
    let mut solved_after = None;
    for update in 0..40 {
        let batch = bandit_batch(
            &ppo.inference_net(&device),
            ppo.version(),
            &mut rng,
            &device,
        );
        let stats = ppo.update(&batch, &mut rng);
        assert!(stats.approx_kl.is_finite() && stats.entropy > 0.0);
        let score = bandit_score(Some(&ppo.inference_net(&device)), 512, &mut rng, &device);
        if score >= threshold {
            solved_after = Some(update + 1);
            break;
        }
    }
    let random = bandit_score(None, 2048, &mut rng, &device);
    eprintln!(
        "bandit: solved after {solved_after:?} updates of 128 steps; random scores {random:.3}"
    );
    assert!(
        solved_after.is_some(),
        "PPO did not reach {threshold} in 40 updates"
    );
    assert!(random < threshold - 0.4, "random policy scored {random}");
}

/// Log-probabilities and values of `net` on fixed bandit inputs, flattened.
fn bandit_outputs(net: &PolicyNet) -> Vec<f32> {
    let envs: Vec<Bandit> = (0..16)
        .map(|i| Bandit {
            context: i % 4,
            masked: (i % 4 + 1 + i / 4 % 3) % 4,
        })
        .collect();
    let input = bandit_input(&envs, &cpu());
    let out = net.forward(&input, None);
    let mut all: Vec<f32> = out.log_probs.into_data().try_to_vec().unwrap();
    all.extend(out.values.into_data().try_to_vec::<f32>().unwrap());
    all.retain(|x| x.is_finite()); // masked actions' log-probabilities are -inf
    all
}

#[test]
fn a_run_resumed_with_the_saved_adam_state_continues_the_same_optimisation() {
    let device = cpu();
    let mut rng = StdRng::seed_from_u64(5);
    let config = PpoConfig {
        learning_rate: 3e-3,
        ..PpoConfig::default()
    };
    let mut original = Ppo::new(bandit_net(&device), config, &device);
    for _ in 0..3 {
        let batch = bandit_batch(
            &original.inference_net(&device),
            original.version(),
            &mut rng,
            &device,
        );
        original.update(&batch, &mut rng);
    }
    // What a checkpoint holds, through bytes: weights, Adam's record and the parameter list.
    let weights = to_safetensors(&original.inference_net(&device)).unwrap();
    let saved = original.optimizer_state().unwrap();
    let saved =
        OptimizerState::from_parts(saved.record.clone(), &saved.parameter_list_json()).unwrap();
    let rebuilt = || {
        let mut net = bandit_net(&device);
        load_safetensors(&mut net, weights.clone()).unwrap();
        Ppo::new(net, config, &device)
    };
    let mut resumed = rebuilt();
    resumed.restore_optimizer(&saved).unwrap();
    let mut restarted = rebuilt();

    let batch = bandit_batch(
        &original.inference_net(&device),
        original.version(),
        &mut rng,
        &device,
    );
    for ppo in [&mut original, &mut resumed, &mut restarted] {
        ppo.update(&batch, &mut StdRng::seed_from_u64(9));
    }
    let reference = bandit_outputs(&original.inference_net(&device));
    let largest_difference = |ppo: &Ppo| {
        let outputs = bandit_outputs(&ppo.inference_net(&device));
        assert_eq!(outputs.len(), reference.len());
        outputs
            .iter()
            .zip(&reference)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max)
    };
    let (with_state, without) = (largest_difference(&resumed), largest_difference(&restarted));
    eprintln!("after one more update: resumed with Adam's state {with_state:e}, with a fresh Adam {without:e}");
    assert!(with_state < 1e-5, "resumed run drifted by {with_state}");
    assert!(
        without > 100.0 * with_state.max(1e-7),
        "a fresh Adam should have changed the outcome ({without})"
    );

    // A state saved for another network is refused and changes nothing.
    let mut other = Ppo::new(recall_net(&device, None), config, &device);
    let err = other.restore_optimizer(&saved).unwrap_err();
    assert!(
        err.to_string().contains("does not fit this network"),
        "{err}"
    );
}

/// Cue recall: step 0 shows a cue (one of two), step 1 shows nothing, step 2
/// asks; answering the cue at step 2 pays 1. Needs memory.
const RECALL_STEPS: usize = 3;

fn recall_observation(step: usize, cue: usize) -> Vec<f32> {
    match step {
        0 => vec![
            f32::from(u8::from(cue == 0)),
            f32::from(u8::from(cue == 1)),
            0.0,
        ],
        1 => vec![0.0, 0.0, 0.0],
        _ => vec![0.0, 0.0, 1.0],
    }
}

fn recall_net(device: &Device, gru: Option<usize>) -> PolicyNet {
    PolicyNet::new(
        &PolicyLayout {
            image_channels: vec![],
            image_size: 0,
            vector_dims: vec![3],
            n_actions: 2,
            obs_dtype: ObsDtype::F32,
            gru_hidden: gru,
        },
        device,
    )
}

/// Plays `episodes` episodes; returns the batch rows (sequence-major) and the mean final reward.
fn play_recall(
    net: &PolicyNet,
    episodes: usize,
    rng: &mut StdRng,
) -> (PolicyInput, Vec<u32>, Vec<f32>, Vec<f32>, Vec<f32>, f32) {
    let device = cpu();
    let hidden = 16;
    let cues: Vec<usize> = (0..episodes).map(|_| rng.random_range(0..2)).collect();
    let mut h = Tensor::<2>::zeros([episodes, hidden], &device);
    let mut per_step = Vec::new();
    for step in 0..RECALL_STEPS {
        let obs: Vec<Vec<f32>> = cues.iter().map(|&c| recall_observation(step, c)).collect();
        let input = PolicyInput {
            images: vec![],
            vectors: vec![vectors(&obs, &device)],
            mask: Tensor::<2, Bool>::full([episodes, 2], true, &device),
        };
        let out = net.forward(&input, Some(h.clone()));
        h = out.hidden.clone().unwrap_or(h);
        let (actions, log_probs) = sample_rows(&out.log_probs, rng);
        let values: Vec<f32> = out.values.into_data().try_to_vec().unwrap();
        per_step.push((obs, actions, log_probs, values));
    }
    // Reorder to sequence-major rows.
    let mut obs = Vec::new();
    let (mut actions, mut log_probs, mut values, mut rewards) = (vec![], vec![], vec![], vec![]);
    for (e, &cue) in cues.iter().enumerate() {
        for (step, (o, a, lp, v)) in per_step.iter().enumerate() {
            obs.push(o[e].clone());
            actions.push(a[e]);
            log_probs.push(lp[e]);
            values.push(v[e]);
            rewards.push(if step == RECALL_STEPS - 1 {
                f32::from(u8::from(a[e] as usize == cue))
            } else {
                0.0
            });
        }
    }
    let score = rewards.iter().sum::<f32>() / episodes as f32;
    let input = PolicyInput {
        images: vec![],
        vectors: vec![vectors(&obs, &device)],
        mask: Tensor::<2, Bool>::full([obs.len(), 2], true, &device),
    };
    (input, actions, log_probs, values, rewards, score)
}

/// Trains on cue recall for at most `budget` updates; returns the number of
/// updates it took to reach `threshold` (or `None`) and the last score.
fn train_recall(
    gru: Option<usize>,
    budget: usize,
    threshold: f32,
    seed: u64,
) -> (Option<usize>, f32) {
    let device = cpu();
    let mut rng = StdRng::seed_from_u64(seed);
    let config = PpoConfig {
        learning_rate: 3e-3,
        entropy_coef: 0.0,
        ..PpoConfig::default()
    };
    let mut ppo = Ppo::new(recall_net(&device, gru), config, &device);
    let episodes = 64;
    let mut last = 0.0;
    for update in 0..budget {
        let net = ppo.inference_net(&device);
        let (input, actions, log_probs, values, rewards, _) = play_recall(&net, episodes, &mut rng);
        let mut advantages = Vec::new();
        let mut returns = Vec::new();
        for e in 0..episodes {
            let r = e * RECALL_STEPS..(e + 1) * RECALL_STEPS;
            let mut dones = vec![false; RECALL_STEPS];
            dones[RECALL_STEPS - 1] = true;
            let (a, ret) = gae(&rewards[r.clone()], &values[r], &dones, 0.0, 0.99, 0.95);
            advantages.extend(a);
            returns.extend(ret);
        }
        let episode_starts: Vec<f32> = (0..episodes * RECALL_STEPS)
            .map(|i| f32::from(u8::from(i % RECALL_STEPS == 0)))
            .collect();
        let batch = PpoBatch {
            input,
            actions,
            behaviour_log_probs: log_probs,
            values,
            advantages,
            returns,
            policy_versions: vec![ppo.version(); episodes * RECALL_STEPS],
            sequences: Some(Sequences {
                lengths: vec![RECALL_STEPS; episodes],
                start_hidden: vec![0.0; episodes * 16],
                hidden: 16,
                episode_starts,
            }),
        };
        ppo.update(&batch, &mut rng);
        last = play_recall(&ppo.inference_net(&device), 512, &mut rng).5;
        if last >= threshold {
            return (Some(update + 1), last);
        }
    }
    (None, last)
}

#[test]
fn ppo_with_a_gru_solves_cue_recall_and_random_and_memoryless_policies_do_not() {
    let threshold = 0.9;
    let (solved_after, last) = train_recall(Some(16), 80, threshold, 3);
    let (memoryless, memoryless_last) = train_recall(None, 80, threshold, 3);
    let mut rng = StdRng::seed_from_u64(4);
    // A uniformly random answer is right half the time.
    let random: f32 = (0..4096)
        .filter(|_| rng.random_range(0..2) == rng.random_range(0..2))
        .count() as f32
        / 4096.0;
    eprintln!(
        "cue recall: GRU solved after {solved_after:?} updates of 64 episodes (score {last:.3}); \
         without memory {memoryless:?} (score {memoryless_last:.3}); random {random:.3}"
    );
    assert!(
        solved_after.is_some(),
        "PPO + GRU did not reach {threshold} in 80 updates (last {last})"
    );
    assert!(memoryless.is_none(), "the task must need memory");
    assert!(random < threshold - 0.3);
}

#[test]
fn sequences_of_unequal_length_replay_exactly_as_they_were_stepped() {
    let device = cpu();
    let net = recall_net(&device, Some(16));
    let mut rng = StdRng::seed_from_u64(11);
    // Two sequences, 3 and 5 steps, the second from a nonzero state.
    let lengths = [3usize, 5];
    let rows: Vec<Vec<f32>> = (0..8)
        .map(|_| (0..3).map(|_| rng.random_range(0.0..1.0)).collect())
        .collect();
    let start_hidden: Vec<f32> = (0..32)
        .map(|i| {
            if i < 16 {
                0.0
            } else {
                rng.random_range(-0.5..0.5)
            }
        })
        .collect();
    let mut stepped = Vec::new();
    let mut at = 0;
    for (s, &len) in lengths.iter().enumerate() {
        let mut h =
            Tensor::<1>::from_floats(&start_hidden[s * 16..(s + 1) * 16], &device).reshape([1, 16]);
        for row in &rows[at..at + len] {
            let input = PolicyInput {
                images: vec![],
                vectors: vec![vectors(std::slice::from_ref(row), &device)],
                mask: Tensor::<2, Bool>::full([1, 2], true, &device),
            };
            let out = net.forward(&input, Some(h));
            h = out.hidden.unwrap();
            let lp: Vec<f32> = out.log_probs.into_data().try_to_vec().unwrap();
            stepped.push((lp, out.values.into_scalar::<f32>()));
        }
        at += len;
    }
    let sequences = Sequences {
        lengths: lengths.to_vec(),
        start_hidden,
        hidden: 16,
        episode_starts: vec![0.0; 8],
    };
    let input = PolicyInput {
        images: vec![],
        vectors: vec![vectors(&rows, &device)],
        mask: Tensor::<2, Bool>::full([8, 2], true, &device),
    };
    // Replayed in the other order: outputs follow the order asked for.
    let (log_probs, values) =
        training::ppo::replay_sequences(&net, &input, &sequences, &[1, 0], &device);
    let log_probs: Vec<f32> = log_probs.into_data().try_to_vec().unwrap();
    let values: Vec<f32> = values.into_data().try_to_vec().unwrap();
    assert_eq!(values.len(), 8);
    let order: Vec<usize> = (3..8).chain(0..3).collect();
    for (k, &row) in order.iter().enumerate() {
        let (lp, v) = &stepped[row];
        assert!(
            (values[k] - v).abs() < 1e-5,
            "row {row}: {} vs {v}",
            values[k]
        );
        for j in 0..2 {
            assert!((log_probs[2 * k + j] - lp[j]).abs() < 1e-5, "row {row}");
        }
    }
}
