//! The `ours` state from a real simulator frame and map: shapes, value
//! ranges, the interacted-objects mask, the history, and egocentric maps
//! that turn with the agent.

use actor::env::actions::{ActionSpace, Selection};
use actor::env::reach::horizontal_distances;
use actor::env::state::{build_state, ActionHistory, State, StateConfig, StateInputs};
use actor::mapping::{class_image, instance_classes, intrinsics, map_frame};
use mapper::{Affordance, Map, MapConfig, ObjectId, Outcome};
use nalgebra::Point2;
use proto::Method;
use sim::agent::{AgentState, NavAction, Simulator};
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::randomise::reachable_nearest;

const AFFORDANCES: [Affordance; 2] = [Affordance::PickUp, Affordance::Push];

fn simulator() -> Simulator {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/ithor-livingrooms");
    let scene = load_scene(&dir.join("FloorPlan227.json")).unwrap();
    let profile = RobotProfile::load("default").unwrap();
    let centre = scene.floor_min + (scene.floor_max - scene.floor_min) / 2.0;
    let (x, y) = reachable_nearest(&scene, &profile, centre.x, centre.y).unwrap();
    let start = AgentState {
        x,
        y,
        yaw_deg: 0.0,
        horizon_deg: 30.0,
    };
    Simulator::new(scene, profile, start, 128).unwrap()
}

/// Integrates the current view and builds the state.
fn observe(
    sim: &Simulator,
    map: &mut Map,
    history: &ActionHistory,
    config: &StateConfig,
) -> (State, Vec<u32>) {
    let camera = sim.camera();
    let frame = sim.render_cpu();
    let classes = instance_classes(sim.scene().objects.iter().map(|o| o.object_type.as_str()));
    let class = class_image(&frame.ids, &classes);
    let map_ids = map.integrate(&map_frame(&camera, &frame, &class)).unwrap();
    let a = sim.agent();
    let probabilities = vec![vec![0.25; frame.ids.len()]; AFFORDANCES.len()];
    let horizontal_m = horizontal_distances(
        &frame.depth_m,
        &intrinsics(&camera),
        &camera.t_world_camera,
        (a.x, a.y),
    );
    let inputs = StateInputs {
        rgb: &frame.rgb,
        horizontal_m: &horizontal_m,
        map_ids: &map_ids,
        agent: (a.x, a.y, a.yaw_deg.to_radians()),
        floor_z: sim.scene().floor_top_m,
        reach_m: sim.profile().reach_m,
        visited: &[Point2::new(a.x, a.y)],
        probabilities: &probabilities,
        map: Some(map),
        history,
        holding: false,
        ratings: &[],
    };
    (build_state(config, &inputs), map_ids)
}

/// Centroid (row, col) of the non-zero cells of a plane.
fn centroid(plane: &[u8], side: usize) -> (f32, f32) {
    let cells: Vec<usize> = (0..plane.len()).filter(|&i| plane[i] > 0).collect();
    assert!(!cells.is_empty(), "the plane is empty");
    let n = cells.len() as f32;
    (
        cells.iter().map(|&i| (i / side) as f32).sum::<f32>() / n,
        cells.iter().map(|&i| (i % side) as f32).sum::<f32>() / n,
    )
}

#[test]
fn state_shapes_ranges_masks_and_egocentric_maps() {
    let space = ActionSpace::new(&AFFORDANCES, Selection::Grid);
    let config = StateConfig::paper(Method::Ours, &AFFORDANCES, space.len());
    let mut sim = simulator();
    let mut map = Map::new(MapConfig::default());
    let mut history = ActionHistory::default();
    let (state, map_ids) = observe(&sim, &mut map, &history, &config);
    let (s, m) = (config.image_size, config.map_cells);
    // Every value a byte: 0..1 scaled to 0..255.
    assert_eq!(state.camera().len(), config.camera_channels() * s * s);
    assert_eq!(state.camera().len(), 10 * s * s);
    assert_eq!(state.global_map().len(), config.map_channels() * m * m);
    assert_eq!(state.local_map().len(), 8 * m * m);
    assert_eq!(state.history(), vec![0; 5 * (30 + 2)]);
    assert_eq!(state.inventory(), [0]);
    assert!(state.ratings().is_empty());
    for plane in [state.global_map(), state.local_map()] {
        assert!(plane.iter().all(|&v| v == 0 || v == 255));
    }
    // RGB as the frame has it; the probabilities' 0.25 as 64.
    let frame = sim.render_cpu();
    assert!((0..s * s).all(|p| state.camera()[p] == frame.rgb[3 * p]));
    assert!((0..s * s).all(|p| state.camera()[2 * s * s + p] == frame.rgb[3 * p + 2]));
    assert!(state.camera()[4 * s * s..6 * s * s]
        .iter()
        .all(|&v| v == 64));
    // The distance image: some pixels within reach (< 0.5), some beyond.
    let distance = &state.camera()[3 * s * s..4 * s * s];
    assert!(distance.iter().any(|&d| d < 128) && distance.iter().any(|&d| d > 128));
    // The planes by name (recordings label them so).
    let names = config.map_plane_names();
    assert_eq!(names.len(), config.map_channels());
    let plane_index = |name: &str| names.iter().position(|n| n == name).unwrap();
    let (visited, occupancy, pick_up_success) = (
        plane_index("visited"),
        plane_index("occupancy"),
        plane_index("pick_up_success"),
    );
    // Occupancy and the agent's own cell appear on both maps.
    let occupancy = &state.global_map()[occupancy * m * m..(occupancy + 1) * m * m];
    assert!(occupancy.iter().filter(|&&v| v > 0).count() > 50);
    let visited_cell = (m / 2) * m + m / 2;
    assert_eq!(state.global_map()[visited * m * m + visited_cell], 255);

    // The object nearest the image's middle column, told it can be picked up.
    let width = s;
    let mut best = (0u32, 0usize);
    let mut ids = map_ids.clone();
    ids.sort_unstable();
    ids.dedup();
    for &id in ids.iter().filter(|&&id| id != 0) {
        let pixels: Vec<usize> = (0..map_ids.len()).filter(|&p| map_ids[p] == id).collect();
        let mean_u = pixels.iter().map(|p| (p % width) as f32).sum::<f32>() / pixels.len() as f32;
        if (mean_u - 63.5).abs() < 12.0 && pixels.len() > best.1 {
            best = (id, pixels.len());
        }
    }
    assert!(best.1 > 50, "no object ahead");
    map.record_interaction(ObjectId(best.0), Affordance::PickUp, Outcome::Success)
        .unwrap();
    history.push(7, true, 1.0, 5);
    let (state, map_ids) = observe(&sim, &mut map, &history, &config);
    // Camera channel 4 + 2A + 0 is pick-up success: exactly the object's pixels.
    let success_mask = &state.camera()[6 * s * s..7 * s * s];
    for (p, &v) in success_mask.iter().enumerate() {
        assert_eq!(v == 255, map_ids[p] == best.0, "pixel {p}");
    }
    assert!(success_mask.iter().all(|&v| v == 0 || v == 255));
    assert_eq!(state.history()[7], 255);
    assert_eq!(state.history()[30], 255, "success");
    assert_eq!(
        state.history()[31],
        170,
        "reward 1 is stored as 2/3 of the [-1, 2] range"
    );
    assert_eq!(state.history()[..7], [0; 7]);

    // The global pick-up success plane: the object is ahead (upper half, middle).
    let plane = |state: &State| {
        state.global_map()[pick_up_success * m * m..(pick_up_success + 1) * m * m].to_vec()
    };
    let (row, col) = centroid(&plane(&state), m);
    println!("facing it: row {row:.1}, col {col:.1}");
    assert!(row < m as f32 / 2.0 - 3.0, "ahead means up: row {row}");
    assert!((col - m as f32 / 2.0).abs() < m as f32 / 8.0, "col {col}");
    // A quarter turn left puts it on the agent's right.
    for _ in 0..3 {
        assert!(sim.step(NavAction::RotateLeft).success);
    }
    let (state, _) = observe(&sim, &mut map, &history, &config);
    let (row, col) = centroid(&plane(&state), m);
    println!("after turning left 90°: row {row:.1}, col {col:.1}");
    assert!(col > m as f32 / 2.0 + 3.0, "on the right: col {col}");
    assert!((row - m as f32 / 2.0).abs() < m as f32 / 8.0, "row {row}");
}
