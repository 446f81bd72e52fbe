//! The CPU reference renderer: one parry ray cast per pixel against the scene
//! geometry (every object's convex parts, the walls and the floor). It gives
//! RGB, metric z-depth and instance ids, and is what the GPU renderer is
//! checked against.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::geometry::{Candidate, SceneGeometry};
use crate::scene::aabb_corners;

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

/// Side of the square image tiles that instances are binned into, pixels.
const TILE: usize = 16;
/// Nearest depth at which an instance box is projected; boxes reaching
/// closer go into every tile.
const NEAR_M: f32 = 0.01;

/// For each tile (row-major, `TILE` pixels square) the instances whose
/// world box projects onto it, nearest box first: a ray then meets the
/// surface it shows early, and stops once the boxes left lie beyond it
/// (the walls, last in scene order, were tried by every ray before).
fn bin_instances<'a>(
    geometry: &'a SceneGeometry,
    camera: &Camera,
    max_depth_m: f32,
) -> (usize, Vec<Vec<Candidate<'a>>>) {
    let (tiles_x, tiles_y) = (camera.width.div_ceil(TILE), camera.height.div_ceil(TILE));
    let mut tiles = vec![Vec::new(); tiles_x * tiles_y];
    let t_camera_world = camera.t_world_camera.inverse();
    let f = camera.focal_px();
    let (cu, cv) = (
        (camera.width as f32 - 1.0) / 2.0,
        (camera.height as f32 - 1.0) / 2.0,
    );
    let origin = camera.t_world_camera * Point3::origin();
    for (order, instance) in geometry.instances.iter().enumerate() {
        let (lo, hi) = instance.world_box();
        let corners = aabb_corners(&lo, &hi).map(|c| t_camera_world * c);
        if corners.iter().all(|p| p.z < NEAR_M) || corners.iter().all(|p| p.z > max_depth_m) {
            continue;
        }
        let (mut u0, mut v0, mut u1, mut v1) =
            (0.0f32, 0.0f32, camera.width as f32, camera.height as f32);
        if corners.iter().all(|p| p.z >= NEAR_M) {
            let us = corners.iter().map(|p| f * p.x / p.z + cu);
            let vs = corners.iter().map(|p| f * p.y / p.z + cv);
            u0 = us.clone().fold(f32::INFINITY, f32::min) - 1.0;
            u1 = us.fold(f32::NEG_INFINITY, f32::max) + 1.0;
            v0 = vs.clone().fold(f32::INFINITY, f32::min) - 1.0;
            v1 = vs.fold(f32::NEG_INFINITY, f32::max) + 1.0;
        }
        let tile_range = |a: f32, b: f32, tiles: usize| {
            let first = (a.max(0.0) as usize / TILE).min(tiles);
            let last = ((b.max(0.0) as usize) / TILE).min(tiles - 1);
            first..=last
        };
        if u1 < 0.0 || v1 < 0.0 || u0 >= camera.width as f32 || v0 >= camera.height as f32 {
            continue;
        }
        // The box's point nearest the camera.
        let nearest =
            Point3::from(
                (origin.coords).zip_zip_map(&lo.coords, &hi.coords, |o, l, h| o.max(l).min(h)),
            );
        let candidate = Candidate {
            order,
            near_m: (nearest - origin).norm(),
            instance,
        };
        for ty in tile_range(v0, v1, tiles_y) {
            for tx in tile_range(u0, u1, tiles_x) {
                tiles[ty * tiles_x + tx].push(candidate);
            }
        }
    }
    for tile in &mut tiles {
        tile.sort_by(|a, b| a.near_m.total_cmp(&b.near_m).then(a.order.cmp(&b.order)));
    }
    (tiles_x, tiles)
}

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
    let (tiles_x, tiles) = bin_instances(geometry, camera, max_depth_m);
    for v in 0..camera.height {
        for u in 0..camera.width {
            let ray_camera = camera.ray(u as f32, v as f32);
            let z_per_metre = 1.0 / ray_camera.norm();
            let dir = camera.t_world_camera.rotation * ray_camera.normalize();
            let candidates = tiles[(v / TILE) * tiles_x + u / TILE].iter().copied();
            let Some((distance, id, colour, normal)) =
                geometry.cast_among(candidates, &origin, &dir, max_depth_m / z_per_metre)
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
