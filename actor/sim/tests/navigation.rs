//! Navigation with AI2-THOR's semantics: walls and furniture block moves,
//! the horizon has limits, and the reachable grid is free and connected.

use nalgebra::{Point2, Point3};
use sim::agent::{AgentState, Failure, NavAction, SetupError, Simulator};
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::scene::{walls_around, OrientedBox, Scene, SceneObject};

fn empty_room() -> Scene {
    let floor =
        OrientedBox::axis_aligned(Point3::new(-2.0, -1.5, -0.1), Point3::new(2.0, 1.5, 0.0));
    Scene {
        name: "empty".into(),
        objects: vec![SceneObject {
            id: "Floor|0".into(),
            object_type: "Floor".into(),
            position: floor.center,
            rotation: floor.rotation,
            bounds: floor,
            aabb_min: Point3::new(-2.0, -1.5, -0.1),
            aabb_max: Point3::new(2.0, 1.5, 0.0),
            mass_kg: 0.0,
            pickupable: false,
            moveable: false,
            receptacle: true,
            openable: false,
            materials: vec![],
            parent_receptacles: vec![],
        }],
        floor_min: Point2::new(-2.0, -1.5),
        floor_max: Point2::new(2.0, 1.5),
        floor_top_m: 0.0,
        walls: walls_around(Point2::new(-2.0, -1.5), Point2::new(2.0, 1.5), 0.0, 0.0),
    }
}

fn start(x: f32, y: f32, yaw_deg: f32) -> AgentState {
    AgentState {
        x,
        y,
        yaw_deg,
        horizon_deg: 0.0,
    }
}

#[test]
fn moving_into_a_wall_fails_and_leaves_the_agent_in_place() {
    let mut sim = Simulator::new(
        empty_room(),
        RobotProfile::load("default").unwrap(),
        start(0.0, 0.0, 0.0),
        128,
    )
    .unwrap();
    let mut moves = 0;
    let failure = loop {
        let before = sim.agent();
        let outcome = sim.step(NavAction::MoveAhead);
        if !outcome.success {
            assert_eq!(sim.agent(), before, "a failed move must not move the agent");
            break outcome.failure.unwrap();
        }
        moves += 1;
        assert!(moves < 20, "never blocked");
    };
    assert_eq!(failure, Failure::Blocked { object: None });
    // 2 m to the wall, radius 0.2: seven steps fit (1.75 m), the eighth does not.
    assert_eq!(moves, 7);
    assert!((sim.agent().x - 1.75).abs() < 1e-5);
}

#[test]
fn turning_and_looking_follow_ai2thor_limits() {
    let mut sim = Simulator::new(
        empty_room(),
        RobotProfile::load("default").unwrap(),
        start(0.0, 0.0, 0.0),
        128,
    )
    .unwrap();
    for expected in [15.0, 30.0, 45.0, 60.0] {
        assert!(sim.step(NavAction::LookDown).success);
        assert_eq!(sim.agent().horizon_deg, expected);
    }
    let o = sim.step(NavAction::LookDown);
    assert_eq!(o.failure, Some(Failure::HorizonLimit));
    for _ in 0..6 {
        assert!(sim.step(NavAction::LookUp).success);
    }
    assert_eq!(sim.agent().horizon_deg, -30.0);
    assert!(!sim.step(NavAction::LookUp).success);
    for _ in 0..12 {
        sim.step(NavAction::RotateLeft);
    }
    assert!(sim.agent().yaw_deg.abs() < 1e-3 || (sim.agent().yaw_deg - 360.0).abs() < 1e-3);
    sim.step(NavAction::RotateRight);
    assert!((sim.agent().yaw_deg - 330.0).abs() < 1e-3);
}

#[test]
fn furniture_blocks_and_the_reachable_grid_is_free_and_connected() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms/FloorPlan227.json");
    let scene = load_scene(&path).unwrap();
    let sofa = scene
        .objects
        .iter()
        .find(|o| o.object_type == "Sofa")
        .unwrap()
        .bounds
        .center;
    let profile = RobotProfile::load("default").unwrap();
    let err = Simulator::new(
        scene.clone(),
        profile.clone(),
        start(sofa.x, sofa.y, 0.0),
        128,
    )
    .unwrap_err();
    assert!(matches!(err, SetupError::StartBlocked { .. }));
    assert!(err.to_string().contains("Sofa"), "{err}");

    // Any free spot will do to ask for the reachable grid.
    let reference = (0..40)
        .flat_map(|i| (0..40).map(move |j| (i, j)))
        .find_map(|(i, j)| {
            let (x, y) = (
                scene.floor_min.x + 0.25 * i as f32,
                scene.floor_min.y + 0.25 * j as f32,
            );
            Simulator::new(scene.clone(), profile.clone(), start(x, y, 0.0), 128).ok()
        })
        .expect("some free spot");
    let reachable = reference.reachable_positions();
    eprintln!("FloorPlan227: {} reachable grid positions", reachable.len());
    assert!(reachable.len() > 40);
    for &(x, y) in reachable.iter().step_by(7) {
        assert!(Simulator::new(scene.clone(), profile.clone(), start(x, y, 90.0), 128).is_ok());
    }
    // Walking around the reachable grid: every blocked move names what blocked it.
    let (x, y) = reachable[reachable.len() / 2];
    let mut sim = Simulator::new(scene, profile, start(x, y, 0.0), 128).unwrap();
    let mut blocked_by_objects = 0;
    for k in 0..200 {
        let action = if k % 5 == 4 {
            NavAction::RotateLeft
        } else {
            NavAction::MoveAhead
        };
        let outcome = sim.step(action);
        if let Some(Failure::Blocked { object: Some(id) }) = &outcome.failure {
            assert!(sim.scene().objects.iter().any(|o| &o.id == id));
            blocked_by_objects += 1;
        }
    }
    eprintln!("{blocked_by_objects} moves blocked by furniture in 200 steps");
}
