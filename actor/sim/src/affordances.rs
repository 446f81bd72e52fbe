//! Ground-truth affordances of every object for a robot profile, for
//! evaluation. They come from the same rules and physics the actions use,
//! never from a table: pick-up from the profile's rules, push from trying
//! the push in a copy of the room in four horizontal directions.

use nalgebra::Vector3;

use crate::agent::{pickup_rule, PUSH_SUCCESS_M};
use crate::physics::simulate_push;
use crate::profile::RobotProfile;
use crate::scene::{Scene, SceneObject};

/// What a robot can do with one object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObjectAffordances {
    /// The object's id.
    pub id: String,
    /// It can be picked up (given a clear view within reach).
    pub pick_up: bool,
    /// A push in at least one horizontal direction moves it.
    pub push: bool,
}

/// The pick-up rule of `profile` for `object` (see [`pickup_rule`]).
pub fn can_pick_up(object: &SceneObject, profile: &RobotProfile) -> bool {
    pickup_rule(object, profile).is_ok()
}

/// Whether the profile's push moves object `index` by at least
/// [`PUSH_SUCCESS_M`] in any of the four horizontal directions.
pub fn can_push(scene: &Scene, index: usize, profile: &RobotProfile) -> bool {
    let o = &scene.objects[index];
    if !o.pushable() {
        return false;
    }
    [Vector3::x(), -Vector3::x(), Vector3::y(), -Vector3::y()]
        .iter()
        .any(|d| {
            let after = simulate_push(scene, index, d * profile.push_force_n);
            (after.center - o.bounds.center).xy().norm() >= PUSH_SUCCESS_M
        })
}

/// Affordances of every object of `scene` (the floor excluded), in scene order.
pub fn ground_truth(scene: &Scene, profile: &RobotProfile) -> Vec<ObjectAffordances> {
    scene
        .objects
        .iter()
        .enumerate()
        .filter(|(_, o)| !o.is_floor())
        .map(|(i, o)| ObjectAffordances {
            id: o.id.clone(),
            pick_up: can_pick_up(o, profile),
            push: can_push(scene, i, profile),
        })
        .collect()
}
