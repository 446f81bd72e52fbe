//! The CPU reference renderer: one parry ray cast per pixel against every
//! object's convex parts (culled by their world boxes), the walls and the
//! floor. It gives RGB, metric z-depth and instance ids, and is what the GPU
//! renderer is checked against.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d::math::Vector as PVec;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::{Ball, Cuboid, Cylinder};

use crate::scene::{OrientedBox, Scene};
use crate::shapes::{parts_for, Primitive};

/// A pinhole camera: x right, y down, z forward (the mapper's convention).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Camera pose in the world.
    pub t_world_camera: Isometry3<f32>,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Horizontal field of view, degrees.
    pub fov_deg: f32,
}

impl Camera {
    /// Focal length in pixels (square pixels).
    pub fn focal_px(&self) -> f32 {
        self.width as f32 / 2.0 / (self.fov_deg.to_radians() / 2.0).tan()
    }

    /// Camera-frame direction through pixel `(u, v)` with z = 1.
    pub fn ray(&self, u: f32, v: f32) -> Vector3<f32> {
        let f = self.focal_px();
        Vector3::new(
            (u - (self.width as f32 - 1.0) / 2.0) / f,
            (v - (self.height as f32 - 1.0) / 2.0) / f,
            1.0,
        )
    }
}

/// The camera of an agent standing at `(x, y)` with its eye `eye_height_m`
/// above `floor_z`, heading `yaw_deg` (counter-clockwise from +x) and
/// looking `horizon_deg` down (AI2-THOR's sign: positive is down).
pub fn agent_camera_pose(
    x: f32,
    y: f32,
    floor_z: f32,
    eye_height_m: f32,
    yaw_deg: f32,
    horizon_deg: f32,
) -> Isometry3<f32> {
    let (yaw, pitch) = (yaw_deg.to_radians(), horizon_deg.to_radians());
    let forward = Vector3::new(
        yaw.cos() * pitch.cos(),
        yaw.sin() * pitch.cos(),
        -pitch.sin(),
    );
    let right = Vector3::new(yaw.sin(), -yaw.cos(), 0.0);
    let down = forward.cross(&right);
    let rotation = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
        right, down, forward,
    ]));
    Isometry3::from_parts(
        Translation3::new(x, y, floor_z + eye_height_m),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

/// One rendered view.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Row-major RGB, 3 bytes per pixel.
    pub rgb: Vec<u8>,
    /// Z-depth in metres; 0 where nothing was hit.
    pub depth_m: Vec<f32>,
    /// Instance id per pixel: object index + 1, 0 for floor, walls and nothing.
    pub ids: Vec<u32>,
}

#[derive(Debug, Clone, Copy)]
enum Convex {
    Cuboid(Cuboid),
    Cylinder(Cylinder),
    Ball(Ball),
}

/// A part placed in the world with what the renderer needs.
#[derive(Debug, Clone, Copy)]
struct PlacedPart {
    t_part_world: Isometry3<f32>,
    shape: Convex,
    colour: [f32; 3],
}

/// Everything that can be hit, grouped per instance with a world box for culling.
#[derive(Debug, Clone)]
struct Instance {
    id: u32,
    aabb_min: Point3<f32>,
    aabb_max: Point3<f32>,
    parts: Vec<PlacedPart>,
}

/// A scene turned into ray-castable geometry.
#[derive(Debug, Clone)]
pub struct SceneGeometry {
    instances: Vec<Instance>,
}

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
fn object_colours(object_type: &str, id: &str, materials: &[String]) -> [[f32; 3]; 2] {
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
    [main, accent]
}

fn placed(
    box_pose: &Isometry3<f32>,
    part_pose: &Isometry3<f32>,
    primitive: &Primitive,
    colour: [f32; 3],
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
    }
}

fn world_aabb(b: &OrientedBox) -> (Point3<f32>, Point3<f32>) {
    b.corners().iter().fold(
        (
            Point3::from([f32::INFINITY; 3]),
            Point3::from([f32::NEG_INFINITY; 3]),
        ),
        |(lo, hi), c| (lo.inf(c), hi.sup(c)),
    )
}

impl SceneGeometry {
    /// Geometry of `scene`: every object's parts; the floor and walls as boxes (id 0).
    pub fn new(scene: &Scene) -> Self {
        let mut instances = Vec::with_capacity(scene.objects.len() + 4);
        for (index, o) in scene.objects.iter().enumerate() {
            let structural = o.object_type == "Floor";
            let colours = if structural {
                [[0.62, 0.50, 0.36], [0.5, 0.4, 0.3]]
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
            let (aabb_min, aabb_max) = world_aabb(&o.bounds);
            instances.push(Instance {
                id: if structural { 0 } else { index as u32 + 1 },
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
            let (aabb_min, aabb_max) = world_aabb(wall);
            let pose = Isometry3::from_parts(Translation3::from(wall.center.coords), wall.rotation);
            instances.push(Instance {
                id: 0,
                aabb_min,
                aabb_max,
                parts: vec![placed(
                    &pose,
                    &Isometry3::identity(),
                    &Primitive::Cuboid(wall.half_extents),
                    [0.82, 0.80, 0.74],
                )],
            });
        }
        Self { instances }
    }

    /// The nearest hit along a world ray within `max_m`: distance along the
    /// (unit) direction, instance id, colour and world normal.
    fn cast(
        &self,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        max_m: f32,
    ) -> Option<(f32, u32, [f32; 3], Vector3<f32>)> {
        let mut best: Option<(f32, u32, [f32; 3], Vector3<f32>)> = None;
        for inst in &self.instances {
            let limit = best.map_or(max_m, |b| b.0);
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
                let limit = best.map_or(max_m, |b| b.0);
                let hit = match &part.shape {
                    Convex::Cuboid(s) => s.cast_local_ray_and_get_normal(&ray, limit, true),
                    Convex::Cylinder(s) => s.cast_local_ray_and_get_normal(&ray, limit, true),
                    Convex::Ball(s) => s.cast_local_ray_and_get_normal(&ray, limit, true),
                };
                if let Some(hit) = hit {
                    if best.is_none_or(|b| hit.time_of_impact < b.0) {
                        let n = Vector3::new(hit.normal.x, hit.normal.y, hit.normal.z);
                        let world_n = part.t_part_world.rotation.inverse() * n;
                        best = Some((hit.time_of_impact, inst.id, part.colour, world_n));
                    }
                }
            }
        }
        best
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

/// Direction of the light used for shading (from above and a little to the side).
const LIGHT: Vector3<f32> = Vector3::new(0.3, 0.2, 0.93);

/// Renders `geometry` from `camera` by ray casting; depths beyond `max_depth_m` are 0.
pub fn render(geometry: &SceneGeometry, camera: &Camera, max_depth_m: f32) -> Frame {
    let n = camera.width * camera.height;
    let mut frame = Frame {
        width: camera.width,
        height: camera.height,
        rgb: vec![0; 3 * n],
        depth_m: vec![0.0; n],
        ids: vec![0; n],
    };
    let origin = camera.t_world_camera * Point3::origin();
    let light = LIGHT.normalize();
    for v in 0..camera.height {
        for u in 0..camera.width {
            let ray_camera = camera.ray(u as f32, v as f32);
            let z_per_metre = 1.0 / ray_camera.norm();
            let dir = camera.t_world_camera.rotation * ray_camera.normalize();
            let Some((distance, id, colour, normal)) =
                geometry.cast(&origin, &dir, max_depth_m / z_per_metre)
            else {
                continue;
            };
            let px = v * camera.width + u;
            frame.depth_m[px] = distance * z_per_metre;
            frame.ids[px] = id;
            let facing = if normal.dot(&dir) > 0.0 {
                -normal
            } else {
                normal
            };
            let shade = 0.35 + 0.65 * facing.dot(&light).max(0.0);
            for (out, c) in frame.rgb[3 * px..3 * px + 3].iter_mut().zip(colour) {
                *out = (c * shade * 255.0).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    frame
}
