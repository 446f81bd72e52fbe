//! Which voxels of a block make its surface, one bit each: small enough to
//! copy and keep per block, and laid out so that a block's voxel columns
//! (which an upright object's floor projection marks once each) fall out of
//! a few ORs.

use super::BLOCK_EDGE;

/// Voxels per z level of a block (one bit each in a [`SurfaceMask`] level).
pub const LEVEL_VOXELS: usize = (BLOCK_EDGE * BLOCK_EDGE) as usize;

/// One bit per voxel of a block: a `u64` per z level, bit `x + 8·y`.
/// Small enough to copy, and a level's bits OR-ed over z give the block's
/// columns (x, y) that hold any marked voxel in those levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SurfaceMask(pub [u64; BLOCK_EDGE as usize]);

impl SurfaceMask {
    /// How many voxels are marked.
    pub fn count(&self) -> usize {
        self.0.iter().map(|level| level.count_ones() as usize).sum()
    }

    /// The columns (bit `x + 8·y`) with a marked voxel in any of the z
    /// levels whose bits are set in `levels`.
    pub fn columns(&self, levels: u8) -> u64 {
        self.0
            .iter()
            .enumerate()
            .filter(|(z, _)| levels >> z & 1 == 1)
            .fold(0, |columns, (_, level)| columns | level)
    }

    /// Calls `f(offset)` for every marked voxel a column at a time: the
    /// marked voxels of one x and y together, z rising, the columns in
    /// offset order (x fastest, then y). A voxel column of an upright
    /// object falls in one cell of a floor grid, so a rasteriser can look
    /// that cell up once.
    #[inline]
    pub fn for_each_offset_by_column(&self, mut f: impl FnMut(usize)) {
        let mut columns = self.columns(u8::MAX);
        while columns != 0 {
            let column = columns.trailing_zeros() as usize;
            columns &= columns - 1;
            for (z, &level) in self.0.iter().enumerate() {
                if level >> column & 1 == 1 {
                    f(z * LEVEL_VOXELS + column);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mask_visits_its_voxels_a_column_at_a_time() {
        let mut levels = [0u64; BLOCK_EDGE as usize];
        levels[0] = 1 << 3 | 1 << 8; // columns 3 and 8 at z 0
        levels[2] = 1 << 3; // column 3 at z 2
        let mut offsets = Vec::new();
        SurfaceMask(levels).for_each_offset_by_column(|o| offsets.push(o));
        assert_eq!(offsets, [3, 2 * LEVEL_VOXELS + 3, 8]);
    }
}
