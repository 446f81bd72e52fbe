//! Per-episode randomisation (the paper's): pickupable objects are re-placed
//! on random receptacles, dropped from just above so that they come to rest
//! on the receptacle's real surface, and kept only if they interpenetrate
//! nothing; the agent starts on a random reachable grid position with a
//! random heading (a multiple of 30°) and horizon. Object states (open,
//! toggled) are not modelled by this simulator, so they are not randomised.

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;

use crate::agent::{AgentState, SetupError, Simulator};
use crate::physics::{deepest_penetration, simulate_drop};
use crate::profile::RobotProfile;
use crate::scene::{OrientedBox, Scene};

/// Deepest overlap accepted between resting objects, metres (contact slop).
pub const MAX_PENETRATION_M: f32 = 0.01;
/// Placement attempts per object before it keeps its original place.
const ATTEMPTS: usize = 8;

/// Why a randomised episode could not be set up.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RandomiseError {
    /// No position on the floor fits the agent.
    #[error("no reachable position for the agent in {scene}")]
    NoReachablePosition {
        /// The scene.
        scene: String,
    },
    /// The chosen start was rejected.
    #[error(transparent)]
    Setup(#[from] SetupError),
}

/// How many objects moved, for logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RandomiseReport {
    /// Pickupable objects placed somewhere new.
    pub moved: usize,
    /// Pickupable objects that kept their place (no free spot found).
    pub kept: usize,
}

/// Re-places the pickupable objects of `scene` and returns a simulator with
/// the agent at a random reachable start, its camera taking images of
/// `image_size` pixels a side. Deterministic for a given `rng` state.
pub fn randomise(
    scene: &Scene,
    profile: &RobotProfile,
    image_size: usize,
    rng: &mut impl Rng,
) -> Result<(Simulator, RandomiseReport), RandomiseError> {
    let mut scene = scene.clone();
    let receptacles: Vec<usize> = (0..scene.objects.len())
        .filter(|&i| scene.objects[i].receptacle)
        .collect();
    let mut report = RandomiseReport { moved: 0, kept: 0 };
    for index in 0..scene.objects.len() {
        if !scene.objects[index].pickupable || receptacles.is_empty() {
            continue;
        }
        let original = scene.objects[index].bounds;
        let mut placed = false;
        for _ in 0..ATTEMPTS {
            let r = receptacles[rng.random_range(0..receptacles.len())];
            if r == index {
                continue;
            }
            let support = scene.objects[r].bounds;
            let Some(release) = release_above(&support, &original, rng) else {
                continue;
            };
            let rest = simulate_drop(&scene, index, &release);
            let mut candidate = scene.clone();
            candidate.objects[index].bounds = rest;
            let inside_room = rest.center.x > scene.floor_min.x
                && rest.center.x < scene.floor_max.x
                && rest.center.y > scene.floor_min.y
                && rest.center.y < scene.floor_max.y
                && rest.center.z > scene.floor_top_m - 0.05;
            if inside_room && deepest_penetration(&candidate, index) <= MAX_PENETRATION_M {
                scene.objects[index].move_to(rest);
                placed = true;
                break;
            }
        }
        if placed {
            report.moved += 1;
        } else {
            report.kept += 1;
        }
    }
    let reachable = reachable_grid(&scene, profile)?;
    let (x, y) = reachable[rng.random_range(0..reachable.len())];
    let start = AgentState {
        x,
        y,
        yaw_deg: 30.0 * rng.random_range(0..12) as f32,
        horizon_deg: [0.0, 15.0, 30.0][rng.random_range(0..3)],
    };
    Ok((
        Simulator::new(scene, profile.clone(), start, image_size)?,
        report,
    ))
}

/// A release pose for `object` a little above a random point of the
/// support's top face, with a random heading; `None` if it does not fit.
pub(crate) fn release_above(
    support: &OrientedBox,
    object: &OrientedBox,
    rng: &mut impl Rng,
) -> Option<OrientedBox> {
    let (hx, hy) = (support.half_extents.x, support.half_extents.y);
    let margin = object.half_extents.x.max(object.half_extents.y);
    if hx <= margin || hy <= margin {
        return None;
    }
    let local = Vector3::new(
        rng.random_range(-(hx - margin)..(hx - margin)),
        rng.random_range(-(hy - margin)..(hy - margin)),
        support.half_extents.z + object.half_extents.z + 0.02,
    );
    let yaw = rng.random_range(0.0..std::f32::consts::TAU);
    Some(OrientedBox {
        center: support.center + support.rotation * local,
        rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        half_extents: object.half_extents,
    })
}

/// The reachable 0.25 m grid of `scene` for an agent with `profile` (see
/// [`Simulator::reachable_positions`]); an error if the agent fits nowhere.
pub fn reachable_grid(
    scene: &Scene,
    profile: &RobotProfile,
) -> Result<Vec<(f32, f32)>, RandomiseError> {
    let reachable = probe_start(scene, profile)?.reachable_positions();
    if reachable.is_empty() {
        return Err(RandomiseError::NoReachablePosition {
            scene: scene.name.clone(),
        });
    }
    Ok(reachable)
}

/// The reachable grid position of `scene` nearest `(x, y)` (the first on ties).
pub fn reachable_nearest(
    scene: &Scene,
    profile: &RobotProfile,
    x: f32,
    y: f32,
) -> Result<(f32, f32), RandomiseError> {
    let d = |p: &(f32, f32)| (p.0 - x).powi(2) + (p.1 - y).powi(2);
    let reachable = reachable_grid(scene, profile)?;
    Ok(reachable
        .into_iter()
        .min_by(|a, b| d(a).total_cmp(&d(b)))
        .expect("reachable_grid is never empty"))
}

/// The camera side of simulators made only to ask where the agent fits:
/// they never render.
const NEVER_RENDERED: usize = 1;

/// A simulator at the first free grid spot, only to ask for the reachable grid.
fn probe_start(scene: &Scene, profile: &RobotProfile) -> Result<Simulator, RandomiseError> {
    let nx = ((scene.floor_max.x - scene.floor_min.x) / 0.25) as i32;
    let ny = ((scene.floor_max.y - scene.floor_min.y) / 0.25) as i32;
    (0..=nx)
        .flat_map(|i| (0..=ny).map(move |j| (i, j)))
        .find_map(|(i, j)| {
            let state = AgentState {
                x: scene.floor_min.x + 0.25 * i as f32,
                y: scene.floor_min.y + 0.25 * j as f32,
                yaw_deg: 0.0,
                horizon_deg: 0.0,
            };
            Simulator::new(scene.clone(), profile.clone(), state, NEVER_RENDERED).ok()
        })
        .ok_or_else(|| RandomiseError::NoReachablePosition {
            scene: scene.name.clone(),
        })
}
