//! Same seed and same actions give identical frames and outcomes, through
//! randomisation, navigation, pushes, pick-ups, hand moves and drops.

use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::agent::{Action, AgentState, NavAction, Outcome};
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::randomise::randomise;
use sim::raycast::Frame;
use sim::script::Script;

type Trace = Vec<(Action, Outcome, AgentState, Frame)>;

fn run(seed: u64, steps: usize) -> Trace {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    let scene = load_scene(&dir.join("FloorPlan227.json")).unwrap();
    let profile = RobotProfile::load("default").unwrap();
    let (mut sim, _) = randomise(&scene, &profile, 128, &mut StdRng::seed_from_u64(seed)).unwrap();
    let mut frame = sim.render_cpu();
    let mut script = Script::new(1000 + seed);
    let mut trace = Vec::with_capacity(steps);
    for _ in 0..steps {
        let action = script.next(&sim, &frame);
        let outcome = sim.apply(action);
        frame = sim.render_cpu();
        trace.push((action, outcome, sim.agent(), frame.clone()));
    }
    trace
}

#[test]
fn same_seed_and_actions_give_identical_frames_and_outcomes() {
    let steps = 150;
    let first = run(11, steps);
    let second = run(11, steps);
    for (step, (a, b)) in first.iter().zip(&second).enumerate() {
        assert_eq!(a.0, b.0, "action {step} differs");
        assert_eq!(a.1, b.1, "outcome of step {step} ({:?}) differs", a.0);
        assert_eq!(a.2, b.2, "agent after step {step} differs");
        assert!(a.3 == b.3, "frame after step {step} differs");
    }
    let succeeded = |kind: fn(&Action) -> bool| {
        first
            .iter()
            .filter(|(a, o, _, _)| kind(a) && o.success)
            .count()
    };
    let pushes = succeeded(|a| matches!(a, Action::Push { .. }));
    let picks = succeeded(|a| matches!(a, Action::PickUp { .. }));
    let moves = succeeded(|a| matches!(a, Action::Nav(NavAction::MoveAhead)));
    println!("successful pushes {pushes}, pick-ups {picks}, moves {moves} in {steps} steps");
    assert!(pushes + picks > 0, "the script must exercise the physics");
    assert!(moves > 0);

    let other = run(12, steps);
    assert!(
        first.iter().zip(&other).any(|(a, b)| a.3 != b.3),
        "another seed gives another episode"
    );
}
