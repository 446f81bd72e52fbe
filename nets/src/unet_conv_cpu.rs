//! The U-Net's 3 × 3 convolutions, with their ReLU or (before a batch
//! normalisation) without, as one differentiable operation on burn's CPU
//! backend, for training.
//!
//! Why it exists: burn's CPU backend turns every convolution of a training
//! step into copies. Its forward pass and its weight gradient each build an
//! im2col matrix nine times the input's size (the weight gradient as a
//! convolution whose kernel is the whole output gradient), and a profile of
//! a U-Net training step (batch 8 at 128 px) put a third of the time in
//! those copies against 43 % in matrix products. Here, on zero-bordered
//! channels-first planes (the layout of `kernels`):
//! - the forward pass is the inference path's convolution (`kernels::Conv3x3`)
//!   (Winograd, or nine shifted products over odd sides), ReLU included;
//! - the input gradient is the same convolution with each kernel flipped and
//!   inputs and outputs swapped, over the output gradient masked by the ReLU;
//! - the weight gradient is taken in Winograd's domain over even sides (16
//!   matrix products per block of tiles, whose summed products are mapped
//!   back to the 3 × 3 kernels), and over odd sides as nine matrix products
//!   per image, one per kernel tap, each over a shifted view of the padded
//!   input.
//!
//! The images of a batch run in parallel on rayon's threads.
//! Tensors elsewhere (the GPU) take burn's own `Conv2d` and ReLU. (The
//! matrix-product form the policy encoders train with on a GPU, padded, with
//! nine taps per image, made the U-Net's training step slower there;
//! docs/notebook/2026-11-26-gpu-learner.md.)

use std::borrow::Cow;
use std::sync::Arc;

use burn::backend::{Autodiff, Flex};
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::activation::relu;
use burn::tensor::{DType, TensorData};
use burn_autodiff::checkpoint::base::Checkpointer;
use burn_autodiff::checkpoint::strategy::NoCheckpointing;
use burn_autodiff::grads::Gradients;
use burn_autodiff::ops::{Backward, Ops, OpsKind};
use burn_flex::FlexTensor;
use rayon::prelude::*;

use crate::kernels::{
    fill, fill_padded, grow, plane_len, transform_input_block, wide_len, winograd_blocks, Conv3x3,
    TileBuffers,
};

/// The autodiff backend a training step's tensors live on when on the CPU.
type Tracked = Autodiff<Flex>;

/// What follows a convolution inside the operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Activation {
    /// ReLU: the U-Net's convolutions without normalisation.
    Relu,
    /// Nothing: the convolution's values go on to a batch normalisation,
    /// whose output the ReLU then follows.
    Identity,
}

impl Activation {
    /// The kernels' floor: every output is `max(value, floor)`.
    fn floor(self) -> f32 {
        match self {
            Self::Relu => 0.0,
            Self::Identity => f32::NEG_INFINITY,
        }
    }

    /// Whether the output gradient passes where the output is `output`.
    fn passes(self, output: f32) -> bool {
        self == Self::Identity || output > 0.0
    }
}

/// `activation(layer(x))` for a 3 × 3, same-padded, stride-1 convolution
/// with a bias (as the U-Net's `DoubleConv` builds them): on the CPU through
/// the operation above, anywhere else through burn.
pub(crate) fn conv3x3(layer: &Conv2d, x: Tensor<4>, activation: Activation) -> Tensor<4> {
    if let Some(bias) = &layer.bias {
        let (weight, bias) = (layer.weight.val(), bias.val());
        if let Some(out) = tracked_on_cpu(&x, &weight, &bias, activation) {
            return out;
        }
        if let Some(out) = untracked_on_cpu(&x, &weight, &bias, activation) {
            return out;
        }
    }
    let out = layer.forward(x);
    match activation {
        Activation::Relu => relu(out),
        Activation::Identity => out,
    }
}

/// Sizes of one call: images, channels in and out, image sides.
#[derive(Clone, Copy, Debug)]
struct Sizes {
    batch: usize,
    inputs: usize,
    outputs: usize,
    h: usize,
    w: usize,
}

impl Sizes {
    /// From `x` `[batch, inputs, h, w]`, `weight` `[outputs, inputs, 3, 3]`
    /// and `bias` `[outputs]`, all f32; `None` for anything else.
    fn of(x: &FlexTensor, weight: &FlexTensor, bias: &FlexTensor) -> Option<Self> {
        let (x_dims, w_dims) = (x.layout().shape(), weight.layout().shape());
        let ([batch, inputs, h, w], [outputs, weight_inputs, 3, 3]) =
            (x_dims.dims::<4>(), w_dims.dims::<4>())
        else {
            return None;
        };
        let f32_only = [x, weight, bias].iter().all(|t| t.dtype() == DType::F32);
        let fits = inputs == weight_inputs && bias.layout().num_elements() == outputs;
        (f32_only && fits && batch * h * w > 0).then_some(Self {
            batch,
            inputs,
            outputs,
            h,
            w,
        })
    }
}

/// The tracked path: `None` when the tensors are not all on the CPU
/// backend with autodiff.
fn tracked_on_cpu(
    x: &Tensor<4>,
    weight: &Tensor<4>,
    bias: &Tensor<1>,
    activation: Activation,
) -> Option<Tensor<4>> {
    let x = x.clone().try_into_primitive::<Tracked>().ok()?;
    let weight = weight.clone().try_into_primitive::<Tracked>().ok()?;
    let bias = bias.clone().try_into_primitive::<Tracked>().ok()?;
    let sizes = Sizes::of(x.primitive(), weight.primitive(), bias.primitive())?;
    let nodes = [x.node(), weight.node(), bias.node()];
    let weight = contiguous(weight.primitive());
    let bias = contiguous(bias.primitive());
    let (out, padded) = forward(
        &contiguous(x.primitive()),
        &weight,
        &bias,
        sizes,
        activation,
    );
    let output = to_tensor(out, [sizes.batch, sizes.outputs, sizes.h, sizes.w]);
    let out = match ConvActivation
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let state = ConvActivationState {
                sizes,
                activation,
                padded_input: Arc::new(padded),
                weight: Arc::new(weight.into_owned()),
                output: output.clone(),
            };
            prep.finish(state, output)
        }
        OpsKind::UnTracked(prep) => prep.finish(output),
    };
    Some(Tensor::from_primitive::<Tracked>(out))
}

/// The path without autodiff (validation, a network without gradients).
fn untracked_on_cpu(
    x: &Tensor<4>,
    weight: &Tensor<4>,
    bias: &Tensor<1>,
    activation: Activation,
) -> Option<Tensor<4>> {
    let x = x.clone().try_into_primitive::<Flex>().ok()?;
    let weight = weight.clone().try_into_primitive::<Flex>().ok()?;
    let bias = bias.clone().try_into_primitive::<Flex>().ok()?;
    let sizes = Sizes::of(&x, &weight, &bias)?;
    let (out, _) = forward(
        &contiguous(&x),
        &contiguous(&weight),
        &contiguous(&bias),
        sizes,
        activation,
    );
    let out = to_tensor(out, [sizes.batch, sizes.outputs, sizes.h, sizes.w]);
    Some(Tensor::from_primitive::<Flex>(out))
}

/// A tensor's values in row-major order (copied only when its layout is not).
fn contiguous(tensor: &FlexTensor) -> Cow<'_, [f32]> {
    match tensor.as_slice::<f32>() {
        Some(values) => Cow::Borrowed(values),
        None => Cow::Owned(
            tensor
                .to_contiguous()
                .as_slice::<f32>()
                .expect("a contiguous tensor of f32, as `Sizes::of` checked")
                .to_vec(),
        ),
    }
}

fn to_tensor<const D: usize>(values: Vec<f32>, shape: [usize; D]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

/// `activation(conv(x) + bias)` as `[batch, outputs, h, w]`, and the input
/// in padded planes `[batch][inputs]` (the weight gradient reads it).
fn forward(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    s: Sizes,
    activation: Activation,
) -> (Vec<f32>, Vec<f32>) {
    let conv = Conv3x3::from_weights(
        weight,
        (s.outputs, s.inputs),
        bias.to_vec(),
        activation.floor(),
    );
    let plane = plane_len(s.h, s.w);
    let mut padded = vec![0.0; s.batch * s.inputs * plane];
    let mut out = vec![0.0; s.batch * s.outputs * s.h * s.w];
    padded
        .par_chunks_exact_mut(s.inputs * plane)
        .zip(x.par_chunks_exact(s.inputs * s.h * s.w))
        .zip(out.par_chunks_exact_mut(s.outputs * s.h * s.w))
        .for_each_init(
            || (vec![0.0; s.outputs * plane], TileBuffers::default()),
            |(planes, tiles), ((padded, image), out)| {
                fill_padded(padded, image, s.h, s.w);
                conv.forward(padded, planes, (s.h, s.w), tiles);
                copy_interiors(planes, out, s.h, s.w);
            },
        );
    (out, padded)
}

/// Copies the interiors of padded planes into a channels-first image.
fn copy_interiors(planes: &[f32], image: &mut [f32], h: usize, w: usize) {
    let row = w + 2;
    for (plane, channel) in planes
        .chunks_exact(plane_len(h, w))
        .zip(image.chunks_exact_mut(h * w))
    {
        for (y, line) in channel.chunks_exact_mut(w).enumerate() {
            let start = (y + 1) * row + 1;
            line.copy_from_slice(&plane[start..start + w]);
        }
    }
}

/// The backward step of [`conv3x3`]'s CPU operation.
#[derive(Debug)]
struct ConvActivation;

/// What the backward step needs of the forward pass.
#[derive(Clone, Debug)]
struct ConvActivationState {
    sizes: Sizes,
    activation: Activation,
    padded_input: Arc<Vec<f32>>,
    /// `[outputs][inputs][3][3]`.
    weight: Arc<Vec<f32>>,
    /// The output after the activation (after ReLU, its zeros pass no
    /// gradient).
    output: FlexTensor,
}

impl Backward<Flex, 3> for ConvActivation {
    type State = ConvActivationState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_weight, node_bias] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let grad = contiguous(&grad);
        let state = ops.state;
        let s = state.sizes;
        let (masked, bias_grad) =
            masked_gradient(&grad, &contiguous(&state.output), s, state.activation);
        if let Some(node) = node_weight {
            let weight_grad = weight_gradient(&masked, &state.padded_input, s);
            grads.register::<Flex>(node.id, to_tensor(weight_grad, [s.outputs, s.inputs, 3, 3]));
        }
        if let Some(node) = node_bias {
            grads.register::<Flex>(node.id, to_tensor(bias_grad, [s.outputs]));
        }
        if let Some(node) = node_x {
            let input_grad = input_gradient(&masked, &state.weight, s);
            grads.register::<Flex>(
                node.id,
                to_tensor(input_grad, [s.batch, s.inputs, s.h, s.w]),
            );
        }
    }
}

/// The output gradient where the activation passed its value (zero
/// elsewhere), in padded planes `[batch][outputs]`, and its sum per output
/// (the bias's gradient).
fn masked_gradient(
    grad: &[f32],
    output: &[f32],
    s: Sizes,
    activation: Activation,
) -> (Vec<f32>, Vec<f32>) {
    let (row, plane) = (s.w + 2, plane_len(s.h, s.w));
    let mut masked = vec![0.0; s.batch * s.outputs * plane];
    let mut sums = vec![0.0f64; s.outputs];
    for (index, ((plane, grad), output)) in masked
        .chunks_exact_mut(plane)
        .zip(grad.chunks_exact(s.h * s.w))
        .zip(output.chunks_exact(s.h * s.w))
        .enumerate()
    {
        let mut sum = 0.0f32;
        for (y, (grad, output)) in grad
            .chunks_exact(s.w)
            .zip(output.chunks_exact(s.w))
            .enumerate()
        {
            let line = &mut plane[(y + 1) * row + 1..][..s.w];
            for ((to, &g), &out) in line.iter_mut().zip(grad).zip(output) {
                *to = if activation.passes(out) { g } else { 0.0 };
                sum += *to;
            }
        }
        sums[index % s.outputs] += f64::from(sum);
    }
    (masked, sums.into_iter().map(|sum| sum as f32).collect())
}

/// `∂L/∂W[o][i][tap] = Σ_images Σ_pixels masked[o][p] · input[i][p + shift(tap)]`,
/// as `[outputs][inputs][3][3]`. Over even sides in Winograd's domain (16
/// products per 2 × 2 tile instead of 36), otherwise per kernel tap.
fn weight_gradient(masked: &[f32], padded: &[f32], s: Sizes) -> Vec<f32> {
    let winograd = s.h.is_multiple_of(2) && s.w.is_multiple_of(2);
    let len = if winograd { 16 } else { 9 } * s.outputs * s.inputs;
    let sum = masked
        .par_chunks_exact(s.outputs * plane_len(s.h, s.w))
        .zip(padded.par_chunks_exact(s.inputs * plane_len(s.h, s.w)))
        .fold(
            || (vec![0.0; len], TileBuffers::default()),
            |(mut grad, mut tiles), (masked, padded)| {
                if winograd {
                    add_image_winograd_gradient(&mut grad, &mut tiles, masked, padded, s);
                } else {
                    add_image_weight_gradient(&mut grad, masked, padded, s);
                }
                (grad, tiles)
            },
        )
        .map(|(grad, _)| grad)
        .reduce_with(|mut total, part| {
            total.iter_mut().zip(&part).for_each(|(t, p)| *t += p);
            total
        })
        .unwrap_or_else(|| vec![0.0; len]);
    if winograd {
        from_winograd_domain(&sum, s)
    } else {
        sum
    }
}

/// Adds one image's share of the weight gradient in Winograd's domain,
/// `∂L/∂U[e][o][i]` for `U = G g Gᵀ`: the forward pass computes
/// `Y = Aᵀ (Σ_i U_oi ⊙ V_i) A` per tile with `V = Bᵀ d B`, so each tile
/// adds `(A ∂Y Aᵀ) ⊙ V`, summed over tiles as 16 products.
fn add_image_winograd_gradient(
    grad: &mut [f32],
    tiles: &mut TileBuffers,
    masked: &[f32],
    padded: &[f32],
    s: Sizes,
) {
    let (inputs, outputs) = (s.inputs, s.outputs);
    let (row, plane) = (s.w + 2, plane_len(s.h, s.w));
    let tiles_per_row = s.w / 2;
    for (first_row, block_rows) in winograd_blocks((s.h, s.w), inputs.max(outputs)) {
        let n = transform_input_block(padded, (s.h, s.w), (first_row, block_rows), tiles);
        grow(&mut tiles.products, 16 * outputs * n);
        for (o, channel) in masked.chunks_exact(plane).enumerate() {
            for r in 0..block_rows {
                let top = (2 * (first_row + r) + 1) * row + 1;
                let j = r * tiles_per_row;
                winograd_gradient_row(
                    &channel[top..top + row + s.w],
                    row,
                    &mut tiles.across,
                    |element| (element * outputs + o) * n + j,
                    &mut tiles.products,
                );
            }
        }
        // ∂U[e] += (A ∂Y Aᵀ)[e] · V[e]ᵀ over the block's tiles.
        for element in 0..16 {
            add_product(
                (&mut grad[element * outputs * inputs..], [1, inputs]),
                (&tiles.products[element * outputs * n..], [1, n]),
                (&tiles.transformed[element * inputs * n..], [n, 1]),
                (outputs, inputs, n),
            );
        }
    }
}

/// `A ∂Y Aᵀ` of every 2 × 2 gradient tile of one row of tiles, with
/// `A = [1 0; 1 1; 1 −1; 0 −1]`: `rows` starts at the tiles' first pixel and
/// holds their two rows, `row` apart; element `e` (row-major in 4 × 4) of
/// tile `t` goes to `products[start(e) + t]`. `across` is scratch of 8
/// values per tile.
fn winograd_gradient_row(
    rows: &[f32],
    row: usize,
    across: &mut [f32],
    start: impl Fn(usize) -> usize,
    products: &mut [f32],
) {
    let tiles = (row - 2) / 2;
    let (top, bottom) = (&rows[..2 * tiles], &rows[row..row + 2 * tiles]);
    // A down each tile's two columns: left[r][t] and right[r][t].
    let (left, right) = across[..8 * tiles].split_at_mut(4 * tiles);
    for (column, parts) in [left, right].into_iter().enumerate() {
        let (first, rest) = parts.split_at_mut(tiles);
        let (second, rest) = rest.split_at_mut(tiles);
        let (third, fourth) = rest.split_at_mut(tiles);
        let pairs = top.chunks_exact(2).zip(bottom.chunks_exact(2));
        for ((((upper, lower), p0), p1), (p2, p3)) in pairs
            .zip(first.iter_mut())
            .zip(second.iter_mut())
            .zip(third.iter_mut().zip(fourth.iter_mut()))
        {
            let (a, b) = (upper[column], lower[column]);
            (*p0, *p1, *p2, *p3) = (a, a + b, a - b, -b);
        }
    }
    // Then along each of the four rows: [a, b] → [a, a + b, a − b, −b].
    let (left, right) = across[..8 * tiles].split_at(4 * tiles);
    for r in 0..4 {
        let (a, b) = (&left[r * tiles..][..tiles], &right[r * tiles..][..tiles]);
        fill(&mut products[start(4 * r)..][..tiles], a, b, |p, _| p);
        fill(&mut products[start(4 * r + 1)..][..tiles], a, b, |p, q| {
            p + q
        });
        fill(&mut products[start(4 * r + 2)..][..tiles], a, b, |p, q| {
            p - q
        });
        fill(&mut products[start(4 * r + 3)..][..tiles], a, b, |_, q| -q);
    }
}

/// `∂L/∂g = Gᵀ (∂L/∂U) G` for every kernel: `[16][outputs][inputs]` in
/// Winograd's domain → `[outputs][inputs][3][3]`.
fn from_winograd_domain(grad: &[f32], s: Sizes) -> Vec<f32> {
    // Gᵀ u for a 4-vector u, with G = [1 0 0; ½ ½ ½; ½ −½ ½; 0 0 1].
    let g_t = |u: [f32; 4]| {
        let (sum, difference) = ((u[1] + u[2]) / 2.0, (u[1] - u[2]) / 2.0);
        [u[0] + sum, difference, sum + u[3]]
    };
    let pairs = s.outputs * s.inputs;
    let mut kernels = vec![0.0; 9 * pairs];
    for (pair, kernel) in kernels.chunks_exact_mut(9).enumerate() {
        let u = |r: usize, k: usize| grad[(4 * r + k) * pairs + pair];
        // Gᵀ down each of the four columns, then along each of the three rows.
        let columns: Vec<[f32; 3]> = (0..4)
            .map(|k| g_t([u(0, k), u(1, k), u(2, k), u(3, k)]))
            .collect();
        for (r, line) in kernel.chunks_exact_mut(3).enumerate() {
            let along = g_t([columns[0][r], columns[1][r], columns[2][r], columns[3][r]]);
            line.copy_from_slice(&along);
        }
    }
    kernels
}

/// Adds one image's share of [`weight_gradient`] to `grad`, one product per
/// kernel tap: the masked gradient's wide rows by the shifted padded input,
/// read transposed in place.
fn add_image_weight_gradient(grad: &mut [f32], masked: &[f32], padded: &[f32], s: Sizes) {
    let (row, plane, wide) = (s.w + 2, plane_len(s.h, s.w), wide_len(s.h, s.w));
    let start = row + 1;
    for tap in 0..9 {
        let shift = (tap / 3) * row + tap % 3;
        add_product(
            (&mut grad[tap..], [9, 9 * s.inputs]),
            (&masked[start..], [1, plane]),
            (&padded[shift..], [plane, 1]),
            (s.outputs, s.inputs, wide),
        );
    }
}

/// `dst[i][j] += Σ_k lhs[i][k] · rhs[k][j]` for `i < m`, `j < n`, `k < k`,
/// each matrix a slice with its `[column, row]` strides.
///
/// # Panics
/// If a matrix's last element lies outside its slice.
fn add_product(
    (dst, [dst_column, dst_row]): (&mut [f32], [usize; 2]),
    (lhs, [lhs_column, lhs_row]): (&[f32], [usize; 2]),
    (rhs, [rhs_column, rhs_row]): (&[f32], [usize; 2]),
    (m, n, k): (usize, usize, usize),
) {
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    let last = |rows: usize, columns: usize, column: usize, row: usize| {
        (rows - 1) * row + (columns - 1) * column
    };
    assert!(
        last(m, n, dst_column, dst_row) < dst.len()
            && last(m, k, lhs_column, lhs_row) < lhs.len()
            && last(k, n, rhs_column, rhs_row) < rhs.len(),
        "add_product: a matrix runs past its slice"
    );
    // SAFETY: the assert keeps the last (largest) element of each matrix,
    // hence every element gemm touches, inside its slice; `dst` is borrowed
    // mutably, so nothing aliases it.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            dst_column as isize,
            dst_row as isize,
            true,
            lhs.as_ptr(),
            lhs_column as isize,
            lhs_row as isize,
            rhs.as_ptr(),
            rhs_column as isize,
            rhs_row as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// `∂L/∂x`: the masked gradient through the convolution with kernels
/// flipped and inputs and outputs swapped, as `[batch, inputs, h, w]`.
fn input_gradient(masked: &[f32], weight: &[f32], s: Sizes) -> Vec<f32> {
    let mut flipped = vec![0.0; weight.len()];
    for o in 0..s.outputs {
        for i in 0..s.inputs {
            let from = &weight[(o * s.inputs + i) * 9..][..9];
            let to = &mut flipped[(i * s.outputs + o) * 9..][..9];
            for (tap, value) in to.iter_mut().enumerate() {
                *value = from[8 - tap];
            }
        }
    }
    let transposed = Conv3x3::from_weights(
        &flipped,
        (s.inputs, s.outputs),
        vec![0.0; s.inputs],
        f32::NEG_INFINITY,
    );
    let plane = plane_len(s.h, s.w);
    let mut grad = vec![0.0; s.batch * s.inputs * s.h * s.w];
    masked
        .par_chunks_exact(s.outputs * plane)
        .zip(grad.par_chunks_exact_mut(s.inputs * s.h * s.w))
        .for_each_init(
            || (vec![0.0; s.inputs * plane], TileBuffers::default()),
            |(planes, tiles), (masked, grad)| {
                transposed.forward(masked, planes, (s.h, s.w), tiles);
                copy_interiors(planes, grad, s.h, s.w);
            },
        );
    grad
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{assert_close, assert_same_values_and_gradients};
    use burn::nn::conv::Conv2dConfig;
    use burn::nn::PaddingConfig2d;
    use burn::tensor::Distribution;

    fn layer(inputs: usize, outputs: usize, device: &Device) -> Conv2d {
        Conv2dConfig::new([inputs, outputs], [3, 3])
            .with_padding(PaddingConfig2d::Same)
            .init(device)
    }

    /// Values and the gradients of input, weight and bias against burn's
    /// convolution and `activation`, for `batch` images of `inputs` channels.
    fn check(
        (batch, inputs, outputs): (usize, usize, usize),
        (h, w): (usize, usize),
        activation: Activation,
    ) {
        let device = Device::flex().autodiff();
        let conv = layer(inputs, outputs, &device);
        let input = Tensor::<4>::random([batch, inputs, h, w], Distribution::Default, &device)
            .sub_scalar(0.5);
        // A loss that weighs every output differently, so a shifted or
        // transposed output cannot give the same gradients; outputs whose
        // value before the ReLU lies within rounding of zero weigh nothing,
        // since the two paths' rounding may put them on either side of the
        // ReLU's kink (one run in a few dozen did: an input gradient 0.15
        // of 2.9 apart).
        let at_kink = conv.forward(input.clone().detach()).abs().lower_elem(1e-4);
        let weights = Tensor::<4>::random(
            [batch, outputs, h, w],
            Distribution::Normal(0.0, 1.0),
            &device,
        )
        .mask_fill(at_kink, 0.0);
        let x_ours = input.clone().detach().require_grad();
        let bias = conv.bias.as_ref().expect("bias");
        let ours = tracked_on_cpu(&x_ours, &conv.weight.val(), &bias.val(), activation)
            .expect("the CPU path");
        let x_burn = input.detach().require_grad();
        let burns = match activation {
            Activation::Relu => relu(conv.forward(x_burn.clone())),
            Activation::Identity => conv.forward(x_burn.clone()),
        };
        assert_same_values_and_gradients(
            (ours, &x_ours),
            (burns, &x_burn),
            weights,
            &[("the", &conv)],
            &format!("{batch} x {inputs} -> {outputs} at {h} x {w}, {activation:?}"),
        );
    }

    #[test]
    fn gives_the_values_and_gradients_of_burns_convolution_and_relu() {
        // Even sides (Winograd), odd sides (nine taps), a single pixel, and
        // the U-Net's first layer at a small size. The single pixel has 32
        // outputs so that the ReLU cuts some whatever the random weights (with
        // 6 it cut none in about one run in sixty).
        check((2, 3, 5), (8, 8), Activation::Relu);
        check((3, 6, 4), (5, 7), Activation::Relu);
        check((4, 2, 8), (1, 1), Activation::Relu);
        check((2, 4, 24), (16, 12), Activation::Relu);
    }

    #[test]
    fn without_its_relu_gives_the_values_and_gradients_of_burns_convolution() {
        // Negative outputs must come out negative and pass their gradient.
        check((2, 3, 5), (8, 8), Activation::Identity);
        check((3, 6, 4), (5, 7), Activation::Identity);
    }

    #[test]
    fn without_autodiff_gives_burns_values() {
        let device = Device::flex();
        let conv = layer(5, 7, &device);
        let input = Tensor::<4>::random([2, 5, 10, 6], Distribution::Default, &device);
        let bias = conv.bias.as_ref().expect("bias").val();
        assert_close(
            untracked_on_cpu(&input, &conv.weight.val(), &bias, Activation::Relu)
                .expect("the CPU path"),
            relu(conv.forward(input.clone())),
            "outputs",
        );
        assert_close(
            untracked_on_cpu(&input, &conv.weight.val(), &bias, Activation::Identity)
                .expect("the CPU path"),
            conv.forward(input),
            "outputs without ReLU",
        );
    }
}
