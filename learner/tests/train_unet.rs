//! `learner train-unet` on a tiny synthetic ladder dataset: it learns the
//! ground-truth rung (a bright square that affords, a dark floor that does
//! not) and does not learn from labels shuffled over the same frames.

use std::path::Path;

use burn::prelude::Device;
use learner::config::LearnerConfig;
use learner::tools::train_unet::{train_unet, TrainUnetSettings};
use nets::unet::{AffordanceUnet, ClassBalance};
use proto::{Affordance, FrameBatch, LabelRung, MessageHeader, LABEL_UNKNOWN};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use training::affordance::{evaluate, LabelledFrame};

const SIZE: usize = 16;

/// A frame with a bright square at a random place: its RGB-D and the
/// square's mask.
fn frame(rng: &mut StdRng) -> (Vec<u8>, Vec<f32>, Vec<bool>) {
    let (x0, y0) = (rng.random_range(0..SIZE - 6), rng.random_range(0..SIZE - 6));
    let mut rgb = vec![20u8; 3 * SIZE * SIZE];
    let depth = vec![2.0f32; SIZE * SIZE];
    let mut mask = vec![false; SIZE * SIZE];
    for y in y0..y0 + 6 {
        for x in x0..x0 + 6 {
            let i = y * SIZE + x;
            mask[i] = true;
            rgb[3 * i..3 * i + 3].fill(230);
        }
    }
    (rgb, depth, mask)
}

/// Writes a dataset of `episodes` × 4 frames: L0 the squares' true labels,
/// L1 as many positives at random pixels, L2 unknown. Returns the frames
/// with their true labels, for scoring.
fn write_dataset(dir: &Path, episodes: usize) -> Vec<LabelledFrame> {
    let mut config = LearnerConfig::default();
    config.task.image_size = SIZE;
    config.task.affordances = vec![Affordance::PickUp];
    config.unet.steps_per_episode = 16;
    std::fs::create_dir_all(dir.join(proto::DATASET_EPISODES_DIR)).unwrap();
    std::fs::write(dir.join("config.toml"), config.to_toml()).unwrap();
    let mut rng = StdRng::seed_from_u64(5);
    let mut truth = Vec::new();
    for episode in 0..episodes {
        let mut batch = FrameBatch {
            episode_id: episode as u64,
            height: SIZE as u32,
            width: SIZE as u32,
            n_affordances: LabelRung::ALL.len() as u32,
            depth_m: Vec::new(),
            rgb: Vec::new(),
            labels: Vec::new(),
        };
        for _ in 0..4 {
            let (rgb, depth, mask) = frame(&mut rng);
            let true_labels: Vec<u8> = mask.iter().map(|&m| u8::from(m)).collect();
            let mut shuffled = vec![0u8; SIZE * SIZE];
            for _ in 0..mask.iter().filter(|&&m| m).count() {
                shuffled[rng.random_range(0..SIZE * SIZE)] = 1;
            }
            batch.labels.extend(&true_labels);
            batch.labels.extend(&shuffled);
            batch
                .labels
                .extend(std::iter::repeat_n(LABEL_UNKNOWN, SIZE * SIZE));
            truth.push(LabelledFrame {
                size: [SIZE, SIZE],
                rgbd: (0..3)
                    .flat_map(|c| rgb.iter().skip(c).step_by(3).map(|&b| f32::from(b) / 255.0))
                    .chain(depth.iter().copied())
                    .collect(),
                labels: true_labels,
            });
            batch.rgb.extend(rgb);
            batch.depth_m.extend(depth);
        }
        let path = dir
            .join(proto::DATASET_EPISODES_DIR)
            .join(format!("actor0_episode{episode:03}.frames"));
        std::fs::write(path, proto::encode(&batch, MessageHeader::default())).unwrap();
    }
    truth
}

/// Trains on `rung` and returns the trained network's IoU on the true labels.
fn iou_after_training(dataset: &Path, out: &Path, rung: LabelRung, truth: &[LabelledFrame]) -> f32 {
    let device = Device::flex();
    let settings = TrainUnetSettings {
        dataset: dataset.to_path_buf(),
        rung,
        out: out.to_path_buf(),
        passes: 3,
        steps_per_episode: None,
        checkpoints: 1,
        class_balance: None,
        seed: 1,
    };
    let report = train_unet(&settings, &device, &mut |_| {}).unwrap();
    assert_eq!(report.episodes, 12);
    assert_eq!(report.frames_read, 48);
    if rung == LabelRung::GroundTruth {
        assert_eq!(report.planes[0].1.positive_pixels, 48 * 36, "{report:?}");
        assert_eq!(report.planes[0].1.frames_with_positives, 48);
    }
    let step = report.checkpoints.last().copied().unwrap();
    let bytes = std::fs::read(out.join(format!("checkpoints/{step}/weights.safetensors"))).unwrap();
    let unet = nets::weights::unbundle(&bytes, proto::WEIGHTS_UNET_PREFIX).unwrap();
    let mut net = AffordanceUnet::new(4, 1, &device);
    nets::weights::load_safetensors(&mut net, unet).unwrap();
    let refs: Vec<&LabelledFrame> = truth.iter().collect();
    evaluate(&net, &refs, ClassBalance::Pixels, &device).iou
}

#[test]
fn the_offline_trainer_learns_the_ground_truth_and_not_shuffled_labels() {
    let dir = tempfile::tempdir().unwrap();
    let dataset = dir.path().join("dataset");
    let truth = write_dataset(&dataset, 12);
    let learnt = iou_after_training(
        &dataset,
        &dir.path().join("l0"),
        LabelRung::GroundTruth,
        &truth,
    );
    assert!(learnt > 0.7, "the ground truth's IoU {learnt}");
    let shuffled = iou_after_training(
        &dataset,
        &dir.path().join("l1"),
        LabelRung::TriedTruth,
        &truth,
    );
    assert!(
        shuffled < 0.3,
        "shuffled labels' IoU {shuffled} (truth {learnt})"
    );
    // The output is a run directory `actor evaluate` reads: the config with
    // the task, and a checkpoint.
    let config = LearnerConfig::from_toml_file(&dir.path().join("l0/config.toml")).unwrap();
    assert_eq!(config.task.image_size, SIZE);
    // A second training into the same directory is refused, not mixed in.
    let again = train_unet(
        &TrainUnetSettings {
            dataset: dataset.clone(),
            rung: LabelRung::Run,
            out: dir.path().join("l0"),
            passes: 1,
            steps_per_episode: None,
            checkpoints: 1,
            class_balance: None,
            seed: 1,
        },
        &Device::flex(),
        &mut |_| {},
    );
    assert!(again
        .unwrap_err()
        .to_string()
        .contains("already holds checkpoints"));
}
