//! Same seed and same actions give identical frames and outcomes, through
//! randomisation, navigation, pushes, pick-ups, hand moves and drops.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use sim::agent::{AgentState, HandMove, NavAction, Outcome, Simulator};
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::randomise::randomise;
use sim::raycast::Frame;

/// One scripted action; interactions aim at the nearest object pixel.
#[derive(Debug, Clone, Copy)]
enum Scripted {
    Nav(NavAction),
    Push,
    PickUp,
    Hand(HandMove),
    Drop,
}

/// The next action: a fixed mix of navigation and interaction.
fn scripted(rng: &mut StdRng) -> Scripted {
    match rng.random_range(0..12) {
        0..=2 => Scripted::Nav(NavAction::MoveAhead),
        3 => Scripted::Nav(NavAction::RotateLeft),
        4 => Scripted::Nav(NavAction::RotateRight),
        5 => Scripted::Nav(NavAction::LookDown),
        6 => Scripted::Nav(NavAction::LookUp),
        7 | 8 => Scripted::Push,
        9 => Scripted::PickUp,
        10 => Scripted::Hand(HandMove::ALL[rng.random_range(0..6)]),
        _ => Scripted::Drop,
    }
}

/// The nearest pixel within reach showing an object the action could work
/// on (a script may peek at the scene; a policy would not).
fn target_pixel(sim: &Simulator, frame: &Frame, action: Scripted) -> (usize, usize) {
    let fits = |id: u32| {
        let o = &sim.scene().objects[id as usize - 1];
        match action {
            Scripted::PickUp => o.pickupable,
            _ => o.pushable(),
        }
    };
    let best = (0..frame.ids.len())
        .filter(|&i| frame.ids[i] != 0 && frame.depth_m[i] < sim.profile().reach_m)
        .filter(|&i| fits(frame.ids[i]))
        .min_by(|&a, &b| frame.depth_m[a].total_cmp(&frame.depth_m[b]))
        .unwrap_or(frame.ids.len() / 2);
    (best % frame.width, best / frame.width)
}

type Trace = Vec<(Scripted, Outcome, AgentState, Frame)>;

fn run(seed: u64, steps: usize) -> Trace {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    let scene = load_scene(&dir.join("FloorPlan227.json")).unwrap();
    let profile = RobotProfile::load("default").unwrap();
    let (mut sim, _) = randomise(&scene, &profile, &mut StdRng::seed_from_u64(seed)).unwrap();
    let mut frame = sim.render_cpu();
    let mut trace = Vec::with_capacity(steps);
    let mut script = StdRng::seed_from_u64(1000 + seed);
    for _ in 0..steps {
        let action = scripted(&mut script);
        let (u, v) = target_pixel(&sim, &frame, action);
        let outcome = act(&mut sim, action, u, v);
        frame = sim.render_cpu();
        trace.push((action, outcome, sim.agent(), frame.clone()));
    }
    trace
}

fn act(sim: &mut Simulator, action: Scripted, u: usize, v: usize) -> Outcome {
    match action {
        Scripted::Nav(a) => sim.step(a),
        Scripted::Push => sim.push(u, v),
        Scripted::PickUp => sim.pick_up(u, v),
        Scripted::Hand(m) => sim.move_held(m),
        Scripted::Drop => sim.drop_held(),
    }
}

#[test]
fn same_seed_and_actions_give_identical_frames_and_outcomes() {
    let steps = 150;
    let first = run(11, steps);
    let second = run(11, steps);
    for (step, (a, b)) in first.iter().zip(&second).enumerate() {
        assert_eq!(a.1, b.1, "outcome of step {step} ({:?}) differs", a.0);
        assert_eq!(a.2, b.2, "agent after step {step} differs");
        assert!(a.3 == b.3, "frame after step {step} differs");
    }
    let succeeded = |kind: fn(&Scripted) -> bool| {
        first
            .iter()
            .filter(|(a, o, _, _)| kind(a) && o.success)
            .count()
    };
    let pushes = succeeded(|a| matches!(a, Scripted::Push));
    let picks = succeeded(|a| matches!(a, Scripted::PickUp));
    let moves = succeeded(|a| matches!(a, Scripted::Nav(NavAction::MoveAhead)));
    println!("successful pushes {pushes}, pick-ups {picks}, moves {moves} in {steps} steps");
    assert!(pushes + picks > 0, "the script must exercise the physics");
    assert!(moves > 0);

    let other = run(12, steps);
    assert!(
        first.iter().zip(&other).any(|(a, b)| a.3 != b.3),
        "another seed gives another episode"
    );
}
