//! The agent and its navigation actions, with AI2-THOR's semantics: move
//! ahead 0.25 m unless the capsule would collide, turn by 30°, look up or
//! down by 15° within [−30°, 60°] (positive is down). Every step says whether
//! it succeeded and, if not, why in machine-readable form.

mod hand;
mod interact;

pub use hand::{HandMove, DEFAULT_HAND, HAND_STEP_M};
pub use interact::{pickup_rule, PUSH_SUCCESS_M};

use std::collections::VecDeque;

use crate::geometry::{AgentBody, Obstacle, SceneGeometry};
use crate::gpu::GpuError;
use crate::profile::RobotProfile;
use crate::raycast::{agent_camera_pose, render, Camera, Frame};
use crate::renderer::Renderer;
use crate::scene::Scene;

/// Farthest depth the agent's camera sees, metres.
pub const MAX_DEPTH_M: f32 = 20.0;
/// Length of a step, metres.
pub const STEP_M: f32 = 0.25;
/// Turn per rotate action, degrees.
pub const TURN_DEG: f32 = 30.0;
/// Tilt per look action, degrees.
pub const LOOK_DEG: f32 = 15.0;
/// Horizon limits (positive looks down), degrees.
pub const HORIZON_RANGE_DEG: (f32, f32) = (-30.0, 60.0);
/// Gap kept between the capsule and the floor, metres (small objects lying
/// flat on the floor do not block; anything taller does).
pub const FLOOR_CLEARANCE_M: f32 = 0.02;

/// Where the agent is and where it looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgentState {
    /// Position on the floor, world x, metres.
    pub x: f32,
    /// Position on the floor, world y, metres.
    pub y: f32,
    /// Heading, degrees counter-clockwise from +x.
    pub yaw_deg: f32,
    /// Camera tilt, degrees, positive looks down.
    pub horizon_deg: f32,
}

/// A navigation action.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NavAction {
    /// Move 0.25 m along the heading.
    MoveAhead,
    /// Turn 30° counter-clockwise.
    RotateLeft,
    /// Turn 30° clockwise.
    RotateRight,
    /// Tilt the camera 15° up.
    LookUp,
    /// Tilt the camera 15° down.
    LookDown,
}

/// Any action the agent can take; interactions aim at an image pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// A navigation action.
    Nav(NavAction),
    /// Pick up the object under pixel `(u, v)`.
    PickUp {
        /// Column.
        u: usize,
        /// Row.
        v: usize,
    },
    /// Push the object under pixel `(u, v)`.
    Push {
        /// Column.
        u: usize,
        /// Row.
        v: usize,
    },
    /// Drop the held object.
    Drop,
    /// Move the held object.
    MoveHeld(HandMove),
}

/// Why an action failed.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// The agent would collide with this object (its id) or a wall.
    Blocked {
        /// The object's id, or `None` for a wall.
        object: Option<String>,
    },
    /// The camera is already at the horizon limit.
    HorizonLimit,
    /// No object under the selected pixel (floor, wall or nothing).
    NothingThere,
    /// The point aimed at is farther from the agent's vertical axis than
    /// the robot's reach.
    OutOfReach {
        /// Horizontal distance from the agent's axis to the point, metres.
        distance_m: f32,
    },
    /// The object cannot be picked up (AI2-THOR's flag).
    NotPickupable,
    /// Heavier than the robot's payload.
    TooHeavy {
        /// Its mass, kg.
        mass_kg: f32,
    },
    /// Wider than the gripper opens.
    TooWide {
        /// Its narrowest horizontal size, metres.
        width_m: f32,
    },
    /// The hand already holds an object.
    HandFull,
    /// The hand is empty.
    HandEmpty,
    /// There is no room where the object would be held or released.
    NoRoom {
        /// What is in the way.
        blocked_by: String,
    },
    /// The object can be neither picked up nor moved (static).
    NotPushable,
    /// The push did not move the object by 2 cm.
    DidNotMove {
        /// How far it moved, metres.
        moved_m: f32,
    },
    /// The pixel is outside the image.
    BadPixel,
    /// The hand would leave the arm's workspace: beyond reach from the eye,
    /// or into the agent's body.
    HandLimit {
        /// How far ahead of the eye the hand would be, metres.
        ahead_m: f32,
        /// How far from the eye the hand would be, metres.
        distance_m: f32,
    },
}

impl Failure {
    /// Whether the failure lies with the object: it does not afford the
    /// action, whatever the robot's pose (cannot be picked up, too heavy or
    /// wide, static, did not move). The other failures say nothing about it.
    pub fn object_does_not_afford(&self) -> bool {
        matches!(
            self,
            Failure::NotPickupable
                | Failure::TooHeavy { .. }
                | Failure::TooWide { .. }
                | Failure::NotPushable
                | Failure::DidNotMove { .. }
        )
    }
}

/// What a step did.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// True if the action happened.
    pub success: bool,
    /// Why not, when it did not.
    pub failure: Option<Failure>,
}

impl Outcome {
    fn ok() -> Self {
        Self {
            success: true,
            failure: None,
        }
    }

    fn failed(f: Failure) -> Self {
        Self {
            success: false,
            failure: Some(f),
        }
    }
}

/// A scene with an agent in it.
#[derive(Debug, Clone)]
pub struct Simulator {
    scene: Scene,
    geometry: SceneGeometry,
    profile: RobotProfile,
    /// Side of the camera's square image, pixels.
    image_size: usize,
    agent: AgentState,
    /// Index of the object in the hand, if any (it is not in the room's geometry).
    held: Option<usize>,
    /// The hand's offset from the eye, body frame (ahead, right, up), metres.
    hand: nalgebra::Vector3<f32>,
}

/// Why a simulator could not be set up.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetupError {
    /// The start pose collides with something.
    #[error("the agent cannot start at ({x:.2}, {y:.2}): it would collide with {what}")]
    StartBlocked {
        /// Start x.
        x: f32,
        /// Start y.
        y: f32,
        /// What it hits.
        what: String,
    },
}

impl Simulator {
    /// Puts an agent with `profile` into `scene` at `start`, its camera
    /// taking square images of `image_size` pixels a side.
    pub fn new(
        scene: Scene,
        profile: RobotProfile,
        start: AgentState,
        image_size: usize,
    ) -> Result<Self, SetupError> {
        let geometry = SceneGeometry::new(&scene);
        let sim = Self {
            scene,
            geometry,
            profile,
            image_size,
            agent: start,
            held: None,
            hand: DEFAULT_HAND,
        };
        if let Some(o) = sim.obstacle_at(start.x, start.y) {
            return Err(SetupError::StartBlocked {
                x: start.x,
                y: start.y,
                what: sim.describe(o),
            });
        }
        Ok(sim)
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The agent's state.
    pub fn agent(&self) -> AgentState {
        self.agent
    }

    /// The robot profile.
    pub fn profile(&self) -> &RobotProfile {
        &self.profile
    }

    fn is_floor(&self, index: usize) -> bool {
        self.scene.objects[index].is_floor()
    }

    fn obstacle_at(&self, x: f32, y: f32) -> Option<Obstacle> {
        let body = AgentBody {
            radius_m: self.profile.agent_radius_m,
            height_m: self.profile.agent_height_m,
            clearance_m: FLOOR_CLEARANCE_M,
        };
        self.geometry
            .capsule_obstacle(x, y, self.scene.floor_top_m, &body, &|i| {
                self.is_floor(i) || self.held == Some(i)
            })
    }

    fn describe(&self, o: Obstacle) -> String {
        match o {
            Obstacle::Object(i) => self.scene.objects[i].id.clone(),
            Obstacle::Wall => "a wall".into(),
        }
    }

    /// Performs a navigation action. With an object in the hand, moving and
    /// turning also fail when the held object would collide.
    pub fn step(&mut self, action: NavAction) -> Outcome {
        let before = self.agent;
        let mut a = before;
        match action {
            NavAction::RotateLeft => a.yaw_deg = (a.yaw_deg + TURN_DEG).rem_euclid(360.0),
            NavAction::RotateRight => a.yaw_deg = (a.yaw_deg - TURN_DEG).rem_euclid(360.0),
            NavAction::LookUp | NavAction::LookDown => {
                let delta = if action == NavAction::LookUp {
                    -LOOK_DEG
                } else {
                    LOOK_DEG
                };
                let next = a.horizon_deg + delta;
                if next < HORIZON_RANGE_DEG.0 - 1e-3 || next > HORIZON_RANGE_DEG.1 + 1e-3 {
                    return Outcome::failed(Failure::HorizonLimit);
                }
                a.horizon_deg = next;
            }
            NavAction::MoveAhead => {
                let yaw = a.yaw_deg.to_radians();
                (a.x, a.y) = (a.x + STEP_M * yaw.cos(), a.y + STEP_M * yaw.sin());
                if let Some(o) = self.obstacle_at(a.x, a.y) {
                    return Outcome::failed(Failure::Blocked {
                        object: match o {
                            Obstacle::Object(i) => Some(self.scene.objects[i].id.clone()),
                            Obstacle::Wall => None,
                        },
                    });
                }
            }
        }
        self.agent = a;
        if let Some(index) = self.held {
            let carried = self.hold_box(index);
            if let Some(what) = self.hold_blocked(index, &carried) {
                self.agent = before;
                return Outcome::failed(Failure::Blocked {
                    object: (what != crate::physics::WALL_NAME).then_some(what),
                });
            }
            // The held object follows the agent.
            self.set_box(index, carried);
        }
        Outcome::ok()
    }

    /// Performs any action.
    pub fn apply(&mut self, action: Action) -> Outcome {
        match action {
            Action::Nav(a) => self.step(a),
            Action::PickUp { u, v } => self.pick_up(u, v),
            Action::Push { u, v } => self.push(u, v),
            Action::Drop => self.drop_held(),
            Action::MoveHeld(m) => self.move_held(m),
        }
    }

    /// The agent's camera.
    pub fn camera(&self) -> Camera {
        let a = self.agent;
        Camera {
            t_world_camera: agent_camera_pose(
                a.x,
                a.y,
                self.scene.floor_top_m,
                self.profile.camera_height_m,
                a.yaw_deg,
                a.horizon_deg,
            ),
            width: self.image_size,
            height: self.image_size,
            fov_deg: self.profile.fov_deg,
        }
    }

    /// What the agent sees, by the CPU reference renderer.
    pub fn render_cpu(&self) -> Frame {
        render(&self.geometry, &self.camera(), MAX_DEPTH_M)
    }

    /// What the agent sees, by `renderer`.
    pub fn render(&self, renderer: &mut Renderer) -> Result<Frame, GpuError> {
        renderer.render(&self.geometry, &self.camera(), MAX_DEPTH_M)
    }

    /// The room as rendered and ray-cast (without the held object).
    pub fn geometry(&self) -> &SceneGeometry {
        &self.geometry
    }

    /// Positions on the 0.25 m grid (aligned to the floor's minimum corner)
    /// where the agent fits, restricted to the largest set connected by
    /// single steps; sorted, so deterministic.
    pub fn reachable_positions(&self) -> Vec<(f32, f32)> {
        let (min, max) = (self.scene.floor_min, self.scene.floor_max);
        let nx = ((max.x - min.x) / STEP_M).floor() as i32;
        let ny = ((max.y - min.y) / STEP_M).floor() as i32;
        let at = |i: i32, j: i32| (min.x + STEP_M * i as f32, min.y + STEP_M * j as f32);
        let free: Vec<bool> = (0..=nx)
            .flat_map(|i| (0..=ny).map(move |j| (i, j)))
            .map(|(i, j)| {
                let (x, y) = at(i, j);
                self.obstacle_at(x, y).is_none()
            })
            .collect();
        let index = |i: i32, j: i32| (i * (ny + 1) + j) as usize;
        let mut component = vec![usize::MAX; free.len()];
        let mut best: Vec<(i32, i32)> = Vec::new();
        for i in 0..=nx {
            for j in 0..=ny {
                if !free[index(i, j)] || component[index(i, j)] != usize::MAX {
                    continue;
                }
                let label = index(i, j);
                let mut members = vec![(i, j)];
                let mut queue = VecDeque::from([(i, j)]);
                component[label] = label;
                while let Some((ci, cj)) = queue.pop_front() {
                    for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                        let (ni, nj) = (ci + di, cj + dj);
                        if ni < 0 || nj < 0 || ni > nx || nj > ny {
                            continue;
                        }
                        let k = index(ni, nj);
                        if free[k] && component[k] == usize::MAX {
                            component[k] = label;
                            members.push((ni, nj));
                            queue.push_back((ni, nj));
                        }
                    }
                }
                if members.len() > best.len() {
                    best = members;
                }
            }
        }
        best.sort_unstable();
        best.into_iter().map(|(i, j)| at(i, j)).collect()
    }
}
