//! The first convolution of each image encoder, the one that reads the
//! observation: its mostly-zero planes added pixel by pixel, the rest as
//! GEMMs ([`Conv`]).
//!
//! Why: most of the state's planes are 0 / 1 masks that are nearly all
//! zeros (where the agent has been, the objects tried with success or
//! failure, in the map grids and in the image), and the first layer (an
//! 8 × 8 kernel with stride 4 over 128 × 128 planes) is most of the pass's
//! arithmetic. A GEMM pays for every zero; added from its nonzero pixels, a
//! plane costs what it holds: each such pixel reaches at most
//! `⌈k / s⌉²` outputs (4 here), and adds its weights for every output
//! channel to each, 16 values in a row.

use std::cell::RefCell;

use burn::nn::conv::Conv2d;

use super::strided_conv::Conv;
use super::ObservationValue;
use crate::kernels::values;

/// By default a plane goes pixel by pixel when fewer than this share of
/// its values are nonzero: short of where the two ways cross (about 0.25
/// at 128 px in the `cpu_policy` bench's sweep,
/// docs/notebook/2026-12-01-policy-sparse-planes.md), since a plane's GEMM
/// costs the same whatever it holds and the pixels' way grows with them.
pub const SPARSE_PLANES_BELOW: f32 = 0.2;

/// The first layer of an image encoder.
#[derive(Debug, Clone)]
pub(super) struct InputConv {
    conv: Conv,
    /// burn's weights as `[input][ky][kx][output]`: what one input pixel
    /// adds to the outputs at one kernel offset, in a row.
    by_pixel: Vec<f32>,
    /// Planes with fewer nonzero values than this share go pixel by pixel
    /// (0: every plane through the GEMM).
    sparse_below: f32,
}

impl InputConv {
    pub(super) fn from_layer(layer: &Conv2d) -> Self {
        Self::new(Conv::from_layer(layer), &values(&layer.weight))
    }

    /// `conv`, whose weights in burn's `[output][input][ky][kx]` order are `weight`.
    fn new(conv: Conv, weight: &[f32]) -> Self {
        let [inputs, outputs, k, _] = conv.shape();
        let mut by_pixel = vec![0.0; inputs * k * k * outputs];
        for o in 0..outputs {
            for c in 0..inputs {
                for kk in 0..k * k {
                    by_pixel[(c * k * k + kk) * outputs + o] =
                        weight[(o * inputs + c) * k * k + kk];
                }
            }
        }
        Self {
            conv,
            by_pixel,
            sparse_below: SPARSE_PLANES_BELOW,
        }
    }

    /// The same layer, adding planes with fewer than `share` of their
    /// values nonzero pixel by pixel.
    pub(super) fn with_sparse_below(self, share: f32) -> Self {
        Self {
            sparse_below: share,
            ..self
        }
    }

    /// `[inputs][size][size]` → (`[outputs][out][out]`, `out`), as
    /// [`Conv::forward`] gives it.
    pub(super) fn forward<T: ObservationValue>(&self, x: &[T], size: usize) -> (Vec<f32>, usize) {
        let [inputs, outputs, k, s] = self.conv.shape();
        let planes: Vec<&[T]> = x.chunks_exact(size * size).take(inputs).collect();
        let limit = self.sparse_below * (size * size) as f32;
        let sparse: Vec<bool> = (planes.iter())
            .map(|p| (count_nonzero(p) as f32) < limit)
            .collect();
        if !sparse.contains(&true) {
            return self.conv.forward(x, size);
        }
        let geometry = Geometry::new(size, k, s);
        ADDED.with_borrow_mut(|added| {
            added.clear();
            added.resize(geometry.out * geometry.out * outputs, 0.0);
            for (c, plane) in planes.iter().enumerate().filter(|&(c, _)| sparse[c]) {
                let weights = &self.by_pixel[c * k * k * outputs..][..k * k * outputs];
                add_plane(plane, weights, &geometry, outputs, added);
            }
            let dense: Vec<usize> = (0..inputs).filter(|&c| !sparse[c]).collect();
            let dense_planes: Vec<&[T]> = dense.iter().map(|&c| planes[c]).collect();
            self.conv
                .forward_planes(&dense_planes, &dense, size, Some(added))
        })
    }
}

thread_local! {
    /// Each thread's sums of the sparse planes (`[out][out][outputs]`),
    /// kept from pass to pass as [`Conv`]'s buffers are.
    static ADDED: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
}

/// A valid convolution's sides, with the outputs each input coordinate reaches.
struct Geometry {
    size: usize,
    k: usize,
    s: usize,
    out: usize,
    /// For each input coordinate (row or column), the output coordinates
    /// whose kernel covers it.
    reached: Vec<std::ops::Range<usize>>,
}

impl Geometry {
    /// Input side `size`, kernel `k`, stride `s`.
    fn new(size: usize, k: usize, s: usize) -> Self {
        let out = (size - k) / s + 1;
        let reached = (0..size)
            .map(|i| {
                let first = (i + 1).saturating_sub(k).div_ceil(s);
                let last = (i / s).min(out - 1);
                first..(last + 1).max(first)
            })
            .collect();
        Self {
            size,
            k,
            s,
            out,
            reached,
        }
    }
}

/// Adds every nonzero pixel of `plane` times its `weights`
/// (`[ky][kx][output]`) to the outputs it reaches, into `added`
/// (`[out][out][outputs]`): with AVX2 where the processor has it (a row of
/// 16 sums is two vectors, where the build's baseline has four).
fn add_plane<T: ObservationValue>(
    plane: &[T],
    weights: &[f32],
    geometry: &Geometry,
    outputs: usize,
    added: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2.
        unsafe { add_plane_avx2(plane, weights, geometry, outputs, added) };
        return;
    }
    add_plane_here(plane, weights, geometry, outputs, added);
}

/// [`add_plane`] compiled for AVX2.
///
/// # Safety
/// The processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn add_plane_avx2<T: ObservationValue>(
    plane: &[T],
    weights: &[f32],
    geometry: &Geometry,
    outputs: usize,
    added: &mut [f32],
) {
    add_plane_here(plane, weights, geometry, outputs, added);
}

/// [`add_plane`]'s work, compiled into its caller's instruction set.
#[inline(always)]
fn add_plane_here<T: ObservationValue>(
    plane: &[T],
    weights: &[f32],
    geometry: &Geometry,
    outputs: usize,
    added: &mut [f32],
) {
    let Geometry {
        size,
        k,
        s,
        out,
        ref reached,
    } = *geometry;
    for (y, row) in plane.chunks_exact(size).enumerate() {
        let rows = reached[y].clone();
        if rows.is_empty() {
            continue;
        }
        // Most pieces of a sparse row are all zeros: each piece's nonzero
        // values are found from a bit mask in a few vector instructions,
        // not with a branch per value.
        for (piece, values) in row.chunks(PIECE).enumerate() {
            let mut nonzero = nonzero_mask(values);
            while nonzero != 0 {
                let i = nonzero.trailing_zeros() as usize;
                nonzero &= nonzero - 1;
                let (x, value) = (piece * PIECE + i, values[i].unit());
                for oy in rows.clone() {
                    let ky = y - s * oy;
                    let sums = &mut added[oy * out * outputs..][..out * outputs];
                    for ox in reached[x].clone() {
                        let kx = x - s * ox;
                        add_scaled(
                            &mut sums[ox * outputs..][..outputs],
                            &weights[(ky * k + kx) * outputs..][..outputs],
                            value,
                        );
                    }
                }
            }
        }
    }
}

/// Values of a row [`add_plane`] looks at at once (a mask's bits).
const PIECE: usize = 32;

/// Bit `i` set where `values[i]` (at most [`PIECE`] of them) is nonzero.
#[inline]
fn nonzero_mask<T: ObservationValue>(values: &[T]) -> u32 {
    (values.iter().enumerate()).fold(0, |mask, (i, v)| mask | (u32::from(!v.is_zero()) << i))
}

/// How many of `values` are nonzero, counted in pieces whose counts fit a
/// byte (so that the count vectorises in byte lanes).
fn count_nonzero<T: ObservationValue>(values: &[T]) -> usize {
    values
        .chunks(255)
        .map(|piece| {
            let count = piece.iter().fold(0u8, |n, v| n + u8::from(!v.is_zero()));
            usize::from(count)
        })
        .sum()
}

/// `sums += value · weights`. The policy's first layers have 16 outputs
/// (`layers::ENCODER_CONVS`): a row of 16 is one fixed-length loop the
/// compiler turns into vector instructions, where a loop of unknown length
/// stayed several times slower (`cpu_policy` bench).
#[inline(always)]
fn add_scaled(sums: &mut [f32], weights: &[f32], value: f32) {
    if let (Ok(sums), Ok(weights)) = (
        <&mut [f32; 16]>::try_from(&mut *sums),
        <&[f32; 16]>::try_from(weights),
    ) {
        for (sum, &w) in sums.iter_mut().zip(weights) {
            *sum += value * w;
        }
        return;
    }
    for (sum, &w) in sums.iter_mut().zip(weights) {
        *sum += value * w;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane of `size²` values, about `density` of them nonzero, some 1
    /// and some between.
    fn masks(planes: usize, size: usize, density: f32, seed: usize) -> Vec<f32> {
        (0..planes * size * size)
            .map(|i| {
                let h = (i * 2_654_435_761 + seed * 40_503) % 1_000_003;
                if (h as f32 / 1_000_003.0) < density {
                    [1.0, 0.5, 0.25][h % 3]
                } else {
                    0.0
                }
            })
            .collect()
    }

    #[test]
    fn sparse_planes_give_what_the_gemm_gives() {
        // The first layer at 128 and 64 px, a side the stride does not
        // divide, and a plane whose nonzero pixels sit on the last rows
        // and columns (which reach fewer outputs).
        for [outputs, inputs, k, s, size] in
            [[16, 10, 8, 4, 128], [16, 8, 8, 4, 64], [5, 3, 8, 4, 66]]
        {
            let weight: Vec<f32> = (0..outputs * inputs * k * k)
                .map(|i| ((i * 7919) % 211) as f32 / 211.0 - 0.45)
                .collect();
            let bias: Vec<f32> = (0..outputs).map(|o| o as f32 * 0.01 - 0.05).collect();
            let conv = Conv::from_weights(&weight, bias, [outputs, inputs, k], s);
            let layer = InputConv::new(conv.clone(), &weight);
            // Dense, sparse and empty planes, alternating.
            let mut x = Vec::new();
            for c in 0..inputs {
                let density = [0.9, 0.05, 0.0, 0.01][c % 4];
                x.extend(masks(1, size, density, c));
            }
            let edge = &mut x[size * size..2 * size * size];
            for i in 0..size {
                edge[(size - 1) * size + i] = 1.0;
                edge[i * size + size - 1] = 1.0;
            }
            let (expected, out) = conv.forward(&x, size);
            let (got, got_out) = layer.forward(&x, size);
            assert_eq!(got_out, out);
            for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
                assert!(
                    (g - e).abs() <= 1e-4 * (1.0 + e.abs()),
                    "side {size}: value {i}: {g} against {e}"
                );
            }
            let (dense_only, _) = layer.clone().with_sparse_below(0.0).forward(&x, size);
            assert_eq!(dense_only, expected, "the GEMM alone is the plain layer");
            assert!(expected.iter().filter(|&&v| v > 0.05).count() > expected.len() / 10);
        }
    }

    #[test]
    fn every_plane_sparse_or_empty() {
        let [outputs, inputs, k, s, size] = [4, 2, 8, 4, 32];
        let weight: Vec<f32> = (0..outputs * inputs * k * k)
            .map(|i| ((i * 31) % 17) as f32 / 17.0 - 0.3)
            .collect();
        let conv = Conv::from_weights(&weight, vec![0.1; outputs], [outputs, inputs, k], s);
        let layer = InputConv::new(conv.clone(), &weight);
        for density in [0.0, 0.02] {
            let x = masks(inputs, size, density, 7);
            let (expected, _) = conv.forward(&x, size);
            let (got, _) = layer.forward(&x, size);
            for (g, e) in got.iter().zip(&expected) {
                assert!((g - e).abs() <= 1e-5, "density {density}: {g} against {e}");
            }
        }
    }
}
