//! The scalar block search and what both searches share: points to blocks
//! and neighbour bits ([`PointsToBlocks`]), runs of points in one block
//! ([`BlockRuns`]). Apart from the dispatch in `search`, so that the vector
//! search in `search_avx2` and the dispatch do not import each other.

use nalgebra::Point3;
use rustc_hash::{FxHashMap, FxHashSet};

use super::frame::usable_point;
use crate::layer::BlockIndex;
use crate::Pose;

/// Pushes the block and neighbour bits of every usable point among
/// `points[pixels]` into `runs`, in order, one point at a time.
pub(super) fn push_blocks_one_at_a_time(
    to_blocks: &PointsToBlocks,
    points: &[[f32; 3]],
    pixels: &[u32],
    runs: &mut BlockRuns,
) {
    for &i in pixels {
        if let Some(point) = usable_point(points[i as usize]) {
            let (block, bits) = to_blocks.block_and_bits(&point);
            runs.push(block, bits);
        }
    }
}

/// Turns camera-frame points into the block each lies in, in the layer's
/// frame, and the neighbours it needs.
pub(super) struct PointsToBlocks {
    /// Rows of the rotation from camera to layer frame (a matrix rotates a
    /// point in half the operations of a quaternion).
    pub(super) rows: [[f32; 3]; 3],
    /// Camera centre in the layer's frame.
    pub(super) translation: [f32; 3],
    /// Block edge in metres.
    pub(super) size: f32,
    /// Its reciprocal. A multiplication instead of a division per axis and
    /// point: where the two disagree, the point lies on a face, within the
    /// truncation distance of both blocks, and either way both are needed.
    pub(super) per_block: f32,
    /// Truncation distance in metres.
    pub(super) truncation: f32,
}

impl PointsToBlocks {
    /// The search of a layer with blocks of `size` metres, from a camera at
    /// `t_layer_camera`, for a truncation band of `truncation` metres.
    pub(super) fn new(t_layer_camera: &Pose, size: f32, truncation: f32) -> Self {
        let rotation = t_layer_camera.rotation.to_rotation_matrix();
        let t = t_layer_camera.translation.vector;
        Self {
            rows: [0, 1, 2].map(|r| [0, 1, 2].map(|c| rotation.matrix()[(r, c)])),
            translation: [t.x, t.y, t.z],
            size,
            per_block: 1.0 / size,
            truncation,
        }
    }

    /// Point `point`'s block and the bits of the neighbours it needs
    /// ([`neighbour_bit`]).
    #[inline]
    pub(super) fn block_and_bits(&self, point: &Point3<f32>) -> ([i32; 3], u32) {
        let mut block = [0i32; 3];
        let mut bits = u32::MAX;
        for a in 0..3 {
            let r = &self.rows[a];
            // The order of operations the vector search uses too.
            let p = ((r[0] * point.x + r[1] * point.y) + r[2] * point.z) + self.translation[a];
            block[a] = crate::layer::floor_to_i32(p * self.per_block);
            let within = p - block[a] as f32 * self.size;
            let band = usize::from(within < self.truncation)
                | usize::from(within > self.size - self.truncation) << 1;
            bits &= NEIGHBOURS_BY_BAND[a][band];
        }
        (block, bits)
    }
}

/// Per block holding points, which of its 27 neighbours (itself included)
/// are needed, as bits, gathered over a run of points in one block: one map
/// update per change of block instead of one set insertion per needed block.
#[derive(Default)]
pub(super) struct BlockRuns {
    needed: FxHashMap<[i32; 3], u32>,
    run: Option<([i32; 3], u32)>,
}

impl BlockRuns {
    /// Adds one point's block and neighbour bits.
    #[inline]
    pub(super) fn push(&mut self, block: [i32; 3], bits: u32) {
        match &mut self.run {
            Some((current, run_bits)) if *current == block => *run_bits |= bits,
            _ => {
                if let Some((block, bits)) = self.run.replace((block, bits)) {
                    *self.needed.entry(block).or_default() |= bits;
                }
            }
        }
    }

    /// Every block needed.
    pub(super) fn into_blocks(mut self) -> FxHashSet<BlockIndex> {
        if let Some((block, bits)) = self.run.take() {
            *self.needed.entry(block).or_default() |= bits;
        }
        let mut blocks = FxHashSet::default();
        for (block, bits) in self.needed {
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
}

/// Per axis and band (bit 0: the point lies within the truncation distance
/// of the block's lower face on that axis, bit 1: of its upper face), the
/// neighbour bits whose offset along that axis the band needs: the block's
/// own layer, plus the neighbour across each near face. A point needs the
/// intersection of its three axes' sets.
pub(super) const NEIGHBOURS_BY_BAND: [[u32; 4]; 3] = {
    let mut table = [[0u32; 4]; 3];
    let mut axis = 0;
    while axis < 3 {
        let mut band = 0;
        while band < 4 {
            let mut bit = 0;
            while bit < 27 {
                let offset = [bit / 9, (bit / 3) % 3, bit % 3][axis] - 1;
                let lowest = if band & 1 != 0 { -1 } else { 0 };
                let highest = if band & 2 != 0 { 1 } else { 0 };
                if offset >= lowest && offset <= highest {
                    table[axis][band] |= 1 << bit;
                }
                bit += 1;
            }
            band += 1;
        }
        axis += 1;
    }
    table
};

/// The bit of a neighbour at offset `[-1..=1; 3]` in [`BlockRuns`]' masks.
#[inline]
fn neighbour_bit(offset: [i32; 3]) -> u32 {
    ((offset[0] + 1) * 9 + (offset[1] + 1) * 3 + offset[2] + 1) as u32
}
