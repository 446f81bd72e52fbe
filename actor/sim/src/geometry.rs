//! A scene as placed convex parts: what rays hit and what the agent bumps
//! into. Parts come from [`crate::shapes`]; colours from the objects' materials.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d::math::Pose;
use parry3d::math::Vector as PVec;
use parry3d::query::intersection_test;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::{Ball, Capsule, Cuboid, Cylinder, Shape};

use crate::scene::Scene;
use crate::shapes::{parts_for, Primitive};
use crate::texture::{material_pattern, shade, PLAIN, WOOD};

/// A parry primitive.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Convex {
    Cuboid(Cuboid),
    Cylinder(Cylinder),
    Ball(Ball),
}

/// A part placed in the world with what the renderer needs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PlacedPart {
    /// World to part frame (parry's cylinders stand along the part's y).
    pub(crate) t_part_world: Isometry3<f32>,
    pub(crate) shape: Convex,
    pub(crate) colour: [f32; 3],
    /// Procedural texture ([`crate::texture`]).
    pub(crate) pattern: u32,
}

/// Everything that can be hit, grouped per instance with a world box for culling.
#[derive(Debug, Clone)]
pub(crate) struct Instance {
    /// Instance id: object index + 1, or 0 for the floor and walls.
    pub(crate) id: u32,
    object: Option<usize>,
    aabb_min: Point3<f32>,
    aabb_max: Point3<f32>,
    pub(crate) parts: Vec<PlacedPart>,
}

impl Instance {
    /// The instance's world box.
    pub(crate) fn world_box(&self) -> (Point3<f32>, Point3<f32>) {
        (self.aabb_min, self.aabb_max)
    }
}

/// A scene turned into ray-castable geometry.
#[derive(Debug, Clone)]
pub struct SceneGeometry {
    pub(crate) instances: Vec<Instance>,
    generation: u64,
}

/// Source of [`SceneGeometry::generation`] numbers.
static GENERATIONS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Base colour of a material (linear 0..1), or `None` if unknown.
fn material_colour(material: &str) -> Option<[f32; 3]> {
    Some(match material {
        "Wood" => [0.55, 0.38, 0.22],
        "Fabric" => [0.45, 0.47, 0.62],
        "Leather" => [0.35, 0.22, 0.14],
        "Metal" => [0.62, 0.63, 0.66],
        "Glass" => [0.66, 0.78, 0.82],
        "Plastic" => [0.78, 0.25, 0.22],
        "Ceramic" => [0.88, 0.86, 0.80],
        "Stone" => [0.52, 0.52, 0.50],
        "Paper" | "Cardboard" => [0.86, 0.80, 0.66],
        "Rubber" => [0.15, 0.15, 0.15],
        "Sponge" => [0.90, 0.85, 0.30],
        "Organic" => [0.25, 0.50, 0.22],
        "Food" => [0.80, 0.55, 0.25],
        "Soap" => [0.90, 0.90, 0.95],
        "Wax" => [0.92, 0.90, 0.78],
        _ => return None,
    })
}

/// A small deterministic hash (FNV-1a) for per-instance colour variation.
fn hash(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    })
}

/// The main and accent colours of an object: its first salient material (or a
/// colour from its type), varied slightly per instance.
fn object_colours(object_type: &str, id: &str, materials: &[String]) -> [([f32; 3], u32); 2] {
    let h = hash(object_type);
    let base = materials
        .iter()
        .find_map(|m| material_colour(m))
        .unwrap_or([
            0.3 + (h % 50) as f32 / 100.0,
            0.3 + ((h >> 8) % 50) as f32 / 100.0,
            0.3 + ((h >> 16) % 50) as f32 / 100.0,
        ]);
    let v = hash(id);
    let jitter = |k: u32| ((v >> (8 * k)) % 31) as f32 / 100.0 - 0.15;
    let main = [0, 1, 2].map(|c| (base[c] + jitter(c as u32)).clamp(0.02, 0.98));
    let accent = materials
        .get(1)
        .and_then(|m| material_colour(m))
        .unwrap_or(main.map(|c| c * 0.6));
    let pattern = |i: usize| {
        materials
            .get(i)
            .or(materials.first())
            .map_or(PLAIN, |m| material_pattern(m))
    };
    [(main, pattern(0)), (accent, pattern(1))]
}

fn placed(
    box_pose: &Isometry3<f32>,
    part_pose: &Isometry3<f32>,
    primitive: &Primitive,
    (colour, pattern): ([f32; 3], u32),
) -> PlacedPart {
    let v = |x: Vector3<f32>| PVec::new(x.x, x.y, x.z);
    // parry's cylinders stand along y; ours along z.
    let (shape, fix) = match *primitive {
        Primitive::Cuboid(h) => (
            Convex::Cuboid(Cuboid::new(v(h))),
            UnitQuaternion::identity(),
        ),
        Primitive::Cylinder {
            half_height,
            radius,
        } => (
            Convex::Cylinder(Cylinder::new(half_height, radius)),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::FRAC_PI_2),
        ),
        Primitive::Ball(r) => (Convex::Ball(Ball::new(r)), UnitQuaternion::identity()),
    };
    let t_world_part = box_pose * part_pose * Isometry3::from_parts(Translation3::identity(), fix);
    PlacedPart {
        t_part_world: t_world_part.inverse(),
        shape,
        colour,
        pattern,
    }
}

impl SceneGeometry {
    /// Geometry of `scene`: every object's parts; the floor and walls as boxes (id 0).
    pub fn new(scene: &Scene) -> Self {
        Self::without(scene, None)
    }

    /// Like [`SceneGeometry::new`], leaving out object `hidden` (one in the hand).
    pub fn without(scene: &Scene, hidden: Option<usize>) -> Self {
        let mut instances = Vec::with_capacity(scene.objects.len() + 4);
        for (index, o) in scene.objects.iter().enumerate() {
            if hidden == Some(index) {
                continue;
            }
            let structural = o.is_floor();
            let colours = if structural {
                [([0.62, 0.50, 0.36], WOOD), ([0.5, 0.4, 0.3], WOOD)]
            } else {
                object_colours(&o.object_type, &o.id, &o.materials)
            };
            let box_pose = Isometry3::from_parts(
                Translation3::from(o.bounds.center.coords),
                o.bounds.rotation,
            );
            let parts = if structural {
                vec![crate::shapes::Part {
                    pose: Isometry3::identity(),
                    primitive: Primitive::Cuboid(o.bounds.half_extents),
                    tone: 0,
                }]
            } else {
                parts_for(&o.object_type, o.bounds.half_extents)
            };
            let (aabb_min, aabb_max) = o.bounds.world_aabb();
            instances.push(Instance {
                id: if structural { 0 } else { index as u32 + 1 },
                object: Some(index),
                aabb_min,
                aabb_max,
                parts: parts
                    .iter()
                    .map(|p| {
                        placed(
                            &box_pose,
                            &p.pose,
                            &p.primitive,
                            colours[usize::from(p.tone.min(1))],
                        )
                    })
                    .collect(),
            });
        }
        for wall in &scene.walls {
            let (aabb_min, aabb_max) = wall.world_aabb();
            let pose = Isometry3::from_parts(Translation3::from(wall.center.coords), wall.rotation);
            instances.push(Instance {
                id: 0,
                object: None,
                aabb_min,
                aabb_max,
                parts: vec![placed(
                    &pose,
                    &Isometry3::identity(),
                    &Primitive::Cuboid(wall.half_extents),
                    ([0.82, 0.80, 0.74], PLAIN),
                )],
            });
        }
        Self {
            instances,
            generation: GENERATIONS.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        }
    }

    /// A number unique to this geometry (shared by its clones): renderers
    /// that upload the geometry re-upload only when it changes.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The nearest hit along a world ray within `max_m`: distance along the
    /// (unit) direction, instance id, colour (linear RGB) and world normal.
    pub fn cast(
        &self,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        max_m: f32,
    ) -> Option<(f32, u32, [f32; 3], Vector3<f32>)> {
        let every = self
            .instances
            .iter()
            .enumerate()
            .map(|(order, instance)| Candidate {
                order,
                near_m: 0.0,
                instance,
            });
        self.cast_among(every, origin, dir, max_m)
    }

    /// Like [`SceneGeometry::cast`], against `candidates` only (instances a
    /// renderer has found may lie under the ray), which must come in order
    /// of [`Candidate::near_m`]: once the nearest hit so far lies before the
    /// next candidate's box, no later one can beat it. The hit is the same
    /// whatever their order: the nearest, and of exactly equal distances
    /// the first instance in scene order (and its first part).
    pub(crate) fn cast_among<'a>(
        &'a self,
        candidates: impl IntoIterator<Item = Candidate<'a>>,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        max_m: f32,
    ) -> Option<(f32, u32, [f32; 3], Vector3<f32>)> {
        let mut best: Option<NearestHit> = None;
        for Candidate {
            order,
            near_m,
            instance: inst,
        } in candidates
        {
            let limit = best.map_or(max_m, |b| b.distance_m);
            if near_m > limit + NEAR_MARGIN_M {
                break;
            }
            let Some(enter) = slab(origin, dir, &inst.aabb_min, &inst.aabb_max) else {
                continue;
            };
            if enter > limit {
                continue;
            }
            for part in &inst.parts {
                let o = part.t_part_world * origin;
                let d = part.t_part_world.rotation * dir;
                let ray = Ray::new(PVec::new(o.x, o.y, o.z), PVec::new(d.x, d.y, d.z));
                let limit = best.map_or(max_m, |b| b.distance_m);
                let hit = match &part.shape {
                    Convex::Cuboid(s) => s.cast_local_ray_and_get_normal(&ray, limit, true),
                    Convex::Cylinder(s) => s.cast_local_ray_and_get_normal(&ray, limit, true),
                    Convex::Ball(s) => s.cast_local_ray_and_get_normal(&ray, limit, true),
                };
                let Some(hit) = hit else {
                    continue;
                };
                let toi = hit.time_of_impact;
                if best
                    .is_none_or(|b| toi < b.distance_m || (toi == b.distance_m && order < b.order))
                {
                    let n = Vector3::new(hit.normal.x, hit.normal.y, hit.normal.z);
                    let world_n = part.t_part_world.rotation.inverse() * n;
                    let local = o + d * toi;
                    let k = shade(part.pattern, [local.x, local.y, local.z]);
                    let colour = part.colour.map(|c| c * k);
                    best = Some(NearestHit {
                        distance_m: toi,
                        order,
                        id: inst.id,
                        colour,
                        normal: world_n,
                    });
                }
            }
        }
        best.map(|b| (b.distance_m, b.id, b.colour, b.normal))
    }
}

/// The nearest hit so far of [`SceneGeometry::cast_among`].
#[derive(Debug, Clone, Copy)]
struct NearestHit {
    /// Along the ray.
    distance_m: f32,
    /// The instance's place in scene order.
    order: usize,
    id: u32,
    colour: [f32; 3],
    /// World frame.
    normal: Vector3<f32>,
}

/// How much nearer than its box a candidate of [`SceneGeometry::cast_among`]
/// may be hit, metres: the box's distance and the ray's entry are worked
/// out differently, so they may disagree by rounding (far less than this).
const NEAR_MARGIN_M: f32 = 1e-3;

/// One instance a ray may meet, as [`SceneGeometry::cast_among`] takes it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Candidate<'a> {
    /// The instance's place in the scene's order (which wins exact ties).
    pub(crate) order: usize,
    /// No ray from the camera meets the instance's box nearer than this,
    /// metres (0 when unknown).
    pub(crate) near_m: f32,
    /// The instance.
    pub(crate) instance: &'a Instance,
}

/// The agent's collision body: a vertical capsule standing `clearance_m`
/// above the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgentBody {
    /// Capsule radius, metres.
    pub radius_m: f32,
    /// Capsule height (including the caps), metres.
    pub height_m: f32,
    /// Gap between the floor and the capsule's bottom, metres.
    pub clearance_m: f32,
}

/// What blocked a capsule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Obstacle {
    /// A scene object, by index into `Scene::objects`.
    Object(usize),
    /// A wall or the ceiling.
    Wall,
}

fn to_pose(iso: &Isometry3<f32>) -> Pose {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion();
    Pose::from_parts(
        PVec::new(t.x, t.y, t.z),
        parry3d::math::Rot3::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

impl SceneGeometry {
    /// The first obstacle (in scene order) that the agent's capsule overlaps
    /// when it stands at `(x, y)` on a floor at height `floor_z`; objects for
    /// which `ignore` is true are skipped (the floor, a held object).
    pub fn capsule_obstacle(
        &self,
        x: f32,
        y: f32,
        floor_z: f32,
        body: &AgentBody,
        ignore: &dyn Fn(usize) -> bool,
    ) -> Option<Obstacle> {
        let (radius, height, clearance_m) = (body.radius_m, body.height_m, body.clearance_m);
        let half = (height / 2.0 - radius).max(0.0);
        let capsule = Capsule::new_z(half, radius);
        let centre = Point3::new(x, y, floor_z + clearance_m + height / 2.0);
        let pose = Pose::from_translation(PVec::new(centre.x, centre.y, centre.z));
        let (lo, hi) = (
            centre - Vector3::new(radius, radius, height / 2.0),
            centre + Vector3::new(radius, radius, height / 2.0),
        );
        for inst in &self.instances {
            if inst.object.is_some_and(ignore) {
                continue;
            }
            if (0..3).any(|a| inst.aabb_max[a] < lo[a] || inst.aabb_min[a] > hi[a]) {
                continue;
            }
            for part in &inst.parts {
                let part_pose = to_pose(&part.t_part_world.inverse());
                let shape: &dyn Shape = match &part.shape {
                    Convex::Cuboid(s) => s,
                    Convex::Cylinder(s) => s,
                    Convex::Ball(s) => s,
                };
                if intersection_test(&pose, &capsule, &part_pose, shape)
                    .is_ok_and(|r| r.intersecting)
                {
                    return Some(inst.object.map_or(Obstacle::Wall, Obstacle::Object));
                }
            }
        }
        None
    }
}

/// Ray parameter where the ray enters the box, if it meets it.
fn slab(o: &Point3<f32>, d: &Vector3<f32>, lo: &Point3<f32>, hi: &Point3<f32>) -> Option<f32> {
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (ta, tb) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 <= t1).then_some(t0)
}
