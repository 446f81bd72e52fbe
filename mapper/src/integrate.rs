//! Voxel-centric projective TSDF integration of one depth frame into one layer.
//!
//! Every voxel of the touched blocks is projected into the image and updated
//! from the depth of the pixel it lands on. Pixels that belong to the layer's
//! surface update it normally; pixels of *other* surfaces can only carve: a
//! voxel seen clearly in front of another surface is free space, which clears
//! ghosts of an object that moved away. Voxels behind the measured surface
//! (occluded) are never touched.
//!
//! Carving goes further than TSDF++'s "free beyond the truncation band":
//! within the band of the surface seen, a voxel that claims to be inside its
//! object (negative distance) while the pixel sees past its centre is
//! contradicted too. Without this, a ghost less than a truncation distance in
//! front of another surface (the rim of a shelf's opening smeared over it by
//! grazing views, a panel that is gone) is never cleared, hides what is
//! behind it from association, and every frame makes a new object of it.

use nalgebra::{Point3, Vector3};
use rustc_hash::{FxHashMap, FxHashSet};

use crate::camera::Intrinsics;
use crate::layer::{BlockIndex, Layer, Voxel, VoxelIndex, BLOCK_EDGE};
use crate::Pose;

mod frame;

pub use frame::FramePixels;

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
    /// How far in front of the surface a pixel sees a voxel's centre must be
    /// for that pixel to contradict the voxel claiming to be inside its
    /// object (pixel footprint and depth noise); see [`integrate`].
    pub free_space_margin_m: f32,
}

impl IntegrationParams {
    /// True if `d` is a usable depth.
    pub fn valid_depth(&self, d: f32) -> bool {
        d.is_finite() && d >= self.min_depth_m && d <= self.max_depth_m
    }
}

/// Blocks within the truncation band of the owned pixels' surface points:
/// each point's block, plus the neighbour across every face it is closer to
/// than the truncation distance.
fn blocks_near_points(
    layer: &Layer,
    t_layer_camera: &Pose,
    pixels: &FramePixels,
    owned: Owned<'_>,
    params: &IntegrationParams,
) -> FxHashSet<BlockIndex> {
    let t = params.truncation_m;
    let size = layer.block_size_m();
    // Per block holding points, which of its 27 neighbours (itself included)
    // are needed, as bits: one map update per change of block or band
    // instead of one set insertion per needed block.
    let mut needed: FxHashMap<[i32; 3], u32> = FxHashMap::default();
    let mut previous: Option<([i32; 3], [i32; 3], [i32; 3])> = None;
    // A matrix rotates a point in half the operations of a quaternion.
    let rotation = t_layer_camera.rotation.to_rotation_matrix();
    let translation = t_layer_camera.translation.vector;
    for &i in owned.pixels {
        let Some(point) = pixels.points[i as usize] else {
            continue;
        };
        let p = rotation * point + translation;
        let mut block = [0i32; 3];
        let mut below = [0i32; 3];
        let mut above = [0i32; 3];
        for a in 0..3 {
            block[a] = crate::layer::floor_to_i32(p[a] / size);
            let within = p[a] - block[a] as f32 * size;
            below[a] = i32::from(within < t);
            above[a] = i32::from(within > size - t);
        }
        if previous == Some((block, below, above)) {
            continue;
        }
        previous = Some((block, below, above));
        let mut bits = 0u32;
        for x in -below[0]..=above[0] {
            for y in -below[1]..=above[1] {
                for z in -below[2]..=above[2] {
                    bits |= 1 << neighbour_bit([x, y, z]);
                }
            }
        }
        *needed.entry(block).or_default() |= bits;
    }
    let mut blocks = FxHashSet::default();
    for (block, bits) in needed {
        for x in -1..=1 {
            for y in -1..=1 {
                for z in -1..=1 {
                    if bits & (1 << neighbour_bit([x, y, z])) != 0 {
                        blocks.insert(BlockIndex([block[0] + x, block[1] + y, block[2] + z]));
                    }
                }
            }
        }
    }
    blocks
}

/// The bit of a neighbour at offset `[-1..=1; 3]` in [`blocks_near_points`]'
/// masks.
#[inline]
fn neighbour_bit(offset: [i32; 3]) -> u32 {
    ((offset[0] + 1) * 9 + (offset[1] + 1) * 3 + offset[2] + 1) as u32
}

/// Existing blocks whose centre lies in the view frustum (carving candidates).
fn blocks_in_view(layer: &Layer, t_camera_layer: &Pose, k: &Intrinsics) -> Vec<BlockIndex> {
    let s = layer.block_size_m();
    let half = s / 2.0;
    layer
        .block_indices()
        .into_iter()
        .filter(|b| {
            let c = Point3::new(
                b.0[0] as f32 * s + half,
                b.0[1] as f32 * s + half,
                b.0[2] as f32 * s + half,
            );
            k.project(&(t_camera_layer * c))
                .is_some_and(|(u, v, _)| k.pixel_index(u, v).is_some())
        })
        .collect()
}

/// Where the `BLOCK_EDGE` voxels of one block row land, lane by lane: pixel
/// index (`off_image` if none), continuous pixel coordinates and z-depth.
struct RowLanding {
    px: [u32; BLOCK_EDGE as usize],
    u: [f32; BLOCK_EDGE as usize],
    v: [f32; BLOCK_EDGE as usize],
    z: [f32; BLOCK_EDGE as usize],
}

/// Projects one block row, starting at camera-frame point `row` and
/// stepping by `step`. A pass of its own, without early exits and over
/// plain arrays, so the compiler vectorises it; same arithmetic as
/// [`Intrinsics::project`] and [`Intrinsics::pixel_index`].
#[inline]
fn project_row(
    row: &Vector3<f32>,
    step: &Vector3<f32>,
    k: &Intrinsics,
    off_image: u32,
) -> RowLanding {
    let (width, height) = (k.width as f32, k.height as f32);
    let mut out = RowLanding {
        px: [0; BLOCK_EDGE as usize],
        u: [0.0; BLOCK_EDGE as usize],
        v: [0.0; BLOCK_EDGE as usize],
        z: [0.0; BLOCK_EDGE as usize],
    };
    for xi in 0..BLOCK_EDGE as usize {
        let t = xi as f32;
        let (x, y, z) = (row.x + step.x * t, row.y + step.y * t, row.z + step.z * t);
        let inv_z = 1.0 / z;
        let (u, v) = (k.fx * x * inv_z + k.cx, k.fy * y * inv_z + k.cy);
        let (ui, vi) = (u + 0.5, v + 0.5);
        let inside = (z > 1e-6) & (ui >= 0.0) & (vi >= 0.0) & (ui < width) & (vi < height);
        // In range wherever it is used; `as i32` converts four lanes at once.
        let px = (vi as i32) * k.width as i32 + ui as i32;
        out.px[xi] = if inside { px as u32 } else { off_image };
        out.u[xi] = u;
        out.v[xi] = v;
        out.z[xi] = z;
    }
    out
}

/// One depth image as seen from a layer's frame.
#[derive(Debug, Clone, Copy)]
pub struct DepthView<'a> {
    /// Camera pose in the layer's frame.
    pub t_layer_camera: &'a Pose,
    /// Camera model.
    pub k: &'a Intrinsics,
    /// The frame's pixels, prepared once for all layers.
    pub pixels: &'a FramePixels,
}

/// The pixels that show one layer's surface: those labelled `id`.
#[derive(Debug, Clone, Copy)]
pub struct Owned<'a> {
    /// A label per pixel (map object ids, or instance ids with 0 = background).
    pub labels: &'a [u32],
    /// The layer's label.
    pub id: u32,
    /// The indices of the pixels labelled `id` (from [`pixels_by_label`]), so
    /// each layer visits its own pixels rather than the whole image.
    pub pixels: &'a [u32],
}

/// Pixel indices grouped by label, each group ascending: one pass over the
/// image serves every layer's [`Owned::pixels`].
pub fn pixels_by_label(labels: &[u32]) -> FxHashMap<u32, Vec<u32>> {
    let mut groups: FxHashMap<u32, Vec<u32>> = FxHashMap::default();
    for (i, &label) in labels.iter().enumerate() {
        groups.entry(label).or_default().push(i as u32);
    }
    groups
}

impl Owned<'_> {
    /// True if pixel `px` shows the layer's surface.
    #[inline]
    pub fn contains(&self, px: usize) -> bool {
        self.labels[px] == self.id
    }
}

/// Integrates one frame into `layer`. `owned` says which pixels show
/// this layer's surface; with `carve`, other pixels clear free space.
/// Returns the number of voxels updated.
pub fn integrate(
    layer: &mut Layer,
    view: &DepthView<'_>,
    owned: Owned<'_>,
    params: &IntegrationParams,
    carve: bool,
) -> usize {
    let DepthView {
        t_layer_camera,
        k,
        pixels,
    } = *view;
    let t_camera_layer = t_layer_camera.inverse();
    let mut blocks = blocks_near_points(layer, t_layer_camera, pixels, owned, params);
    if carve {
        blocks.extend(blocks_in_view(layer, &t_camera_layer, k));
    }
    let mut blocks: Vec<BlockIndex> = blocks.into_iter().collect();
    blocks.sort_unstable();
    let trunc = params.truncation_m;
    let mut updated = 0;
    let voxel = layer.voxel_size_m;
    let edge = BLOCK_EDGE as usize;
    // Camera-frame steps between neighbouring voxels: positions are walked
    // incrementally instead of transforming every voxel centre.
    let steps = [0, 1, 2].map(|a| {
        let mut e = Vector3::zeros();
        e[a] = voxel;
        t_camera_layer.rotation * e
    });
    let off_image = pixels.off_image();
    for b in blocks {
        let origin = t_camera_layer * layer.voxel_center(VoxelIndex::join(b, 0));
        let exists = layer.block(b).is_some();
        // Updated in place, which tells the block its cached surface is
        // stale; a block allocated here and never updated is freed again.
        let block_updates = layer.block_mut_or_insert(b).update(|voxels| {
            let mut block_updates = 0;
            for zi in 0..edge {
                for yi in 0..edge {
                    let row = origin.coords + steps[1] * yi as f32 + steps[2] * zi as f32;
                    let landing = project_row(&row, &steps[0], k, off_image);
                    for xi in 0..edge {
                        let (px, u, v, z) =
                            (landing.px[xi], landing.u[xi], landing.v[xi], landing.z[xi]);
                        let pixel = pixels.records[px as usize];
                        let rough = pixel.depth - z;
                        // Off the image, no usable depth (NaN), or so far behind
                        // the surface that even interpolation keeps it occluded.
                        if rough.is_nan() || rough < -2.0 * trunc {
                            continue;
                        }
                        let o = xi + edge * (yi + edge * zi);
                        if owned.contains(px as usize) {
                            // The interpolated depth is within one truncation of
                            // the nearest pixel's: voxels this far in front need
                            // no interpolation.
                            let d = if rough < 2.0 * trunc {
                                pixels.depth_at(u, v, pixel.depth)
                            } else {
                                pixel.depth
                            };
                            let projective = d - z;
                            if projective < -trunc {
                                continue; // occluded: behind the observed surface
                            }
                            let cos = pixel.cos;
                            let sdf = projective * cos;
                            // Full weight in front of the surface, dropping
                            // quadratically behind it (behind a surface, the ray's
                            // distance says least about the voxel's: corners and
                            // edges); grazing views count less.
                            let w = cos
                                * if sdf >= 0.0 {
                                    1.0
                                } else {
                                    (1.0 + sdf / trunc).powi(2).max(0.05)
                                };
                            fuse(&mut voxels[o], sdf.min(trunc), w, params.max_weight);
                            block_updates += 1;
                        } else if carve && exists && rough > params.free_space_margin_m {
                            let voxel = &mut voxels[o];
                            // Free beyond the band of the surface seen; within
                            // it only a voxel inside its object is contradicted
                            // (a positive one may lie near its own surface,
                            // beside the ray). Carving clears known surface; it
                            // never creates knowledge.
                            let free = (rough > trunc && pixel.may_carve)
                                || (voxel.sdf < 0.0 && pixel.may_carve_near);
                            if voxel.weight > 0.0 && free {
                                fuse(voxel, rough.min(trunc), 1.0, params.max_weight);
                                block_updates += 1;
                            }
                        }
                    }
                }
            }
            block_updates
        });
        if !exists && block_updates == 0 {
            layer.remove_block(b);
        }
        updated += block_updates;
    }
    updated
}

/// Folds one measurement (`sdf`, weight `w`) into a voxel's weighted mean.
#[inline]
fn fuse(voxel: &mut Voxel, sdf: f32, w: f32, max_weight: f32) {
    let total = voxel.weight + w;
    voxel.sdf = (voxel.sdf * voxel.weight + sdf * w) / total;
    voxel.weight = total.min(max_weight);
}
