//! A seeded scripted actor for benchmarks, determinism checks and looking at
//! the simulator: a fixed mix of navigation and interactions, the
//! interactions aimed at the nearest suitable object pixel of the last
//! frame. It peeks at the scene's flags to aim, which a learned policy
//! cannot; it exists to exercise the simulator, not to explore well.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use crate::agent::{Action, HandMove, NavAction, Simulator};
use crate::raycast::Frame;

/// The scripted actor.
#[derive(Debug, Clone)]
pub struct Script {
    rng: StdRng,
}

impl Script {
    /// A script whose choices follow from `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            rng: StdRng::seed_from_u64(seed),
        }
    }

    /// The next action, given the simulator and the frame it last rendered:
    /// navigation half the time (moving ahead most), otherwise a push, a
    /// pick-up, a hand move or a drop.
    pub fn next(&mut self, sim: &Simulator, frame: &Frame) -> Action {
        match self.rng.random_range(0..12) {
            0..=2 => Action::Nav(NavAction::MoveAhead),
            3 => Action::Nav(NavAction::RotateLeft),
            4 => Action::Nav(NavAction::RotateRight),
            5 => Action::Nav(NavAction::LookDown),
            6 => Action::Nav(NavAction::LookUp),
            7 | 8 => {
                let (u, v) = target_pixel(sim, frame, false);
                Action::Push { u, v }
            }
            9 => {
                let (u, v) = target_pixel(sim, frame, true);
                Action::PickUp { u, v }
            }
            10 => Action::MoveHeld(HandMove::ALL[self.rng.random_range(0..6)]),
            _ => Action::Drop,
        }
    }
}

/// The nearest pixel within reach that shows an object which could be
/// picked up (`pick`) or pushed; the image centre if there is none.
fn target_pixel(sim: &Simulator, frame: &Frame, pick: bool) -> (usize, usize) {
    let suitable = |id: u32| {
        let o = &sim.scene().objects[id as usize - 1];
        if pick {
            o.pickupable
        } else {
            o.pushable()
        }
    };
    let best = (0..frame.ids.len())
        .filter(|&i| frame.ids[i] != 0 && frame.depth_m[i] < sim.profile().reach_m)
        .filter(|&i| suitable(frame.ids[i]))
        .min_by(|&a, &b| frame.depth_m[a].total_cmp(&frame.depth_m[b]))
        .unwrap_or(frame.width * (frame.height / 2) + frame.width / 2);
    (best % frame.width, best / frame.width)
}
