//! Actors train only in the training rooms: every room an episode can draw,
//! over many episode seeds, is one of FloorPlan201–220 (or a generated room
//! of the training seeds), never a validation or test room.

use std::collections::BTreeSet;
use std::path::PathBuf;

use actor::env::training_rooms;
use sim::ithor::SceneSet;
use sim::procgen::{TEST_SEEDS, TRAIN_SEEDS, VAL_SEEDS};
use sim::profile::RobotProfile;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

#[test]
fn episodes_draw_every_ithor_training_room_and_nothing_else() {
    let profile = RobotProfile::load("default").unwrap();
    let source = training_rooms(&data_dir(), true, &profile).unwrap();
    let allowed: BTreeSet<String> = SceneSet::Train.scene_names().into_iter().collect();
    let held_out: BTreeSet<String> = [SceneSet::Val, SceneSet::Test]
        .into_iter()
        .flat_map(SceneSet::scene_names)
        .collect();
    assert_eq!(allowed.len(), 20);
    let mut drawn = BTreeSet::new();
    for episode_seed in (0..400u64).chain([u64::MAX - 7, 1 << 40]) {
        let (_, scene) = source.pick(episode_seed);
        assert!(
            allowed.contains(&scene.name) && !held_out.contains(&scene.name),
            "episode seed {episode_seed} drew {}, not a training room",
            scene.name
        );
        drawn.insert(scene.name);
    }
    assert_eq!(drawn, allowed, "every training room is drawn");
}

#[test]
fn generated_rooms_come_from_the_training_seeds() {
    let profile = RobotProfile::load("default").unwrap();
    let source = training_rooms(&data_dir(), false, &profile).unwrap();
    assert_eq!(source.len(), TRAIN_SEEDS.end - TRAIN_SEEDS.start);
    for episode_seed in [0, 1, 17, 999_983, u64::MAX] {
        let (_, scene) = source.pick(episode_seed);
        let seed: u64 = scene
            .name
            .strip_prefix("Generated")
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("a generated room's name: {}", scene.name));
        assert!(
            TRAIN_SEEDS.contains(&seed)
                && !VAL_SEEDS.contains(&seed)
                && !TEST_SEEDS.contains(&seed),
            "episode seed {episode_seed} drew generated room {seed}"
        );
    }
}
