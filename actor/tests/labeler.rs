//! The labeler on a scripted episode in an iTHOR room (simulator → map →
//! labels) and on crafted inputs for the confidence and sphere rules.

use actor::labeler::{
    confidence_labels, frame_batch, label_background_negative, map_labels, segment_labels,
    sphere_labels, EpisodeFrame, InteractionPoint,
};
use actor::mapping::{class_image, instance_classes, intrinsics, map_frame};
use mapper::{Affordance, Map, MapConfig, ObjectId, Outcome, Pose};
use nalgebra::{Point3, Translation3};
use proto::{ConfidenceRule, SphereRule, LABEL_NEGATIVE, LABEL_POSITIVE, LABEL_UNKNOWN};
use sim::agent::{AgentState, NavAction, Simulator};
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::randomise::reachable_grid;

/// A scripted episode: frames as the labeler sees them, the simulator's
/// ground-truth ids per frame, the map, the picked object's simulator id
/// and the frame index at which it was picked.
struct Episode {
    frames: Vec<EpisodeFrame>,
    truth: Vec<Vec<u32>>,
    map: Map,
    picked: u32,
    pick_frame: usize,
    sim: Simulator,
}

/// A pose on the reachable grid facing a pickupable object within reach
/// that fills at least 60 pixels.
fn facing_pickupable() -> (Simulator, u32, usize) {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/ithor-livingrooms");
    let scene = load_scene(&dir.join("FloorPlan227.json")).unwrap();
    let profile = RobotProfile::load("default").unwrap();
    for (x, y) in reachable_grid(&scene, &profile).unwrap() {
        for k in 0..12 {
            let start = AgentState {
                x,
                y,
                yaw_deg: 30.0 * k as f32,
                horizon_deg: 30.0,
            };
            let sim = Simulator::new(scene.clone(), profile.clone(), start, 128).unwrap();
            let frame = sim.render_cpu();
            let camera = sim.camera();
            let distance = |p: usize| {
                let ray = camera.ray((p % camera.width) as f32, (p / camera.width) as f32);
                frame.depth_m[p] * ray.norm()
            };
            for (index, o) in sim.scene().objects.iter().enumerate() {
                if !o.pickupable {
                    continue;
                }
                let id = index as u32 + 1;
                let pixels: Vec<usize> = (0..frame.ids.len())
                    .filter(|&p| frame.ids[p] == id && distance(p) < 0.9 * profile.reach_m)
                    .collect();
                if pixels.len() >= 60 {
                    return (sim, id, pixels[pixels.len() / 2]);
                }
            }
        }
    }
    panic!("no pickupable object in view and reach in FloorPlan227");
}

fn scripted_episode() -> Episode {
    let (mut sim, picked, pixel) = facing_pickupable();
    let mut map = Map::new(MapConfig::default());
    let mut episode = Episode {
        frames: Vec::new(),
        truth: Vec::new(),
        map: Map::new(MapConfig::default()),
        picked,
        pick_frame: 0,
        sim: sim.clone(),
    };
    let observe = |sim: &Simulator, map: &mut Map, episode: &mut Episode| {
        let camera = sim.camera();
        let frame = sim.render_cpu();
        let classes = instance_classes(sim.scene().objects.iter().map(|o| o.object_type.as_str()));
        let class = class_image(&frame.ids, &classes);
        let map_ids = map.integrate(&map_frame(&camera, &frame, &class)).unwrap();
        episode.truth.push(frame.ids.clone());
        episode.frames.push(EpisodeFrame {
            rgb: frame.rgb,
            depth_m: frame.depth_m,
            map_ids,
            t_world_camera: camera.t_world_camera,
        });
    };
    observe(&sim, &mut map, &mut episode);
    for action in [
        NavAction::RotateLeft,
        NavAction::RotateRight,
        NavAction::LookUp,
        NavAction::LookDown,
    ] {
        assert!(sim.step(action).success);
        observe(&sim, &mut map, &mut episode);
    }
    // Pick the object at the pixel; the map object there gets the outcome.
    let width = sim.camera().width;
    let map_id = episode.frames.last().unwrap().map_ids[pixel];
    assert_ne!(map_id, 0, "the picked object is in the map");
    let outcome = sim.pick_up(pixel % width, pixel / width);
    assert!(outcome.success, "{outcome:?}");
    map.record_interaction(ObjectId(map_id), Affordance::PickUp, Outcome::Success)
        .unwrap();
    episode.pick_frame = episode.frames.len();
    for action in [NavAction::RotateLeft, NavAction::RotateRight] {
        assert!(sim.step(action).success);
        observe(&sim, &mut map, &mut episode);
    }
    episode.map = map;
    episode.sim = sim;
    episode
}

#[test]
fn the_picked_object_is_labelled_positive_with_its_full_mask_in_every_frame_it_is_visible() {
    let e = scripted_episode();
    let labels = map_labels(&e.map, &e.frames, &[Affordance::PickUp, Affordance::Push]);
    let pixels = e.frames[0].depth_m.len();
    let mut checked = 0;
    for (f, (planes, truth)) in labels.iter().zip(&e.truth).enumerate() {
        let (pick, push) = planes.split_at(pixels);
        assert!(
            push.iter().all(|&l| l == LABEL_UNKNOWN),
            "push was never tried"
        );
        let mask = truth.iter().filter(|&&id| id == e.picked).count();
        let covered = (0..pixels)
            .filter(|&p| truth[p] == e.picked && pick[p] == LABEL_POSITIVE)
            .count();
        let outside = (0..pixels)
            .filter(|&p| truth[p] != e.picked && pick[p] == LABEL_POSITIVE)
            .count();
        println!("frame {f}: mask {mask} px, labelled {covered}, outside {outside}");
        assert!(pick.iter().all(|&l| l != LABEL_NEGATIVE));
        if mask >= 20 {
            assert!(f < e.pick_frame, "the held object is not drawn");
            assert!(
                covered as f32 >= 0.9 * mask as f32,
                "frame {f}: {covered} of {mask} mask pixels labelled"
            );
            assert!(
                outside as f32 <= 0.1 * mask as f32,
                "frame {f}: {outside} pixels outside the mask"
            );
            checked += 1;
        }
    }
    assert!(
        checked >= 3,
        "the object was visible in only {checked} frames"
    );
    // Before the pick the object was visible; the first frame is labelled too.
    assert!(labels[0][..pixels].contains(&LABEL_POSITIVE));
    let batch = frame_batch(
        1,
        &intrinsics(&e.sim.camera()),
        &e.frames,
        &labels,
        2,
        false,
    );
    assert_eq!(batch.n_frames(), checked);
    let balanced = frame_batch(1, &intrinsics(&e.sim.camera()), &e.frames, &labels, 2, true);
    assert_eq!(balanced.n_frames(), 0, "no negatives in this episode");
}

#[test]
fn background_labels_make_the_floor_and_walls_negative_and_leave_objects_alone() {
    let e = scripted_episode();
    let mut labels = map_labels(&e.map, &e.frames, &[Affordance::PickUp, Affordance::Push]);
    let before = labels.clone();
    label_background_negative(&mut labels, &e.truth);
    let pixels = e.frames[0].depth_m.len();
    let mut background = 0;
    for ((planes, old), truth) in labels.iter().zip(&before).zip(&e.truth) {
        for (plane, old_plane) in planes.chunks(pixels).zip(old.chunks(pixels)) {
            for ((&label, &old_label), &id) in plane.iter().zip(old_plane).zip(truth) {
                if id == 0 && old_label == LABEL_UNKNOWN {
                    assert_eq!(label, LABEL_NEGATIVE);
                    background += 1;
                } else {
                    assert_eq!(label, old_label, "objects keep their labels");
                }
            }
        }
    }
    assert!(background > 0, "the scripted room shows floor or walls");
    // The frames showing the picked object now have both classes.
    let balanced = frame_batch(1, &intrinsics(&e.sim.camera()), &e.frames, &labels, 2, true);
    assert!(balanced.n_frames() >= 3, "{}", balanced.n_frames());
}

#[test]
fn confidence_labels_follow_the_p95_p5_rule() {
    let e = scripted_episode();
    let picked_map_id = e
        .map
        .objects_labelled(Affordance::PickUp, Some(true))
        .first()
        .copied()
        .unwrap();
    // Four untouched objects that are in the first frame.
    let mut untouched: Vec<u32> = e.frames[0].map_ids.clone();
    untouched.sort_unstable();
    untouched.dedup();
    untouched.retain(|&id| {
        id != 0
            && id != picked_map_id.0
            && e.frames[0].map_ids.iter().filter(|&&m| m == id).count() >= 10
    });
    assert!(untouched.len() >= 4, "{untouched:?}");
    let [sure_yes, sure_no, unsure, torn] =
        [untouched[0], untouched[1], untouched[2], untouched[3]];
    let probabilities: Vec<Vec<f32>> = e
        .frames
        .iter()
        .enumerate()
        .map(|(f, frame)| {
            frame
                .map_ids
                .iter()
                .map(|&id| {
                    match id {
                        _ if id == sure_yes && f == 0 => 0.95,
                        _ if id == sure_no && f == 0 => 0.04,
                        _ if id == torn && f == 0 => 0.95,
                        _ if id == torn => 0.05,
                        // Close to both thresholds in turn, past neither.
                        _ if id == unsure && f == 0 => 0.85,
                        _ if id == unsure => 0.15,
                        _ if id == picked_map_id.0 => 0.01,
                        _ => 0.5,
                    }
                })
                .collect()
        })
        .collect();
    let decided = confidence_labels(
        &e.map,
        &e.frames,
        &probabilities,
        Affordance::PickUp,
        &ConfidenceRule::default(),
    );
    assert!(decided.contains(&(ObjectId(sure_yes), true)), "{decided:?}");
    assert!(decided.contains(&(ObjectId(sure_no), false)), "{decided:?}");
    let decided_ids: Vec<u32> = decided.iter().map(|(id, _)| id.0).collect();
    assert!(
        !decided_ids.contains(&unsure),
        "P95 of 0.85 and P5 of 0.15 decide nothing"
    );
    assert!(
        !decided_ids.contains(&torn),
        "contradicting frames decide nothing"
    );
    assert!(
        !decided_ids.contains(&picked_map_id.0),
        "interacted objects keep their outcome"
    );
    assert_eq!(decided.len(), 2, "{decided:?}");
}

#[test]
fn sphere_labels_reach_only_0_2_m_around_the_point_and_positive_wins() {
    // A flat wall 2 m ahead, seen by a 64 × 48 camera looking along +x.
    let k = mapper::Intrinsics::from_fov(64, 48, 90.0);
    let camera = sim::raycast::agent_camera_pose(0.0, 0.0, 0.0, 1.5, 0.0, 0.0);
    let depth: Vec<f32> = vec![2.0; k.pixels()];
    let frame = EpisodeFrame {
        rgb: vec![0; 3 * k.pixels()],
        depth_m: depth,
        map_ids: vec![0; k.pixels()],
        t_world_camera: camera,
    };
    let on_wall = Point3::new(2.0, 0.0, 1.5);
    let points = [
        InteractionPoint {
            object: 0,
            affordance: 1,
            success: false,
            p_object: on_wall,
        },
        InteractionPoint {
            object: 0,
            affordance: 1,
            success: true,
            p_object: on_wall + nalgebra::Vector3::new(0.0, 0.15, 0.0),
        },
    ];
    let still = |_: usize, _: usize| Pose::identity();
    let labels = sphere_labels(
        std::slice::from_ref(&frame),
        &k,
        &points,
        2,
        &still,
        &SphereRule::default(),
    );
    let (pick, push) = labels[0].split_at(k.pixels());
    assert!(pick.iter().all(|&l| l == LABEL_UNKNOWN));
    let (mut positives, mut negatives) = (0, 0);
    for (p, &label) in push.iter().enumerate() {
        let (u, v) = ((p % k.width) as f32, (p / k.width) as f32);
        let world = camera * k.back_project(u, v, 2.0);
        let near_failure = (world - points[0].p_object).norm() <= 0.2;
        let near_success = (world - points[1].p_object).norm() <= 0.2;
        let expected = if near_success {
            LABEL_POSITIVE
        } else if near_failure {
            LABEL_NEGATIVE
        } else {
            LABEL_UNKNOWN
        };
        assert_eq!(label, expected, "pixel {p} at {world:?}");
        positives += usize::from(label == LABEL_POSITIVE);
        negatives += usize::from(label == LABEL_NEGATIVE);
    }
    assert!(positives > 20 && negatives > 5, "{positives} / {negatives}");

    // The point moves with its object: shifted out of view, nothing is labelled.
    let gone =
        |_: usize, _: usize| Pose::from_parts(Translation3::new(0.0, 0.0, 5.0), Default::default());
    let labels = sphere_labels(&[frame], &k, &points, 2, &gone, &SphereRule::default());
    assert!(labels[0].iter().all(|&l| l == LABEL_UNKNOWN));
}

#[test]
fn segment_labels_cover_the_whole_segment_under_a_point_in_view_and_positive_wins() {
    // A flat wall 2 m ahead, split into two segments at y = 0.
    let k = mapper::Intrinsics::from_fov(64, 48, 90.0);
    let camera = sim::raycast::agent_camera_pose(0.0, 0.0, 0.0, 1.5, 0.0, 0.0);
    let segment_of = |p: usize| {
        let world = camera * k.back_project((p % k.width) as f32, (p / k.width) as f32, 2.0);
        if world.y > 0.0 {
            1
        } else {
            2
        }
    };
    let frame = EpisodeFrame {
        rgb: vec![0; 3 * k.pixels()],
        depth_m: vec![2.0; k.pixels()],
        map_ids: (0..k.pixels()).map(segment_of).collect(),
        t_world_camera: camera,
    };
    let point = |success, y| InteractionPoint {
        object: 0,
        affordance: 0,
        success,
        p_object: Point3::new(2.0, y, 1.5),
    };
    let still = |_: usize, _: usize| Pose::identity();
    let rule = SphereRule::default();
    // A failure on segment 1: all of segment 1 negative, segment 2 unknown.
    let labels = segment_labels(
        std::slice::from_ref(&frame),
        &k,
        &[point(false, 0.6)],
        1,
        &still,
        &rule,
    );
    for (p, &label) in labels[0].iter().enumerate() {
        let expected = if segment_of(p) == 1 {
            LABEL_NEGATIVE
        } else {
            LABEL_UNKNOWN
        };
        assert_eq!(label, expected, "pixel {p}");
    }
    // A success on the same segment wins; a failure on segment 2 labels it.
    let labels = segment_labels(
        std::slice::from_ref(&frame),
        &k,
        &[point(true, 0.3), point(false, 0.6), point(false, -0.5)],
        1,
        &still,
        &rule,
    );
    for (p, &label) in labels[0].iter().enumerate() {
        let expected = if segment_of(p) == 1 {
            LABEL_POSITIVE
        } else {
            LABEL_NEGATIVE
        };
        assert_eq!(label, expected, "pixel {p}");
    }
    // Hidden behind something 1 m nearer than the wall: no label.
    let blocked = EpisodeFrame {
        depth_m: vec![1.0; k.pixels()],
        ..frame
    };
    let labels = segment_labels(&[blocked], &k, &[point(true, 0.3)], 1, &still, &rule);
    assert!(labels[0].iter().all(|&l| l == LABEL_UNKNOWN));
}
