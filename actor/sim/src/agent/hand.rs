//! The hand: where a held object sits relative to the agent, how it follows
//! the agent, and the move-held-object actions (±0.1 m along the agent's
//! ahead, right and up axes) that fail when the object would collide or
//! leave the arm's workspace.

use nalgebra::{Point3, UnitQuaternion, Vector3};

use super::{Failure, Outcome, Simulator};
use crate::physics::first_overlap;
use crate::scene::OrientedBox;

/// Where a held object's box centre starts, relative to the eye in the
/// agent's body frame (ahead, right, up), metres.
pub const DEFAULT_HAND: Vector3<f32> = Vector3::new(0.55, 0.0, -0.25);
/// Length of one move-held-object action, metres.
pub const HAND_STEP_M: f32 = 0.1;

/// A move of the held object by [`HAND_STEP_M`] along one of the agent's axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HandMove {
    /// Away from the agent along its heading.
    Ahead,
    /// Towards the agent.
    Back,
    /// To the agent's right.
    Right,
    /// To the agent's left.
    Left,
    /// Up.
    Up,
    /// Down.
    Down,
}

impl HandMove {
    /// All six moves, in the order the action space lists them.
    pub const ALL: [HandMove; 6] = [
        HandMove::Ahead,
        HandMove::Back,
        HandMove::Right,
        HandMove::Left,
        HandMove::Up,
        HandMove::Down,
    ];

    /// The move as a body-frame (ahead, right, up) displacement, metres.
    fn delta(self) -> Vector3<f32> {
        let s = HAND_STEP_M;
        match self {
            HandMove::Ahead => Vector3::new(s, 0.0, 0.0),
            HandMove::Back => Vector3::new(-s, 0.0, 0.0),
            HandMove::Right => Vector3::new(0.0, s, 0.0),
            HandMove::Left => Vector3::new(0.0, -s, 0.0),
            HandMove::Up => Vector3::new(0.0, 0.0, s),
            HandMove::Down => Vector3::new(0.0, 0.0, -s),
        }
    }
}

impl Simulator {
    /// The hand's offset from the eye in the body frame (ahead, right, up), metres.
    pub fn hand_offset(&self) -> Vector3<f32> {
        self.hand
    }

    /// The box of object `index` when held at body-frame `offset`: upright,
    /// facing the agent's heading.
    pub(super) fn hold_box_at(&self, index: usize, offset: Vector3<f32>) -> OrientedBox {
        let a = self.agent;
        let yaw = a.yaw_deg.to_radians();
        let ahead = Vector3::new(yaw.cos(), yaw.sin(), 0.0);
        let right = Vector3::new(yaw.sin(), -yaw.cos(), 0.0);
        let eye = Point3::new(
            a.x,
            a.y,
            self.scene.floor_top_m + self.profile.camera_height_m,
        );
        OrientedBox {
            center: eye + ahead * offset.x + right * offset.y + Vector3::z() * offset.z,
            rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
            half_extents: self.scene.objects[index].bounds.half_extents,
        }
    }

    /// The box of object `index` held at the current hand offset.
    pub(super) fn hold_box(&self, index: usize) -> OrientedBox {
        self.hold_box_at(index, self.hand)
    }

    /// Why the held object cannot be at `box_`: the first thing it would
    /// overlap, or `None` if there is room.
    pub(super) fn hold_blocked(&self, index: usize, box_: &OrientedBox) -> Option<String> {
        first_overlap(&self.scene, index, box_, &|_| false)
    }

    /// Moves the held object by one step along `direction`. Fails when the
    /// hand is empty, when the hand would leave the workspace (beyond the
    /// profile's reach from the eye, or into the agent's body), or when the
    /// object would collide with anything.
    pub fn move_held(&mut self, direction: HandMove) -> Outcome {
        let Some(index) = self.held else {
            return Outcome::failed(Failure::HandEmpty);
        };
        let offset = self.hand + direction.delta();
        let half = self.scene.objects[index].bounds.half_extents;
        let near = self.profile.agent_radius_m + half.x.min(half.y);
        if offset.norm() > self.profile.reach_m || offset.x < near {
            return Outcome::failed(Failure::HandLimit {
                ahead_m: offset.x,
                distance_m: offset.norm(),
            });
        }
        let to = self.hold_box_at(index, offset);
        if let Some(blocked_by) = self.hold_blocked(index, &to) {
            return Outcome::failed(Failure::NoRoom { blocked_by });
        }
        self.hand = offset;
        self.set_box(index, to);
        Outcome::ok()
    }
}
