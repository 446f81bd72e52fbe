//! Analytic scenes for the map's tests: spheres and oriented boxes, ray-cast
//! exactly into depth and instance images. World z is up.

#![allow(dead_code)]

use mapper::{Frame, Intrinsics, Pose};
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

/// A primitive with an instance id.
#[derive(Debug, Clone, Copy)]
pub enum Shape {
    /// Sphere.
    Sphere {
        center: Point3<f32>,
        radius: f32,
        id: u32,
    },
    /// Box with half extents, placed by `t_world_box`.
    Box {
        t_world_box: Pose,
        half: Vector3<f32>,
        id: u32,
    },
}

impl Shape {
    pub fn id(&self) -> u32 {
        match self {
            Shape::Sphere { id, .. } | Shape::Box { id, .. } => *id,
        }
    }

    /// Ray parameter of the first hit of `o + t·d` (t > 0).
    fn hit(&self, o: &Point3<f32>, d: &Vector3<f32>) -> Option<f32> {
        match self {
            Shape::Sphere { center, radius, .. } => {
                let oc = o - center;
                let (a, b, c) = (d.dot(d), 2.0 * oc.dot(d), oc.dot(&oc) - radius * radius);
                let disc = b * b - 4.0 * a * c;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / (2.0 * a);
                (t > 0.0).then_some(t)
            }
            Shape::Box {
                t_world_box, half, ..
            } => {
                let inv = t_world_box.inverse();
                let (ol, dl) = (inv * o, inv.rotation * d);
                let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
                for a in 0..3 {
                    if dl[a].abs() < 1e-12 {
                        if ol[a].abs() > half[a] {
                            return None;
                        }
                        continue;
                    }
                    let (ta, tb) = ((-half[a] - ol[a]) / dl[a], (half[a] - ol[a]) / dl[a]);
                    t0 = t0.max(ta.min(tb));
                    t1 = t1.min(ta.max(tb));
                }
                (t0 <= t1 && t0 > 0.0).then_some(t0)
            }
        }
    }

    /// Euclidean distance from `p` to the surface (positive outside).
    pub fn signed_distance(&self, p: &Point3<f32>) -> f32 {
        match self {
            Shape::Sphere { center, radius, .. } => (p - center).norm() - radius,
            Shape::Box {
                t_world_box, half, ..
            } => {
                let q = t_world_box.inverse() * p;
                let d = Vector3::new(q.x.abs() - half.x, q.y.abs() - half.y, q.z.abs() - half.z);
                let outside = Vector3::new(d.x.max(0.0), d.y.max(0.0), d.z.max(0.0)).norm();
                outside + d.x.max(d.y).max(d.z).min(0.0)
            }
        }
    }
}

/// Depth (z) and instance images of `shapes` seen from `t_world_camera`.
pub fn render(shapes: &[Shape], t_world_camera: &Pose, k: &Intrinsics) -> (Vec<f32>, Vec<u32>) {
    let mut depth = vec![0.0; k.pixels()];
    let mut ids = vec![0; k.pixels()];
    let o = t_world_camera * Point3::origin();
    for v in 0..k.height {
        for u in 0..k.width {
            let ray_cam = k.ray(u as f32, v as f32);
            let d = t_world_camera.rotation * ray_cam;
            let mut best = f32::INFINITY;
            for s in shapes {
                if let Some(t) = s.hit(&o, &d) {
                    if t < best {
                        best = t;
                        ids[v * k.width + u] = s.id();
                    }
                }
            }
            if best.is_finite() {
                depth[v * k.width + u] = best; // ray z-component is 1: t is z-depth
            }
        }
    }
    (depth, ids)
}

/// A camera at `eye` looking at `target`, world z up (camera y down).
pub fn look_at(eye: Point3<f32>, target: Point3<f32>) -> Pose {
    let forward = (target - eye).normalize();
    let mut right = forward.cross(&Vector3::z());
    if right.norm() < 1e-6 {
        right = Vector3::x();
    }
    let right = right.normalize();
    let down = forward.cross(&right);
    let rot = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
        right, down, forward,
    ]));
    Pose::from_parts(
        Translation3::from(eye.coords),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// `n` cameras on a circle of `radius` around `target` at `height`.
pub fn orbit(target: Point3<f32>, radius: f32, height: f32, n: usize) -> Vec<Pose> {
    (0..n)
        .map(|i| {
            let a = i as f32 / n as f32 * std::f32::consts::TAU;
            look_at(
                Point3::new(
                    target.x + radius * a.cos(),
                    target.y + radius * a.sin(),
                    height,
                ),
                target,
            )
        })
        .collect()
}

/// Owns the images of a frame.
pub struct OwnedFrame {
    pub pose: Pose,
    pub k: Intrinsics,
    pub depth: Vec<f32>,
    pub ids: Vec<u32>,
}

impl OwnedFrame {
    pub fn capture(shapes: &[Shape], pose: Pose, k: Intrinsics) -> Self {
        let (depth, ids) = render(shapes, &pose, &k);
        Self {
            pose,
            k,
            depth,
            ids,
        }
    }
    pub fn frame(&self) -> Frame<'_> {
        Frame {
            t_world_camera: self.pose,
            intrinsics: self.k,
            depth_m: &self.depth,
            instance: &self.ids,
            class: None,
        }
    }
}

pub fn k128() -> Intrinsics {
    Intrinsics::from_fov(128, 128, 90.0)
}

/// How far a render strays from a reference render of the same camera:
/// pixels showing another id, and the depth differences where both show
/// the same object.
#[derive(Debug, Default)]
pub struct RenderAgreement {
    /// Pixels compared.
    pub compared: usize,
    /// Pixels whose ids differ.
    pub other_id: usize,
    /// Absolute depth differences (metres) on pixels where both show one object.
    pub depth_errors: Vec<f32>,
}

impl RenderAgreement {
    /// Adds one pair of renders.
    pub fn add(
        &mut self,
        render: &mapper::render::RenderTarget,
        reference: &mapper::render::RenderTarget,
    ) {
        for (px, (&id, &reference_id)) in render.ids.iter().zip(&reference.ids).enumerate() {
            self.compared += 1;
            if id != reference_id {
                self.other_id += 1;
            } else if reference_id != 0 {
                self.depth_errors
                    .push((render.depth_m[px] - reference.depth_m[px]).abs());
            }
        }
    }

    /// The 99th percentile and the largest of the depth errors.
    pub fn depth_p99_and_max(&mut self) -> (f32, f32) {
        self.depth_errors.sort_by(f32::total_cmp);
        let p99 = self.depth_errors[self.depth_errors.len() * 99 / 100];
        (p99, self.depth_errors.last().copied().unwrap_or(0.0))
    }
}
