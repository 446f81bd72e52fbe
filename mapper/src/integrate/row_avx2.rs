//! One block row of integration, eight voxels at a time with AVX2: a row of
//! `BLOCK_EDGE` = 8 voxels is one vector.
//!
//! The same arithmetic as the scalar [`super::update_row`], operation for
//! operation and without fused multiply-adds, so both give the same voxels
//! to the bit (tested in `super::tests`). Lanes the scalar code skips are
//! computed too and then discarded by masks; a row none of whose voxels
//! sees usable depth in front of it stops after its first gather.

use std::arch::x86_64::*;

use nalgebra::Vector3;

use super::frame::{MAY_CARVE, MAY_CARVE_NEAR, SMOOTH_QUAD};
use super::{row_start, RowInputs, BEHIND_WEIGHT_FLOOR};
use crate::camera::Intrinsics;
use crate::layer::{Voxel, BLOCK_EDGE, BLOCK_VOXELS};

const _: () = assert!(BLOCK_EDGE == 8, "a block row must fill one AVX2 vector");

/// [`super::Simd::update_block`] with AVX2, a row at a time.
///
/// # Safety
/// The processor must support AVX2, `inputs.pixels` must have been prepared
/// for camera `inputs.k`, and `inputs.owned.labels` must hold one label per
/// pixel ([`super::Simd::for_frame`] checks all three).
#[target_feature(enable = "avx2")]
pub(super) unsafe fn update_block(
    voxels: &mut [Voxel; BLOCK_VOXELS],
    origin: &Vector3<f32>,
    steps: &[Vector3<f32>; 3],
    inputs: &RowInputs<'_>,
) -> usize {
    let edge = BLOCK_EDGE as usize;
    let mut updates = 0;
    for (r, row_voxels) in voxels.chunks_exact_mut(edge).enumerate() {
        updates += update_row(row_voxels, &row_start(origin, steps, r), &steps[0], inputs);
    }
    updates
}

/// One block row of `BLOCK_EDGE` voxels, the first at camera-frame point
/// `row`, the next ones `step` apart: the scalar [`super::update_row`]
/// eight lanes wide.
///
/// # Safety
/// As [`update_block`]; `voxels` must hold `BLOCK_EDGE` voxels.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn update_row(
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
    let Landing { px, u, v, z } = project(row, step, k, pixels.off_image());
    // Each record is three 32-bit words: depth, cosine, flags.
    let words = pixels.records.as_ptr() as *const f32;
    let flag_words = pixels.records.as_ptr() as *const i32;
    let record = _mm256_add_epi32(_mm256_add_epi32(px, px), px);
    let depth = _mm256_i32gather_ps::<4>(words, record);
    let rough = _mm256_sub_ps(depth, z);
    // Not NaN (off the image, no usable depth) and not far behind.
    let usable = _mm256_cmp_ps::<_CMP_GE_OQ>(rough, _mm256_set1_ps(-2.0 * trunc));
    if _mm256_movemask_ps(usable) == 0 {
        return 0;
    }
    let zero = _mm256_setzero_si256();
    let labels = _mm256_mask_i32gather_epi32::<4>(
        zero,
        owned.labels.as_ptr() as *const i32,
        px,
        _mm256_castps_si256(usable),
    );
    let is_owned = _mm256_and_ps(
        usable,
        _mm256_castsi256_ps(_mm256_cmpeq_epi32(
            labels,
            _mm256_set1_epi32(owned.id as i32),
        )),
    );
    let one = _mm256_set1_ps(1.0);
    let truncs = _mm256_set1_ps(trunc);

    // The layer's own surface: fuse the projective distance.
    let cos = _mm256_mask_i32gather_ps::<4>(
        one,
        words,
        _mm256_add_epi32(record, _mm256_set1_epi32(1)),
        is_owned,
    );
    let near = _mm256_and_ps(
        _mm256_and_ps(
            is_owned,
            _mm256_cmp_ps::<_CMP_LT_OQ>(rough, _mm256_set1_ps(2.0 * trunc)),
        ),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(u, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_GE_OQ>(v, _mm256_setzero_ps()),
        ),
    );
    let d = if _mm256_movemask_ps(near) == 0 {
        depth
    } else {
        interpolated_depth(words, flag_words, depth, u, v, near, k.width as i32)
    };
    let projective = _mm256_sub_ps(d, z);
    let fuse_owned = _mm256_and_ps(
        is_owned,
        _mm256_cmp_ps::<_CMP_NLT_UQ>(projective, _mm256_set1_ps(-trunc)),
    );
    let sdf = _mm256_mul_ps(projective, cos);
    let behind = _mm256_add_ps(one, _mm256_div_ps(sdf, truncs));
    let behind = _mm256_max_ps(
        _mm256_mul_ps(behind, behind),
        _mm256_set1_ps(BEHIND_WEIGHT_FLOOR),
    );
    let in_front = _mm256_cmp_ps::<_CMP_GE_OQ>(sdf, _mm256_setzero_ps());
    let owned_weight = _mm256_mul_ps(cos, _mm256_blendv_ps(behind, one, in_front));
    let owned_sdf = _mm256_min_ps(sdf, truncs);

    // The voxels, split into their distances and weights.
    let voxel_words = voxels.as_mut_ptr() as *mut f32;
    let low = _mm256_loadu_ps(voxel_words);
    let high = _mm256_loadu_ps(voxel_words.add(8));
    let old_sdf = in_row_order(_mm256_shuffle_ps::<0x88>(low, high));
    let old_weight = in_row_order(_mm256_shuffle_ps::<0xDD>(low, high));

    // Other surfaces' pixels: carve free space.
    let mut fuse_carved = _mm256_setzero_ps();
    if carve {
        let candidate = _mm256_and_ps(
            _mm256_andnot_ps(is_owned, usable),
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GT_OQ>(rough, _mm256_set1_ps(params.free_space_margin_m)),
                _mm256_cmp_ps::<_CMP_GT_OQ>(old_weight, _mm256_setzero_ps()),
            ),
        );
        if _mm256_movemask_ps(candidate) != 0 {
            let flags = _mm256_mask_i32gather_epi32::<4>(
                zero,
                flag_words,
                _mm256_add_epi32(record, _mm256_set1_epi32(2)),
                _mm256_castps_si256(candidate),
            );
            let free_beyond = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GT_OQ>(rough, truncs),
                flag_set(flags, MAY_CARVE),
            );
            let contradicted = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_LT_OQ>(old_sdf, _mm256_setzero_ps()),
                flag_set(flags, MAY_CARVE_NEAR),
            );
            fuse_carved = _mm256_and_ps(candidate, _mm256_or_ps(free_beyond, contradicted));
        }
    }

    let fused = _mm256_or_ps(fuse_owned, fuse_carved);
    let updates = _mm256_movemask_ps(fused);
    if updates == 0 {
        return 0;
    }
    let measured = _mm256_blendv_ps(_mm256_min_ps(rough, truncs), owned_sdf, is_owned);
    let weight = _mm256_blendv_ps(one, owned_weight, is_owned);
    let total = _mm256_add_ps(old_weight, weight);
    let new_sdf = _mm256_div_ps(
        _mm256_add_ps(
            _mm256_mul_ps(old_sdf, old_weight),
            _mm256_mul_ps(measured, weight),
        ),
        total,
    );
    let new_weight = _mm256_min_ps(total, _mm256_set1_ps(params.max_weight));
    let sdf_out = in_row_order(_mm256_blendv_ps(old_sdf, new_sdf, fused));
    let weight_out = in_row_order(_mm256_blendv_ps(old_weight, new_weight, fused));
    _mm256_storeu_ps(voxel_words, _mm256_unpacklo_ps(sdf_out, weight_out));
    _mm256_storeu_ps(voxel_words.add(8), _mm256_unpackhi_ps(sdf_out, weight_out));
    updates.count_ones() as usize
}

/// Where the voxels of one row land: pixel index (`off_image` if none),
/// continuous pixel coordinates and z-depth, lane by lane.
struct Landing {
    px: __m256i,
    u: __m256,
    v: __m256,
    z: __m256,
}

/// [`super::project_row`] in vectors: the same operations in the same order.
#[target_feature(enable = "avx2")]
unsafe fn project(
    row: &Vector3<f32>,
    step: &Vector3<f32>,
    k: &Intrinsics,
    off_image: u32,
) -> Landing {
    let t = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    let along = |start: f32, step: f32| {
        _mm256_add_ps(
            _mm256_set1_ps(start),
            _mm256_mul_ps(_mm256_set1_ps(step), t),
        )
    };
    let (x, y, z) = (
        along(row.x, step.x),
        along(row.y, step.y),
        along(row.z, step.z),
    );
    let inv_z = _mm256_div_ps(_mm256_set1_ps(1.0), z);
    let u = _mm256_add_ps(
        _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(k.fx), x), inv_z),
        _mm256_set1_ps(k.cx),
    );
    let v = _mm256_add_ps(
        _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(k.fy), y), inv_z),
        _mm256_set1_ps(k.cy),
    );
    let half = _mm256_set1_ps(0.5);
    let (ui, vi) = (_mm256_add_ps(u, half), _mm256_add_ps(v, half));
    let zero = _mm256_setzero_ps();
    let inside = _mm256_and_ps(
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GT_OQ>(z, _mm256_set1_ps(1e-6)),
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(ui, zero),
                _mm256_cmp_ps::<_CMP_GE_OQ>(vi, zero),
            ),
        ),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LT_OQ>(ui, _mm256_set1_ps(k.width as f32)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(vi, _mm256_set1_ps(k.height as f32)),
        ),
    );
    let px = _mm256_add_epi32(
        _mm256_mullo_epi32(_mm256_cvttps_epi32(vi), _mm256_set1_epi32(k.width as i32)),
        _mm256_cvttps_epi32(ui),
    );
    let px = _mm256_castps_si256(_mm256_blendv_ps(
        _mm256_castsi256_ps(_mm256_set1_epi32(off_image as i32)),
        _mm256_castsi256_ps(px),
        inside,
    ));
    Landing { px, u, v, z }
}

/// [`super::FramePixels::depth_at`] for the lanes in `near`: bilinear
/// between the four pixels around `(u, v)` where they form a smooth quad,
/// else `nearest`.
#[target_feature(enable = "avx2")]
unsafe fn interpolated_depth(
    words: *const f32,
    flag_words: *const i32,
    nearest: __m256,
    u: __m256,
    v: __m256,
    near: __m256,
    width: i32,
) -> __m256 {
    let (u0, v0) = (_mm256_cvttps_epi32(u), _mm256_cvttps_epi32(v));
    let corner = _mm256_add_epi32(_mm256_mullo_epi32(v0, _mm256_set1_epi32(width)), u0);
    let record = _mm256_add_epi32(_mm256_add_epi32(corner, corner), corner);
    let flags = _mm256_mask_i32gather_epi32::<4>(
        _mm256_setzero_si256(),
        flag_words,
        _mm256_add_epi32(record, _mm256_set1_epi32(2)),
        _mm256_castps_si256(near),
    );
    let smooth = _mm256_and_ps(near, flag_set(flags, SMOOTH_QUAD));
    if _mm256_movemask_ps(smooth) == 0 {
        return nearest;
    }
    // The four records of a smooth quad lie in the image: this pixel's,
    // its right, lower and lower-right neighbours'.
    let right = _mm256_add_epi32(record, _mm256_set1_epi32(3));
    let below = _mm256_add_epi32(record, _mm256_set1_epi32(3 * width));
    let below_right = _mm256_add_epi32(below, _mm256_set1_epi32(3));
    let q = [
        _mm256_mask_i32gather_ps::<4>(nearest, words, record, smooth),
        _mm256_mask_i32gather_ps::<4>(nearest, words, right, smooth),
        _mm256_mask_i32gather_ps::<4>(nearest, words, below, smooth),
        _mm256_mask_i32gather_ps::<4>(nearest, words, below_right, smooth),
    ];
    let fu = _mm256_sub_ps(u, _mm256_cvtepi32_ps(u0));
    let fv = _mm256_sub_ps(v, _mm256_cvtepi32_ps(v0));
    let one = _mm256_set1_ps(1.0);
    let (gu, gv) = (_mm256_sub_ps(one, fu), _mm256_sub_ps(one, fv));
    let top = _mm256_add_ps(_mm256_mul_ps(q[0], gu), _mm256_mul_ps(q[1], fu));
    let bottom = _mm256_add_ps(_mm256_mul_ps(q[2], gu), _mm256_mul_ps(q[3], fu));
    let bilinear = _mm256_add_ps(_mm256_mul_ps(top, gv), _mm256_mul_ps(bottom, fv));
    _mm256_blendv_ps(nearest, bilinear, smooth)
}

/// All-ones lanes where `flags` has `bit`.
#[target_feature(enable = "avx2")]
unsafe fn flag_set(flags: __m256i, bit: u32) -> __m256 {
    let bit = _mm256_set1_epi32(bit as i32);
    _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(flags, bit), bit))
}

/// Swaps the middle two pairs of lanes: turns `[0 1 4 5 2 3 6 7]`, the
/// order in which shuffles split interleaved voxels, into row order, and
/// back again before unpacking interleaves them.
#[target_feature(enable = "avx2")]
unsafe fn in_row_order(x: __m256) -> __m256 {
    _mm256_castpd_ps(_mm256_permute4x64_pd::<0xD8>(_mm256_castps_pd(x)))
}
