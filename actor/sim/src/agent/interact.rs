//! Interaction actions: pick up the object under a pixel, drop what is held,
//! push the object under a pixel. Rules (flags, reach, payload, gripper) come
//! from the robot profile; outcomes of pushes and drops from the physics.

use nalgebra::{Point3, Vector3};

use super::hand::DEFAULT_HAND;
use super::{Failure, Outcome, Simulator};
use crate::geometry::SceneGeometry;
use crate::physics::{simulate_drop, simulate_push};
use crate::profile::RobotProfile;
use crate::scene::{OrientedBox, SceneObject};

/// Least horizontal motion that makes a push a success, metres.
pub const PUSH_SUCCESS_M: f32 = 0.02;

/// The profile's rule for picking `object` up: AI2-THOR's flag, the payload
/// and the gripper opening (narrowest horizontal side of the object's box).
pub fn pickup_rule(object: &SceneObject, profile: &RobotProfile) -> Result<(), Failure> {
    if !object.pickupable {
        return Err(Failure::NotPickupable);
    }
    if object.mass_kg > profile.payload_kg {
        return Err(Failure::TooHeavy {
            mass_kg: object.mass_kg,
        });
    }
    let width = 2.0
        * object
            .bounds
            .half_extents
            .x
            .min(object.bounds.half_extents.y);
    if width > profile.gripper_opening_m {
        return Err(Failure::TooWide { width_m: width });
    }
    Ok(())
}

impl Simulator {
    /// The object in the hand, by index into the scene's objects.
    pub fn held(&self) -> Option<usize> {
        self.held
    }

    /// The object under pixel `(u, v)`, if it is within reach: the point hit
    /// lies at most the profile's reach from the agent's vertical axis
    /// (AI2-THOR's visibility distance), whatever its height, so an object
    /// on the floor at the agent's feet is within reach as much as one on a
    /// table.
    fn pixel_hit(&self, u: usize, v: usize) -> Result<usize, Failure> {
        let camera = self.camera();
        if u >= camera.width || v >= camera.height {
            return Err(Failure::BadPixel);
        }
        let origin = camera.t_world_camera * Point3::origin();
        let dir = (camera.t_world_camera.rotation * camera.ray(u as f32, v as f32)).normalize();
        let (distance, id, _, _) = self
            .geometry
            .cast(&origin, &dir, 50.0)
            .ok_or(Failure::NothingThere)?;
        if id == 0 {
            return Err(Failure::NothingThere);
        }
        let hit = origin + dir * distance;
        let from_axis = (hit.x - self.agent.x).hypot(hit.y - self.agent.y);
        if from_axis > self.profile.reach_m {
            return Err(Failure::OutOfReach {
                distance_m: from_axis,
            });
        }
        Ok(id as usize - 1)
    }

    /// Moves object `index` to box `to` (its pivot follows rigidly) and rebuilds the geometry.
    fn place(&mut self, index: usize, to: OrientedBox) {
        self.set_box(index, to);
        self.geometry = SceneGeometry::without(&self.scene, self.held);
    }

    /// Moves object `index` to box `to` (its pivot follows rigidly), leaving the geometry as it is.
    pub(super) fn set_box(&mut self, index: usize, to: OrientedBox) {
        self.scene.objects[index].move_to(to);
    }

    /// Picks up the object under pixel `(u, v)`.
    pub fn pick_up(&mut self, u: usize, v: usize) -> Outcome {
        if self.held.is_some() {
            return Outcome::failed(Failure::HandFull);
        }
        let index = match self.pixel_hit(u, v) {
            Ok(i) => i,
            Err(f) => return Outcome::failed(f),
        };
        if let Err(f) = pickup_rule(&self.scene.objects[index], &self.profile) {
            return Outcome::failed(f);
        }
        let hold = self.hold_box_at(index, DEFAULT_HAND);
        if let Some(blocked_by) = self.hold_blocked(index, &hold) {
            return Outcome::failed(Failure::NoRoom { blocked_by });
        }
        self.held = Some(index);
        self.hand = DEFAULT_HAND;
        self.place(index, hold);
        Outcome::ok()
    }

    /// Drops the held object from where it is held; it falls until it rests.
    pub fn drop_held(&mut self) -> Outcome {
        let Some(index) = self.held else {
            return Outcome::failed(Failure::HandEmpty);
        };
        let hold = self.hold_box(index);
        if let Some(blocked_by) = self.hold_blocked(index, &hold) {
            return Outcome::failed(Failure::NoRoom { blocked_by });
        }
        let rest = simulate_drop(&self.scene, index, &hold);
        self.held = None;
        self.hand = DEFAULT_HAND;
        self.place(index, rest);
        Outcome::ok()
    }

    /// Pushes the object under pixel `(u, v)` with the profile's force along
    /// the camera's horizontal forward direction; it succeeds if the object
    /// moves at least [`PUSH_SUCCESS_M`].
    pub fn push(&mut self, u: usize, v: usize) -> Outcome {
        let index = match self.pixel_hit(u, v) {
            Ok(i) => i,
            Err(f) => return Outcome::failed(f),
        };
        if !self.scene.objects[index].pushable() {
            return Outcome::failed(Failure::NotPushable);
        }
        let yaw = self.agent.yaw_deg.to_radians();
        let force = Vector3::new(yaw.cos(), yaw.sin(), 0.0) * self.profile.push_force_n;
        let before = self.scene.objects[index].bounds;
        let after = simulate_push(&self.scene, index, force);
        let moved = (after.center - before.center).xy().norm();
        if moved < PUSH_SUCCESS_M {
            return Outcome::failed(Failure::DidNotMove { moved_m: moved });
        }
        self.place(index, after);
        Outcome::ok()
    }
}
