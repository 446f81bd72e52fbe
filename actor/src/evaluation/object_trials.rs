//! Table 2's trials: the robot placed in front of one object, looking at
//! it, and each affordance tried there on the object's middle pixel, in a
//! copy of the room per attempt (so one attempt cannot change another).
//! Every object is scored once: tried where some position reaches it,
//! otherwise judged against the simulator's ground truth from the view
//! that shows it best.

use anyhow::Context;
use proto::Affordance;
use sim::agent::{Action, AgentState, Failure, Simulator};
use sim::profile::RobotProfile;
use sim::raycast::Frame;
use sim::renderer::Renderer;
use sim::scene::Scene;

/// Reachable grid positions tried per object, nearest first.
const CANDIDATE_POSITIONS: usize = 16;
/// Nearest an object's centre may be to the agent's axis, metres (closer,
/// most of it falls out of view).
const NEAREST_M: f32 = 0.4;
/// Least share of the image an object must cover to be tried.
const MIN_SHARE: f32 = 0.002;
/// Fewest pixels an object must cover to be tried.
const MIN_PIXELS: usize = 8;

/// The agent in front of an object, what it sees, and where it aims.
#[derive(Debug, Clone)]
pub struct ObjectView {
    /// The simulator with the agent in place.
    pub sim: Simulator,
    /// What the agent sees.
    pub frame: Frame,
    /// The object's pixels in `frame`.
    pub pixels: Vec<usize>,
    /// The pixel aimed at: the object's pixel nearest its pixels' centroid.
    pub aim: (usize, usize),
    /// Horizontal distance from the agent to the object's centre, metres.
    pub distance_m: f32,
}

/// How Table 2 scores one object, after looking for it from the room's
/// reachable positions.
#[derive(Debug, Clone)]
pub enum Sighting {
    /// In view from a reachable position with its middle pixel within
    /// reach: each affordance is tried there.
    Reachable(ObjectView),
    /// In view, but within reach from no reachable position (a vase high on
    /// a shelf, a card behind a sofa): the view that shows it largest, whose
    /// prediction is scored against the simulator's ground truth for the
    /// robot instead of an attempt.
    OutOfReach(ObjectView),
    /// In view from no reachable position within [`SEARCH_RADIUS_M`]: no
    /// prediction to score.
    Unseen,
}

/// How far from an object the second search looks for a position that
/// shows it, metres (beyond this an object at 64 px is a few pixels, and
/// far beyond any robot's reach).
pub const SEARCH_RADIUS_M: f32 = 3.0;

/// Looks for object `index` of `scene` the way a person setting up the
/// paper's trials would. First the preferred view: the reachable grid
/// position nearest the object (at least 0.4 m away) from which, facing the
/// object's centre with the camera tilted towards it, the object covers a
/// fair number of pixels and its middle pixel is within reach (of the 16
/// nearest positions). Failing that, every reachable position within
/// [`SEARCH_RADIUS_M`], nearest first, for one that shows any of it within
/// reach; failing that, the one that shows most of it.
pub fn sight_object(
    scene: &Scene,
    profile: &RobotProfile,
    image_size: usize,
    reachable: &[(f32, f32)],
    index: usize,
    renderer: &mut Renderer,
) -> anyhow::Result<Sighting> {
    let target = scene.objects[index].bounds.center;
    let distance = |p: &(f32, f32)| (p.0 - target.x).hypot(p.1 - target.y);
    let mut candidates: Vec<(f32, f32)> = reachable
        .iter()
        .copied()
        .filter(|p| distance(p) >= NEAREST_M)
        .collect();
    candidates.sort_by(|a, b| distance(a).total_cmp(&distance(b)));
    let min_pixels = MIN_PIXELS.max((MIN_SHARE * (image_size.pow(2)) as f32) as usize);
    for &position in candidates.iter().take(CANDIDATE_POSITIONS) {
        if let Some(view) = view_from(scene, profile, image_size, index, position, renderer)? {
            if view.pixels.len() >= min_pixels && within_reach(&view) {
                return Ok(Sighting::Reachable(view));
            }
        }
    }
    let mut largest: Option<ObjectView> = None;
    for &position in candidates
        .iter()
        .take_while(|p| distance(p) <= SEARCH_RADIUS_M)
    {
        let Some(view) = view_from(scene, profile, image_size, index, position, renderer)? else {
            continue;
        };
        if within_reach(&view) {
            return Ok(Sighting::Reachable(view));
        }
        if largest
            .as_ref()
            .is_none_or(|l| view.pixels.len() > l.pixels.len())
        {
            largest = Some(view);
        }
    }
    Ok(largest.map_or(Sighting::Unseen, Sighting::OutOfReach))
}

/// The agent at `position`, facing object `index`'s centre with the camera
/// tilted towards it, and what it sees; `None` if the object is not in view.
fn view_from(
    scene: &Scene,
    profile: &RobotProfile,
    image_size: usize,
    index: usize,
    (x, y): (f32, f32),
    renderer: &mut Renderer,
) -> anyhow::Result<Option<ObjectView>> {
    let target = scene.objects[index].bounds.center;
    let eye_z = scene.floor_top_m + profile.camera_height_m;
    let horizontal = (x - target.x).hypot(y - target.y);
    let pose = AgentState {
        x,
        y,
        yaw_deg: (target.y - y).atan2(target.x - x).to_degrees(),
        horizon_deg: (eye_z - target.z)
            .atan2(horizontal)
            .to_degrees()
            .clamp(-30.0, 60.0),
    };
    let sim = Simulator::new(scene.clone(), profile.clone(), pose, image_size)
        .with_context(|| format!("placing the agent in {}", scene.name))?;
    let frame = sim
        .render(renderer)
        .with_context(|| format!("rendering a view of {}", scene.objects[index].id))?;
    let id = index as u32 + 1;
    let pixels: Vec<usize> = (0..frame.ids.len())
        .filter(|&p| frame.ids[p] == id)
        .collect();
    if pixels.is_empty() {
        return Ok(None);
    }
    let aim = middle_pixel(&pixels, frame.width);
    Ok(Some(ObjectView {
        sim,
        frame,
        pixels,
        aim,
        distance_m: horizontal,
    }))
}

/// Whether the view's aim is within the robot's reach (a push there gets
/// as far as the object).
fn within_reach(view: &ObjectView) -> bool {
    let (u, v) = view.aim;
    let probe = view.sim.clone().apply(Action::Push { u, v });
    !matches!(
        probe.failure,
        Some(Failure::OutOfReach { .. } | Failure::NothingThere | Failure::BadPixel)
    )
}

/// The pixel of `pixels` nearest their centroid, as `(column, row)`.
fn middle_pixel(pixels: &[usize], width: usize) -> (usize, usize) {
    let n = pixels.len() as f32;
    let cu = pixels.iter().map(|&p| (p % width) as f32).sum::<f32>() / n;
    let cv = pixels.iter().map(|&p| (p / width) as f32).sum::<f32>() / n;
    let d = |p: usize| ((p % width) as f32 - cu).powi(2) + ((p / width) as f32 - cv).powi(2);
    let best = pixels
        .iter()
        .copied()
        .min_by(|&a, &b| d(a).total_cmp(&d(b)))
        .unwrap_or(0);
    (best % width, best / width)
}

/// Tries `affordance` on the view's aim in a copy of its room: whether it
/// succeeded, and why not.
pub fn try_affordance(view: &ObjectView, affordance: Affordance) -> (bool, Option<Failure>) {
    let (u, v) = view.aim;
    let action = match affordance {
        Affordance::PickUp => Action::PickUp { u, v },
        Affordance::Push => Action::Push { u, v },
    };
    let outcome = view.sim.clone().apply(action);
    (outcome.success, outcome.failure)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_middle_pixel_is_the_objects_pixel_nearest_its_centroid() {
        // An L (column 1, rows 0–3, and (2, 3)): centroid (1.2, 1.8).
        let width = 4;
        let pixels = [1, 5, 9, 13, 14];
        assert_eq!(middle_pixel(&pixels, width), (1, 2));
        assert_eq!(middle_pixel(&[7], width), (3, 1));
    }
}
