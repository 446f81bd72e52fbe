//! Picking up, dropping and pushing through the simulator, with the rules
//! of the robot profiles and the outcomes of the physics.

use nalgebra::{Point2, Point3, Vector3};
use sim::agent::{
    Action, AgentState, Failure, HandMove, NavAction, Simulator, DEFAULT_HAND, HAND_STEP_M,
};
use sim::ithor::{load_set, SceneSet};
use sim::profile::RobotProfile;
use sim::scene::{walls_around, OrientedBox, Scene, SceneObject};

fn scenes() -> Vec<Scene> {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    let mut all = load_set(&dir, SceneSet::Test).unwrap();
    all.extend(load_set(&dir, SceneSet::Val).unwrap());
    all
}

/// A simulator with the agent on the reachable grid facing object `index`
/// from within reach, and the pixel nearest the middle of the object's image.
fn facing(
    scene: &Scene,
    profile: &RobotProfile,
    index: usize,
) -> Option<(Simulator, usize, usize)> {
    let target = scene.objects[index].bounds.center;
    let probe = (0..60)
        .flat_map(|i| (0..60).map(move |j| (i, j)))
        .find_map(|(i, j)| {
            let (x, y) = (
                scene.floor_min.x + 0.25 * i as f32,
                scene.floor_min.y + 0.25 * j as f32,
            );
            Simulator::new(
                scene.clone(),
                profile.clone(),
                AgentState {
                    x,
                    y,
                    yaw_deg: 0.0,
                    horizon_deg: 0.0,
                },
                128,
            )
            .ok()
        })?;
    let mut spots = probe.reachable_positions();
    spots.sort_by(|a, b| {
        let d = |p: &(f32, f32)| ((p.0 - target.x).powi(2) + (p.1 - target.y).powi(2)).sqrt();
        d(a).total_cmp(&d(b))
    });
    for (x, y) in spots.into_iter().take(12) {
        let (dx, dy) = (target.x - x, target.y - y);
        let horizontal = (dx * dx + dy * dy).sqrt();
        let down = scene.floor_top_m + profile.camera_height_m - target.z;
        let state = AgentState {
            x,
            y,
            yaw_deg: dy.atan2(dx).to_degrees(),
            horizon_deg: down.atan2(horizontal).to_degrees().clamp(-30.0, 60.0),
        };
        let sim = Simulator::new(scene.clone(), profile.clone(), state, 128).ok()?;
        let frame = sim.render_cpu();
        let id = index as u32 + 1;
        let pixels: Vec<usize> = (0..frame.ids.len())
            .filter(|&p| frame.ids[p] == id)
            .collect();
        if pixels.len() < 4 {
            continue;
        }
        let (su, sv) = pixels.iter().fold((0.0, 0.0), |(a, b), &p| {
            (a + (p % frame.width) as f32, b + (p / frame.width) as f32)
        });
        let (cu, cv) = (su / pixels.len() as f32, sv / pixels.len() as f32);
        let best = *pixels
            .iter()
            .min_by(|&&a, &&b| {
                let d = |p: usize| {
                    ((p % frame.width) as f32 - cu).powi(2)
                        + ((p / frame.width) as f32 - cv).powi(2)
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        let distance = frame.depth_m[best];
        if distance < profile.reach_m * 0.9 {
            return Some((sim, best % frame.width, best / frame.width));
        }
    }
    None
}

fn find(
    scenes: &[Scene],
    object_type: &str,
    profile: &RobotProfile,
) -> (Simulator, usize, usize, usize) {
    for scene in scenes {
        for (i, o) in scene.objects.iter().enumerate() {
            if o.object_type == object_type {
                if let Some((sim, u, v)) = facing(scene, profile, i) {
                    return (sim, i, u, v);
                }
            }
        }
    }
    panic!("no reachable {object_type} in the test and validation scenes");
}

#[test]
fn a_pillow_can_be_picked_up_and_dropped_but_a_sofa_cannot_be_picked_up() {
    let profile = RobotProfile::load("default").unwrap();
    let all = scenes();
    let (mut sim, index, u, v) = find(&all, "Pillow", &profile);
    let outcome = sim.pick_up(u, v);
    assert!(outcome.success, "{outcome:?}");
    assert_eq!(sim.held(), Some(index));
    assert!(!sim.render_cpu().ids.is_empty());
    assert_eq!(sim.pick_up(u, v).failure, Some(Failure::HandFull));
    let dropped = sim.drop_held();
    assert!(dropped.success, "{dropped:?}");
    assert_eq!(sim.held(), None);
    let rest = sim.scene().objects[index].bounds;
    let bottom = rest
        .corners()
        .iter()
        .map(|c| c.z)
        .fold(f32::INFINITY, f32::min);
    assert!(
        bottom >= sim.scene().floor_top_m - 0.02,
        "the pillow fell through the floor"
    );
    assert_eq!(sim.drop_held().failure, Some(Failure::HandEmpty));

    let (mut sim, _, u, v) = find(&all, "Sofa", &profile);
    assert_eq!(sim.pick_up(u, v).failure, Some(Failure::NotPickupable));
}

#[test]
fn the_weak_arm_cannot_pick_up_a_laptop() {
    let all = scenes();
    let weak = RobotProfile::load("weak-arm").unwrap();
    let (mut sim, index, u, v) = find(&all, "Laptop", &weak);
    let mass = sim.scene().objects[index].mass_kg;
    assert_eq!(
        sim.pick_up(u, v).failure,
        Some(Failure::TooHeavy { mass_kg: mass })
    );
    let (mut sim, _, u, v) = find(&all, "Laptop", &RobotProfile::load("default").unwrap());
    assert!(
        sim.pick_up(u, v).success,
        "the default profile lifts a laptop"
    );
}

#[test]
fn pushing_moves_a_chair_and_reports_a_sofa_that_did_not_move() {
    let profile = RobotProfile::load("default").unwrap();
    let all = scenes();
    let (mut sim, index, u, v) = find(&all, "Chair", &profile);
    let before = sim.scene().objects[index].bounds.center;
    let outcome = sim.push(u, v);
    assert!(outcome.success, "{outcome:?}");
    let moved = (sim.scene().objects[index].bounds.center - before)
        .xy()
        .norm();
    assert!(moved >= 0.02);
    let (mut sim, index, u, v) = find(&all, "Sofa", &profile);
    let before = sim.scene().objects[index].bounds;
    let outcome = sim.push(u, v);
    assert!(
        matches!(outcome.failure, Some(Failure::DidNotMove { .. })),
        "{outcome:?}"
    );
    assert_eq!(
        sim.scene().objects[index].bounds,
        before,
        "a failed push changes nothing"
    );
}

#[test]
fn the_held_object_moves_with_the_hand_and_the_agent_and_stops_at_limits() {
    let profile = RobotProfile::load("default").unwrap();
    let all = scenes();
    let (mut sim, index, u, v) = find(&all, "Pillow", &profile);
    assert_eq!(
        sim.move_held(HandMove::Up).failure,
        Some(Failure::HandEmpty)
    );
    assert!(sim.pick_up(u, v).success);
    let start = sim.scene().objects[index].bounds.center;
    let outcome = sim.move_held(HandMove::Up);
    assert!(outcome.success, "{outcome:?}");
    let up = sim.scene().objects[index].bounds.center - start;
    assert!(
        (up - Vector3::new(0.0, 0.0, HAND_STEP_M)).norm() < 1e-5,
        "{up:?}"
    );
    assert!((sim.hand_offset() - DEFAULT_HAND - Vector3::z() * HAND_STEP_M).norm() < 1e-5);

    // Towards the body: stops before the object enters the agent's capsule.
    let mut backs = 0;
    let failure = loop {
        let o = sim.move_held(HandMove::Back);
        if !o.success {
            break o.failure.unwrap();
        }
        backs += 1;
        assert!(backs < 10, "the hand never met its limit");
    };
    assert!(matches!(failure, Failure::HandLimit { .. }), "{failure:?}");
    let half = sim.scene().objects[index].bounds.half_extents;
    assert!(sim.hand_offset().x >= profile.agent_radius_m + half.x.min(half.y) - 1e-5);

    // Ahead: stops at reach (or on collision), never past it.
    let failure = loop {
        let o = sim.move_held(HandMove::Ahead);
        if !o.success {
            break o.failure.unwrap();
        }
    };
    assert!(
        matches!(failure, Failure::HandLimit { .. } | Failure::NoRoom { .. }),
        "{failure:?}"
    );
    assert!(sim.hand_offset().norm() <= profile.reach_m + 1e-5);

    // The object follows the agent when it turns.
    let before = sim.scene().objects[index].bounds.center;
    let agent = sim.agent();
    if sim.step(NavAction::RotateLeft).success {
        let after = sim.scene().objects[index].bounds.center;
        let eye_to = |p: nalgebra::Point3<f32>| (p.x - agent.x).atan2(p.y - agent.y);
        assert!((after - before).norm() > 0.05, "the object stayed behind");
        assert!((eye_to(after) - eye_to(before)).abs() > 0.1);
    }
    let dropped = sim.drop_held();
    assert!(dropped.success, "{dropped:?}");
    assert_eq!(sim.hand_offset(), DEFAULT_HAND, "the hand resets");
}

/// An object of `scene` occupying the axis-aligned box `min`–`max`.
fn boxed(id: &str, object_type: &str, min: Point3<f32>, max: Point3<f32>) -> SceneObject {
    let bounds = OrientedBox::axis_aligned(min, max);
    SceneObject {
        id: id.into(),
        object_type: object_type.into(),
        position: bounds.center,
        rotation: bounds.rotation,
        bounds,
        aabb_min: min,
        aabb_max: max,
        mass_kg: if object_type == "Floor" { 0.0 } else { 0.5 },
        pickupable: object_type != "Floor",
        moveable: false,
        receptacle: object_type == "Floor",
        openable: false,
        materials: vec![],
        parent_receptacles: vec![],
    }
}

/// The pixel nearest the centroid of object `index`'s pixels in `sim`'s view.
fn middle_pixel(sim: &Simulator, index: usize) -> (usize, usize) {
    let frame = sim.render_cpu();
    let id = index as u32 + 1;
    let pixels: Vec<usize> = (0..frame.ids.len())
        .filter(|&p| frame.ids[p] == id)
        .collect();
    assert!(pixels.len() > 20, "object {index} is in view");
    let n = pixels.len() as f32;
    let cu = pixels
        .iter()
        .map(|&p| (p % frame.width) as f32)
        .sum::<f32>()
        / n;
    let cv = pixels
        .iter()
        .map(|&p| (p / frame.width) as f32)
        .sum::<f32>()
        / n;
    let d = |p: usize| {
        ((p % frame.width) as f32 - cu).powi(2) + ((p / frame.width) as f32 - cv).powi(2)
    };
    let best = *pixels
        .iter()
        .min_by(|&&a, &&b| d(a).total_cmp(&d(b)))
        .unwrap();
    (best % frame.width, best / frame.width)
}

#[test]
fn reach_is_measured_from_the_agents_axis_so_objects_on_the_floor_can_be_picked_up() {
    // Two 0.3 m boxes on the floor straight ahead of an agent looking down:
    // their near faces 0.85 m and 1.85 m from its axis. The near box's top is
    // more than 1.5 m from the camera (1.58 m up), yet within reach.
    let (lo, hi) = (Point2::new(-2.0, -1.5), Point2::new(2.0, 1.5));
    let scene = Scene {
        name: "two boxes".into(),
        objects: vec![
            boxed(
                "Floor|0",
                "Floor",
                Point3::new(-2.0, -1.5, -0.1),
                Point3::new(2.0, 1.5, 0.0),
            ),
            boxed(
                "Box|near",
                "Box",
                Point3::new(-0.65, -0.15, 0.0),
                Point3::new(-0.35, 0.15, 0.3),
            ),
            boxed(
                "Box|far",
                "Box",
                Point3::new(0.35, -0.15, 0.0),
                Point3::new(0.65, 0.15, 0.3),
            ),
        ],
        floor_min: lo,
        floor_max: hi,
        floor_top_m: 0.0,
        walls: walls_around(lo, hi, 0.0, 0.3),
    };
    let profile = RobotProfile::load("default").unwrap();
    let start = AgentState {
        x: -1.5,
        y: 0.0,
        yaw_deg: 0.0,
        horizon_deg: 45.0,
    };
    let sim = Simulator::new(scene, profile, start, 128).unwrap();
    let (u, v) = middle_pixel(&sim, 2);
    let mut far = sim.clone();
    let outcome = far.apply(Action::PickUp { u, v });
    match outcome.failure {
        Some(Failure::OutOfReach { distance_m }) => {
            assert!((1.85..2.0).contains(&distance_m), "{distance_m}")
        }
        other => panic!("the far box is beyond reach, got {other:?}"),
    }
    let push = far.apply(Action::Push { u, v });
    assert!(
        matches!(push.failure, Some(Failure::OutOfReach { .. })),
        "{push:?}"
    );
    let (u, v) = middle_pixel(&sim, 1);
    let mut near = sim.clone();
    let outcome = near.apply(Action::PickUp { u, v });
    assert!(outcome.success, "the near box is within reach: {outcome:?}");
    assert_eq!(near.held(), Some(1));
}
