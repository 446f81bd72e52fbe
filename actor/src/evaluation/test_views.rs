//! Table 1's fixed test set: views of a room from random reachable poses,
//! the same for a given seed, kept only where objects fill a fair part of
//! the image (a view of a bare wall scores nothing).

use anyhow::Context;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use sim::agent::{AgentState, Simulator};
use sim::profile::RobotProfile;
use sim::raycast::Frame;
use sim::renderer::Renderer;
use sim::scene::Scene;

/// Least share of a test view's pixels that objects must cover.
pub(crate) const MIN_OBJECT_SHARE: f32 = 0.1;
/// Camera tilts of the test views, degrees (as an episode's start).
const HORIZONS_DEG: [f32; 3] = [0.0, 15.0, 30.0];
/// Poses drawn per wanted view before giving up on the room.
const DRAWS_PER_VIEW: usize = 50;

/// `count` views of `scene` as loaded, for `seed` (with the room's index
/// among the evaluated ones, so rooms differ): random positions of
/// `reachable` (the room's reachable grid), headings in 30° steps and horizons of 0°, 15° or 30°, each
/// kept if objects cover at least [`MIN_OBJECT_SHARE`] of it. Fewer if the
/// room rarely shows that much.
pub(crate) fn test_views(
    scene: &Scene,
    profile: &RobotProfile,
    image_size: usize,
    reachable: &[(f32, f32)],
    renderer: &mut Renderer,
    count: usize,
    seed: u64,
) -> anyhow::Result<Vec<Frame>> {
    anyhow::ensure!(
        !reachable.is_empty(),
        "no reachable position in {}",
        scene.name
    );
    let mut rng = StdRng::seed_from_u64(seed);
    let mut views = Vec::with_capacity(count);
    for _ in 0..count * DRAWS_PER_VIEW {
        if views.len() == count {
            break;
        }
        let (x, y) = reachable[rng.random_range(0..reachable.len())];
        let pose = AgentState {
            x,
            y,
            yaw_deg: 30.0 * rng.random_range(0..12) as f32,
            horizon_deg: HORIZONS_DEG[rng.random_range(0..HORIZONS_DEG.len())],
        };
        let sim = Simulator::new(scene.clone(), profile.clone(), pose, image_size)
            .with_context(|| format!("placing the agent in {}", scene.name))?;
        let frame = sim
            .render(renderer)
            .with_context(|| format!("rendering a test view of {}", scene.name))?;
        let objects = frame.ids.iter().filter(|&&id| id != 0).count();
        if objects as f32 >= MIN_OBJECT_SHARE * frame.ids.len() as f32 {
            views.push(frame);
        }
    }
    Ok(views)
}
