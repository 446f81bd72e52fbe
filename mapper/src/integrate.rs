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
//!
//! The two hot loops, the search for blocks near the surface points and the
//! update of a block's voxels, run eight lanes at a time with AVX2 where the
//! processor has it (decided at run time, so one binary runs on any x86-64),
//! with the same results to the bit as their scalar forms.

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;

use crate::camera::Intrinsics;
use crate::layer::{BlockIndex, Layer, Voxel, VoxelIndex, BLOCK_EDGE, BLOCK_VOXELS};
use crate::Pose;

mod frame;
#[cfg(target_arch = "x86_64")]
mod row_avx2;
mod search;
#[cfg(target_arch = "x86_64")]
mod search_avx2;
mod search_points;

pub use frame::FramePixels;
use frame::{MAY_CARVE, MAY_CARVE_NEAR};

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
    // One map lookup per run of equal labels, not per pixel.
    let mut start = 0;
    for run in labels.chunk_by(|a, b| a == b) {
        let end = start + run.len();
        groups
            .entry(run[0])
            .or_default()
            .extend(start as u32..end as u32);
        start = end;
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
    let simd = Simd::for_frame(owned, view.pixels, view.k);
    integrate_with(simd, layer, view, owned, params, carve)
}

/// [`integrate`] with the loops over points and voxels in `simd`.
fn integrate_with(
    simd: Simd,
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
    let mut blocks = search::blocks_near_points(simd, layer, t_layer_camera, pixels, owned, params);
    if carve {
        blocks.extend(blocks_in_view(layer, &t_camera_layer, k));
    }
    let mut blocks: Vec<BlockIndex> = blocks.into_iter().collect();
    blocks.sort_unstable();
    let mut updated = 0;
    let voxel = layer.voxel_size_m;
    // Camera-frame steps between neighbouring voxels: positions are walked
    // incrementally instead of transforming every voxel centre.
    let steps = [0, 1, 2].map(|a| {
        let mut e = Vector3::zeros();
        e[a] = voxel;
        t_camera_layer.rotation * e
    });
    for b in blocks {
        let origin = t_camera_layer * layer.voxel_center(VoxelIndex::join(b, 0));
        let exists = layer.block(b).is_some();
        let inputs = RowInputs {
            k,
            pixels,
            owned,
            params,
            carve: carve && exists,
        };
        // Updated in place, which tells the block its cached surface is
        // stale; a block allocated here and never updated is freed again.
        let block_updates = layer.update_block(b, |voxels| {
            simd.update_block(voxels, &origin.coords, &steps, &inputs)
        });
        if !exists && block_updates == 0 {
            layer.remove_block(b);
        }
        updated += block_updates;
    }
    updated
}

/// What every voxel row of one block reads.
struct RowInputs<'a> {
    k: &'a Intrinsics,
    pixels: &'a FramePixels,
    owned: Owned<'a>,
    params: &'a IntegrationParams,
    /// Voxels on other surfaces' pixels may be carved: carving is on and
    /// the block existed before this frame.
    carve: bool,
}

/// How integration's hot loops run: eight voxels of a block row (and eight
/// surface points in the block search) at a time where the processor has
/// AVX2 ([`row_avx2`], [`search_avx2`]), else one at a time. Both give the
/// same blocks and voxels to the bit (tested).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Simd {
    /// One at a time.
    Scalar,
    /// AVX2; made only where it is safe to use.
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Simd {
    /// The fastest loops this processor runs for `pixels`, a frame from
    /// camera `k` whose pixels `owned` labels. The vector loops read
    /// without bounds checks, so they run only where the frame was prepared
    /// for `k` and the labels cover it (elsewhere the scalar loops' checks
    /// catch the mismatch).
    fn for_frame(owned: Owned<'_>, pixels: &FramePixels, k: &Intrinsics) -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2")
            && pixels.prepared_for(k)
            && owned.labels.len() == k.pixels()
        {
            return Self::Avx2;
        }
        let _ = (owned, pixels, k);
        Self::Scalar
    }

    /// Updates the voxels of one block, whose first voxel's centre is at
    /// camera-frame point `origin` and whose neighbouring voxels lie
    /// `steps[axis]` apart; returns how many changed.
    #[inline]
    fn update_block(
        self,
        voxels: &mut [Voxel; BLOCK_VOXELS],
        origin: &Vector3<f32>,
        steps: &[Vector3<f32>; 3],
        inputs: &RowInputs<'_>,
    ) -> usize {
        match self {
            Self::Scalar => {
                let edge = BLOCK_EDGE as usize;
                let mut updates = 0;
                for (r, row_voxels) in voxels.chunks_exact_mut(edge).enumerate() {
                    updates +=
                        update_row(row_voxels, &row_start(origin, steps, r), &steps[0], inputs);
                }
                updates
            }
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `for_frame` made this kernel only where the
            // processor has AVX2, the frame was prepared for this camera and
            // the labels cover its pixels.
            Self::Avx2 => unsafe { row_avx2::update_block(voxels, origin, steps, inputs) },
        }
    }
}

/// Camera-frame centre of the first voxel of row `r` (voxels are stored x
/// fastest, so row `r` is `y = r % BLOCK_EDGE`, `z = r / BLOCK_EDGE`) of a
/// block whose first voxel is at `origin`, voxels `steps[axis]` apart.
#[inline]
fn row_start(origin: &Vector3<f32>, steps: &[Vector3<f32>; 3], r: usize) -> Vector3<f32> {
    let edge = BLOCK_EDGE as usize;
    let (yi, zi) = (r % edge, r / edge);
    origin + steps[1] * yi as f32 + steps[2] * zi as f32
}

/// One block row of `BLOCK_EDGE` voxels, the first at camera-frame point
/// `row`, the next ones `step` apart, one voxel at a time; returns how
/// many changed.
fn update_row(
    voxels: &mut [Voxel],
    row: &Vector3<f32>,
    step: &Vector3<f32>,
    inputs: &RowInputs<'_>,
) -> usize {
    let RowInputs {
        k,
        pixels,
        owned,
        params,
        carve,
    } = *inputs;
    let trunc = params.truncation_m;
    let landing = project_row(row, step, k, pixels.off_image());
    let mut updates = 0;
    for (xi, voxel) in voxels.iter_mut().enumerate() {
        let (px, u, v, z) = (landing.px[xi], landing.u[xi], landing.v[xi], landing.z[xi]);
        let pixel = pixels.records[px as usize];
        let rough = pixel.depth - z;
        // Off the image, no usable depth (NaN), or so far behind the
        // surface that even interpolation keeps it occluded.
        if rough.is_nan() || rough < -2.0 * trunc {
            continue;
        }
        if owned.contains(px as usize) {
            // The interpolated depth is within one truncation of the
            // nearest pixel's: voxels this far in front need no
            // interpolation.
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
            // Full weight in front of the surface, dropping quadratically
            // behind it (behind a surface, the ray's distance says least
            // about the voxel's: corners and edges); grazing views count
            // less.
            let w = cos
                * if sdf >= 0.0 {
                    1.0
                } else {
                    (1.0 + sdf / trunc).powi(2).max(BEHIND_WEIGHT_FLOOR)
                };
            fuse(voxel, sdf.min(trunc), w, params.max_weight);
            updates += 1;
        } else if carve && rough > params.free_space_margin_m {
            // Free beyond the band of the surface seen; within it only a
            // voxel inside its object is contradicted (a positive one may
            // lie near its own surface, beside the ray). Carving clears
            // known surface; it never creates knowledge.
            let free = (rough > trunc && pixel.has(MAY_CARVE))
                || (voxel.sdf < 0.0 && pixel.has(MAY_CARVE_NEAR));
            if voxel.weight > 0.0 && free {
                fuse(voxel, rough.min(trunc), 1.0, params.max_weight);
                updates += 1;
            }
        }
    }
    updates
}

/// The least weight of a measurement behind the surface, as a fraction of
/// one in front of it.
const BEHIND_WEIGHT_FLOOR: f32 = 0.05;

/// Folds one measurement (`sdf`, weight `w`) into a voxel's weighted mean.
#[inline]
fn fuse(voxel: &mut Voxel, sdf: f32, w: f32, max_weight: f32) {
    let total = voxel.weight + w;
    voxel.sdf = (voxel.sdf * voxel.weight + sdf * w) / total;
    voxel.weight = total.min(max_weight);
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};

    use super::*;

    const PARAMS: IntegrationParams = IntegrationParams {
        truncation_m: 0.12,
        max_weight: 50.0,
        min_depth_m: 0.1,
        max_depth_m: 8.0,
        free_space_margin_m: 0.04,
    };

    /// Depth (z) and labels of a ball of radius 0.4 m at camera-frame
    /// `centre` (label 1) in front of a wall at z = 3 m (label 2), with a
    /// band of pixels that measured nothing (label 0).
    fn ball_before_wall(k: &Intrinsics, centre: Vector3<f32>) -> (Vec<f32>, Vec<u32>) {
        let mut depth = vec![3.0; k.pixels()];
        let mut labels = vec![2; k.pixels()];
        for v in 0..k.height {
            for u in 0..k.width {
                let i = v * k.width + u;
                if (40..44).contains(&v) {
                    (depth[i], labels[i]) = (f32::NAN, 0);
                    continue;
                }
                let ray = k.ray(u as f32, v as f32);
                let (a, b) = (ray.norm_squared(), ray.dot(&centre));
                let disc = b * b - a * (centre.norm_squared() - 0.16);
                if disc >= 0.0 {
                    // Ray points are ray · t with z = t.
                    (depth[i], labels[i]) = ((b - disc.sqrt()) / a, 1);
                }
            }
        }
        (depth, labels)
    }

    /// Integrates a ball that moves and a wall seen from moving cameras
    /// with `kernel`; returns both layers' voxels in block order and the
    /// update counts.
    fn integrate_moving_ball(kernel: Simd) -> (Vec<(BlockIndex, Vec<Voxel>)>, Vec<usize>) {
        let k = Intrinsics::from_fov(128, 128, 90.0);
        let mut ball = Layer::new(0.04);
        let mut wall = Layer::new(0.08);
        let mut pixels = FramePixels::default();
        let mut counts = Vec::new();
        for step in 0..6 {
            let s = step as f32;
            // The ball moves 8 cm a frame; the camera turns and slides.
            let (depth, labels) = ball_before_wall(&k, Vector3::new(0.08 * s - 0.2, 0.1, 2.0));
            let t_layer_camera = Pose::from_parts(
                Translation3::new(0.03 * s, -0.02 * s, 0.01 * s),
                UnitQuaternion::from_euler_angles(0.01 * s, 0.03 * s, 0.02 * s),
            );
            pixels.prepare(&k, &depth, &PARAMS);
            let view = DepthView {
                t_layer_camera: &t_layer_camera,
                k: &k,
                pixels: &pixels,
            };
            let by_label = pixels_by_label(&labels);
            for (layer, id, carve) in [(&mut ball, 1, true), (&mut wall, 2, false)] {
                let owned = Owned {
                    labels: &labels,
                    id,
                    pixels: by_label.get(&id).map_or(&[], Vec::as_slice),
                };
                counts.push(integrate_with(kernel, layer, &view, owned, &PARAMS, carve));
            }
        }
        let mut voxels = Vec::new();
        for layer in [&ball, &wall] {
            let mut blocks = layer.block_indices();
            blocks.sort_unstable();
            for b in blocks {
                voxels.push((b, layer.block(b).unwrap().voxels().to_vec()));
            }
        }
        (voxels, counts)
    }

    #[test]
    fn vector_loops_find_the_same_blocks_and_voxels_as_scalar_loops() {
        let k = Intrinsics::from_fov(128, 128, 90.0);
        let (_, labels) = ball_before_wall(&k, Vector3::new(0.0, 0.1, 2.0));
        let mut pixels = FramePixels::default();
        pixels.prepare(&k, &vec![1.0; k.pixels()], &PARAMS);
        let owned = Owned {
            labels: &labels,
            id: 1,
            pixels: &[],
        };
        let fastest = Simd::for_frame(owned, &pixels, &k);
        if fastest == Simd::Scalar {
            eprintln!("this processor has no AVX2: only the scalar rows run here");
            return;
        }
        let (scalar, scalar_counts) = integrate_moving_ball(Simd::Scalar);
        let (vector, vector_counts) = integrate_moving_ball(fastest);
        assert_eq!(scalar_counts, vector_counts);
        assert!(scalar_counts.iter().all(|&c| c > 1000), "{scalar_counts:?}");
        assert_eq!(scalar.len(), vector.len());
        for ((b, s), (c, v)) in scalar.iter().zip(&vector) {
            assert_eq!(b, c);
            for (i, (s, v)) in s.iter().zip(v).enumerate() {
                assert_eq!(
                    (s.sdf.to_bits(), s.weight.to_bits()),
                    (v.sdf.to_bits(), v.weight.to_bits()),
                    "block {b:?} voxel {i}: scalar {s:?}, vector {v:?}"
                );
            }
        }
    }

    #[test]
    fn vector_loops_are_not_used_on_a_frame_prepared_for_another_camera() {
        let (k, other) = (
            Intrinsics::from_fov(128, 128, 90.0),
            Intrinsics::from_fov(64, 256, 90.0),
        );
        let labels = vec![1; k.pixels()];
        let mut pixels = FramePixels::default();
        pixels.prepare(&other, &vec![1.0; other.pixels()], &PARAMS);
        let owned = Owned {
            labels: &labels,
            id: 1,
            pixels: &[],
        };
        // Same pixel count, other width: the vector loops would read the
        // records with the wrong row length, unchecked.
        assert_eq!(Simd::for_frame(owned, &pixels, &k), Simd::Scalar);
        let short = Owned {
            labels: &labels[1..],
            ..owned
        };
        pixels.prepare(&k, &vec![1.0; k.pixels()], &PARAMS);
        assert_eq!(Simd::for_frame(short, &pixels, &k), Simd::Scalar);
    }
}
