//! Procedural rooms: deterministic per seed, furnished like the iTHOR living
//! rooms (object counts, types, placements), nothing interpenetrating, and
//! room for the agent to move.

use std::collections::BTreeMap;
use std::path::PathBuf;

use sim::catalogue::{Catalogue, Placement};
use sim::physics::deepest_penetration;
use sim::procgen::generate;
use sim::profile::RobotProfile;
use sim::randomise::{reachable_grid, MAX_PENETRATION_M};

fn data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
}

fn catalogue() -> Catalogue {
    Catalogue::load(&data().join("ithor-object-types.tsv")).unwrap()
}

/// Mean object count per iTHOR living room (all objects, floor included).
fn ithor_mean_count() -> f32 {
    let text = std::fs::read_to_string(data().join("ithor-livingroom-scene-counts.tsv")).unwrap();
    let counts: Vec<f32> = text
        .lines()
        .skip(1)
        .filter_map(|l| l.split('\t').nth(2)?.parse().ok())
        .collect();
    counts.iter().sum::<f32>() / counts.len() as f32
}

#[test]
fn the_catalogue_reads_the_tsv_and_round_trips_through_toml() {
    let c = catalogue();
    let sofa = c.entries.iter().find(|e| e.object_type == "Sofa").unwrap();
    assert_eq!(sofa.placement, Placement::Floor);
    assert_eq!(sofa.pickupable, 0.0);
    assert!((sofa.mass_kg - 104.0).abs() < 1e-3);
    assert!(c
        .entries
        .iter()
        .all(|e| e.object_type != "Floor" && e.object_type != "Drawer"));
    let dir = std::env::temp_dir().join(format!("sim-catalogue-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("catalogue.toml");
    std::fs::write(&path, c.to_toml()).unwrap();
    assert_eq!(Catalogue::load(&path).unwrap(), c);
    std::fs::write(&path, "[[object]]\ntype = 3\n").unwrap();
    let error = Catalogue::load(&path).unwrap_err().to_string();
    assert!(error.contains("catalogue.toml"), "{error}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn generated_rooms_are_deterministic_furnished_like_ithor_and_sound() {
    let catalogue = catalogue();
    let profile = RobotProfile::load("default").unwrap();
    assert_eq!(
        generate(&catalogue, 7, &profile),
        generate(&catalogue, 7, &profile),
        "same seed, same room"
    );
    assert_ne!(
        generate(&catalogue, 7, &profile),
        generate(&catalogue, 8, &profile)
    );

    let rooms: Vec<_> = (0..12).map(|s| generate(&catalogue, s, &profile)).collect();
    let mean = rooms.iter().map(|r| r.objects.len() as f32).sum::<f32>() / rooms.len() as f32;
    let ithor = ithor_mean_count();
    println!("objects per room: generated {mean:.1}, iTHOR {ithor:.1}");
    assert!(
        (mean - ithor).abs() < 0.35 * ithor,
        "generated rooms hold {mean:.1} objects on average, iTHOR rooms {ithor:.1}"
    );
    let mut types: BTreeMap<&str, usize> = BTreeMap::new();
    for room in &rooms {
        let mut seen: Vec<&str> = room
            .objects
            .iter()
            .map(|o| o.object_type.as_str())
            .collect();
        seen.sort_unstable();
        seen.dedup();
        for t in seen {
            *types.entry(t).or_default() += 1;
        }
    }
    for must in [
        "Sofa",
        "Pillow",
        "Painting",
        "FloorLamp",
        "Laptop",
        "CreditCard",
    ] {
        assert!(
            types.get(must).copied().unwrap_or(0) >= rooms.len() / 2,
            "{must} is in only {:?} of {} rooms",
            types.get(must),
            rooms.len()
        );
    }
    for room in &rooms {
        let pickupable = room.objects.iter().filter(|o| o.pickupable).count();
        assert!(
            pickupable >= 5,
            "{}: only {pickupable} pickupable objects",
            room.name
        );
        for (i, o) in room.objects.iter().enumerate().skip(1) {
            let depth = deepest_penetration(room, i);
            assert!(
                depth <= MAX_PENETRATION_M,
                "{}: {} interpenetrates by {depth:.3} m",
                room.name,
                o.id
            );
            assert!(
                o.aabb_min.x >= room.floor_min.x - 0.01 && o.aabb_max.y <= room.floor_max.y + 0.01,
                "{}: {} sticks out of the room",
                room.name,
                o.id
            );
        }
        let reachable = reachable_grid(room, &profile).unwrap();
        assert!(
            reachable.len() > 40,
            "{}: {} reachable cells",
            room.name,
            reachable.len()
        );
    }
}

#[test]
fn without_a_scene_directory_episodes_get_generated_rooms_of_the_split() {
    use sim::ithor::SceneSet;
    use sim::scenes::SceneSource;
    let profile = RobotProfile::load("default").unwrap();
    let catalogue = data().join("ithor-object-types.tsv");
    let generated = SceneSource::open(None, SceneSet::Val, &catalogue, &profile).unwrap();
    let (index, room) = generated.pick(3);
    assert_eq!(room.name, format!("Generated{}", 1_000_000 + index));
    assert_eq!(
        generated.pick(3).1,
        room,
        "the same seed picks the same room"
    );

    let dir = data().join("ithor-livingrooms");
    let ithor = SceneSource::open(Some(&dir), SceneSet::Test, &catalogue, &profile).unwrap();
    assert_eq!(ithor.len(), 5);
    let names: Vec<String> = (0..5).map(|s| ithor.pick(s).1.name).collect();
    assert_eq!(names, SceneSet::Test.scene_names());
    let missing = SceneSource::open(None, SceneSet::Train, &dir.join("nope.tsv"), &profile);
    assert!(missing.unwrap_err().to_string().contains("nope.tsv"));
}
