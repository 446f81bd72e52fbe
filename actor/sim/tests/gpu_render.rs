//! The wgpu renderer against the CPU ray-cast reference: 50 random agent
//! poses in each of three test scenes; instance ids must agree on ≥ 99 % of
//! pixels and depth within 1 cm on ≥ 99 %. Runs on any Vulkan adapter,
//! Mesa's lavapipe included (`apt-get install mesa-vulkan-drivers`).

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use sim::agent::{AgentState, Simulator};
use sim::geometry::SceneGeometry;
use sim::gpu::GpuRenderer;
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::randomise::reachable_grid;
use sim::raycast::render;

#[test]
fn gpu_frames_match_the_cpu_reference_on_50_poses_in_3_scenes() {
    let mut gpu = GpuRenderer::new().unwrap_or_else(|e| panic!("{e}"));
    println!("adapter: {}", gpu.adapter());
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    let profile = RobotProfile::load("default").unwrap();
    let mut rng = StdRng::seed_from_u64(5);
    for name in ["FloorPlan226", "FloorPlan228", "FloorPlan230"] {
        let scene = load_scene(&dir.join(format!("{name}.json"))).unwrap();
        let geometry = SceneGeometry::new(&scene);
        let reachable = reachable_grid(&scene, &profile).unwrap();
        assert!(!reachable.is_empty(), "{name}: no reachable positions");
        let (mut ids_ok, mut depth_ok, mut total) = (0usize, 0usize, 0usize);
        let mut worst: (f64, usize) = (1.0, 0);
        for pose in 0..50 {
            let (x, y) = reachable[rng.random_range(0..reachable.len())];
            let start = AgentState {
                x,
                y,
                yaw_deg: rng.random_range(0.0..360.0),
                horizon_deg: rng.random_range(-30.0..60.0),
            };
            let sim = Simulator::new(scene.clone(), profile.clone(), start, 128).unwrap();
            let camera = sim.camera();
            let cpu = render(&geometry, &camera, 20.0);
            let frame = gpu.render(&geometry, &camera, 20.0).unwrap();
            assert_eq!((frame.width, frame.height), (cpu.width, cpu.height));
            let ids = cpu
                .ids
                .iter()
                .zip(&frame.ids)
                .filter(|(a, b)| a == b)
                .count();
            let depth = cpu
                .depth_m
                .iter()
                .zip(&frame.depth_m)
                .filter(|(a, b)| (*a - *b).abs() <= 0.01)
                .count();
            let n = cpu.ids.len();
            (ids_ok, depth_ok, total) = (ids_ok + ids, depth_ok + depth, total + n);
            let agreement = ids.min(depth) as f64 / n as f64;
            if agreement < worst.0 {
                worst = (agreement, pose);
            }
        }
        let (ids, depth) = (ids_ok as f64 / total as f64, depth_ok as f64 / total as f64);
        println!(
            "{name}: ids agree on {:.3} %, depth within 1 cm on {:.3} % (worst pose {} at {:.3} %)",
            100.0 * ids,
            100.0 * depth,
            worst.1,
            100.0 * worst.0
        );
        assert!(
            ids >= 0.99,
            "{name}: ids agree on only {:.3} %",
            100.0 * ids
        );
        assert!(
            depth >= 0.99,
            "{name}: depth agrees on only {:.3} %",
            100.0 * depth
        );
    }
}
