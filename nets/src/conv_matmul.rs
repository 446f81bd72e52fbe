//! The policy encoders' strided convolutions as one matrix product each.
//!
//! burn's CPU backend computes a convolution, and the gradient of its
//! weights, through a general im2col that re-indexes every element; in a PPO
//! update those two took most of the learner's training thread. Its GPU
//! backend (wgpu, no autotuning) runs a direct convolution whose weight
//! gradient gives each thread one weight and a loop over every output of the
//! batch: most of a PPO update's GPU time, many times PyTorch's (the
//! profiles are in docs/decisions/0006-cpu-kernels.md). A valid convolution with kernel
//! `k` and stride `s` is the same as cutting the input into `s × s` blocks
//! (space to depth) and convolving the blocks with a `⌈k/s⌉ × ⌈k/s⌉` kernel
//! at stride 1: one matrix product of the blocks with every tap, then a sum
//! of shifted slices. Its gradients are matrix products, copies and slices,
//! which every backend does well. On wgpu the product runs per image
//! ([`Product::PerImage`]): the weight gradient is then a batch of small
//! products, one per image, summed, instead of one product whose inner
//! dimension is every block of the batch, which wgpu's kernels cannot spread
//! over the GPU's cores. On libtorch the one product is best: cuBLAS splits
//! it, and burn's own convolution there computes its weight gradient as a
//! dilated convolution with the output gradient as kernel, which cuDNN runs
//! slowly (a 1 024-step PPO update at 128 px took three times as long;
//! docs/decisions/0010-libtorch-on-a-gpu.md).

use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::ops::PadMode;

/// How an input's axes are ordered.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Layout {
    /// `[batch, channels, height, width]`, as observations arrive.
    ChannelsFirst,
    /// `[batch, height, width, channels]`, as [`conv`] returns its output.
    ChannelsLast,
}

/// How the blocks meet the taps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Product {
    /// One product over every block of the batch (best on the CPU).
    Batch,
    /// One product per image, the weights broadcast (best on a GPU).
    PerImage,
}

impl Product {
    /// The better form on `device`: per image on wgpu, one product over
    /// the batch on the CPU and on libtorch (cuBLAS splits a long inner
    /// dimension; docs/decisions/0010-libtorch-on-a-gpu.md).
    pub(crate) fn for_device(device: &Device) -> Self {
        if crate::device::is_wgpu(&device.clone().inner()) {
            Self::PerImage
        } else {
            Self::Batch
        }
    }
}

/// `conv`'s valid convolution (square kernel and stride, no dilation or
/// groups, as the policy's encoders build them) of `x`, laid out
/// as `layout` says; the output is channels-last. Taking the first layer's
/// input channels first saves a copy of the largest input.
pub(crate) fn conv(x: Tensor<4>, layout: Layout, conv: &Conv2d, product: Product) -> Tensor<4> {
    let [out_channels, in_channels, kernel, _] = conv.weight.dims();
    let stride = conv.stride[0];
    let [batch, height, width, channels] = match (layout, x.dims()) {
        (Layout::ChannelsFirst, [n, c, h, w]) | (Layout::ChannelsLast, [n, h, w, c]) => {
            [n, h, w, c]
        }
    };
    debug_assert_eq!(channels, in_channels, "input channels");
    let out_h = (height - kernel) / stride + 1;
    let out_w = (width - kernel) / stride + 1;
    // The kernel in whole blocks: `taps × taps` blocks of `stride × stride`.
    let taps = kernel.div_ceil(stride);
    let padded_kernel = taps * stride;

    // Exactly the rows and columns the blocks cover: any the convolution
    // never reads are cut, and any a padded kernel reaches past the input
    // are zeros (they meet the kernel's zero padding).
    let rows = stride * (out_h + taps - 1);
    let cols = stride * (out_w + taps - 1);
    let (kept_rows, kept_cols) = (0..rows.min(height), 0..cols.min(width));
    let (pad_rows, pad_cols) = (
        (0, rows.saturating_sub(height)),
        (0, cols.saturating_sub(width)),
    );
    let padding = rows > height || cols > width;
    // Space to depth: element (n, by, bx, (a·s + b)·C + c) is input
    // (n, by·s + a, bx·s + b, c), whichever the input's layout.
    let (blocks_h, blocks_w) = (rows / stride, cols / stride);
    let block = stride * stride * channels;
    let blocks = match layout {
        Layout::ChannelsFirst => {
            let x = x.slice([0..batch, 0..channels, kept_rows, kept_cols]);
            let x = if padding {
                x.pad([pad_rows, pad_cols], PadMode::Constant(0.0))
            } else {
                x
            };
            x.reshape([batch, channels, blocks_h, stride, blocks_w, stride])
                .permute([0, 2, 4, 3, 5, 1])
        }
        Layout::ChannelsLast => {
            let x = x.slice([0..batch, kept_rows, kept_cols, 0..channels]);
            let x = if padding {
                x.pad([pad_rows, pad_cols, (0, 0)], PadMode::Constant(0.0))
            } else {
                x
            };
            x.reshape([batch, blocks_h, stride, blocks_w, stride, channels])
                .permute([0, 1, 3, 2, 4, 5])
        }
    }
    .reshape([batch * blocks_h * blocks_w, block]);

    // Every block times every tap (i, j) of the block kernel, in one product
    // whose columns are (i, j, output channel): as large as the input, where
    // gathering each output's taps first would copy the input taps² times.
    let weight = conv.weight.val();
    let weight = if padded_kernel > kernel {
        let extra = padded_kernel - kernel;
        weight.pad([(0, extra), (0, extra)], PadMode::Constant(0.0))
    } else {
        weight
    };
    let weight = weight
        .reshape([out_channels, in_channels, taps, stride, taps, stride])
        .permute([3, 5, 1, 2, 4, 0])
        .reshape([block, taps * taps * out_channels]);
    let columns = taps * taps * out_channels;
    let products = match product {
        Product::Batch => blocks.matmul(weight),
        Product::PerImage => blocks
            .reshape([batch, blocks_h * blocks_w, block])
            .matmul(weight.unsqueeze_dim::<3>(0))
            .reshape([batch * blocks_h * blocks_w, columns]),
    }
    .reshape([batch, blocks_h, blocks_w, columns]);
    // Output (y, x) sums tap (i, j) of block (y + i, x + j).
    let mut out = (0..taps)
        .flat_map(|i| (0..taps).map(move |j| (i, j)))
        .map(|(i, j)| {
            // One slice, not three narrows: each is a step of its own in
            // the backward pass, with a gradient as large as `products`.
            let first = (i * taps + j) * out_channels;
            products.clone().slice([
                0..batch,
                i..i + out_h,
                j..j + out_w,
                first..first + out_channels,
            ])
        })
        .reduce(|sum, tap| sum + tap)
        .expect("a kernel has at least one tap");
    if let Some(bias) = &conv.bias {
        out = out + bias.val().unsqueeze::<4>();
    }
    out.reshape([batch, out_h, out_w, out_channels])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::assert_close;
    use burn::nn::conv::Conv2dConfig;
    use burn::tensor::Distribution;

    /// Forward values and all three gradients (input, weight, bias) of the
    /// matrix-product form against burn's convolution, for one shape.
    fn check(channels: usize, out: usize, kernel: usize, stride: usize, h: usize, w: usize) {
        for layout in [Layout::ChannelsFirst, Layout::ChannelsLast] {
            for product in [Product::Batch, Product::PerImage] {
                check_layout(layout, product, channels, out, kernel, stride, h, w);
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn check_layout(
        layout: Layout,
        product: Product,
        channels: usize,
        out: usize,
        kernel: usize,
        stride: usize,
        h: usize,
        w: usize,
    ) {
        let device = Device::flex().autodiff();
        let conv = Conv2dConfig::new([channels, out], [kernel, kernel])
            .with_stride([stride, stride])
            .init(&device);
        let input =
            Tensor::<4>::random([3, channels, h, w], Distribution::Normal(0.0, 1.0), &device);
        // A loss that weighs every output differently, so a transposed or
        // shifted output cannot give the same gradients.
        let out_h = (h - kernel) / stride + 1;
        let out_w = (w - kernel) / stride + 1;
        let weights = Tensor::<4>::random(
            [3, out, out_h, out_w],
            Distribution::Normal(0.0, 1.0),
            &device,
        );

        let x_ours = input.clone().detach().require_grad();
        let ours = match layout {
            Layout::ChannelsFirst => super::conv(x_ours.clone(), layout, &conv, product),
            Layout::ChannelsLast => {
                super::conv(x_ours.clone().permute([0, 2, 3, 1]), layout, &conv, product)
            }
        }
        .permute([0, 3, 1, 2]);
        let ours_grads = (ours.clone() * weights.clone()).sum().backward();
        let x_burn = input.detach().require_grad();
        let burn = conv.forward(x_burn.clone());
        let burn_grads = (burn.clone() * weights).sum().backward();

        let shape =
            format!("({layout:?}, {product:?}, {channels}→{out}, k{kernel}/s{stride}, {h}×{w})");
        assert_close(ours, burn, &format!("outputs {shape}"));
        assert_close(
            x_ours.grad(&ours_grads).expect("gradient"),
            x_burn.grad(&burn_grads).expect("gradient"),
            &format!("input gradients {shape}"),
        );
        assert_close(
            conv.weight.grad(&ours_grads).expect("gradient"),
            conv.weight.grad(&burn_grads).expect("gradient"),
            &format!("weight gradients {shape}"),
        );
        let bias = conv.bias.as_ref().expect("bias");
        assert_close(
            bias.grad(&ours_grads).expect("gradient"),
            bias.grad(&burn_grads).expect("gradient"),
            &format!("bias gradients {shape}"),
        );
    }

    #[test]
    fn gives_the_values_and_gradients_of_burns_convolution() {
        // The encoder's three layers at 64 px, then at 128 px.
        check(4, 16, 8, 4, 64, 64);
        check(16, 32, 4, 2, 15, 15);
        check(32, 32, 3, 2, 6, 6);
        check(2, 16, 8, 4, 128, 128);
        check(32, 32, 3, 2, 14, 14);
        // Sizes the blocks do not divide, on either side; a kernel smaller
        // than its stride; stride 1.
        check(3, 5, 8, 4, 37, 50);
        check(3, 5, 3, 2, 9, 12);
        check(2, 4, 2, 3, 11, 10);
        check(2, 4, 3, 1, 7, 9);
    }
}
