//! The affordance U-Net's forward pass on the CPU, for inference only.
//!
//! Why it exists: an actor runs the U-Net on every frame, and on the CPU that
//! pass was most of a step. burn's CPU backend turns each 3 × 3 convolution
//! into a channels-last copy, an im2col copy and a GEMM, and a profile of the
//! 64-pixel U-Net put about as much time in those copies and in zeroing new
//! buffers as in the GEMM itself (docs/decisions/0006-cpu-kernels.md). Here:
//! - every activation lives in a zero-bordered channels-first buffer, so no
//!   convolution needs a padding copy;
//! - a 3 × 3 convolution over an even-sided image uses Winograd's
//!   F(2 × 2, 3 × 3) (16 products per 2 × 2 output tile and input channel
//!   instead of 36, as 16 GEMMs); over an odd-sided one (the deepest level
//!   of small images) it is nine GEMMs, one per kernel tap, each reading a
//!   shifted view of the same buffer;
//! - the encoder writes its skip outputs straight into the decoder's
//!   concatenation buffers, and buffers are kept between passes.
//!
//! The arithmetic is the network's own: [`CpuUnet::forward`] equals
//! [`AffordanceUnet::forward`] to float rounding (tested below). Training
//! stays with burn, which needs the gradients.
//!
//! The convolution kernels and the buffer layout live in `kernels`.

use std::sync::Mutex;

use crate::kernels::{
    bias_values, fill_padded, matmul, max_pool_2x2, plane_len, values, wide_len, Conv3x3,
    TileBuffers,
};
use crate::unet::{AffordanceUnet, DoubleConv, UpLevel};

/// The U-Net's weights, laid out for [`CpuUnet::forward`].
#[derive(Debug)]
pub struct CpuUnet {
    /// Two convolutions per encoder level.
    down: Vec<[Conv3x3; 2]>,
    /// Per decoder level, shallow to deep (index `l` upsamples level `l + 1`
    /// into level `l`).
    up: Vec<(UpConv, [Conv3x3; 2])>,
    head: Pointwise,
    /// Buffers of earlier passes, for reuse (one per concurrent caller).
    workspaces: Mutex<Vec<Workspace>>,
}

impl CpuUnet {
    /// Copies the weights of `net` (on any device).
    pub fn from_network(net: &AffordanceUnet) -> Self {
        let down: Vec<[Conv3x3; 2]> = net.down.iter().map(double_conv).collect();
        let mut up: Vec<(UpConv, [Conv3x3; 2])> = net
            .up
            .iter()
            .map(|level: &UpLevel| (UpConv::from_layer(&level.up), double_conv(&level.conv)))
            .collect();
        // burn's decoder runs deep to shallow; index ours by the level it fills.
        up.reverse();
        let head = Pointwise::from_layer(&net.head);
        Self {
            down,
            up,
            head,
            workspaces: Mutex::new(Vec::new()),
        }
    }

    /// Logits `[outputs, height, width]` for one image `[input_channels,
    /// height, width]` (both channels-first, row-major).
    ///
    /// # Panics
    /// If `height` or `width` is not a positive multiple of 8, or `input`
    /// is not `input_channels · height · width` long: the caller's frame
    /// size comes from a validated task.
    pub fn forward(&self, input: &[f32], height: usize, width: usize) -> Vec<f32> {
        let levels = self.down.len();
        let divisor = 1 << (levels - 1);
        assert!(
            height > 0
                && width > 0
                && height.is_multiple_of(divisor)
                && width.is_multiple_of(divisor),
            "U-Net input sides must be positive multiples of {divisor}, got {height} × {width}"
        );
        assert_eq!(
            input.len(),
            self.input_channels() * height * width,
            "U-Net input length"
        );
        let mut workspace = self.take_workspace(height, width);
        let logits = self.run(&mut workspace, input);
        self.workspaces
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .push(workspace);
        logits
    }

    /// Channels of the input image.
    fn input_channels(&self) -> usize {
        self.down[0][0].inputs
    }

    /// Channels out of encoder level `l` (0 = shallowest).
    fn channels(&self, l: usize) -> usize {
        self.down[l][1].outputs
    }

    fn take_workspace(&self, height: usize, width: usize) -> Workspace {
        let mut pool = self
            .workspaces
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        match pool.iter().position(|w| w.size == (height, width)) {
            Some(index) => pool.swap_remove(index),
            None => Workspace::new(self, height, width),
        }
    }

    fn run(&self, ws: &mut Workspace, input: &[f32]) -> Vec<f32> {
        let levels = self.down.len();
        let (height, width) = ws.size;
        let level_size = |l: usize| (height >> l, width >> l);
        fill_padded(&mut ws.inputs[0], input, height, width);
        // Encoder: level l reads inputs[l]; its output goes to the skip half
        // of concat[l] (or to `deepest`), then pooled into inputs[l + 1].
        for l in 0..levels {
            let (h, w) = level_size(l);
            let [first, second] = &self.down[l];
            first.forward(&ws.inputs[l], &mut ws.middle[l], (h, w), &mut ws.tiles);
            let output = if l + 1 < levels {
                let skip_start = self.channels(l) * plane_len(h, w);
                &mut ws.concat[l][skip_start..]
            } else {
                &mut ws.deepest[..]
            };
            second.forward(&ws.middle[l], output, (h, w), &mut ws.tiles);
            if l + 1 < levels {
                let skip_start = self.channels(l) * plane_len(h, w);
                max_pool_2x2(&ws.concat[l][skip_start..], &mut ws.inputs[l + 1], h, w);
            }
        }
        // Decoder: level l upsamples the level below into the first half of
        // concat[l], then convolves it into decoded[l].
        for l in (0..levels - 1).rev() {
            let (h, w) = level_size(l);
            let (upconv, [first, second]) = &self.up[l];
            let deeper = if l + 2 == levels {
                &ws.deepest
            } else {
                &ws.decoded[l + 1]
            };
            let up_len = self.channels(l) * plane_len(h, w);
            upconv.forward(
                deeper,
                &mut ws.concat[l][..up_len],
                &mut ws.scratch,
                h / 2,
                w / 2,
            );
            first.forward(&ws.concat[l], &mut ws.middle[l], (h, w), &mut ws.tiles);
            second.forward(&ws.middle[l], &mut ws.decoded[l], (h, w), &mut ws.tiles);
        }
        self.head
            .forward(&ws.decoded[0], &mut ws.scratch, height, width)
    }
}

fn double_conv(pair: &DoubleConv) -> [Conv3x3; 2] {
    [
        Conv3x3::from_layer(&pair.first),
        Conv3x3::from_layer(&pair.second),
    ]
}

/// A 2 × 2 transposed convolution with stride 2 (the decoder's upsampling).
#[derive(Debug)]
struct UpConv {
    inputs: usize,
    outputs: usize,
    /// `[tap][output][input]`, tap = 2 · row + column of the kernel.
    taps: Vec<f32>,
    bias: Vec<f32>,
}

impl UpConv {
    fn from_layer(layer: &burn::nn::conv::ConvTranspose2d) -> Self {
        let [inputs, outputs, kh, kw] = layer.weight.val().dims();
        debug_assert_eq!((kh, kw), (2, 2));
        let weight = values(&layer.weight);
        let mut taps = vec![0.0; 4 * outputs * inputs];
        for i in 0..inputs {
            for o in 0..outputs {
                for tap in 0..4 {
                    taps[(tap * outputs + o) * inputs + i] = weight[(i * outputs + o) * 4 + tap];
                }
            }
        }
        Self {
            inputs,
            outputs,
            taps,
            bias: bias_values(&layer.bias, outputs),
        }
    }

    /// Padded planes `[inputs]` of `h × w` → the interiors of padded planes
    /// `[outputs]` of `2h × 2w` (their borders are left as they are).
    fn forward(
        &self,
        source: &[f32],
        output: &mut [f32],
        scratch: &mut Vec<f32>,
        h: usize,
        w: usize,
    ) {
        let (row, plane, wide) = (w + 2, plane_len(h, w), wide_len(h, w));
        scratch.resize(4 * self.outputs * wide, 0.0);
        matmul(
            scratch,
            wide,
            &self.taps,
            &source[row + 1..],
            plane,
            (4 * self.outputs, wide, self.inputs),
            false,
        );
        let (out_row, out_plane) = (2 * w + 2, plane_len(2 * h, 2 * w));
        for (o, out) in output.chunks_exact_mut(out_plane).enumerate() {
            let bias = self.bias[o];
            for tap in 0..4 {
                let (dy, dx) = (tap / 2, tap % 2);
                let values = &scratch[(tap * self.outputs + o) * wide..][..wide];
                for y in 0..h {
                    let from = &values[y * row..][..w];
                    let to = &mut out[(2 * y + dy + 1) * out_row + dx + 1..][..2 * w];
                    for (x, &value) in from.iter().enumerate() {
                        to[2 * x] = value + bias;
                    }
                }
            }
        }
    }
}

/// The 1 × 1 output convolution.
#[derive(Debug)]
struct Pointwise {
    outputs: usize,
    inputs: usize,
    /// `[output][input]`.
    weight: Vec<f32>,
    bias: Vec<f32>,
}

impl Pointwise {
    fn from_layer(layer: &burn::nn::conv::Conv2d) -> Self {
        let [outputs, inputs, _, _] = layer.weight.val().dims();
        Self {
            outputs,
            inputs,
            weight: values(&layer.weight),
            bias: bias_values(&layer.bias, outputs),
        }
    }

    /// Padded planes `[inputs]` of `h × w` → compact logits `[outputs, h, w]`.
    fn forward(&self, source: &[f32], scratch: &mut Vec<f32>, h: usize, w: usize) -> Vec<f32> {
        let (row, wide) = (w + 2, wide_len(h, w));
        scratch.resize(self.outputs * wide, 0.0);
        matmul(
            scratch,
            wide,
            &self.weight,
            &source[row + 1..],
            plane_len(h, w),
            (self.outputs, wide, self.inputs),
            false,
        );
        let mut logits = Vec::with_capacity(self.outputs * h * w);
        for (o, values) in scratch.chunks(wide).take(self.outputs).enumerate() {
            for y in 0..h {
                logits.extend(values[y * row..][..w].iter().map(|v| v + self.bias[o]));
            }
        }
        logits
    }
}

/// The buffers of one pass at one image size.
#[derive(Debug)]
struct Workspace {
    size: (usize, usize),
    /// Per level, its input planes (level 0: the image; deeper: pooled).
    inputs: Vec<Vec<f32>>,
    /// Per level, between its two convolutions.
    middle: Vec<Vec<f32>>,
    /// Per level but the deepest: upsampled planes, then the encoder's skip.
    concat: Vec<Vec<f32>>,
    /// Per level but the deepest: the decoder's output.
    decoded: Vec<Vec<f32>>,
    /// The deepest level's output.
    deepest: Vec<f32>,
    /// Wide outputs of the upsampling and the head.
    scratch: Vec<f32>,
    /// Winograd's tiles.
    tiles: TileBuffers,
}

impl Workspace {
    fn new(net: &CpuUnet, height: usize, width: usize) -> Self {
        let levels = net.down.len();
        let plane = |l: usize| plane_len(height >> l, width >> l);
        let planes = |count: usize, l: usize| vec![0.0f32; count * plane(l)];
        Self {
            size: (height, width),
            inputs: (0..levels)
                .map(|l| {
                    let channels = if l == 0 {
                        net.input_channels()
                    } else {
                        net.channels(l - 1)
                    };
                    planes(channels, l)
                })
                .collect(),
            middle: (0..levels).map(|l| planes(net.channels(l), l)).collect(),
            concat: (0..levels - 1)
                .map(|l| planes(2 * net.channels(l), l))
                .collect(),
            decoded: (0..levels - 1)
                .map(|l| planes(net.channels(l), l))
                .collect(),
            deepest: planes(net.channels(levels - 1), levels - 1),
            scratch: Vec::new(),
            tiles: TileBuffers::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::largest_difference;
    use burn::prelude::*;
    use burn::tensor::Distribution;

    #[test]
    fn gives_what_burn_gives_at_every_size_the_actor_uses() {
        let device = Device::flex();
        let net = AffordanceUnet::new(4, 2, &device);
        let fast = CpuUnet::from_network(&net);
        for (h, w) in [(8, 8), (32, 32), (64, 64), (48, 80)] {
            let x = Tensor::<4>::random([1, 4, h, w], Distribution::Uniform(0.0, 3.0), &device);
            let input: Vec<f32> = x.clone().into_data().try_to_vec().unwrap();
            let expected: Vec<f32> = net.forward(x).into_data().try_to_vec().unwrap();
            // Twice: the second pass reuses the first one's buffers.
            for _ in 0..2 {
                let got = fast.forward(&input, h, w);
                let scale = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                assert!(scale > 0.01, "a fresh network gives logits up to {scale}");
                let diff = largest_difference(&got, &expected);
                // Measured: about 5e-8 for logits up to 0.17; a 1 % error
                // in one layer's bias gives 9e-5.
                assert!(
                    diff <= 1e-5 * scale,
                    "{h} × {w}: largest difference {diff} (logits up to {scale})"
                );
            }
        }
    }
}
