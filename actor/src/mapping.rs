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
/// the segmentation (ground-truth segmentation) and `class` as the class of
/// every pixel ([`class_image`]).
pub fn map_frame<'a>(camera: &Camera, frame: &'a Frame, class: &'a [u16]) -> mapper::Frame<'a> {
    mapper::Frame {
        t_world_camera: camera.t_world_camera,
        intrinsics: intrinsics(camera),
        depth_m: &frame.depth_m,
        instance: &frame.ids,
        class: Some(class),
    }
}

/// The class of each instance id of a scene whose objects have the types
/// `object_types` (instance id = object index + 1; id 0, floor and walls,
/// is class 0): one class per type, numbered from 1 in the order of the
/// type names. The map keeps classes per object and looks for an object it
/// lost only among segments of its class.
pub fn instance_classes<'a>(object_types: impl Iterator<Item = &'a str> + Clone) -> Vec<u16> {
    let names: std::collections::BTreeSet<&str> = object_types.clone().collect();
    let class = |name: &str| {
        names
            .iter()
            .position(|&n| n == name)
            .map_or(0, |i| i as u16 + 1)
    };
    std::iter::once(0).chain(object_types.map(class)).collect()
}

/// The class of every pixel of a frame from its instance ids.
pub fn class_image(ids: &[u32], classes: &[u16]) -> Vec<u16> {
    ids.iter()
        .map(|&id| classes.get(id as usize).copied().unwrap_or(0))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objects_of_one_type_share_a_class() {
        let classes = instance_classes(["Sofa", "Pillow", "Sofa"].into_iter());
        assert_eq!(classes, [0, 2, 1, 2]);
        assert_eq!(class_image(&[0, 3, 2, 9], &classes), [0, 2, 1, 0]);
    }
}
