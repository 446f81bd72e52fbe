//! Pinhole camera model and the frame the map integrates.
//!
//! Camera frame: x right, y down, z forward (optical axis). Depth images hold
//! **z-depth** in metres (distance along the optical axis), 0 or non-finite
//! where nothing was measured. Pixel `(u, v)` has its centre at `(u, v)` in
//! image coordinates, so a 128-pixel-wide image centred on the axis has `cx = 63.5`.

use nalgebra::{Point3, Vector3};

use crate::Pose;

/// Pixels of the frame that pixel counts in settings are given for: the
/// paper's 128 × 128 image (see [`Intrinsics::scaled_px`]).
pub const REFERENCE_PIXELS: usize = 128 * 128;

/// `px_at_reference` pixels of a [`REFERENCE_PIXELS`] frame scaled to a
/// frame of `frame_pixels` (rounded, at least 1).
pub fn scaled_px(px_at_reference: usize, frame_pixels: usize) -> usize {
    let scaled = px_at_reference as f64 * frame_pixels as f64 / REFERENCE_PIXELS as f64;
    (scaled.round() as usize).max(1)
}

/// Pinhole intrinsics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// A centred camera with the given horizontal field of view (square pixels).
    pub fn from_fov(width: usize, height: usize, horizontal_fov_deg: f32) -> Self {
        let fx = width as f32 / 2.0 / (horizontal_fov_deg.to_radians() / 2.0).tan();
        Self {
            width,
            height,
            fx,
            fy: fx,
            cx: (width as f32 - 1.0) / 2.0,
            cy: (height as f32 - 1.0) / 2.0,
        }
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// A pixel count given for a [`REFERENCE_PIXELS`] frame, scaled to this
    /// frame's area (rounded, at least 1): the same share of the view at
    /// any resolution, so that a small object is no more "noise" at 64 × 64
    /// than at 128 × 128.
    pub fn scaled_px(&self, px_at_reference: usize) -> usize {
        scaled_px(px_at_reference, self.pixels())
    }

    /// Direction through pixel `(u, v)` scaled so its z is 1: `point = ray * z_depth`.
    pub fn ray(&self, u: f32, v: f32) -> Vector3<f32> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// Camera-frame point of pixel `(u, v)` at z-depth `z`.
    pub fn back_project(&self, u: f32, v: f32, z: f32) -> Point3<f32> {
        Point3::from(self.ray(u, v) * z)
    }

    /// Pixel coordinates (continuous) and z-depth of a camera-frame point,
    /// or `None` behind the camera.
    pub fn project(&self, p: &Point3<f32>) -> Option<(f32, f32, f32)> {
        if p.z <= 1e-6 {
            return None;
        }
        Some((
            self.fx * p.x / p.z + self.cx,
            self.fy * p.y / p.z + self.cy,
            p.z,
        ))
    }

    /// Index of the pixel containing continuous coordinates `(u, v)`, if inside.
    pub fn pixel_index(&self, u: f32, v: f32) -> Option<usize> {
        let (ui, vi) = (u + 0.5, v + 0.5);
        // Written so that NaN fails too; truncation is floor for non-negative values
        // (and, unlike `floor`, needs no libm call on baseline x86-64).
        if !(ui >= 0.0 && vi >= 0.0 && ui < self.width as f32 && vi < self.height as f32) {
            return None;
        }
        Some(vi as usize * self.width + ui as usize)
    }
}

/// A posed depth frame with an instance mask: what the map integrates.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    /// Camera pose in the world.
    pub t_world_camera: Pose,
    /// Camera model.
    pub intrinsics: Intrinsics,
    /// Z-depth per pixel, metres, row-major.
    pub depth_m: &'a [f32],
    /// Instance id per pixel; 0 = background structure (floor, walls).
    pub instance: &'a [u32],
    /// Optional semantic class per pixel (kept as a histogram per object).
    pub class: Option<&'a [u16]>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_inverts_back_project() {
        let k = Intrinsics::from_fov(128, 128, 90.0);
        assert!((k.fx - 64.0).abs() < 1e-4 && (k.cx - 63.5).abs() < 1e-6);
        for (u, v, z) in [
            (0.0, 0.0, 0.5),
            (63.5, 63.5, 2.0),
            (127.0, 3.0, 7.9),
            (40.25, 99.5, 1.3),
        ] {
            let p = k.back_project(u, v, z);
            let (pu, pv, pz) = k.project(&p).unwrap();
            assert!((pu - u).abs() < 1e-4 && (pv - v).abs() < 1e-4 && (pz - z).abs() < 1e-6);
        }
        assert_eq!(k.pixel_index(127.4, 0.0), Some(127));
        assert_eq!(k.pixel_index(127.6, 0.0), None);
        assert_eq!(k.pixel_index(-0.4, 0.0), Some(0));
    }
}
