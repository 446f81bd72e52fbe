//! Rigid-body simulation of one object at a time with rapier3d: a push (a
//! force along the camera's forward direction through the object's centre of
//! mass, then sliding to rest) or a
//! drop (falling until it rests). Everything else in the room is static:
//! the floor, the walls and the other objects, as compounds of their convex
//! parts. Friction is the same everywhere, so whether a push overcomes an
//! object's weight is decided by the physics, not by a table.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rapier3d::math::{Pose, Rot3, Vector};
use rapier3d::prelude::{
    ColliderBuilder, PhysicsWorld, RigidBodyBuilder, RigidBodyHandle, SharedShape,
};

use crate::scene::{OrientedBox, Scene};
use crate::shapes::{parts_for, Primitive};

/// Coulomb friction of every contact.
pub const FRICTION: f32 = 0.5;
/// How long a push force acts, seconds.
pub const PUSH_DURATION_S: f32 = 0.3;
/// Longest simulated time after the force or the release, seconds.
pub const MAX_SETTLE_S: f32 = 5.0;
/// Speeds below this count as rest, m/s (and rad/s).
pub const REST_SPEED: f32 = 0.01;

fn vec(v: &Vector3<f32>) -> Vector {
    Vector::new(v.x, v.y, v.z)
}

fn pose(iso: &Isometry3<f32>) -> Pose {
    let q = iso.rotation.quaternion();
    Pose::from_parts(
        vec(&iso.translation.vector),
        Rot3::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

fn from_pose(p: &Pose) -> Isometry3<f32> {
    let t = p.translation;
    let r = p.rotation;
    Isometry3::from_parts(
        Translation3::new(t.x, t.y, t.z),
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(r.w, r.x, r.y, r.z)),
    )
}

/// The parts of a box of `object_type` as rapier shapes in the box frame.
fn compound(
    object_type: &str,
    half_extents: Vector3<f32>,
    structural: bool,
) -> Vec<(Pose, SharedShape)> {
    let parts = if structural {
        vec![crate::shapes::Part {
            pose: Isometry3::identity(),
            primitive: Primitive::Cuboid(half_extents),
            tone: 0,
        }]
    } else {
        parts_for(object_type, half_extents)
    };
    parts
        .iter()
        .map(|p| match p.primitive {
            Primitive::Cuboid(h) => (pose(&p.pose), SharedShape::cuboid(h.x, h.y, h.z)),
            Primitive::Cylinder {
                half_height,
                radius,
            } => {
                // rapier's cylinders stand along y; ours along z.
                let fix = Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_axis_angle(
                        &Vector3::x_axis(),
                        std::f32::consts::FRAC_PI_2,
                    ),
                );
                (
                    pose(&(p.pose * fix)),
                    SharedShape::cylinder(half_height, radius),
                )
            }
            Primitive::Ball(r) => (pose(&p.pose), SharedShape::ball(r)),
        })
        .collect()
}

fn box_pose(b: &OrientedBox) -> Isometry3<f32> {
    Isometry3::from_parts(Translation3::from(b.center.coords), b.rotation)
}

/// The first thing (object id, or `wall`) that object `index` would overlap
/// with its box at `at`; objects for which `ignore` is true do not count.
pub fn first_overlap(
    scene: &Scene,
    index: usize,
    at: &OrientedBox,
    ignore: &dyn Fn(usize) -> bool,
) -> Option<String> {
    let o = &scene.objects[index];
    let shape = SharedShape::compound(compound(&o.object_type, at.half_extents, false));
    let here = pose(&box_pose(at));
    let hits = |other: &SharedShape, other_pose: &Pose| {
        rapier3d::parry::query::intersection_test(&here, shape.as_ref(), other_pose, other.as_ref())
            .is_ok_and(|r| r.intersecting)
    };
    let (lo, hi) = at.world_aabb();
    let apart =
        |min: &Point3<f32>, max: &Point3<f32>| (0..3).any(|a| max[a] < lo[a] || min[a] > hi[a]);
    for (i, other) in scene.objects.iter().enumerate() {
        if i == index || ignore(i) || apart(&other.aabb_min, &other.aabb_max) {
            continue;
        }
        let structural = other.is_floor();
        let s = SharedShape::compound(compound(
            &other.object_type,
            other.bounds.half_extents,
            structural,
        ));
        if hits(&s, &pose(&box_pose(&other.bounds))) {
            return Some(other.id.clone());
        }
    }
    scene
        .walls
        .iter()
        .filter(|w| {
            let (min, max) = w.world_aabb();
            !apart(&min, &max)
        })
        .any(|w| {
            hits(
                &SharedShape::cuboid(w.half_extents.x, w.half_extents.y, w.half_extents.z),
                &pose(&box_pose(w)),
            )
        })
        .then(|| WALL_NAME.to_string())
}

/// What [`first_overlap`] names a wall or the ceiling.
pub const WALL_NAME: &str = "wall";

/// The deepest overlap (metres, 0 if none) between object `index` and
/// anything else in the room: other objects, the floor, the walls.
pub fn deepest_penetration(scene: &Scene, index: usize) -> f32 {
    let o = &scene.objects[index];
    let shape = SharedShape::compound(compound(&o.object_type, o.bounds.half_extents, false));
    let here = pose(&box_pose(&o.bounds));
    let depth = |other: &SharedShape, other_pose: &Pose| match rapier3d::parry::query::contact(
        &here,
        shape.as_ref(),
        other_pose,
        other.as_ref(),
        0.0,
    ) {
        Ok(Some(c)) if c.dist < 0.0 => -c.dist,
        _ => 0.0,
    };
    let objects = scene
        .objects
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != index)
        .map(|(_, other)| {
            let structural = other.is_floor();
            let s = SharedShape::compound(compound(
                &other.object_type,
                other.bounds.half_extents,
                structural,
            ));
            depth(&s, &pose(&box_pose(&other.bounds)))
        });
    let walls = scene.walls.iter().map(|w| {
        depth(
            &SharedShape::cuboid(w.half_extents.x, w.half_extents.y, w.half_extents.z),
            &pose(&box_pose(w)),
        )
    });
    objects.chain(walls).fold(0.0, f32::max)
}

/// A room with one dynamic object.
struct OneBody {
    world: PhysicsWorld,
    body: RigidBodyHandle,
}

/// Builds the room with object `index` dynamic at `start`. Objects whose
/// shapes overlap it there are left out: the parametric shapes are coarser
/// than the real ones, so a pillow on a sofa's seat may overlap the seat
/// block, and keeping it would shove the sofa at the first step.
fn build(scene: &Scene, index: usize, start: &OrientedBox) -> OneBody {
    let mut world = PhysicsWorld {
        gravity: Vector::new(0.0, 0.0, -9.81),
        ..Default::default()
    };
    let moving = &scene.objects[index];
    let moving_shape =
        SharedShape::compound(compound(&moving.object_type, start.half_extents, false));
    let moving_pose = pose(&box_pose(start));
    for (i, o) in scene.objects.iter().enumerate() {
        if i == index {
            continue;
        }
        let structural = o.is_floor();
        let shape =
            SharedShape::compound(compound(&o.object_type, o.bounds.half_extents, structural));
        let at = pose(&box_pose(&o.bounds));
        let overlaps = !structural
            && rapier3d::parry::query::intersection_test(
                &moving_pose,
                moving_shape.as_ref(),
                &at,
                shape.as_ref(),
            )
            .is_ok_and(|r| r.intersecting);
        if overlaps {
            continue;
        }
        world.insert(
            RigidBodyBuilder::fixed().pose(at),
            ColliderBuilder::new(shape).friction(FRICTION),
        );
    }
    for wall in &scene.walls {
        world.insert(
            RigidBodyBuilder::fixed().pose(pose(&box_pose(wall))),
            ColliderBuilder::cuboid(
                wall.half_extents.x,
                wall.half_extents.y,
                wall.half_extents.z,
            )
            .friction(FRICTION),
        );
    }
    let o = &scene.objects[index];
    let (body, _) = world.insert(
        RigidBodyBuilder::dynamic()
            .pose(pose(&box_pose(start)))
            .ccd_enabled(true),
        ColliderBuilder::compound(compound(&o.object_type, start.half_extents, false))
            .friction(FRICTION)
            .mass(o.mass_kg.max(0.05)),
    );
    OneBody { world, body }
}

impl OneBody {
    /// Steps until the body rests (after `min_s`) or `max_s` passes; returns the final box pose.
    fn settle(&mut self, min_s: f32, max_s: f32, template: &OrientedBox) -> OrientedBox {
        let dt = self.world.integration_parameters.dt;
        let mut t = 0.0;
        let mut still = 0;
        while t < max_s {
            self.world.step();
            t += dt;
            let b = &self.world.bodies[self.body];
            let resting = b.is_sleeping()
                || (b.linvel().length() < REST_SPEED && b.angvel().length() < REST_SPEED);
            still = if resting { still + 1 } else { 0 };
            if t >= min_s && still >= 10 {
                break;
            }
        }
        let p = from_pose(self.world.bodies[self.body].position());
        OrientedBox {
            center: Point3::from(p.translation.vector),
            rotation: p.rotation,
            half_extents: template.half_extents,
        }
    }
}

/// Pushes object `index` with `force_n` (world frame, newtons) through its
/// centre of mass for [`PUSH_DURATION_S`], as AI2-THOR's `PushObject` does
/// (Unity's `AddForce`), then lets it come to rest. Returns its new box.
pub fn simulate_push(scene: &Scene, index: usize, force_n: Vector3<f32>) -> OrientedBox {
    let start = scene.objects[index].bounds;
    let mut sim = build(scene, index, &start);
    let dt = sim.world.integration_parameters.dt;
    // A few steps first, so that contacts settle before the push.
    for _ in 0..5 {
        sim.world.step();
    }
    let steps = (PUSH_DURATION_S / dt).round() as usize;
    for _ in 0..steps {
        let body = &mut sim.world.bodies[sim.body];
        body.reset_forces(false);
        body.add_force(vec(&force_n), true);
        sim.world.step();
    }
    sim.world.bodies[sim.body].reset_forces(false);
    sim.settle(0.0, MAX_SETTLE_S, &start)
}

/// Releases object `index` at box pose `release` and lets it fall to rest.
/// Returns its resting box.
pub fn simulate_drop(scene: &Scene, index: usize, release: &OrientedBox) -> OrientedBox {
    let mut sim = build(scene, index, release);
    sim.settle(0.1, MAX_SETTLE_S, release)
}
