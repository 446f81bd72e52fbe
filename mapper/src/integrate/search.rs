//! Which blocks of a layer a frame's surface points need: each point's
//! block, plus the neighbour across every face it is closer to than the
//! truncation distance.

use rustc_hash::FxHashSet;

use super::search_points::{push_blocks_one_at_a_time, BlockRuns, PointsToBlocks};
use super::{FramePixels, IntegrationParams, Owned, Simd};
use crate::layer::{BlockIndex, Layer};
use crate::Pose;

/// Blocks within the truncation band of the owned pixels' surface points.
pub(super) fn blocks_near_points(
    simd: Simd,
    layer: &Layer,
    t_layer_camera: &Pose,
    pixels: &FramePixels,
    owned: Owned<'_>,
    params: &IntegrationParams,
) -> FxHashSet<BlockIndex> {
    let to_blocks = PointsToBlocks::new(t_layer_camera, layer.block_size_m(), params.truncation_m);
    let mut runs = BlockRuns::default();
    match simd {
        Simd::Scalar => {
            push_blocks_one_at_a_time(&to_blocks, &pixels.points, owned.pixels, &mut runs)
        }
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Simd::Avx2` is made only where the processor has AVX2.
        Simd::Avx2 => unsafe {
            super::search_avx2::push_blocks(&to_blocks, &pixels.points, owned.pixels, &mut runs)
        },
    }
    runs.into_blocks()
}
