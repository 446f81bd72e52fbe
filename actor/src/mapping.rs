//! The seam between the simulator and the map: a rendered view as the
//! frame the map integrates (same camera convention: x right, y down,
//! z forward; z-depth; instance ids with 0 for floor and walls).

use mapper::Intrinsics;
use sim::raycast::{Camera, Frame};

/// The pinhole intrinsics of a simulator camera.
pub fn intrinsics(camera: &Camera) -> Intrinsics {
    Intrinsics::from_fov(camera.width, camera.height, camera.fov_deg)
}

/// A simulator view as a map frame, with the simulator's instance ids as
/// the segmentation (ground-truth segmentation).
pub fn map_frame<'a>(camera: &Camera, frame: &'a Frame) -> mapper::Frame<'a> {
    mapper::Frame {
        t_world_camera: camera.t_world_camera,
        intrinsics: intrinsics(camera),
        depth_m: &frame.depth_m,
        instance: &frame.ids,
        class: None,
    }
}
