//! All 30 iTHOR living rooms import, with the object counts of
//! `../shared/data/ithor-livingroom-scene-counts.tsv`, and boxes consistent
//! with AI2-THOR's own axis-aligned boxes.

use std::path::PathBuf;

use sim::ithor::{load_scene, load_set, ImportError, SceneSet};

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
}

#[test]
fn all_thirty_scenes_import_with_the_published_counts() {
    let counts = std::fs::read_to_string(data_dir().join("ithor-livingroom-scene-counts.tsv"))
        .expect("../shared/data holds the scene counts");
    let mut checked = 0;
    for line in counts.lines().skip(1).filter(|l| !l.trim().is_empty()) {
        let f: Vec<&str> = line.split('\t').collect();
        let expected: Vec<usize> = f[2..7].iter().map(|v| v.trim().parse().unwrap()).collect();
        let scene =
            load_scene(&data_dir().join(format!("ithor-livingrooms/{}.json", f[0]))).unwrap();
        let o = &scene.objects;
        let got = vec![
            o.len(),
            o.iter().filter(|x| x.pickupable).count(),
            o.iter().filter(|x| x.moveable).count(),
            o.iter().filter(|x| x.pushable()).count(),
            o.iter().filter(|x| x.receptacle).count(),
        ];
        assert_eq!(
            got, expected,
            "{}: all / pickupable / moveable / pushable / receptacle",
            f[0]
        );
        assert_eq!(scene.walls.len(), 5, "four walls and a ceiling");
        assert!(
            scene.floor_max.x - scene.floor_min.x > 2.0
                && scene.floor_max.y - scene.floor_min.y > 2.0
        );
        checked += 1;
    }
    assert_eq!(checked, 30);
    let dir = data_dir().join("ithor-livingrooms");
    let test: usize = load_set(&dir, SceneSet::Test)
        .unwrap()
        .iter()
        .map(|s| s.objects.len())
        .sum();
    assert_eq!(test, 236, "the paper's test set has 236 objects");
    assert_eq!(load_set(&dir, SceneSet::Train).unwrap().len(), 20);
    assert_eq!(load_set(&dir, SceneSet::Val).unwrap().len(), 5);
}

#[test]
fn oriented_boxes_contain_the_axis_aligned_boxes_and_sit_in_the_room() {
    let mut worst = (0.0f32, String::new());
    for set in [SceneSet::Train, SceneSet::Val, SceneSet::Test] {
        for scene in load_set(&data_dir().join("ithor-livingrooms"), set).unwrap() {
            for o in &scene.objects {
                let (lo, hi) = o.bounds.corners().iter().fold(
                    ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
                    |(lo, hi), c| {
                        (
                            [lo[0].min(c.x), lo[1].min(c.y), lo[2].min(c.z)],
                            [hi[0].max(c.x), hi[1].max(c.y), hi[2].max(c.z)],
                        )
                    },
                );
                // The oriented box holds the object, so its bounds contain
                // AI2-THOR's (tight) axis-aligned box of the object's mesh.
                for a in 0..3 {
                    let off = (lo[a] - o.aabb_min[a]).max(o.aabb_max[a] - hi[a]);
                    if off > worst.0 && o.bounds.half_extents[a] > 0.006 {
                        worst = (off, format!("{} {} axis {a}", scene.name, o.id));
                    }
                }
                if o.object_type != "Floor" {
                    assert!(
                        lo[2] > scene.floor_top_m - 0.1 && hi[2] < scene.floor_top_m + 3.5,
                        "{}: {} spans z {}..{}",
                        scene.name,
                        o.id,
                        lo[2],
                        hi[2]
                    );
                    let inside = |v: f32, a: f32, b: f32| v > a - 0.3 && v < b + 0.3;
                    assert!(
                        inside(o.bounds.center.x, scene.floor_min.x, scene.floor_max.x)
                            && inside(o.bounds.center.y, scene.floor_min.y, scene.floor_max.y),
                        "{}: {} is outside the room",
                        scene.name,
                        o.id
                    );
                }
            }
        }
    }
    eprintln!(
        "largest part of an axis-aligned box outside its oriented box: {:.4} m ({})",
        worst.0, worst.1
    );
    assert!(worst.0 < 0.02, "{worst:?}");
}

#[test]
fn bad_files_give_errors_that_name_the_file() {
    let dir = std::env::temp_dir().join(format!("sim-import-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let not_json = dir.join("broken.json");
    std::fs::write(&not_json, "{ \"a\": [1, 2").unwrap();
    let err = load_scene(&not_json).unwrap_err();
    assert!(matches!(err, ImportError::Json { .. }));
    assert!(err.to_string().contains("broken.json"), "{err}");
    let missing = load_scene(&dir.join("nope.json")).unwrap_err();
    assert!(matches!(missing, ImportError::Io { .. }));
    let no_floor = dir.join("nofloor.json");
    std::fs::write(&no_floor, "{}").unwrap();
    assert!(matches!(
        load_scene(&no_floor).unwrap_err(),
        ImportError::NoFloor { .. }
    ));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn euler_rotations_convert_to_the_frame_of_the_oriented_boxes() {
    // For upright objects with a non-square footprint, the pivot's yaw (from
    // AI2-THOR's Euler angles) and the oriented box's yaw agree modulo 90°.
    let mut compared = 0;
    for scene in load_set(&data_dir().join("ithor-livingrooms"), SceneSet::Train).unwrap() {
        for o in &scene.objects {
            let up = o.rotation * nalgebra::Vector3::z();
            let h = o.bounds.half_extents;
            if up.z < 0.999 || (h.x - h.y).abs() < 0.05 || o.aabb_max == o.aabb_min {
                continue;
            }
            let pivot_x = o.rotation * nalgebra::Vector3::x();
            let box_x = o.bounds.rotation * nalgebra::Vector3::x();
            let yaw = |v: nalgebra::Vector3<f32>| v.y.atan2(v.x).to_degrees();
            let diff = (yaw(pivot_x) - yaw(box_x)).rem_euclid(90.0);
            let diff = diff.min(90.0 - diff);
            assert!(
                diff < 2.0,
                "{}: {}: yaw differs by {diff} degrees",
                scene.name,
                o.id
            );
            compared += 1;
        }
    }
    assert!(compared > 100, "only {compared} objects compared");
}
