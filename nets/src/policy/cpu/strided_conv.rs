//! The strided convolutions of the policy's image encoders on the CPU,
//! computed as GEMMs over the input's stride phases ([`Conv`]).

use std::cell::RefCell;

use burn::nn::conv::Conv2d;

use super::ObservationValue;
use crate::kernels::{bias_values, matmul_lhs_rows, values};
use crate::layers::ENCODER_ACTIVATION;

/// A valid (unpadded), strided, square convolution followed by the
/// encoders' activation.
///
/// Computed without im2col columns: a `k × k` convolution with stride `s`
/// is a `t × t` convolution with stride 1 (`t = ⌈k / s⌉` taps a side) over
/// the input's stride phases ([`split_phases`]: `s²` planes per input
/// channel, `⌈size / s⌉` square), and each tap is one GEMM whose right-hand
/// side is the phase planes themselves, read from the tap's offset: output
/// row `oy` is computed `⌈size / s⌉` wide, so that output pixel
/// `oy · ⌈size / s⌉ + ox` reads phase pixel `(oy + ty) · ⌈size / s⌉ + ox +
/// tx` for every pixel at once. The columns past the output's side read the
/// next row and are dropped. Copying im2col columns (four times the input
/// for an 8 × 8 kernel with stride 4) took a quarter of a 128-px pass.
#[derive(Debug, Clone)]
pub(super) struct Conv {
    inputs: usize,
    outputs: usize,
    kernel: usize,
    stride: usize,
    /// One block per tap `(ty, tx)`, row-major `outputs × (inputs · s²)`:
    /// row `o`, column `(c, py, px)` holds burn's weight
    /// `[o][c][ty · s + py][tx · s + px]`, zero where that lies past the
    /// kernel (a 3 × 3 kernel with stride 2 fills 9 of 2 × 2 taps' 16).
    taps: Vec<f32>,
    bias: Vec<f32>,
}

impl Conv {
    pub(super) fn from_layer(layer: &Conv2d) -> Self {
        let [outputs, inputs, kernel, _] = layer.weight.val().dims();
        Self::from_weights(
            &values(&layer.weight),
            bias_values(&layer.bias, outputs),
            [outputs, inputs, kernel],
            layer.stride[0],
        )
    }

    /// From burn's `[output][input][ky][kx]` weights.
    pub(super) fn from_weights(
        weight: &[f32],
        bias: Vec<f32>,
        [outputs, inputs, kernel]: [usize; 3],
        stride: usize,
    ) -> Self {
        let (k, s) = (kernel, stride);
        let t = k.div_ceil(s);
        let depth = inputs * s * s;
        let mut taps = vec![0.0; t * t * outputs * depth];
        for o in 0..outputs {
            for c in 0..inputs {
                for ky in 0..k {
                    for kx in 0..k {
                        let tap = (ky / s) * t + kx / s;
                        let column = (c * s + ky % s) * s + kx % s;
                        taps[(tap * outputs + o) * depth + column] =
                            weight[((o * inputs + c) * k + ky) * k + kx];
                    }
                }
            }
        }
        Self {
            inputs,
            outputs,
            kernel,
            stride,
            taps,
            bias,
        }
    }

    /// Input planes, output planes, kernel side and stride.
    pub(super) fn shape(&self) -> [usize; 4] {
        [self.inputs, self.outputs, self.kernel, self.stride]
    }

    /// `[inputs][size][size]` → (`[outputs][out][out]`, `out`).
    pub(super) fn forward<T: ObservationValue>(&self, x: &[T], size: usize) -> (Vec<f32>, usize) {
        let planes: Vec<&[T]> = x.chunks_exact(size * size).take(self.inputs).collect();
        let every: Vec<usize> = (0..self.inputs).collect();
        self.forward_planes(&planes, &every, size, None)
    }

    /// The convolution of the input planes `planes`, the inputs numbered
    /// `channels` (in order; the others read as zeros), with `added`
    /// (channels last, `[out][out][outputs]`) added to its sums before
    /// the activation: (`[outputs][out][out]`, `out`).
    pub(super) fn forward_planes<T: ObservationValue>(
        &self,
        planes: &[&[T]],
        channels: &[usize],
        size: usize,
        added: Option<&[f32]>,
    ) -> (Vec<f32>, usize) {
        let (k, s) = (self.kernel, self.stride);
        let t = k.div_ceil(s);
        let out = (size - k) / s + 1;
        let phase = size.div_ceil(s);
        let wide = out * phase;
        let depth = channels.len() * s * s;
        let mut y = vec![0.0; self.outputs * out * out];
        SCRATCH.with_borrow_mut(|scratch| {
            let Scratch {
                wide_output,
                split,
                taps,
            } = scratch;
            let taps = if channels.len() == self.inputs {
                &self.taps
            } else {
                self.taps_of(channels, taps);
                &*taps
            };
            wide_output.resize(self.outputs * wide, 0.0);
            if channels.is_empty() {
                wide_output.fill(0.0);
            } else {
                // The last taps' dropped columns read up to (t − 1) · (phase + 1)
                // values past the last plane.
                split_phases(planes, size, s, (t - 1) * (phase + 1), split);
                // Output rows in bands whose phase rows stay in the cache while
                // every tap reads them.
                let band = (BAND_BYTES / (depth * phase * 4)).clamp(1, out);
                for first in (0..out).step_by(band) {
                    let columns = band.min(out - first) * phase;
                    for (tap, weights) in taps.chunks_exact(self.outputs * depth).enumerate() {
                        let (ty, tx) = (tap / t, tap % t);
                        matmul_lhs_rows(
                            &mut wide_output[first * phase..],
                            wide,
                            (weights, depth),
                            &split[(first + ty) * phase + tx..],
                            phase_plane_len(phase),
                            (self.outputs, columns, depth),
                            tap > 0,
                        );
                    }
                }
            }
            for (o, ((plane, wide), &bias)) in y
                .chunks_exact_mut(out * out)
                .zip(wide_output.chunks_exact(wide))
                .zip(&self.bias)
                .enumerate()
            {
                for (oy, (row, wide)) in plane
                    .chunks_exact_mut(out)
                    .zip(wide.chunks_exact(phase))
                    .enumerate()
                {
                    for (ox, (v, &w)) in row.iter_mut().zip(wide).enumerate() {
                        let extra = added.map_or(0.0, |a| a[(oy * out + ox) * self.outputs + o]);
                        *v = ENCODER_ACTIVATION.value(w + bias + extra);
                    }
                }
            }
        });
        (y, out)
    }

    /// [`Conv::taps`]' columns of the inputs `channels`, into `out`.
    fn taps_of(&self, channels: &[usize], out: &mut Vec<f32>) {
        let s2 = self.stride * self.stride;
        out.clear();
        for row in self.taps.chunks_exact(self.inputs * s2) {
            for &c in channels {
                out.extend_from_slice(&row[c * s2..(c + 1) * s2]);
            }
        }
    }
}

/// The most bytes of phase rows one band of [`Conv::forward`]'s output rows
/// reads: about what a core's L2 cache holds beside the weights and the
/// output, so that each tap after the first finds them there.
const BAND_BYTES: usize = 128 * 1024;

/// One thread's buffers for [`Conv::forward_planes`].
#[derive(Default)]
struct Scratch {
    /// The output rows computed `⌈size / s⌉` wide.
    wide_output: Vec<f32>,
    /// The input's stride phases ([`split_phases`]).
    split: Vec<f32>,
    /// The taps' columns of the inputs in use ([`Conv::taps_of`]).
    taps: Vec<f32>,
}

thread_local! {
    /// Each thread's [`Scratch`], kept from pass to pass: allocated anew on
    /// every pass (hundreds of kB) they cost page faults whenever the
    /// allocator had handed the memory back to the system, which made a
    /// 64-px pass more than twice as slow in one process as in another
    /// (`cpu_policy` bench; docs/performance.md).
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

/// Values from one phase plane to the next in [`split_phases`]' output: the
/// plane and 16 values (a cache line) more. A GEMM reads the planes as the
/// rows of its right-hand side, and at 128 px a plane of 32 × 32 values is
/// 4 KiB: rows a power of two apart fall into the same few cache sets and
/// evict each other.
fn phase_plane_len(phase: usize) -> usize {
    phase * phase + 16
}

/// The planes `x` (each `size × size`) split into their stride-`s` phases, into `out`:
/// `[plane][py][px][Y][X] = x[c][Y·s + py][X·s + px]`, each phase
/// `⌈size / s⌉` square and [`phase_plane_len`] values from the next, zeros
/// past the edge, between the planes and in `tail` values after the last.
fn split_phases<T: ObservationValue>(
    x: &[&[T]],
    size: usize,
    s: usize,
    tail: usize,
    out: &mut Vec<f32>,
) {
    let phase = size.div_ceil(s);
    let plane_len = phase_plane_len(phase);
    let len = x.len() * s * s * plane_len;
    out.resize(len + tail, 0.0);
    out[len..].fill(0.0);
    for plane in out[..len].chunks_exact_mut(plane_len) {
        plane[phase * phase..].fill(0.0);
    }
    let past_edge = vec![T::default(); size];
    for (c, input) in x.iter().enumerate() {
        for y in 0..phase * s {
            let line = input.get(y * size..(y + 1) * size).unwrap_or(&past_edge);
            // Phases (py, 0..s) of channel c lie one after another.
            let planes = &mut out[(c * s + y % s) * s * plane_len..][..s * plane_len];
            match s {
                2 => deinterleave::<2, T>(line, planes, phase, y / s),
                4 => deinterleave::<4, T>(line, planes, phase, y / s),
                _ => {
                    for (px, plane) in planes.chunks_exact_mut(plane_len).enumerate() {
                        let row = &mut plane[y / s * phase..][..phase];
                        let mut values = line.iter().skip(px).step_by(s);
                        for slot in row {
                            *slot = values.next().map_or(0.0, |v| v.unit());
                        }
                    }
                }
            }
        }
    }
}

/// Row `row` of each of the `S` planes of `planes` (each `phase` square,
/// [`phase_plane_len`] apart):
/// plane `px` takes `line[X · S + px]` at column `X`, zeros past the line's
/// end. With the stride a constant, the copy is one pass over the line in
/// vector registers; a strided gather per plane took a quarter of a 128-px
/// pass.
fn deinterleave<const S: usize, T: ObservationValue>(
    line: &[T],
    planes: &mut [f32],
    phase: usize,
    row: usize,
) {
    let mut planes = planes.chunks_exact_mut(phase_plane_len(phase));
    let mut rows: [&mut [f32]; S] =
        std::array::from_fn(|_| &mut planes.next().expect("S planes")[row * phase..][..phase]);
    let whole = line.len() / S;
    for (x, values) in line.chunks_exact(S).enumerate() {
        for (row, &value) in rows.iter_mut().zip(values) {
            row[x] = value.unit();
        }
    }
    for (px, row) in rows.iter_mut().enumerate() {
        for (x, slot) in row.iter_mut().enumerate().skip(whole) {
            *slot = line.get(x * S + px).map_or(0.0, |v| v.unit());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The convolution by its definition, one output value at a time.
    fn reference_conv(
        x: &[f32],
        weight: &[f32],
        bias: &[f32],
        [outputs, inputs, k, s, size]: [usize; 5],
    ) -> Vec<f32> {
        let out = (size - k) / s + 1;
        let mut y = Vec::with_capacity(outputs * out * out);
        for o in 0..outputs {
            for oy in 0..out {
                for ox in 0..out {
                    let mut sum = f64::from(bias[o]);
                    for c in 0..inputs {
                        for ky in 0..k {
                            for kx in 0..k {
                                let w = weight[((o * inputs + c) * k + ky) * k + kx];
                                let v = x[(c * size + oy * s + ky) * size + ox * s + kx];
                                sum += f64::from(w) * f64::from(v);
                            }
                        }
                    }
                    y.push(ENCODER_ACTIVATION.value(sum as f32));
                }
            }
        }
        y
    }

    #[test]
    fn convolutions_over_stride_phases_equal_the_definition() {
        // The policy's three layers at 128 px, sides that the stride does
        // not divide, and a stride of 1.
        for [outputs, inputs, k, s, size] in [
            [16, 10, 8, 4, 128],
            [32, 16, 4, 2, 31],
            [32, 32, 3, 2, 14],
            [5, 3, 8, 4, 66],
            [4, 2, 3, 2, 9],
            [3, 2, 3, 1, 7],
        ] {
            let pseudo = |i: usize, m: usize| ((i * 7919 + m) % 211) as f32 / 211.0 - 0.4;
            let weight: Vec<f32> = (0..outputs * inputs * k * k)
                .map(|i| pseudo(i, 1))
                .collect();
            let bias: Vec<f32> = (0..outputs).map(|i| pseudo(i, 5) * 0.1).collect();
            let x: Vec<f32> = (0..inputs * size * size).map(|i| pseudo(i, 3)).collect();
            let conv = Conv::from_weights(&weight, bias.clone(), [outputs, inputs, k], s);
            let (got, out) = conv.forward(&x, size);
            let expected = reference_conv(&x, &weight, &bias, [outputs, inputs, k, s, size]);
            assert_eq!(out, (size - k) / s + 1);
            assert_eq!(got.len(), expected.len());
            for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
                assert!(
                    (g - e).abs() <= 1e-4 * (1.0 + e.abs()),
                    "k {k}, s {s}, side {size}: value {i}: {g} against {e}"
                );
            }
            assert!(expected.iter().any(|&v| v > 0.1), "a test that can see");
        }
    }
}
