//! Voxel-centric projective TSDF integration of one depth frame into one layer.
//!
//! Every voxel of the touched blocks is projected into the image and updated
//! from the depth of the pixel it lands on. Pixels that belong to the layer's
//! surface update it normally; pixels of *other* surfaces can only carve: a
//! voxel seen clearly in front of another surface is free space, which clears
//! ghosts of an object that moved away. Voxels behind the measured surface
//! (occluded) are never touched.

use nalgebra::Point3;
use rustc_hash::FxHashSet;

use crate::camera::Intrinsics;
use crate::layer::{BlockIndex, Layer, VoxelIndex, BLOCK_VOXELS};
use crate::Pose;

/// Settings of the integrator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntegrationParams {
    /// Truncation distance in metres.
    pub truncation_m: f32,
    /// Cap on a voxel's accumulated weight (bounds how slowly it forgets).
    pub max_weight: f32,
    /// Depths below this are ignored.
    pub min_depth_m: f32,
    /// Depths above this are ignored.
    pub max_depth_m: f32,
}

impl IntegrationParams {
    /// True if `d` is a usable depth.
    pub fn valid_depth(&self, d: f32) -> bool {
        d.is_finite() && d >= self.min_depth_m && d <= self.max_depth_m
    }
}

/// Blocks within the truncation band of the owned pixels' surface points.
fn blocks_near_points(
    layer: &Layer,
    t_layer_camera: &Pose,
    k: &Intrinsics,
    depth_m: &[f32],
    owned: &dyn Fn(usize) -> bool,
    params: &IntegrationParams,
) -> FxHashSet<BlockIndex> {
    let mut blocks = FxHashSet::default();
    let t = params.truncation_m;
    for (i, &d) in depth_m.iter().enumerate() {
        if !owned(i) || !params.valid_depth(d) {
            continue;
        }
        let (u, v) = ((i % k.width) as f32, (i / k.width) as f32);
        let p = t_layer_camera * k.back_project(u, v, d);
        let lo = layer.block_of(&Point3::new(p.x - t, p.y - t, p.z - t));
        let hi = layer.block_of(&Point3::new(p.x + t, p.y + t, p.z + t));
        for x in lo.0[0]..=hi.0[0] {
            for y in lo.0[1]..=hi.0[1] {
                for z in lo.0[2]..=hi.0[2] {
                    blocks.insert(BlockIndex([x, y, z]));
                }
            }
        }
    }
    blocks
}

/// Existing blocks whose centre lies in the view frustum (carving candidates).
fn blocks_in_view(layer: &Layer, t_camera_layer: &Pose, k: &Intrinsics) -> Vec<BlockIndex> {
    let half = layer.block_size_m() / 2.0;
    layer
        .block_indices()
        .into_iter()
        .filter(|b| {
            let s = layer.block_size_m();
            let c = Point3::new(b.0[0] as f32 * s + half, b.0[1] as f32 * s + half, b.0[2] as f32 * s + half);
            k.project(&(t_camera_layer * c)).is_some_and(|(u, v, _)| k.pixel_index(u, v).is_some())
        })
        .collect()
}

/// Integrates one frame into `layer`. `owned(pixel)` says which pixels show
/// this layer's surface; with `carve`, other pixels clear free space.
/// Returns the number of voxels updated.
pub fn integrate(
    layer: &mut Layer,
    t_layer_camera: &Pose,
    k: &Intrinsics,
    depth_m: &[f32],
    owned: &dyn Fn(usize) -> bool,
    params: &IntegrationParams,
    carve: bool,
) -> usize {
    let t_camera_layer = t_layer_camera.inverse();
    let mut blocks = blocks_near_points(layer, t_layer_camera, k, depth_m, owned, params);
    if carve {
        blocks.extend(blocks_in_view(layer, &t_camera_layer, k));
    }
    let mut blocks: Vec<BlockIndex> = blocks.into_iter().collect();
    blocks.sort_unstable();
    let trunc = params.truncation_m;
    let mut updated = 0;
    for b in blocks {
        let exists = layer.block(b).is_some();
        let mut updates = Vec::new();
        for o in 0..BLOCK_VOXELS {
            let center = layer.voxel_center(VoxelIndex::join(b, o));
            let Some((u, v, z)) = k.project(&(t_camera_layer * center)) else { continue };
            let Some(px) = k.pixel_index(u, v) else { continue };
            let d = depth_m[px];
            if !params.valid_depth(d) {
                continue;
            }
            let sdf = d - z;
            if owned(px) {
                if sdf < -trunc {
                    continue; // occluded: behind the observed surface
                }
                // Full weight in front of the surface, dropping linearly behind it.
                let w = if sdf >= 0.0 { 1.0 } else { (1.0 + sdf / trunc).max(0.05) };
                updates.push((o, sdf.min(trunc), w, false));
            } else if carve && exists && sdf > trunc {
                updates.push((o, trunc, 1.0, true));
            }
        }
        if updates.is_empty() {
            continue;
        }
        let block = layer.block_mut_or_insert(b);
        for (o, sdf, w, carving) in updates {
            let voxel = &mut block.voxels[o];
            if carving && voxel.weight == 0.0 {
                // Carving clears known surface; it never creates knowledge.
                continue;
            }
            let total = voxel.weight + w;
            voxel.sdf = (voxel.sdf * voxel.weight + sdf * w) / total;
            voxel.weight = total.min(params.max_weight);
            updated += 1;
        }
    }
    updated
}
