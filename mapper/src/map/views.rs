//! What the map shows: its objects rendered into a camera (for
//! association, and ids for label propagation to past frames), and an
//! object's surface as a mesh or points (recordings, tests).

use nalgebra::Point3;

use super::{Map, MapError, ObjectId};
use crate::camera::{Frame, Intrinsics};
use crate::mesh::{mesh_layer, Mesh};
use crate::render::{raycast_layer, render_layers, Pixels, PlacedLayer, RenderTarget};
use crate::Pose;

impl Map {
    /// The placed objects ([`MapObject::is_placed`](super::MapObject::is_placed))
    /// in a camera, front to back (rendered in this order, the z-buffer cuts
    /// the rays of occluded objects short).
    pub fn objects_in_camera(&self, t_world_camera: &Pose) -> Vec<PlacedLayer<'_>> {
        let t_camera_world = t_world_camera.inverse();
        let mut layers: Vec<(ObjectId, PlacedLayer<'_>)> = self
            .objects
            .values()
            .filter(|o| o.is_placed())
            .map(|o| {
                let placed = PlacedLayer {
                    layer: &o.volume,
                    t_camera_layer: t_camera_world * o.t_world_object,
                    id: o.id.0,
                };
                (o.id, placed)
            })
            .collect();
        let z = |p: &PlacedLayer<'_>| p.t_camera_layer.translation.vector.z;
        layers.sort_by(|a, b| z(&a.1).total_cmp(&z(&b.1)).then(a.0.cmp(&b.0)));
        layers.into_iter().map(|(_, placed)| placed).collect()
    }

    /// Renders every object into a camera: nearest object depth and id per
    /// pixel ([`render_layers`]: exact at silhouettes and depth edges,
    /// interpolated within a surface), only nearer than `far_m` per pixel
    /// when given.
    pub(super) fn render_objects(
        &self,
        t_world_camera: &Pose,
        k: &Intrinsics,
        far_m: Option<&[f32]>,
    ) -> RenderTarget {
        render_layers(
            &self.objects_in_camera(t_world_camera),
            k,
            self.config.settings.min_depth_m,
            self.config.settings.voxel_size_m,
            far_m,
        )
    }

    /// How far the map needs rendering into a frame, per pixel: a surface
    /// more than association's depth tolerance (and a voxel, for the ray's
    /// step) behind the measured depth is hidden by what the camera sees. It
    /// can match no segment (association counts only pixels whose depths
    /// agree), it is not where the object should be seen (no miss), and
    /// integration never touches occluded voxels. Pixels without a usable
    /// depth measurement limit nothing.
    pub(super) fn visible_depth_limits(&self, frame: &Frame<'_>) -> Vec<f32> {
        let params = self.config.integration();
        let margin = self.config.depth_tolerance_m() + self.config.settings.voxel_size_m;
        frame
            .depth_m
            .iter()
            .map(|&d| {
                if params.valid_depth(d) {
                    d + margin
                } else {
                    f32::INFINITY
                }
            })
            .collect()
    }

    /// Renders the map's object ids and depth into any camera (label
    /// propagation to past frames). The background volume occludes objects
    /// behind walls; its own pixels get id 0.
    pub fn render_ids(&self, t_world_camera: &Pose, k: &Intrinsics) -> RenderTarget {
        let mut target = self.render_objects(t_world_camera, k, None);
        let t_camera_world = t_world_camera.inverse();
        let mut background = RenderTarget::new(k);
        raycast_layer(
            &self.background,
            &t_camera_world,
            k,
            0,
            self.config.settings.min_depth_m,
            &mut background,
            Pixels::All,
        );
        for ((d, id), bd) in target
            .depth_m
            .iter_mut()
            .zip(target.ids.iter_mut())
            .zip(&background.depth_m)
        {
            if *bd + self.config.depth_tolerance_m() < *d {
                *d = *bd;
                *id = 0;
            }
        }
        target
    }

    /// An object's surface as a world-frame triangle mesh (see [`crate::mesh`]).
    pub fn object_mesh(&self, id: ObjectId) -> Result<Mesh, MapError> {
        let object = self.objects.get(&id).ok_or(MapError::UnknownObject(id))?;
        Ok(mesh_layer(&object.volume, &object.t_world_object))
    }

    /// World-frame points of an object's surface (observed voxels within half a voxel).
    pub fn object_surface_points(&self, id: ObjectId) -> Result<Vec<Point3<f32>>, MapError> {
        let object = self.objects.get(&id).ok_or(MapError::UnknownObject(id))?;
        let band = self.config.settings.voxel_size_m * 0.5;
        Ok(object
            .volume
            .near_surface_voxels(band)
            .into_iter()
            .map(|(p, _)| object.t_world_object * p)
            .collect())
    }
}
