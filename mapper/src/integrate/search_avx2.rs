//! The block search of `super::search_points`, eight surface points at a time
//! with AVX2: the same operations in the same order as
//! `PointsToBlocks::block_and_bits`, so the same blocks (tested in
//! `super::tests`).

use std::arch::x86_64::*;

use super::search_points::{
    push_blocks_one_at_a_time, BlockRuns, PointsToBlocks, NEIGHBOURS_BY_BAND,
};

/// Pushes the block and neighbour bits of every usable point among
/// `points[pixels]` into `runs`, in order.
///
/// # Panics
/// If an index in `pixels` is out of range for `points`.
///
/// # Safety
/// The processor must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn push_blocks(
    to_blocks: &PointsToBlocks,
    points: &[[f32; 3]],
    pixels: &[u32],
    runs: &mut BlockRuns,
) {
    let words = points.as_ptr() as *const f32;
    let bands_to_bits = NEIGHBOURS_BY_BAND.map(|axis| {
        _mm256_setr_epi32(
            axis[0] as i32,
            axis[1] as i32,
            axis[2] as i32,
            axis[3] as i32,
            0,
            0,
            0,
            0,
        )
    });
    let mut chunks = pixels.chunks_exact(8);
    let last = _mm256_set1_epi32(points.len().saturating_sub(1) as i32);
    for chunk in &mut chunks {
        let index = _mm256_loadu_si256(chunk.as_ptr() as *const __m256i);
        // The gathers below read without bounds checks; a chunk with an
        // index out of range goes the checked way (and panics there).
        let in_range = _mm256_cmpeq_epi32(_mm256_min_epu32(index, last), index);
        if points.is_empty() || _mm256_movemask_epi8(in_range) != -1 {
            push_blocks_one_at_a_time(to_blocks, points, chunk, runs);
            continue;
        }
        let word = _mm256_add_epi32(_mm256_add_epi32(index, index), index);
        let x = _mm256_i32gather_ps::<4>(words, word);
        let y = _mm256_i32gather_ps::<4>(words, _mm256_add_epi32(word, _mm256_set1_epi32(1)));
        let z = _mm256_i32gather_ps::<4>(words, _mm256_add_epi32(word, _mm256_set1_epi32(2)));
        let usable = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_ORD_Q>(z, z)) as u32;
        if usable == 0 {
            continue;
        }
        let mut blocks = [[0i32; 8]; 3];
        let mut bits = _mm256_set1_epi32(-1);
        for (a, block) in blocks.iter_mut().enumerate() {
            let r = to_blocks.rows[a];
            let p = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_mul_ps(_mm256_set1_ps(r[0]), x),
                        _mm256_mul_ps(_mm256_set1_ps(r[1]), y),
                    ),
                    _mm256_mul_ps(_mm256_set1_ps(r[2]), z),
                ),
                _mm256_set1_ps(to_blocks.translation[a]),
            );
            let scaled = _mm256_mul_ps(p, _mm256_set1_ps(to_blocks.per_block));
            // `floor_to_i32`: truncate, then one less where that rounded up.
            let truncated = _mm256_cvttps_epi32(scaled);
            let rounded_up = _mm256_cmp_ps::<_CMP_GT_OQ>(_mm256_cvtepi32_ps(truncated), scaled);
            let index = _mm256_add_epi32(truncated, _mm256_castps_si256(rounded_up));
            let within = _mm256_sub_ps(
                p,
                _mm256_mul_ps(_mm256_cvtepi32_ps(index), _mm256_set1_ps(to_blocks.size)),
            );
            let t = to_blocks.truncation;
            let near_lower = _mm256_cmp_ps::<_CMP_LT_OQ>(within, _mm256_set1_ps(t));
            let near_upper =
                _mm256_cmp_ps::<_CMP_GT_OQ>(within, _mm256_set1_ps(to_blocks.size - t));
            let band = _mm256_or_si256(
                _mm256_and_si256(_mm256_castps_si256(near_lower), _mm256_set1_epi32(1)),
                _mm256_and_si256(_mm256_castps_si256(near_upper), _mm256_set1_epi32(2)),
            );
            bits = _mm256_and_si256(bits, _mm256_permutevar8x32_epi32(bands_to_bits[a], band));
            _mm256_storeu_si256(block.as_mut_ptr() as *mut __m256i, index);
        }
        let mut lane_bits = [0u32; 8];
        _mm256_storeu_si256(lane_bits.as_mut_ptr() as *mut __m256i, bits);
        let mut lanes = usable;
        while lanes != 0 {
            let l = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            runs.push([blocks[0][l], blocks[1][l], blocks[2][l]], lane_bits[l]);
        }
    }
    push_blocks_one_at_a_time(to_blocks, points, chunks.remainder(), runs);
}
