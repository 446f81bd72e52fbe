//! U-Net training on synthetic labelled frames, the labelled-pixels-only
//! loss, and the global dataset's split, 35-use eviction, cap and validation gate.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use nets::unet::{masked_bce_dice, AffordanceUnet, ClassBalance};
use nets::unet_inference::UnetInference;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use training::affordance::{
    batch_tensors, evaluate, predict_logits, LabelledFrame, UnetTrainer, UnetTrainingConfig,
    UNKNOWN,
};
use training::dataset::{AffordanceDataset, DatasetConfig, Split};
use training::gate::{validation_gate, Gate};

const SIZE: usize = 32;

/// A frame with a bright disc or square (affords) and a dark square (does
/// not) on a noisy background; a band of pixels is unlabelled.
fn synthetic_frame(rng: &mut StdRng) -> LabelledFrame {
    let n = SIZE * SIZE;
    let mut rgbd = vec![0.0f32; 4 * n];
    let mut labels = vec![UNKNOWN; n];
    let (cx, cy, r) = (
        rng.random_range(8.0..24.0f32),
        rng.random_range(8.0..24.0f32),
        rng.random_range(4.0..7.0f32),
    );
    let disc = rng.random_bool(0.5);
    let (qx, qy) = (rng.random_range(0..SIZE - 8), rng.random_range(0..SIZE - 8));
    for y in 0..SIZE {
        for x in 0..SIZE {
            let p = y * SIZE + x;
            let (dx, dy) = (x as f32 - cx, y as f32 - cy);
            let inside = if disc {
                dx * dx + dy * dy < r * r
            } else {
                dx.abs() < r && dy.abs() < r
            };
            let in_square = x >= qx && x < qx + 8 && y >= qy && y < qy + 8 && !inside;
            let noise = rng.random_range(0.0..0.15f32);
            let (red, green, blue, depth) = if inside {
                (0.9, 0.6, 0.2, 1.2)
            } else if in_square {
                (0.2, 0.3, 0.8, 1.5)
            } else {
                (0.3, 0.3, 0.3, 2.5)
            };
            for (c, v) in [red, green, blue, depth].into_iter().enumerate() {
                rgbd[c * n + p] = v + noise;
            }
            labels[p] = if inside {
                1
            } else if in_square || (y + x) % 5 != 0 {
                0
            } else {
                UNKNOWN
            };
        }
    }
    LabelledFrame {
        size: [SIZE, SIZE],
        rgbd,
        labels,
    }
}

#[test]
fn the_unet_overfits_sixteen_labelled_frames() {
    overfits_on(&Device::flex());
}

/// The same on libtorch: the U-Net as one libtorch operation
/// (`training::unet_train_torch`) and the optimiser's libtorch calls (`training::adam`).
#[cfg(feature = "gpu-torch")]
#[test]
#[allow(deprecated)]
fn the_unet_overfits_on_libtorch_too() {
    overfits_on(&Device::libtorch());
}

fn overfits_on(device: &Device) {
    let device = device.clone();
    let mut rng = StdRng::seed_from_u64(11);
    let frames: Vec<LabelledFrame> = (0..16).map(|_| synthetic_frame(&mut rng)).collect();
    let refs: Vec<&LabelledFrame> = frames.iter().collect();
    let mut trainer = UnetTrainer::new(
        AffordanceUnet::new(4, 1, &device),
        UnetTrainingConfig {
            learning_rate: 3e-3,
            weight_decay: 1e-5,
            class_balance: ClassBalance::Pixels,
        },
        &device,
    );
    let before = evaluate(
        &trainer.inference_net(&device),
        &refs,
        ClassBalance::Pixels,
        &device,
    );
    let mut reached = None;
    for step in 1..=400 {
        let start = (step * 8) % 16;
        trainer.step(&refs[start..start + 8]);
        if step % 20 == 0 {
            let e = evaluate(
                &trainer.inference_net(&device),
                &refs,
                ClassBalance::Pixels,
                &device,
            );
            if e.iou > 0.9 {
                reached = Some((step, e));
                break;
            }
        }
    }
    eprintln!("unet: before {before:?}; reached {reached:?}");
    let (_, after) = reached.expect("IoU > 0.9 within 400 steps");
    assert!(after.loss < before.loss);
}

#[test]
fn a_step_returns_the_loss_of_the_weights_before_it() {
    let device = Device::flex();
    let mut rng = StdRng::seed_from_u64(5);
    let frames: Vec<LabelledFrame> = (0..4).map(|_| synthetic_frame(&mut rng)).collect();
    let refs: Vec<&LabelledFrame> = frames.iter().collect();
    let net = AffordanceUnet::new(4, 1, &device);
    let loss_of = |net: &AffordanceUnet| {
        let (x, y, known) = batch_tensors(&refs, &device);
        let balance = UnetTrainingConfig::default().class_balance;
        masked_bce_dice(net.forward(x), y, known, balance).into_scalar::<f32>()
    };
    let before = loss_of(&net);
    let mut trainer = UnetTrainer::new(net, UnetTrainingConfig::default(), &device);
    let returned = trainer.step(&refs);
    assert!(
        (returned - before).abs() <= 1e-5 * before.abs(),
        "{returned} against {before}"
    );
    let after = loss_of(&trainer.inference_net(&device));
    assert!(
        (after - before).abs() > 1e-4 * before.abs(),
        "the step changed nothing: {after} against {before}"
    );
    let next = trainer.step(&refs);
    assert!(
        (next - after).abs() <= 1e-5 * after.abs(),
        "the next step's: {next} against {after}"
    );
}

/// Every parameter's gradient, flattened, in module order.
fn gradients(net: &AffordanceUnet, grads: &GradientsParams) -> Vec<f32> {
    struct Collect<'a> {
        grads: &'a GradientsParams,
        out: Vec<f32>,
    }
    impl ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.get::<D>(param.id) {
                self.out.extend(g.into_data().try_to_vec::<f32>().unwrap());
            }
        }
    }
    let mut c = Collect {
        grads,
        out: Vec::new(),
    };
    net.visit(&mut c);
    c.out
}

#[test]
fn unknown_pixels_do_not_affect_the_loss_or_its_gradients() {
    let device = Device::flex().autodiff();
    let mut rng = StdRng::seed_from_u64(5);
    let net = AffordanceUnet::new(4, 1, &device).train();
    let frame = synthetic_frame(&mut rng);
    let run = |labels: &[u8], flip_unknown: bool| {
        let f = LabelledFrame {
            labels: labels.to_vec(),
            ..frame.clone()
        };
        let (x, mut y, known) = batch_tensors(&[&f], &device);
        if flip_unknown {
            // Give every unknown pixel the label 1 instead of 0.
            y = y.clone() + (known.clone().neg() + 1.0);
        }
        let loss = masked_bce_dice(net.forward(x), y, known, ClassBalance::Pixels);
        let value = loss.clone().into_scalar::<f32>();
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        (value, gradients(&net, &grads))
    };
    let (loss_a, grads_a) = run(&frame.labels, false);
    let (loss_b, grads_b) = run(&frame.labels, true);
    assert_eq!(loss_a, loss_b);
    assert!(!grads_a.is_empty());
    assert_eq!(grads_a, grads_b, "unknown pixels changed the gradients");
}

#[test]
fn each_affordance_counts_as_if_it_were_learnt_alone() {
    // Plane 0: many labels; plane 1: four labelled pixels, one positive. The
    // loss of both is the mean of each plane's loss on its own, and a plane
    // without labels adds nothing.
    let device = Device::flex();
    let mut rng = StdRng::seed_from_u64(9);
    let (b, h, w) = (2, 8, 8);
    let n = b * 2 * h * w;
    let logits: Vec<f32> = (0..n).map(|_| rng.random_range(-3.0..3.0)).collect();
    let labels: Vec<f32> = (0..n).map(|i| f32::from(i % 3 == 0)).collect();
    let known: Vec<f32> = (0..n)
        .map(|i| {
            let (plane, pixel) = ((i / (h * w)) % 2, i % (h * w));
            f32::from(plane == 0 || pixel < 4)
        })
        .collect();
    let tensor = |v: &[f32]| Tensor::<1>::from_floats(v, &device).reshape([b, 2, h, w]);
    let loss = |l: Tensor<4>, y: Tensor<4>, k: Tensor<4>| {
        masked_bce_dice(l, y, k, ClassBalance::Pixels).into_scalar::<f32>()
    };
    let plane = |t: Tensor<4>, a: usize| t.slice([0..b, a..a + 1, 0..h, 0..w]);
    let (l, y, k) = (tensor(&logits), tensor(&labels), tensor(&known));
    let both = loss(l.clone(), y.clone(), k.clone());
    let alone: Vec<f32> = (0..2)
        .map(|a| {
            loss(
                plane(l.clone(), a),
                plane(y.clone(), a),
                plane(k.clone(), a),
            )
        })
        .collect();
    assert!(
        (both - (alone[0] + alone[1]) / 2.0).abs() < 1e-5,
        "{both} vs {alone:?}"
    );
    assert!(alone[1] > 0.0);
    let unlabelled = Tensor::cat(vec![plane(k.clone(), 0), plane(k, 1).zeros_like()], 1);
    let first_only = loss(l, y, unlabelled);
    assert!(
        (first_only - alone[0]).abs() < 1e-5,
        "{first_only} vs {alone:?}"
    );
}

fn tiny_frame(value: f32) -> LabelledFrame {
    LabelledFrame {
        size: [8, 8],
        rgbd: vec![value; 4 * 64],
        labels: vec![1; 64],
    }
}

#[test]
fn the_dataset_splits_evicts_after_35_uses_and_respects_its_cap() {
    let mut rng = StdRng::seed_from_u64(2);
    let mut data = AffordanceDataset::new(DatasetConfig {
        max_frames: 1_000_000,
        max_held_out: 1_000_000,
        ..DatasetConfig::default()
    });
    let mut counts = [0usize; 3];
    for episode in 0..200 {
        for split in data.add_episode(
            episode,
            (0..20).map(|i| tiny_frame(i as f32)).collect(),
            &mut rng,
        ) {
            counts[match split {
                Split::Train => 0,
                Split::Validation => 1,
                Split::Test => 2,
            }] += 1;
        }
    }
    let total = 4000.0;
    assert_eq!(data.sizes(), (counts[0], counts[1], counts[2]));
    assert!((counts[1] as f64 / total - 0.15).abs() < 0.02, "{counts:?}");
    assert!((counts[2] as f64 / total - 0.15).abs() < 0.02, "{counts:?}");

    // Use every training frame: each leaves after exactly 35 uses.
    let mut uses = 0usize;
    let train = counts[0];
    while data.sizes().0 > 0 {
        uses += data.sample_train(8, &mut rng).len();
        assert!(uses <= 35 * train, "a frame outlived its 35 uses");
    }
    assert_eq!(uses, 35 * train);
    assert_eq!(data.counters().evicted_after_uses, train as u64);
    assert!(data.sample_train(8, &mut rng).is_empty());

    // The cap drops the oldest frames and counts them.
    let mut capped = AffordanceDataset::new(DatasetConfig {
        max_frames: 50,
        ..DatasetConfig::default()
    });
    for episode in 0..10 {
        capped.add_episode(
            episode,
            (0..10).map(|_| tiny_frame(0.0)).collect(),
            &mut rng,
        );
    }
    let (t, v, s) = capped.sizes();
    assert_eq!(t + v + s, 50);
    assert_eq!(capped.counters().evicted_by_cap, 50);
    assert!(
        !capped.training_episodes().contains(&0),
        "the oldest episode must go first"
    );
}

#[test]
fn held_out_splits_keep_their_newest_frames_and_pass_the_rest_to_training() {
    let mut rng = StdRng::seed_from_u64(5);
    let mut data = AffordanceDataset::new(DatasetConfig {
        max_held_out: 30,
        ..DatasetConfig::default()
    });
    let mut drawn_held_out = 0;
    for episode in 0..100 {
        let splits = data.add_episode(
            episode,
            (0..10).map(|_| tiny_frame(episode as f32)).collect(),
            &mut rng,
        );
        drawn_held_out += splits.iter().filter(|&&s| s != Split::Train).count();
    }
    let (train, validation, test) = data.sizes();
    assert_eq!((validation, test), (30, 30));
    assert_eq!(train, 1000 - 60, "no frame is lost");
    assert_eq!(data.counters().moved_to_train, (drawn_held_out - 60) as u64);
    // The validation split holds the newest episodes' frames (about 1.5 a
    // episode go there, so 30 span the last 20 or so).
    let oldest_kept = data
        .frames(Split::Validation)
        .iter()
        .map(|f| f.rgbd[0])
        .fold(f32::INFINITY, f32::min);
    assert!(oldest_kept >= 60.0, "{oldest_kept}");
}

/// A dataset that draws half its frames into validation and none into test.
fn half_held_out_for_validation() -> AffordanceDataset {
    AffordanceDataset::new(DatasetConfig {
        validation_fraction: 0.5,
        test_fraction: 0.0,
        ..DatasetConfig::default()
    })
}

#[test]
fn a_candidate_replaces_the_deployed_network_only_if_better_on_validation() {
    let device = Device::flex();
    let mut rng = StdRng::seed_from_u64(21);
    let mut data = half_held_out_for_validation();
    let untrained = AffordanceUnet::new(4, 1, &device);
    assert!(
        !validation_gate(
            &untrained,
            &untrained,
            &data.gate_frames(usize::MAX),
            ClassBalance::Pixels,
            &device
        )
        .replace,
        "no validation data, no replacement"
    );
    data.add_episode(
        0,
        (0..32).map(|_| synthetic_frame(&mut rng)).collect(),
        &mut rng,
    );
    let mut trainer = UnetTrainer::new(
        untrained.clone(),
        UnetTrainingConfig {
            learning_rate: 3e-3,
            weight_decay: 1e-5,
            class_balance: ClassBalance::Pixels,
        },
        &device,
    );
    for _ in 0..60 {
        let batch = data.sample_train(4, &mut rng);
        if batch.is_empty() {
            break;
        }
        let refs: Vec<&LabelledFrame> = batch.iter().map(|f| f.as_ref()).collect();
        trainer.step(&refs);
    }
    let trained = trainer.inference_net(&device);
    let better = validation_gate(
        &trained,
        &untrained,
        &data.gate_frames(usize::MAX),
        ClassBalance::Pixels,
        &device,
    );
    eprintln!("gate: {better:?}");
    assert!(better.replace, "{better:?}");
    let worse = validation_gate(
        &untrained,
        &trained,
        &data.gate_frames(usize::MAX),
        ClassBalance::Pixels,
        &device,
    );
    assert!(!worse.replace);
    assert!(
        !validation_gate(
            &trained,
            &trained,
            &data.gate_frames(usize::MAX),
            ClassBalance::Pixels,
            &device
        )
        .replace,
        "a tie keeps the deployed network"
    );
}

#[test]
fn unet_training_resumed_with_the_saved_adam_state_continues_the_same_optimisation() {
    use nets::weights::{load_safetensors, to_safetensors};
    use training::affordance::predict_logits;
    use training::optimizer_state::OptimizerState;

    let device = Device::flex();
    let mut rng = StdRng::seed_from_u64(3);
    let frames: Vec<LabelledFrame> = (0..8).map(|_| synthetic_frame(&mut rng)).collect();
    let refs: Vec<&LabelledFrame> = frames.iter().collect();
    let config = UnetTrainingConfig {
        learning_rate: 3e-3,
        weight_decay: 1e-5,
        class_balance: ClassBalance::Pixels,
    };
    let mut original = UnetTrainer::new(AffordanceUnet::new(4, 1, &device), config, &device);
    for step in 0..3 {
        original.step(&refs[step * 2..step * 2 + 4]);
    }
    // What a checkpoint holds, through bytes: weights, Adam's record and the parameter list.
    let weights = to_safetensors(&original.inference_net(&device)).unwrap();
    let saved = original.optimizer_state().unwrap();
    let saved =
        OptimizerState::from_parts(saved.record.clone(), &saved.parameter_list_json()).unwrap();
    let rebuilt = || {
        let mut net = AffordanceUnet::new(4, 1, &device);
        load_safetensors(&mut net, weights.clone()).unwrap();
        UnetTrainer::new(net, config, &device)
    };
    let mut resumed = rebuilt();
    resumed.restore_optimizer(&saved).unwrap();
    let mut restarted = rebuilt();
    for trainer in [&mut original, &mut resumed, &mut restarted] {
        trainer.step(&refs[4..8]);
    }
    let reference = predict_logits(
        &UnetInference::new(original.inference_net(&device), &device),
        &frames[0],
    );
    let largest_difference = |trainer: &UnetTrainer| {
        predict_logits(
            &UnetInference::new(trainer.inference_net(&device), &device),
            &frames[0],
        )
        .iter()
        .zip(&reference)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max)
    };
    let (with_state, without) = (largest_difference(&resumed), largest_difference(&restarted));
    eprintln!("after one more step: resumed with Adam's state {with_state:e}, with a fresh Adam {without:e}");
    assert!(
        with_state < 1e-4,
        "resumed training drifted by {with_state}"
    );
    assert!(
        without > 100.0 * with_state.max(1e-6),
        "a fresh Adam should have changed the outcome ({without})"
    );

    // A state saved for a U-Net with another number of affordances is refused.
    let mut other = UnetTrainer::new(AffordanceUnet::new(4, 2, &device), config, &device);
    let err = other.restore_optimizer(&saved).unwrap_err();
    assert!(
        err.to_string().contains("does not fit this network"),
        "{err}"
    );
}

/// A frame whose first plane (pick up) is positive where `pick_up` says and
/// whose second (push) is positive everywhere.
fn two_plane_frame(tag: f32, pick_up: bool) -> LabelledFrame {
    let mut labels = vec![u8::from(pick_up); 64];
    labels.extend([1; 64]);
    LabelledFrame {
        size: [8, 8],
        rgbd: vec![tag; 4 * 64],
        labels,
    }
}

#[test]
fn the_cap_drops_rare_positives_last_until_they_reach_their_share() {
    let mut rng = StdRng::seed_from_u64(8);
    let config = |rare_positive_share| DatasetConfig {
        max_frames: 100,
        validation_fraction: 0.0,
        test_fraction: 0.0,
        rare_positive_share,
        ..DatasetConfig::default()
    };
    let (mut plain, mut sparing) = (
        AffordanceDataset::new(config(0.0)),
        AffordanceDataset::new(config(0.25)),
    );
    // 60 episodes of 10 frames; one frame in each of the first 20 episodes
    // shows a pick-up (its tag the episode), push positives everywhere.
    for episode in 0..60u64 {
        let frames: Vec<LabelledFrame> = (0..10)
            .map(|i| two_plane_frame(episode as f32, i == 0 && episode < 20))
            .collect();
        plain.add_episode(episode, frames.clone(), &mut rng);
        sparing.add_episode(episode, frames, &mut rng);
    }
    let pick_ups = |data: &AffordanceDataset| {
        data.frames(Split::Train)
            .iter()
            .filter(|f| f.labels[..64].contains(&1))
            .map(|f| f.rgbd[0] as u64)
            .collect::<Vec<_>>()
    };
    assert!(
        pick_ups(&plain).is_empty(),
        "oldest first: the pick-ups are gone"
    );
    // Push positives are in every frame, so they are never rare; the 20
    // pick-up frames stay, under their share of 25 of the 100 frames.
    assert_eq!(pick_ups(&sparing), (0..20).collect::<Vec<_>>());
    assert_eq!(sparing.positive_frames(2), vec![20, 100]);
    assert_eq!(plain.positive_frames(2), vec![0, 100]);
    assert_eq!(sparing.sizes().0, 100);
    assert!(sparing.counters().spared_by_cap > 0);

    // Rare no more: with 40 pick-up frames the share caps them at 25.
    let mut crowded = AffordanceDataset::new(config(0.25));
    for episode in 0..60u64 {
        let frames: Vec<LabelledFrame> = (0..10)
            .map(|i| two_plane_frame(episode as f32, i < 2 && episode < 20))
            .collect();
        crowded.add_episode(episode, frames, &mut rng);
    }
    let kept = pick_ups(&crowded);
    assert_eq!(kept.len(), 25, "{kept:?}");
    assert!(
        kept.iter().all(|&e| e >= 7),
        "the oldest went first: {kept:?}"
    );
}

#[test]
fn whole_episodes_are_held_out_and_the_gate_sees_several_of_them() {
    let mut rng = StdRng::seed_from_u64(9);
    let config = |split_by_episode| DatasetConfig {
        validation_fraction: 0.3,
        test_fraction: 0.2,
        max_held_out: 1_000,
        split_by_episode,
        ..DatasetConfig::default()
    };
    let (mut by_episode, mut by_frame) = (
        AffordanceDataset::new(config(true)),
        AffordanceDataset::new(config(false)),
    );
    // 200 episodes of 10 frames, each sent in two parts; a frame's tag is
    // its episode.
    for episode in 0..200u64 {
        for _part in 0..2 {
            let frames: Vec<LabelledFrame> = (0..5)
                .map(|_| two_plane_frame(episode as f32, false))
                .collect();
            by_episode.add_episode(episode, frames.clone(), &mut rng);
            by_frame.add_episode(episode, frames, &mut rng);
        }
    }
    let episodes = |data: &AffordanceDataset, split| {
        let mut tags: Vec<u64> = data
            .frames(split)
            .iter()
            .map(|f| f.rgbd[0] as u64)
            .collect();
        tags.sort_unstable();
        tags.dedup();
        tags
    };
    let (train, validation, test) = (
        episodes(&by_episode, Split::Train),
        episodes(&by_episode, Split::Validation),
        episodes(&by_episode, Split::Test),
    );
    // Every episode's ten frames, both parts, in one split alone...
    assert_eq!(train.len() + validation.len() + test.len(), 200);
    for (split, tags) in [
        (Split::Train, &train),
        (Split::Validation, &validation),
        (Split::Test, &test),
    ] {
        assert_eq!(by_episode.frames(split).len(), 10 * tags.len());
    }
    // ...drawn with the configured shares (binomial, 200 draws: ±4 sd).
    assert!(
        (60 - 26..=60 + 26).contains(&validation.len()),
        "{validation:?}"
    );
    assert!((40 - 23..=40 + 23).contains(&test.len()), "{test:?}");
    // Drawn frame by frame, most episodes have frames in every split.
    let shared = episodes(&by_frame, Split::Validation)
        .iter()
        .filter(|e| episodes(&by_frame, Split::Train).contains(e))
        .count();
    assert!(shared > 100, "{shared}");

    // The gate's 16 frames span the held-out episodes, the newest last;
    // frame by frame, the newest 16.
    let gate: Vec<u64> = (by_episode.gate_frames(16).iter())
        .map(|f| f.rgbd[0] as u64)
        .collect();
    let mut distinct = gate.clone();
    distinct.dedup();
    assert!(distinct.len() >= 12, "{gate:?}");
    assert_eq!(gate.first(), validation.first(), "{gate:?}");
    assert_eq!(gate.last(), validation.last(), "{gate:?}");
    let newest: Vec<u64> = (by_frame.gate_frames(16).iter())
        .map(|f| f.rgbd[0] as u64)
        .collect();
    assert!(newest.iter().all(|&e| e >= 190), "{newest:?}");
}

#[test]
fn a_gate_that_keeps_the_deployed_scores_decides_as_one_that_scores_everything() {
    let device = Device::flex();
    let mut rng = StdRng::seed_from_u64(5);
    let mut data = half_held_out_for_validation();
    let balance = ClassBalance::Classes;
    let mut trainer = UnetTrainer::new(
        AffordanceUnet::new(4, 1, &device),
        UnetTrainingConfig {
            learning_rate: 3e-3,
            weight_decay: 1e-5,
            class_balance: balance,
        },
        &device,
    );
    let mut deployed = trainer.inference_net(&device);
    let mut gate = Gate::default();
    let (mut replaced, mut kept) = (0, 0);
    for round in 0..6u64 {
        data.add_episode(
            round,
            (0..8).map(|_| synthetic_frame(&mut rng)).collect(),
            &mut rng,
        );
        for _ in 0..4 {
            let batch = data.sample_train(4, &mut rng);
            let refs: Vec<&LabelledFrame> = batch.iter().map(|f| f.as_ref()).collect();
            if !refs.is_empty() {
                trainer.step(&refs);
            }
        }
        // Every other round a fresh network, which should lose.
        let candidate = if round % 2 == 0 {
            trainer.inference_net(&device)
        } else {
            AffordanceUnet::new(4, 1, &device)
        };
        // The newest 6 frames: some scored in the round before, some new.
        let frames = data.gate_frames(6);
        let outcome = gate.decide(&candidate, &deployed, &frames, balance, &device);
        let refs: Vec<&LabelledFrame> = frames.iter().map(|f| f.as_ref()).collect();
        // Both networks scored afresh on every frame: the same figures.
        let fresh_candidate = evaluate(&candidate, &refs, balance, &device);
        let fresh_deployed = evaluate(&deployed, &refs, balance, &device);
        assert_eq!(outcome.decision.candidate, fresh_candidate, "round {round}");
        assert_eq!(outcome.decision.deployed, fresh_deployed, "round {round}");
        assert_eq!(
            outcome.decision.replace,
            fresh_candidate.loss < fresh_deployed.loss,
            "round {round}"
        );
        let inference = UnetInference::new(candidate.clone(), &device);
        for (frame, logits) in refs.iter().zip(&outcome.candidate_logits) {
            assert_eq!(logits, &predict_logits(&inference, frame));
        }
        if outcome.decision.replace {
            deployed = candidate;
            replaced += 1;
        } else {
            kept += 1;
        }
    }
    assert!(replaced > 0 && kept > 0, "replaced {replaced}, kept {kept}");
}
