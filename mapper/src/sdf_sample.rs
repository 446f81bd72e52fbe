//! Reading a layer's signed distance at any point: trilinear between the
//! eight voxel centres around it, with its gradient, as rendering's rays
//! and tracking's ICP sample the map.

use nalgebra::{Point3, Vector3};

use crate::layer::{BlockIndex, CachedReader, Voxel, VoxelIndex, BLOCK_EDGE, BLOCK_VOXELS};

/// What a ray learns at one point of a layer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Sample {
    /// The SDF there ([`sdf_at`]).
    Known(f32),
    /// The voxel there was never observed, in an allocated block.
    Unobserved,
    /// The point's block is not allocated.
    Unallocated(BlockIndex),
}

/// Known SDF at `p`: trilinear between the eight surrounding voxel centres
/// when all are observed (sub-voxel silhouettes), else the nearest voxel's;
/// `None` if unobserved.
pub(crate) fn sdf_at(reader: &mut CachedReader<'_>, p: &Point3<f32>) -> Option<f32> {
    match sample(reader, p) {
        Sample::Known(sdf) => Some(sdf),
        Sample::Unobserved | Sample::Unallocated(_) => None,
    }
}

/// The trilinear SDF at `p` and its gradient (per metre) inside the cell
/// of the eight voxel centres around `p`; `None` unless all eight were
/// observed. One stencil for both: a central difference would read six
/// more.
pub(crate) fn sdf_with_gradient(
    reader: &mut CachedReader<'_>,
    p: &Point3<f32>,
) -> Option<(f32, Vector3<f32>)> {
    let s = reader.layer().voxel_size_m;
    let q = p.coords * (1.0 / s);
    let g = [q.x - 0.5, q.y - 0.5, q.z - 0.5];
    let base = g.map(crate::layer::floor_to_i32);
    let f = [0, 1, 2].map(|a| g[a] - base[a] as f32);
    let (block_index, first) = VoxelIndex(base).split();
    let mut v = [0.0f32; 8];
    if base
        .iter()
        .all(|&i| i.rem_euclid(BLOCK_EDGE) < BLOCK_EDGE - 1)
    {
        let voxels = reader.block(block_index)?.voxels();
        let edge = BLOCK_EDGE as usize;
        for (corner, sdf) in v.iter_mut().enumerate() {
            let o = first + (corner & 1) + edge * ((corner >> 1) & 1) + edge * edge * (corner >> 2);
            let voxel = voxels[o];
            if voxel.weight <= 0.0 {
                return None;
            }
            *sdf = voxel.sdf;
        }
    } else {
        for (corner, sdf) in v.iter_mut().enumerate() {
            let index = VoxelIndex([0, 1, 2].map(|a| base[a] + ((corner >> a) & 1) as i32));
            *sdf = reader.observed_sdf(index)?;
        }
    }
    // Along x between the corner pairs, then y, then z.
    let [fx, fy, fz] = f;
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let x00 = lerp(v[0], v[1], fx);
    let x10 = lerp(v[2], v[3], fx);
    let x01 = lerp(v[4], v[5], fx);
    let x11 = lerp(v[6], v[7], fx);
    let y0 = lerp(x00, x10, fy);
    let y1 = lerp(x01, x11, fy);
    let value = lerp(y0, y1, fz);
    let dx = lerp(
        lerp(v[1] - v[0], v[3] - v[2], fy),
        lerp(v[5] - v[4], v[7] - v[6], fy),
        fz,
    );
    let dy = lerp(x10 - x00, x11 - x01, fz);
    let dz = y1 - y0;
    Some((value, Vector3::new(dx, dy, dz) * (1.0 / s)))
}

/// [`sdf_at`], also telling an unobserved voxel from an unallocated block
/// (which a ray may leap) from the one voxel lookup.
pub(crate) fn sample(reader: &mut CachedReader<'_>, p: &Point3<f32>) -> Sample {
    let layer = reader.layer();
    // In voxel units; a multiplication, as a division here would sit on
    // every ray's chain of dependent steps.
    let s = layer.voxel_size_m;
    let q = p.coords * (1.0 / s);
    let (block_index, offset) = VoxelIndex(q.map(crate::layer::floor_to_i32).into()).split();
    let Some(block) = reader.block(block_index) else {
        return Sample::Unallocated(block_index);
    };
    let voxel = block.voxels()[offset];
    if voxel.weight <= 0.0 {
        return Sample::Unobserved;
    }
    let nearest = voxel.sdf;
    let g = [q.x - 0.5, q.y - 0.5, q.z - 0.5];
    let base = g.map(crate::layer::floor_to_i32);
    let f = [0, 1, 2].map(|a| g[a] - base[a] as f32);
    let weight = |corner: usize| -> f32 {
        (0..3)
            .map(|a| {
                if (corner >> a) & 1 == 1 {
                    f[a]
                } else {
                    1.0 - f[a]
                }
            })
            .product()
    };
    let (stencil_block, first) = VoxelIndex(base).split();
    // The nearest voxel is one of the stencil's corners, so a stencil inside
    // one block lies in the block already read.
    let interior = stencil_block == block_index
        && base
            .iter()
            .all(|&i| i.rem_euclid(BLOCK_EDGE) < BLOCK_EDGE - 1);
    if interior {
        // The whole stencil lies in one block: index it directly.
        return Sample::Known(trilinear_in_block(block.voxels(), first, f).unwrap_or(nearest));
    }
    let mut sum = 0.0;
    for corner in 0..8 {
        let index = VoxelIndex([0, 1, 2].map(|a| base[a] + ((corner >> a) & 1) as i32));
        let Some(sdf) = reader.observed_sdf(index) else {
            return Sample::Known(nearest);
        };
        sum += weight(corner) * sdf;
    }
    Sample::Known(sum)
}

/// Trilinear interpolation of the 2 × 2 × 2 voxels of one block from offset
/// `first` (all inside the block) at fractions `f`; `None` if one of them is
/// unobserved. Four loads of two neighbouring voxels each, in SSE2 (every
/// x86-64 has it): a ray's samples near a surface spend most of their time
/// here.
#[cfg(target_arch = "x86_64")]
#[inline]
fn trilinear_in_block(voxels: &[Voxel; BLOCK_VOXELS], first: usize, f: [f32; 3]) -> Option<f32> {
    use std::arch::x86_64::*;
    let edge = BLOCK_EDGE as usize;
    // The stencil's eight voxels, as four pairs along x.
    let stencil = &voxels[first..first + edge * edge + edge + 2];
    let pair = |o: usize| {
        let pair: &[Voxel; 2] = stencil[o..o + 2].try_into().expect("two voxels");
        // SAFETY: `Voxel` is `repr(C)` of two f32, so a pair is four f32;
        // SSE2 is part of x86-64.
        unsafe { _mm_loadu_ps(pair.as_ptr() as *const f32) }
    };
    let (y0z0, y1z0) = (pair(0), pair(edge));
    let (y0z1, y1z1) = (pair(edge * edge), pair(edge * edge + edge));
    // SAFETY: SSE2 is part of x86-64.
    unsafe {
        // Distances and weights of corners (x, y) = 00, 10, 01, 11.
        let near_sdf = _mm_shuffle_ps::<0x88>(y0z0, y1z0);
        let near_weight = _mm_shuffle_ps::<0xDD>(y0z0, y1z0);
        let far_sdf = _mm_shuffle_ps::<0x88>(y0z1, y1z1);
        let far_weight = _mm_shuffle_ps::<0xDD>(y0z1, y1z1);
        let zero = _mm_setzero_ps();
        let observed = _mm_and_ps(
            _mm_cmpgt_ps(near_weight, zero),
            _mm_cmpgt_ps(far_weight, zero),
        );
        if _mm_movemask_ps(observed) != 0b1111 {
            return None;
        }
        let [fx, fy, fz] = f;
        let xy = _mm_mul_ps(
            _mm_setr_ps(1.0 - fx, fx, 1.0 - fx, fx),
            _mm_setr_ps(1.0 - fy, 1.0 - fy, fy, fy),
        );
        let sum = _mm_add_ps(
            _mm_mul_ps(_mm_mul_ps(xy, _mm_set1_ps(1.0 - fz)), near_sdf),
            _mm_mul_ps(_mm_mul_ps(xy, _mm_set1_ps(fz)), far_sdf),
        );
        let halves = _mm_add_ps(sum, _mm_movehl_ps(sum, sum));
        Some(_mm_cvtss_f32(_mm_add_ss(
            halves,
            _mm_shuffle_ps::<0x55>(halves, halves),
        )))
    }
}

/// [`trilinear_in_block`] one voxel at a time, where SSE2 may be missing.
#[cfg(not(target_arch = "x86_64"))]
#[inline]
fn trilinear_in_block(voxels: &[Voxel; BLOCK_VOXELS], first: usize, f: [f32; 3]) -> Option<f32> {
    let edge = BLOCK_EDGE as usize;
    let mut sum = 0.0;
    for corner in 0..8 {
        let o = first + (corner & 1) + edge * ((corner >> 1) & 1) + edge * edge * (corner >> 2);
        let v = voxels[o];
        if v.weight <= 0.0 {
            return None;
        }
        let along = |a: usize| {
            if (corner >> a) & 1 == 1 {
                f[a]
            } else {
                1.0 - f[a]
            }
        };
        sum += along(0) * along(1) * along(2) * v.sdf;
    }
    Some(sum)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::layer::Layer;

    /// A ball's TSDF (centre, radius) in blocks reaching well beyond it:
    /// unobserved deep inside and, on one side, in front beyond the band;
    /// with `gaps`, also at scattered voxels through the band (the
    /// nearest-voxel fallback).
    pub(crate) fn ball_layer(centre: Point3<f32>, radius: f32, gaps: bool) -> Layer {
        let reach = Vector3::repeat(radius + 0.48);
        sampled_layer(centre - reach, centre + reach, |v, p| {
            let d = (p - centre).norm() - radius;
            let gap = gaps && v.0.iter().sum::<i32>().rem_euclid(7) == 0;
            // Free space behind the ball (x beyond its centre) unobserved.
            (!(d > 0.12 && p.x > centre.x || gap)).then_some(d)
        })
    }

    /// A layer of 4-cm voxels over the blocks of the box `[lo, hi]`, each
    /// voxel observed with the distance `sdf(voxel, centre)` gives
    /// (`None`: unobserved), truncated at 12 cm; voxels deeper than that
    /// behind the surface are left unobserved, as integration leaves them.
    pub(crate) fn sampled_layer(
        lo: Point3<f32>,
        hi: Point3<f32>,
        sdf: impl Fn(VoxelIndex, Point3<f32>) -> Option<f32>,
    ) -> Layer {
        let (s, trunc) = (0.04f32, 0.12f32);
        let mut layer = Layer::new(s);
        let first = lo.map(|c| (c / (8.0 * s)).floor() as i32);
        let last = hi.map(|c| (c / (8.0 * s)).floor() as i32);
        for bx in first.x..=last.x {
            for by in first.y..=last.y {
                for bz in first.z..=last.z {
                    let block_index = BlockIndex([bx, by, bz]);
                    layer.block_mut_or_insert(block_index).update(|voxels| {
                        for (o, voxel) in voxels.iter_mut().enumerate() {
                            let v = VoxelIndex::join(block_index, o);
                            let p = Point3::from(v.0.map(|i| (i as f32 + 0.5) * s));
                            match sdf(v, p) {
                                Some(d) if d >= -trunc => {
                                    *voxel = Voxel {
                                        sdf: d.min(trunc),
                                        weight: 1.0,
                                    }
                                }
                                _ => {}
                            }
                        }
                        BLOCK_VOXELS
                    });
                }
            }
        }
        layer
    }

    /// Trilinear interpolation written the plain way: eight lookups through the hash map.
    fn reference_sdf(layer: &Layer, p: &Point3<f32>) -> Option<f32> {
        let observed = |v: VoxelIndex| layer.voxel(v).filter(|x| x.weight > 0.0).map(|x| x.sdf);
        let nearest = observed(layer.voxel_of(p))?;
        let s = layer.voxel_size_m;
        let g = [p.x / s - 0.5, p.y / s - 0.5, p.z / s - 0.5];
        let base = g.map(|c| c.floor());
        let mut sum = 0.0;
        for corner in 0..8usize {
            let offset = [0, 1, 2].map(|a| (corner >> a) & 1);
            let index = VoxelIndex([0, 1, 2].map(|a| base[a] as i32 + offset[a] as i32));
            let Some(sdf) = observed(index) else {
                return Some(nearest);
            };
            let w: f32 = (0..3)
                .map(|a| {
                    let f = g[a] - base[a];
                    if offset[a] == 1 {
                        f
                    } else {
                        1.0 - f
                    }
                })
                .product();
            sum += w * sdf;
        }
        Some(sum)
    }

    /// A linear SDF in voxel units (slopes 0.3, −0.2, 0.1 per voxel) over
    /// two neighbouring blocks and a third, below, with every third voxel
    /// unobserved.
    fn plane_layer(voxel_size_m: f32) -> Layer {
        let mut layer = Layer::new(voxel_size_m);
        for b in [[0, 0, 0], [1, 0, 0], [0, -1, 0]] {
            let block_index = crate::layer::BlockIndex(b);
            layer.block_mut_or_insert(block_index).update(|voxels| {
                for (o, voxel) in voxels.iter_mut().enumerate() {
                    if b == [0, -1, 0] && o % 3 == 0 {
                        continue;
                    }
                    let v = VoxelIndex::join(block_index, o);
                    voxel.weight = 1.0;
                    voxel.sdf = 0.3 * v.0[0] as f32 - 0.2 * v.0[1] as f32 + 0.1 * v.0[2] as f32;
                }
                crate::layer::BLOCK_VOXELS
            });
        }
        layer
    }

    /// 4 000 scattered points over [`plane_layer`]'s blocks (at 4 cm voxels)
    /// and a little beyond them.
    fn probe_points() -> impl Iterator<Item = Point3<f32>> {
        (0..4000).map(|i| {
            let t = i as f32 * 0.618_034;
            Point3::new(
                (t * 1.7).fract() * 0.64 - 0.02,
                (t * 2.3).fract() * 0.64 - 0.33,
                (t * 3.1).fract() * 0.34 - 0.01,
            )
        })
    }

    #[test]
    fn cached_trilinear_lookup_matches_plain_lookup_across_block_borders() {
        // Unobserved voxels force the nearest-voxel fallback.
        let layer = plane_layer(0.04);
        let mut reader = CachedReader::new(&layer);
        let mut checked = 0;
        for p in probe_points() {
            let fast = sdf_at(&mut reader, &p);
            let plain = reference_sdf(&layer, &p);
            match (fast, plain) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 1e-5, "{p:?}: {a} vs {b}");
                    checked += 1;
                }
                (a, b) => assert_eq!(a, b, "{p:?}"),
            }
        }
        assert!(checked > 2000, "only {checked} observed samples");
    }

    #[test]
    fn the_gradient_is_the_trilinear_cells_own_and_needs_all_eight_voxels() {
        // Trilinear interpolation reproduces a linear SDF, gradient and all.
        let s = 0.04;
        let layer = plane_layer(s);
        let slope = Vector3::new(0.3, -0.2, 0.1) / s;
        let all_observed = |p: &Point3<f32>| {
            let base = [p.x, p.y, p.z].map(|c| (c / s - 0.5).floor() as i32);
            (0..8).all(|corner: i32| {
                let v = VoxelIndex([0, 1, 2].map(|a| base[a] + ((corner >> a) & 1)));
                layer.voxel(v).is_some_and(|x| x.weight > 0.0)
            })
        };
        let mut reader = CachedReader::new(&layer);
        let (mut known, mut unknown) = (0, 0);
        for p in probe_points() {
            match sdf_with_gradient(&mut reader, &p) {
                Some((value, gradient)) => {
                    assert!(
                        all_observed(&p),
                        "{p:?}: a value from an incomplete stencil"
                    );
                    let plain = reference_sdf(&layer, &p).expect("observed");
                    assert!((value - plain).abs() < 1e-5, "{p:?}: {value} vs {plain}");
                    assert!(
                        (gradient - slope).norm() < 1e-3 * slope.norm(),
                        "{p:?}: {gradient:?}"
                    );
                    known += 1;
                }
                None => {
                    assert!(!all_observed(&p), "{p:?}: no value from a full stencil");
                    unknown += 1;
                }
            }
        }
        assert!(
            known > 1000 && unknown > 100,
            "{known} known, {unknown} not"
        );
    }

    #[test]
    fn the_gradient_of_a_curved_sdf_matches_finite_differences_inside_a_cell() {
        let centre = Point3::new(0.31, -0.12, 0.47);
        let layer = ball_layer(centre, 0.2, false);
        let s = layer.voxel_size_m;
        let mut reader = CachedReader::new(&layer);
        let h = 1e-3 * s;
        let mut checked = 0;
        for i in 0..2000 {
            let t = i as f32 * 0.618_034;
            let direction = Vector3::new(
                (t * 1.7).fract() - 0.5,
                (t * 2.3).fract() - 0.5,
                (t * 3.1).fract() - 0.5,
            )
            .normalize();
            let p = centre + direction * (0.2 + ((t * 5.3).fract() - 0.5) * 0.06);
            let Some((_, gradient)) = sdf_with_gradient(&mut reader, &p) else {
                continue;
            };
            // Central differences that stay inside p's cell.
            let g = [p.x, p.y, p.z].map(|c| c / s - 0.5);
            if g.iter()
                .any(|c| (c - c.floor()) < 0.01 || (c - c.floor()) > 0.99)
            {
                continue;
            }
            let mut numeric = Vector3::zeros();
            for a in 0..3 {
                let mut e = Vector3::zeros();
                e[a] = h;
                let hi = reference_sdf(&layer, &(p + e)).expect("observed");
                let lo = reference_sdf(&layer, &(p - e)).expect("observed");
                numeric[a] = (hi - lo) / (2.0 * h);
            }
            assert!(
                (gradient - numeric).norm() < 0.02 * numeric.norm().max(0.1),
                "{p:?}: {gradient:?} vs {numeric:?}"
            );
            checked += 1;
        }
        assert!(checked > 500, "only {checked} points checked");
    }
}
