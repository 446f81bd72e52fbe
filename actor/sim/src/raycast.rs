//! The CPU reference renderer: one parry ray cast per pixel against the scene
//! geometry (every object's convex parts, the walls and the floor). It gives
//! RGB, metric z-depth and instance ids, and is what the GPU renderer is
//! checked against.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::geometry::SceneGeometry;

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

/// Direction of the light used for shading (from above and a little to the side).
pub const LIGHT: Vector3<f32> = Vector3::new(0.3, 0.2, 0.93);

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
