//! Block-hashed voxel storage: `Layer` → 8³-voxel `Block`s → `Voxel`s.
//!
//! Voxel `(i, j, k)` covers `[i·s, (i+1)·s)` along each axis (its centre is at
//! `(i + ½)·s`); negative indices use floor division, so there is no seam at 0.

use std::sync::OnceLock;

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;

mod footprint;
mod surface_mask;
pub(crate) use footprint::{band_holds, Band, KeptFootprint, MAX_BANDS};
pub use surface_mask::{SurfaceMask, LEVEL_VOXELS};

/// Voxels per block edge.
pub const BLOCK_EDGE: i32 = 8;
/// Voxels per block.
pub const BLOCK_VOXELS: usize = (BLOCK_EDGE * BLOCK_EDGE * BLOCK_EDGE) as usize;

/// `x.floor() as i32` (saturating, NaN → 0) without the libm call that
/// `f32::floor` compiles to on baseline x86-64 (no SSE4.1): the hot loops
/// of integration and rendering floor several times per voxel.
#[inline]
pub fn floor_to_i32(x: f32) -> i32 {
    let t = x as i32;
    if (t as f32) > x {
        t - 1
    } else {
        t
    }
}

/// One TSDF sample. `repr(C)`: integration's vector code reads a block row
/// as interleaved `sdf, weight` pairs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[repr(C)]
pub struct Voxel {
    /// Truncated signed distance in metres (positive in front of the surface).
    pub sdf: f32,
    /// Accumulated weight; 0 = never observed.
    pub weight: f32,
}

/// Global voxel index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VoxelIndex(pub [i32; 3]);

/// Block index (a block covers `BLOCK_EDGE` voxels per axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BlockIndex(pub [i32; 3]);

impl VoxelIndex {
    /// The block holding this voxel and the voxel's offset inside it.
    pub fn split(self) -> (BlockIndex, usize) {
        let b = self.0.map(|i| i.div_euclid(BLOCK_EDGE));
        let l = self.0.map(|i| i.rem_euclid(BLOCK_EDGE) as usize);
        (
            BlockIndex(b),
            l[0] + BLOCK_EDGE as usize * (l[1] + BLOCK_EDGE as usize * l[2]),
        )
    }

    /// Voxel at `offset` inside `block`.
    pub fn join(block: BlockIndex, offset: usize) -> Self {
        let e = BLOCK_EDGE as usize;
        let l = [offset % e, (offset / e) % e, offset / (e * e)];
        Self([0, 1, 2].map(|a| block.0[a] * BLOCK_EDGE + l[a] as i32))
    }
}

/// A block of voxels.
#[derive(Debug, Clone, Default)]
pub struct Block {
    /// One allocation, so that a block is a pointer in its layer's hash map.
    data: Box<BlockData>,
}

/// A block's voxels and what is derived from them.
#[derive(Debug, Clone)]
struct BlockData {
    /// Voxels, x fastest, then y, then z.
    voxels: [Voxel; BLOCK_VOXELS],
    /// Which voxels are observed and within one voxel of the surface
    /// ([`Layer::surface_mask`]), worked out on first request and forgotten
    /// when a voxel changes: the actor's state asks for the whole map's
    /// surface every step, while a step changes only the blocks in view
    /// (about a third of them over an episode).
    surface: OnceLock<SurfaceMask>,
    /// The least and greatest offsets (per axis) of the observed voxels at
    /// or behind the surface (`sdf <= 0`), `None` if there are none: where
    /// rays can find a zero crossing ([`Layer::crossing_bounds`]). Worked
    /// out on first request and forgotten when a voxel changes, like
    /// `surface`.
    behind: OnceLock<Option<[[i32; 3]; 2]>>,
}

impl Default for BlockData {
    fn default() -> Self {
        Self {
            voxels: [Voxel::default(); BLOCK_VOXELS],
            surface: OnceLock::new(),
            behind: OnceLock::new(),
        }
    }
}

impl Block {
    /// The voxels, x fastest, then y, then z.
    #[inline]
    pub fn voxels(&self) -> &[Voxel; BLOCK_VOXELS] {
        &self.data.voxels
    }

    /// Lets `f` change the voxels; `f` returns how many it changed, and
    /// when that is not zero the block's cached surface is forgotten.
    /// Returns `f`'s count.
    #[inline]
    pub fn update(&mut self, f: impl FnOnce(&mut [Voxel; BLOCK_VOXELS]) -> usize) -> usize {
        let changed = f(&mut self.data.voxels);
        if changed > 0 {
            self.data.surface.take();
            self.data.behind.take();
        }
        changed
    }

    /// The least and greatest offsets, per axis, of the observed voxels at
    /// or behind the surface; `None` if there are none. Kept until a voxel
    /// changes.
    fn behind_offsets(&self) -> Option<[[i32; 3]; 2]> {
        *self.data.behind.get_or_init(|| {
            // One bit per voxel of a row, then which x, y and z hold any.
            let edge = BLOCK_EDGE as usize;
            let (mut xs, mut ys, mut zs) = (0u32, 0u32, 0u32);
            for (row, voxels) in self.voxels().chunks_exact(edge).enumerate() {
                let mut mask = 0u32;
                for (i, v) in voxels.iter().enumerate() {
                    mask |= u32::from((v.weight > 0.0) & (v.sdf <= 0.0)) << i;
                }
                let any = u32::from(mask != 0);
                xs |= mask;
                ys |= any << (row % edge);
                zs |= any << (row / edge);
            }
            let range = |bits: u32| {
                [
                    bits.trailing_zeros() as i32,
                    31 - bits.leading_zeros() as i32,
                ]
            };
            (xs != 0).then(|| {
                let [x, y, z] = [range(xs), range(ys), range(zs)];
                [[x[0], y[0], z[0]], [x[1], y[1], z[1]]]
            })
        })
    }

    /// Which voxels [`Block::for_each_near_surface`] visits, a z level's 64
    /// at a time without a branch.
    fn near_surface_mask(&self, band_m: f32) -> SurfaceMask {
        let mut mask = SurfaceMask::default();
        for (bits, level) in mask
            .0
            .iter_mut()
            .zip(self.voxels().chunks_exact(LEVEL_VOXELS))
        {
            *bits = level.iter().enumerate().fold(0, |bits, (i, v)| {
                bits | u64::from((v.weight > 0.0) & (v.sdf.abs() < band_m)) << i
            });
        }
        mask
    }

    /// Calls `f(offset, sdf)` for every observed voxel within `band_m` of
    /// the surface, in offset order. Tests eight voxels at a time into a
    /// bit mask, so the (mostly empty) runs cost no branch per voxel.
    #[inline]
    pub fn for_each_near_surface(&self, band_m: f32, mut f: impl FnMut(usize, f32)) {
        for (chunk_index, chunk) in self.voxels().chunks_exact(8).enumerate() {
            let mut mask = 0u8;
            for (i, v) in chunk.iter().enumerate() {
                mask |= u8::from((v.weight > 0.0) & (v.sdf.abs() < band_m)) << i;
            }
            while mask != 0 {
                let i = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                f(chunk_index * 8 + i, chunk[i].sdf);
            }
        }
    }
}

/// Reads one layer's voxels, remembering the last block it looked up:
/// successive samples along a ray or within a trilinear stencil mostly fall
/// in the same block, so most reads skip the hash lookup.
#[derive(Debug, Clone)]
pub struct CachedReader<'a> {
    layer: &'a Layer,
    last: Option<(BlockIndex, Option<&'a Block>)>,
}

impl<'a> CachedReader<'a> {
    /// A reader of `layer` with an empty cache.
    pub fn new(layer: &'a Layer) -> Self {
        Self { layer, last: None }
    }

    /// The layer read.
    pub fn layer(&self) -> &'a Layer {
        self.layer
    }

    /// The block at `b`, if allocated.
    #[inline]
    pub fn block(&mut self, b: BlockIndex) -> Option<&'a Block> {
        match self.last {
            Some((cached, block)) if cached == b => block,
            _ => {
                let block = self.layer.block(b);
                self.last = Some((b, block));
                block
            }
        }
    }

    /// SDF of voxel `v` if it was ever observed.
    #[inline]
    pub fn observed_sdf(&mut self, v: VoxelIndex) -> Option<f32> {
        let (b, o) = v.split();
        self.block(b)
            .map(|block| block.voxels()[o])
            .filter(|voxel| voxel.weight > 0.0)
            .map(|voxel| voxel.sdf)
    }
}

/// A sparse voxel volume in one coordinate frame.
#[derive(Debug, Clone)]
pub struct Layer {
    /// Voxel edge length in metres.
    pub voxel_size_m: f32,
    blocks: FxHashMap<BlockIndex, Block>,
    /// [`Layer::block_bounds`] and [`Layer::crossing_bounds`], worked out
    /// on first use and forgotten whenever a block may change: the map
    /// asks for them several times a frame for every object it renders,
    /// and most objects are not touched in a frame.
    bounds: OnceLock<Bounds>,
    /// [`Layer::surface_centres`], worked out on first use and forgotten
    /// whenever a block may change: the policy's state projects every
    /// placed object's surface each step, and most objects are not touched
    /// in a step.
    surface_centres: OnceLock<Vec<Point3<f32>>>,
    /// [`Layer::surface_footprint`], the last one asked for, forgotten
    /// with the surface centres.
    surface_footprint: KeptFootprint,
}

/// A layer's two boxes, as [`Layer::block_bounds`] and
/// [`Layer::crossing_bounds`] give them.
#[derive(Debug, Clone, Copy)]
struct Bounds {
    blocks: Option<(Point3<f32>, Point3<f32>)>,
    crossings: Option<(Point3<f32>, Point3<f32>)>,
}

impl Layer {
    /// An empty layer.
    pub fn new(voxel_size_m: f32) -> Self {
        Self {
            voxel_size_m,
            blocks: FxHashMap::default(),
            bounds: OnceLock::new(),
            surface_centres: OnceLock::new(),
            surface_footprint: KeptFootprint::default(),
        }
    }

    /// Block edge length in metres.
    pub fn block_size_m(&self) -> f32 {
        self.voxel_size_m * BLOCK_EDGE as f32
    }

    /// The voxel containing point `p` (layer frame).
    pub fn voxel_of(&self, p: &Point3<f32>) -> VoxelIndex {
        VoxelIndex([p.x, p.y, p.z].map(|c| floor_to_i32(c / self.voxel_size_m)))
    }

    /// Centre of a voxel (layer frame).
    pub fn voxel_center(&self, v: VoxelIndex) -> Point3<f32> {
        let s = self.voxel_size_m;
        Point3::new(
            (v.0[0] as f32 + 0.5) * s,
            (v.0[1] as f32 + 0.5) * s,
            (v.0[2] as f32 + 0.5) * s,
        )
    }

    /// The voxel at `v`, if its block exists.
    pub fn voxel(&self, v: VoxelIndex) -> Option<&Voxel> {
        let (b, o) = v.split();
        self.blocks.get(&b).map(|blk| &blk.voxels()[o])
    }

    /// The block at `b`, if allocated.
    pub fn block(&self, b: BlockIndex) -> Option<&Block> {
        self.blocks.get(&b)
    }

    /// The block at `b`, allocated if missing.
    pub fn block_mut_or_insert(&mut self, b: BlockIndex) -> &mut Block {
        self.forget_derived();
        self.blocks.entry(b).or_default()
    }

    /// [`Block::update`] of the block at `b` (allocated if missing), keeping
    /// the layer's [`Layer::surface_centres`] while the block's surface
    /// mask stays what it was: integration changes every block in view each
    /// frame, mostly without moving its surface, and the state gathers
    /// every placed object's centres each step (tens of thousands of points
    /// for a large object). Returns `f`'s count.
    pub fn update_block(
        &mut self,
        b: BlockIndex,
        f: impl FnOnce(&mut [Voxel; BLOCK_VOXELS]) -> usize,
    ) -> usize {
        self.bounds.take();
        let voxel_size_m = self.voxel_size_m;
        let block = self.blocks.entry(b).or_default();
        // While the centres are kept every block's mask is (they were
        // worked out from all of them, and a block whose mask changed
        // dropped them); a block allocated since has none yet, an empty one.
        let before = block.data.surface.get().copied().unwrap_or_default();
        let changed = block.update(f);
        if changed > 0 && self.surface_centres.get().is_some() {
            let after = block.near_surface_mask(voxel_size_m);
            block.data.surface.get_or_init(|| after);
            if after != before {
                self.forget_surface();
            }
        }
        changed
    }

    /// Which of block `b`'s voxels are observed and within one voxel of the
    /// surface (`None` if `b` is not allocated): the voxels whose centres
    /// make the map's surface points ([`crate::Map::surface_points`]).
    /// Worked out once and kept until the block's voxels change.
    pub fn surface_mask(&self, b: BlockIndex) -> Option<SurfaceMask> {
        let block = self.blocks.get(&b)?;
        Some(
            *block
                .data
                .surface
                .get_or_init(|| block.near_surface_mask(self.voxel_size_m)),
        )
    }

    /// The centres of the voxels of every block's [`Layer::surface_mask`]
    /// (layer frame), block by block in index order and a voxel column at
    /// a time within a block ([`SurfaceMask::for_each_offset_by_column`]):
    /// the points a placed object's surface projects from. Worked out once
    /// and kept until a block may change.
    pub fn surface_centres(&self) -> &[Point3<f32>] {
        self.surface_centres.get_or_init(|| {
            let masks: Vec<(BlockIndex, SurfaceMask)> = self
                .block_indices()
                .into_iter()
                .filter_map(|b| self.surface_mask(b).map(|m| (b, m)))
                .collect();
            // One allocation of the right size, not one per doubling.
            let mut centres = Vec::with_capacity(masks.iter().map(|(_, m)| m.count()).sum());
            for (b, mask) in masks {
                mask.for_each_offset_by_column(|o| {
                    centres.push(self.voxel_center(VoxelIndex::join(b, o)))
                });
            }
            centres
        })
    }

    /// Forgets what is worked out from the blocks, before one may change.
    fn forget_derived(&mut self) {
        self.bounds.take();
        self.forget_surface();
    }

    /// Forgets the surface centres and what is made of them.
    fn forget_surface(&mut self) {
        self.surface_centres.take();
        self.surface_footprint.forget();
    }

    /// Frees the block at `b` (a no-op if it is not allocated). The layer's
    /// [`Layer::surface_centres`] are kept when none of them lay in the
    /// block (integration frees the blocks it allocated and then left
    /// unobserved).
    pub fn remove_block(&mut self, b: BlockIndex) {
        self.bounds.take();
        let Some(block) = self.blocks.remove(&b) else {
            return;
        };
        if self.surface_centres.get().is_some()
            && block.near_surface_mask(self.voxel_size_m).count() > 0
        {
            self.forget_surface();
        }
    }

    /// Allocated block indices, sorted (deterministic iteration).
    pub fn block_indices(&self) -> Vec<BlockIndex> {
        let mut v: Vec<_> = self.blocks.keys().copied().collect();
        v.sort_unstable();
        v
    }

    /// Number of allocated blocks.
    pub fn len(&self) -> usize {
        self.blocks.len()
    }

    /// True when nothing is allocated.
    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    /// Centres and SDF of observed voxels within `band_m` of the surface (sorted by index).
    pub fn near_surface_voxels(&self, band_m: f32) -> Vec<(Point3<f32>, f32)> {
        let mut out = Vec::new();
        for b in self.block_indices() {
            self.blocks[&b].for_each_near_surface(band_m, |o, sdf| {
                out.push((self.voxel_center(VoxelIndex::join(b, o)), sdf));
            });
        }
        out
    }

    /// Calls `f(a, b, point)` for every sign change between two observed
    /// neighbouring voxels `a` and `b`, `point` linearly interpolated between
    /// their centres (the vertices marching cubes would place). Pairs
    /// straddling more than `max_jump_m` are skipped as truncation artefacts.
    /// Visits in voxel-index order, so results are deterministic.
    fn for_each_crossing(
        &self,
        max_jump_m: f32,
        mut f: impl FnMut(VoxelIndex, VoxelIndex, Point3<f32>),
    ) {
        for b in self.block_indices() {
            let block = &self.blocks[&b];
            for (o, a) in block.voxels().iter().enumerate() {
                if a.weight <= 0.0 {
                    continue;
                }
                let v = VoxelIndex::join(b, o);
                for axis in 0..3 {
                    let mut n = v.0;
                    n[axis] += 1;
                    let n = VoxelIndex(n);
                    let Some(bv) = self.voxel(n).filter(|x| x.weight > 0.0) else {
                        continue;
                    };
                    if (a.sdf > 0.0) == (bv.sdf > 0.0) || (a.sdf - bv.sdf).abs() > max_jump_m {
                        continue;
                    }
                    let (ca, cb) = (self.voxel_center(v), self.voxel_center(n));
                    f(v, n, ca + (cb - ca) * (a.sdf / (a.sdf - bv.sdf)));
                }
            }
        }
    }

    /// Surface points: every sign change between observed neighbours (see
    /// `for_each_crossing`), sorted by voxel index.
    pub fn zero_crossings(&self, max_jump_m: f32) -> Vec<Point3<f32>> {
        let mut out = Vec::new();
        self.for_each_crossing(max_jump_m, |_, _, p| out.push(p));
        out
    }

    /// SDF gradient at voxel `v` by central differences (one-sided where a
    /// neighbour is unobserved), or `None` if an axis has no observed neighbour.
    pub fn gradient(&self, v: VoxelIndex) -> Option<Vector3<f32>> {
        let observed = |i: VoxelIndex| self.voxel(i).filter(|x| x.weight > 0.0).map(|x| x.sdf);
        let centre = observed(v)?;
        let mut g = Vector3::zeros();
        for axis in 0..3 {
            let (mut lo, mut hi) = (v.0, v.0);
            lo[axis] -= 1;
            hi[axis] += 1;
            g[axis] = match (observed(VoxelIndex(lo)), observed(VoxelIndex(hi))) {
                (Some(a), Some(b)) => (b - a) / 2.0,
                (None, Some(b)) => b - centre,
                (Some(a), None) => centre - a,
                (None, None) => return None,
            } / self.voxel_size_m;
        }
        Some(g)
    }

    /// [`Layer::zero_crossings`] with unit outward normals (SDF gradient,
    /// averaged over the two voxels of the crossing); crossings without a
    /// usable gradient are left out. What tracking aligns to a frame.
    pub fn surface_samples(&self, max_jump_m: f32) -> Vec<(Point3<f32>, Vector3<f32>)> {
        let mut out = Vec::new();
        self.for_each_crossing(max_jump_m, |a, b, p| {
            if let (Some(ga), Some(gb)) = (self.gradient(a), self.gradient(b)) {
                if let Some(normal) = (ga + gb).try_normalize(1e-6) {
                    out.push((p, normal));
                }
            }
        });
        out
    }

    /// Axis-aligned bounds (layer frame) of every point where a ray marched
    /// through this layer can find its zero crossing, or `None` where it
    /// can find none. A crossing is found at a sample whose distance is not
    /// positive, and such a sample interpolates (or is) an observed voxel
    /// at or behind the surface whose centre is less than a voxel away per
    /// axis: so the bounds are those voxels' centres, a voxel wider on
    /// every side. Rays that miss this box, and the parts of rays beyond
    /// it, need no marching.
    pub fn crossing_bounds(&self) -> Option<(Point3<f32>, Point3<f32>)> {
        self.bounds().crossings
    }

    /// Axis-aligned bounds (layer frame) of all allocated blocks, or `None` when empty.
    pub fn block_bounds(&self) -> Option<(Point3<f32>, Point3<f32>)> {
        self.bounds().blocks
    }

    fn bounds(&self) -> Bounds {
        *self.bounds.get_or_init(|| Bounds {
            blocks: self.scan_block_bounds(),
            crossings: self.scan_crossing_bounds(),
        })
    }

    /// [`Layer::crossing_bounds`] from the blocks.
    fn scan_crossing_bounds(&self) -> Option<(Point3<f32>, Point3<f32>)> {
        let mut bounds: Option<[[i32; 3]; 2]> = None;
        for (b, block) in &self.blocks {
            let Some([lo, hi]) = block.behind_offsets() else {
                continue;
            };
            let first = b.0.map(|i| i * BLOCK_EDGE);
            let (lo, hi) = (
                [0, 1, 2].map(|a| first[a] + lo[a]),
                [0, 1, 2].map(|a| first[a] + hi[a]),
            );
            bounds = Some(match bounds {
                None => [lo, hi],
                Some([l, h]) => [
                    [0, 1, 2].map(|a| l[a].min(lo[a])),
                    [0, 1, 2].map(|a| h[a].max(hi[a])),
                ],
            });
        }
        let [lo, hi] = bounds?;
        // Voxel centres are at (i + 1/2)·s: one voxel beyond the lowest
        // centre is (lo - 1/2)·s, beyond the highest (hi + 3/2)·s; a
        // hundredth of a voxel more covers rounding along the ray.
        let s = self.voxel_size_m;
        let slack = 0.01;
        Some((
            Point3::from(lo.map(|i| (i as f32 - 0.5 - slack) * s)),
            Point3::from(hi.map(|i| (i as f32 + 1.5 + slack) * s)),
        ))
    }

    /// [`Layer::block_bounds`] from the blocks.
    fn scan_block_bounds(&self) -> Option<(Point3<f32>, Point3<f32>)> {
        let s = self.block_size_m();
        let mut it = self.blocks.keys();
        let first = it.next()?;
        let (mut lo, mut hi) = (first.0, first.0);
        for b in it {
            for a in 0..3 {
                lo[a] = lo[a].min(b.0[a]);
                hi[a] = hi[a].max(b.0[a]);
            }
        }
        Some((
            Point3::new(lo[0] as f32 * s, lo[1] as f32 * s, lo[2] as f32 * s),
            Point3::new(
                (hi[0] + 1) as f32 * s,
                (hi[1] + 1) as f32 * s,
                (hi[2] + 1) as f32 * s,
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_surface_mask_marks_the_voxels_near_the_surface_and_forgets_them_on_change() {
        let mut layer = Layer::new(0.1);
        let b = BlockIndex([0, -1, 2]);
        // Observed near the surface: offsets 3 (x 3), 8 + 64 (y 1, z 1) and
        // 511; observed but far from it: 9; near it but never observed: 10.
        let near = [3, 72, 511];
        layer.block_mut_or_insert(b).update(|voxels| {
            for o in near {
                voxels[o] = Voxel {
                    sdf: -0.05,
                    weight: 1.0,
                };
            }
            voxels[9] = Voxel {
                sdf: 0.15,
                weight: 1.0,
            };
            voxels[10] = Voxel {
                sdf: 0.0,
                weight: 0.0,
            };
            5
        });
        let mask = layer.surface_mask(b).expect("an allocated block");
        assert_eq!(mask.count(), 3);
        let mut offsets = Vec::new();
        mask.for_each_offset_by_column(|o| offsets.push(o));
        assert_eq!(
            offsets, near,
            "a column at a time, the columns in offset order"
        );
        // Columns: (3, 0) at z 0, (0, 1) at z 1, (7, 7) at z 7.
        assert_eq!(mask.columns(0b1), 1 << 3);
        assert_eq!(mask.columns(0b10), 1 << 8);
        assert_eq!(mask.columns(0xff), 1 << 3 | 1 << 8 | 1 << 63);
        assert_eq!(mask.columns(0b0111_1100), 0);
        assert_eq!(layer.surface_mask(BlockIndex([0, 0, 0])), None);
        // A change forgets the kept mask.
        layer.block_mut_or_insert(b).update(|voxels| {
            voxels[3].sdf = 0.5;
            1
        });
        assert_eq!(layer.surface_mask(b).unwrap().count(), 2);
    }

    #[test]
    fn a_blocks_surface_mask_holds_the_voxels_its_scan_visits() {
        let mut block = Block::default();
        block.update(|voxels| {
            for (o, v) in voxels.iter_mut().enumerate() {
                let pseudo = (o * 7919 % 211) as f32 / 211.0;
                *v = Voxel {
                    sdf: (pseudo - 0.5) * 0.5,
                    weight: if o % 5 == 0 { 0.0 } else { pseudo },
                };
            }
            BLOCK_VOXELS
        });
        let mut visited = SurfaceMask::default();
        block.for_each_near_surface(0.1, |o, _| {
            visited.0[o / LEVEL_VOXELS] |= 1 << (o % LEVEL_VOXELS)
        });
        assert!(
            visited.count() > 50 && visited.count() < 400,
            "{}",
            visited.count()
        );
        assert_eq!(block.near_surface_mask(0.1), visited);
    }

    #[test]
    fn surface_centres_are_kept_through_updates_that_leave_the_surface_where_it_was() {
        let s = 0.04;
        let mut layer = Layer::new(s);
        set(&mut layer, [3, 4, 5], 0.0);
        layer.surface_centres();
        let kept = |layer: &Layer| layer.surface_centres.get().is_some();
        let near = |sdf: f32| {
            move |voxels: &mut [Voxel; BLOCK_VOXELS]| {
                voxels[VoxelIndex([3, 4, 5]).split().1] = Voxel { sdf, weight: 2.0 };
                1
            }
        };
        let b = VoxelIndex([3, 4, 5]).split().0;
        // Still within a voxel of the surface: the same centres, kept.
        layer.update_block(b, near(0.01));
        assert!(kept(&layer));
        // Another voxel of the block reaches the surface: worked out again.
        layer.update_block(b, |voxels| {
            voxels[VoxelIndex([4, 4, 5]).split().1] = Voxel {
                sdf: 0.0,
                weight: 1.0,
            };
            1
        });
        assert!(!kept(&layer));
        let at = |v: [i32; 3]| Layer::new(s).voxel_center(VoxelIndex(v));
        assert_eq!(layer.surface_centres(), [at([3, 4, 5]), at([4, 4, 5])]);
        // A block allocated and freed unobserved: kept.
        layer.surface_centres();
        layer.update_block(BlockIndex([7, 7, 7]), |_| 0);
        layer.remove_block(BlockIndex([7, 7, 7]));
        assert!(kept(&layer));
        // A new block whose voxels reach the surface: worked out again.
        layer.update_block(VoxelIndex([-9, 4, 20]).split().0, |voxels| {
            voxels[VoxelIndex([-9, 4, 20]).split().1] = Voxel {
                sdf: 0.0,
                weight: 1.0,
            };
            1
        });
        assert!(!kept(&layer));
        assert_eq!(
            layer.surface_centres(),
            [at([-9, 4, 20]), at([3, 4, 5]), at([4, 4, 5])]
        );
        // A voxel leaving the surface: worked out again.
        layer.update_block(b, near(0.5));
        assert!(!kept(&layer));
        assert_eq!(layer.surface_centres(), [at([-9, 4, 20]), at([4, 4, 5])]);
    }

    #[test]
    fn negative_coordinates_and_block_boundaries_index_without_seams() {
        let layer = Layer::new(0.04);
        assert_eq!(
            layer.voxel_of(&Point3::new(-0.001, 0.0, 0.039)),
            VoxelIndex([-1, 0, 0])
        );
        assert_eq!(
            layer.voxel_of(&Point3::new(-0.001, 0.3199, 0.32)).split().0,
            BlockIndex([-1, 0, 1])
        );
        for v in [
            [-1, -8, -9],
            [0, 7, 8],
            [-17, 15, 16],
            [i32::MIN / 16, 3, -3],
        ] {
            let (b, o) = VoxelIndex(v).split();
            assert_eq!(VoxelIndex::join(b, o), VoxelIndex(v));
            assert!(o < BLOCK_VOXELS);
        }
        assert_eq!(
            VoxelIndex([-1, -1, -1]).split(),
            (BlockIndex([-1, -1, -1]), BLOCK_VOXELS - 1)
        );
        let c = layer.voxel_center(VoxelIndex([-1, 0, 2]));
        assert_eq!(layer.voxel_of(&c), VoxelIndex([-1, 0, 2]));
    }

    /// Makes voxel `v` observed with `sdf`.
    fn set(layer: &mut Layer, v: [i32; 3], sdf: f32) {
        let (b, o) = VoxelIndex(v).split();
        layer.block_mut_or_insert(b).update(|voxels| {
            voxels[o] = Voxel { sdf, weight: 1.0 };
            1
        });
    }

    #[test]
    fn crossing_bounds_follow_the_voxels_behind_surfaces_as_they_change() {
        let s = 0.04;
        let mut layer = Layer::new(s);
        // Observed free space only: no crossing anywhere.
        set(&mut layer, [3, 4, 5], 0.05);
        assert_eq!(layer.crossing_bounds(), None);
        // One voxel behind a surface: a voxel's reach around its centre.
        set(&mut layer, [3, 4, 5], -0.01);
        let (lo, hi) = layer.crossing_bounds().expect("a voxel behind the surface");
        let centre = layer.voxel_center(VoxelIndex([3, 4, 5]));
        for a in 0..3 {
            assert!((centre[a] - s - lo[a]).abs() < 0.02 * s, "{lo} vs {centre}");
            assert!((centre[a] + s - hi[a]).abs() < 0.02 * s, "{hi} vs {centre}");
        }
        // A second one in another block widens the bounds...
        set(&mut layer, [-9, 4, 20], 0.0);
        let (lo, hi) = layer.crossing_bounds().unwrap();
        assert!(
            lo.x < -9.0 * s && hi.z > 21.0 * s && lo.z < 5.0 * s,
            "{lo} – {hi}"
        );
        // ...and carving both away (positive again) leaves none.
        set(&mut layer, [3, 4, 5], 0.02);
        set(&mut layer, [-9, 4, 20], 0.02);
        assert_eq!(layer.crossing_bounds(), None);
    }

    #[test]
    fn surface_centres_follow_the_voxels_as_they_change() {
        let s = 0.04;
        let mut layer = Layer::new(s);
        assert!(layer.surface_centres().is_empty());
        // On the surface: its centre. Far from it (free space): nothing.
        set(&mut layer, [3, 4, 5], 0.0);
        set(&mut layer, [-9, 4, 20], 0.5);
        let at = |v: [i32; 3]| Layer::new(s).voxel_center(VoxelIndex(v));
        assert_eq!(layer.surface_centres(), [at([3, 4, 5])]);
        // A second surface voxel, in a block earlier in index order, is
        // seen although the first answer was kept...
        set(&mut layer, [-9, 4, 20], 0.01);
        assert_eq!(layer.surface_centres(), [at([-9, 4, 20]), at([3, 4, 5])]);
        // ...and a removed block's centres go with it.
        layer.remove_block(VoxelIndex([-9, 4, 20]).split().0);
        assert_eq!(layer.surface_centres(), [at([3, 4, 5])]);
    }

    #[test]
    fn block_bounds_follow_blocks_added_and_removed() {
        let mut layer = Layer::new(0.04);
        assert_eq!(layer.block_bounds(), None);
        let edge = layer.block_size_m();
        layer.block_mut_or_insert(BlockIndex([0, 0, 0]));
        assert_eq!(
            layer.block_bounds(),
            Some((Point3::origin(), Point3::new(edge, edge, edge)))
        );
        layer.block_mut_or_insert(BlockIndex([-2, 1, 0]));
        assert_eq!(
            layer.block_bounds(),
            Some((
                Point3::new(-2.0 * edge, 0.0, 0.0),
                Point3::new(edge, 2.0 * edge, edge)
            ))
        );
        layer.remove_block(BlockIndex([0, 0, 0]));
        assert_eq!(
            layer.block_bounds(),
            Some((
                Point3::new(-2.0 * edge, edge, 0.0),
                Point3::new(-edge, 2.0 * edge, edge)
            ))
        );
        layer.remove_block(BlockIndex([-2, 1, 0]));
        assert_eq!(layer.block_bounds(), None);
    }

    #[test]
    fn behind_offsets_bound_exactly_the_voxels_behind_surfaces() {
        for seed in 0..50u32 {
            let mut block = Block::default();
            // A pseudo-random handful of voxels behind a surface, among
            // observed free ones and unobserved ones with negative values.
            let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                state
            };
            let count = 1 + next() % 6;
            block.update(|voxels| {
                for voxel in voxels.iter_mut() {
                    *voxel = match next() % 3 {
                        0 => Voxel {
                            sdf: 0.05,
                            weight: 1.0,
                        },
                        1 => Voxel {
                            sdf: -0.05,
                            weight: 0.0,
                        },
                        _ => Voxel::default(),
                    };
                }
                for _ in 0..count {
                    voxels[next() as usize % BLOCK_VOXELS] = Voxel {
                        sdf: -0.01,
                        weight: 2.0,
                    };
                }
                BLOCK_VOXELS
            });
            let behind: Vec<[i32; 3]> = (0..BLOCK_VOXELS)
                .filter(|&o| block.voxels()[o].weight > 0.0 && block.voxels()[o].sdf <= 0.0)
                .map(|o| VoxelIndex::join(BlockIndex([0, 0, 0]), o).0)
                .collect();
            let lo = [0, 1, 2].map(|a| behind.iter().map(|v| v[a]).min().unwrap());
            let hi = [0, 1, 2].map(|a| behind.iter().map(|v| v[a]).max().unwrap());
            assert_eq!(block.behind_offsets(), Some([lo, hi]), "seed {seed}");
        }
        assert_eq!(Block::default().behind_offsets(), None);
    }

    #[test]
    fn fast_floor_matches_floor() {
        for x in [
            -2.5f32, -2.0, -1e-7, -0.0, 0.0, 0.3, 1.0, 7.999, -7.999, 123456.7,
        ] {
            assert_eq!(floor_to_i32(x), x.floor() as i32, "{x}");
        }
        assert_eq!(floor_to_i32(f32::NAN), 0);
    }
}
