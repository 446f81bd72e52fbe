//! The affordance U-Net's forward pass on the CPU, for inference only.
//!
//! Why it exists: an actor runs the U-Net on every frame, and on the CPU that
//! pass was most of a step. burn's CPU backend turns each 3 × 3 convolution
//! into a channels-last copy, an im2col copy and a GEMM, and a profile of the
//! 64-pixel U-Net put 40 % of the time in those copies and 7 % in zeroing new
//! buffers, against 42 % in the GEMM itself. Here:
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
//! Layout: a "padded plane" of an `h × w` image is `(h + 2) × (w + 2)` floats
//! with a zero border; channels follow each other. The nine-tap convolution
//! computes a "wide" output of `h` rows of `w + 2` columns, whose two extra
//! columns land on the border and are zeroed again afterwards.

use std::sync::Mutex;

use burn::module::Param;
use burn::prelude::*;

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

/// Floats of one padded plane of an `h × w` image.
pub(crate) fn plane_len(h: usize, w: usize) -> usize {
    (h + 2) * (w + 2)
}

/// Columns of a wide output: `h` rows of `w + 2`, less the last row's two
/// border columns (so that every shifted read stays inside the plane).
pub(crate) fn wide_len(h: usize, w: usize) -> usize {
    h * (w + 2) - 2
}

/// Copies a channels-first image into the interiors of padded planes.
pub(crate) fn fill_padded(padded: &mut [f32], image: &[f32], h: usize, w: usize) {
    let row = w + 2;
    for (plane, channel) in padded
        .chunks_exact_mut(plane_len(h, w))
        .zip(image.chunks_exact(h * w))
    {
        for (y, line) in channel.chunks_exact(w).enumerate() {
            let start = (y + 1) * row + 1;
            plane[start..start + w].copy_from_slice(line);
        }
    }
}

/// 2 × 2 max pooling, stride 2, from padded planes of `h × w` into padded
/// planes of `h/2 × w/2`.
fn max_pool_2x2(source: &[f32], pooled: &mut [f32], h: usize, w: usize) {
    let (row, half_row) = (w + 2, w / 2 + 2);
    for (from, to) in source
        .chunks_exact(plane_len(h, w))
        .zip(pooled.chunks_exact_mut(plane_len(h / 2, w / 2)))
    {
        for y in 0..h / 2 {
            let top = &from[(2 * y + 1) * row + 1..][..w];
            let bottom = &from[(2 * y + 2) * row + 1..][..w];
            let out = &mut to[(y + 1) * half_row + 1..][..w / 2];
            for (x, value) in out.iter_mut().enumerate() {
                *value = top[2 * x]
                    .max(top[2 * x + 1])
                    .max(bottom[2 * x])
                    .max(bottom[2 * x + 1]);
            }
        }
    }
}

/// `dst[i][j] (+)= Σ_k lhs[i][k] · rhs[k][j]` for `i < m`, `j < n`, `k < k`:
/// `lhs` is row-major `m × k`; row `i` of `dst` starts at `i · dst_rows`,
/// row `k` of `rhs` at `k · rhs_rows`; columns are contiguous.
#[allow(clippy::too_many_arguments)]
pub(crate) fn matmul(
    dst: &mut [f32],
    dst_rows: usize,
    lhs: &[f32],
    rhs: &[f32],
    rhs_rows: usize,
    (m, n, k): (usize, usize, usize),
    accumulate: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(lhs.len() >= m * k, "matmul: lhs too short");
    assert!(
        dst.len() >= (m - 1) * dst_rows + n,
        "matmul: destination too short"
    );
    assert!(
        k == 0 || rhs.len() >= (k - 1) * rhs_rows + n,
        "matmul: rhs too short"
    );
    // SAFETY: the asserts above keep every element gemm touches
    // (dst[i · dst_rows + j], lhs[i · k + kk], rhs[kk · rhs_rows + j]) inside
    // its slice; `dst` is borrowed mutably, so nothing else aliases it.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            dst_rows as isize,
            accumulate,
            lhs.as_ptr(),
            1,
            k as isize,
            rhs.as_ptr(),
            1,
            rhs_rows as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// A same-padded 3 × 3 convolution followed by ReLU (or, with a floor of
/// −∞, by nothing: the training path's input gradient).
#[derive(Debug)]
pub(crate) struct Conv3x3 {
    pub(crate) inputs: usize,
    pub(crate) outputs: usize,
    /// `[tap][output][input]`, tap = 3 · row + column of the kernel.
    taps: Vec<f32>,
    /// The kernels in Winograd's domain, `[16][output][input]` (`G g Gᵀ`).
    winograd: Vec<f32>,
    bias: Vec<f32>,
    /// Each output is `max(value, floor)`: 0 for ReLU, −∞ for none.
    floor: f32,
}

impl Conv3x3 {
    fn from_layer(layer: &burn::nn::conv::Conv2d) -> Self {
        let [outputs, inputs, kh, kw] = layer.weight.val().dims();
        debug_assert_eq!((kh, kw), (3, 3));
        Self::from_weights(
            &values(&layer.weight),
            (outputs, inputs),
            bias_values(&layer.bias, outputs),
            0.0,
        )
    }

    /// From row-major weights `[outputs][inputs][3][3]` and one bias per
    /// output; `floor` as in the field.
    pub(crate) fn from_weights(
        weight: &[f32],
        (outputs, inputs): (usize, usize),
        bias: Vec<f32>,
        floor: f32,
    ) -> Self {
        assert_eq!(weight.len(), 9 * outputs * inputs, "3 × 3 weights");
        assert_eq!(bias.len(), outputs, "one bias per output");
        let mut taps = vec![0.0; 9 * outputs * inputs];
        let mut winograd = vec![0.0; 16 * outputs * inputs];
        for o in 0..outputs {
            for i in 0..inputs {
                let kernel = &weight[(o * inputs + i) * 9..][..9];
                for (tap, &value) in kernel.iter().enumerate() {
                    taps[(tap * outputs + o) * inputs + i] = value;
                }
                for (element, value) in winograd_kernel(kernel).into_iter().enumerate() {
                    winograd[(element * outputs + o) * inputs + i] = value;
                }
            }
        }
        Self {
            inputs,
            outputs,
            taps,
            winograd,
            bias,
            floor,
        }
    }

    /// Padded planes `[inputs]` of `h × w` → padded planes `[outputs]`.
    pub(crate) fn forward(
        &self,
        source: &[f32],
        output: &mut [f32],
        (h, w): (usize, usize),
        tiles: &mut TileBuffers,
    ) {
        if h.is_multiple_of(2) && w.is_multiple_of(2) {
            self.forward_winograd(source, output, (h, w), tiles);
        } else {
            self.forward_taps(source, output, (h, w));
        }
    }

    /// Nine GEMMs, one per kernel tap, over shifted views of the planes.
    fn forward_taps(&self, source: &[f32], output: &mut [f32], (h, w): (usize, usize)) {
        let (row, plane, wide) = (w + 2, plane_len(h, w), wide_len(h, w));
        let start = row + 1;
        for (o, out) in output.chunks_exact_mut(plane).enumerate() {
            out[start..start + wide].fill(self.bias[o]);
        }
        let tap_len = self.outputs * self.inputs;
        for (tap, weights) in self.taps.chunks_exact(tap_len).enumerate() {
            let shift = (tap / 3) * row + tap % 3;
            matmul(
                &mut output[start..],
                plane,
                weights,
                &source[shift..],
                plane,
                (self.outputs, wide, self.inputs),
                true,
            );
        }
        for out in output.chunks_exact_mut(plane) {
            for y in 1..=h {
                let line = &mut out[y * row..(y + 1) * row];
                line[0] = 0.0;
                line[row - 1] = 0.0;
                for value in &mut line[1..=w] {
                    *value = value.max(self.floor);
                }
            }
        }
    }

    /// Winograd's F(2 × 2, 3 × 3): each 2 × 2 output tile from a 4 × 4
    /// input tile with 16 products per input channel instead of 36, as 16
    /// GEMMs over blocks of whole tile rows (sized to stay in cache). The
    /// transforms run over a whole row of tiles at a time, so that their
    /// loops are plain slice arithmetic the compiler vectorises.
    fn forward_winograd(
        &self,
        source: &[f32],
        output: &mut [f32],
        (h, w): (usize, usize),
        tiles: &mut TileBuffers,
    ) {
        let (inputs, outputs) = (self.inputs, self.outputs);
        let (row, plane) = (w + 2, plane_len(h, w));
        let tiles_per_row = w / 2;
        for (first_row, block_rows) in winograd_blocks((h, w), inputs.max(outputs)) {
            let n = transform_input_block(source, (h, w), (first_row, block_rows), tiles);
            grow(&mut tiles.products, 16 * outputs * n);
            for element in 0..16 {
                matmul(
                    &mut tiles.products[element * outputs * n..],
                    n,
                    &self.winograd[element * outputs * inputs..],
                    &tiles.transformed[element * inputs * n..],
                    n,
                    (outputs, n, inputs),
                    false,
                );
            }
            for (o, out) in output.chunks_exact_mut(plane).enumerate() {
                for r in 0..block_rows {
                    let top = (2 * (first_row + r) + 1) * row + 1;
                    let j = r * tiles_per_row;
                    winograd_output_row(
                        &tiles.products,
                        |element| (element * outputs + o) * n + j,
                        &mut tiles.across,
                        (self.bias[o], self.floor),
                        &mut out[top..top + row + w],
                        row,
                    );
                }
            }
        }
    }
}

/// Floats of a block of Winograd tiles, per buffer (about 1 MB: the level-2
/// cache's size, so a block's transforms and products stay close).
const WINOGRAD_BLOCK_FLOATS: usize = 1 << 18;

/// The blocks of whole tile rows Winograd's F(2 × 2, 3 × 3) works through
/// over an even-sided `h × w` image, as (first tile row, tile rows), sized
/// for buffers of `16 · channels` floats per tile.
pub(crate) fn winograd_blocks(
    (h, w): (usize, usize),
    channels: usize,
) -> impl Iterator<Item = (usize, usize)> {
    let (tile_rows, tiles_per_row) = (h / 2, w / 2);
    let rows_per_block =
        (WINOGRAD_BLOCK_FLOATS / (16 * channels * tiles_per_row)).clamp(1, tile_rows);
    (0..tile_rows)
        .step_by(rows_per_block)
        .map(move |first_row| (first_row, rows_per_block.min(tile_rows - first_row)))
}

/// `Bᵀ d B` of every input tile of one block (see [`winograd_blocks`]) of
/// the padded planes `source`, into `tiles.transformed` as
/// `[16][channels][tiles of the block]`; returns the block's tile count.
pub(crate) fn transform_input_block(
    source: &[f32],
    (h, w): (usize, usize),
    (first_row, block_rows): (usize, usize),
    tiles: &mut TileBuffers,
) -> usize {
    let (row, plane) = (w + 2, plane_len(h, w));
    let tiles_per_row = w / 2;
    let channels = source.len() / plane;
    let n = block_rows * tiles_per_row;
    tiles.across.resize(18 * (tiles_per_row + 1), 0.0);
    grow(&mut tiles.transformed, 16 * channels * n);
    for (c, channel) in source.chunks_exact(plane).enumerate() {
        for r in 0..block_rows {
            let corner = 2 * (first_row + r) * row;
            let j = r * tiles_per_row;
            winograd_input_row(
                &channel[corner..corner + 4 * row],
                row,
                &mut tiles.across,
                |element| (element * channels + c) * n + j,
                &mut tiles.transformed,
            );
        }
    }
    n
}

/// The buffers of Winograd's tiles: transformed inputs `[16][inputs][tiles]`
/// and products `[16][outputs][tiles]` of one block, and one row of tiles
/// half transformed, `[16][tiles in a row]`.
#[derive(Debug, Default)]
pub(crate) struct TileBuffers {
    pub(crate) transformed: Vec<f32>,
    pub(crate) products: Vec<f32>,
    pub(crate) across: Vec<f32>,
}

/// Makes `buffer` at least `len` long (never shorter: shrinking and
/// growing again would zero it every time).
pub(crate) fn grow(buffer: &mut Vec<f32>, len: usize) {
    if buffer.len() < len {
        buffer.resize(len, 0.0);
    }
}

/// `G g Gᵀ` of a row-major 3 × 3 kernel `g`, row-major 4 × 4, with
/// `G = [1 0 0; ½ ½ ½; ½ −½ ½; 0 0 1]`.
fn winograd_kernel(g: &[f32]) -> [f32; 16] {
    let apply = |a: f32, b: f32, c: f32| [a, (a + b + c) / 2.0, (a - b + c) / 2.0, c];
    // G g: a 4 × 3 matrix, by columns.
    let columns: Vec<[f32; 4]> = (0..3).map(|k| apply(g[k], g[3 + k], g[6 + k])).collect();
    let mut u = [0.0; 16];
    for r in 0..4 {
        let row = apply(columns[0][r], columns[1][r], columns[2][r]);
        u[4 * r..4 * r + 4].copy_from_slice(&row);
    }
    u
}

/// `Bᵀ d B` of every 4 × 4 input tile of one row of tiles, with
/// `Bᵀ = [1 0 −1 0; 0 1 1 0; 0 −1 1 0; 0 1 0 −1]`. `rows` holds the four
/// padded rows the tiles cover (`row` floats each; tile `t` starts at column
/// `2t`); element `e` (row-major in 4 × 4) of tile `t` goes to
/// `transformed[start(e) + t]`. `across` is scratch of 18 values per tile.
fn winograd_input_row(
    rows: &[f32],
    row: usize,
    across: &mut [f32],
    start: impl Fn(usize) -> usize,
    transformed: &mut [f32],
) {
    let tiles = (row - 2) / 2;
    let (across, split) = across.split_at_mut(16 * tiles);
    let (even, odd) = split[..2 * (tiles + 1)].split_at_mut(tiles + 1);
    // Bᵀ applied along each of the four rows: across[4 r + k][t].
    for (r, parts) in across.chunks_exact_mut(4 * tiles).enumerate() {
        let x = &rows[r * row..(r + 1) * row];
        for ((pair, e), o) in x.chunks_exact(2).zip(even.iter_mut()).zip(odd.iter_mut()) {
            *e = pair[0];
            *o = pair[1];
        }
        let (a, rest) = parts.split_at_mut(tiles);
        let (b, rest) = rest.split_at_mut(tiles);
        let (c, d) = rest.split_at_mut(tiles);
        let columns = even
            .iter()
            .zip(odd.iter())
            .zip(even[1..].iter().zip(&odd[1..]));
        for (((((x0, x1), (x2, x3)), a), b), (c, d)) in columns
            .zip(a.iter_mut())
            .zip(b.iter_mut())
            .zip(c.iter_mut().zip(d.iter_mut()))
        {
            *a = x0 - x2;
            *b = x1 + x2;
            *c = x2 - x1;
            *d = x1 - x3;
        }
    }
    // Then down each column k.
    let across = &*across;
    for k in 0..4 {
        let part = |r: usize| &across[(4 * r + k) * tiles..][..tiles];
        let (d0, d1, d2, d3) = (part(0), part(1), part(2), part(3));
        fill(&mut transformed[start(k)..][..tiles], d0, d2, |p, q| p - q);
        fill(&mut transformed[start(4 + k)..][..tiles], d1, d2, |p, q| {
            p + q
        });
        fill(&mut transformed[start(8 + k)..][..tiles], d2, d1, |p, q| {
            p - q
        });
        fill(
            &mut transformed[start(12 + k)..][..tiles],
            d1,
            d3,
            |p, q| p - q,
        );
    }
}

/// `to[i] = f(p[i], q[i])`.
#[inline(always)]
pub(crate) fn fill(to: &mut [f32], p: &[f32], q: &[f32], f: impl Fn(f32, f32) -> f32) {
    for (v, (&p, &q)) in to.iter_mut().zip(p.iter().zip(q)) {
        *v = f(p, q);
    }
}

/// `Aᵀ m A` of every 4 × 4 product of one row of tiles, plus `bias`, then
/// `max(·, floor)`, written into the two output rows the tiles cover (`out` starts at
/// the first one's first interior pixel; rows `row` apart); with
/// `Aᵀ = [1 1 1 0; 0 1 −1 −1]`. Element `e` of tile `t` is
/// `products[start(e) + t]`; `across` is scratch of 8 values per tile.
fn winograd_output_row(
    products: &[f32],
    start: impl Fn(usize) -> usize,
    across: &mut [f32],
    (bias, floor): (f32, f32),
    out: &mut [f32],
    row: usize,
) {
    let tiles = (row - 2) / 2;
    // Aᵀ applied down each column k: across[2 k + i][t], i = output row.
    for (k, parts) in across[..8 * tiles].chunks_exact_mut(2 * tiles).enumerate() {
        let m = |r: usize| &products[start(4 * r + k)..][..tiles];
        let (m0, m1, m2, m3) = (m(0), m(1), m(2), m(3));
        let (top, bottom) = parts.split_at_mut(tiles);
        let sums = m0.iter().zip(m1).zip(m2.iter().zip(m3));
        for ((((m0, m1), (m2, m3)), top), bottom) in sums.zip(top.iter_mut()).zip(bottom.iter_mut())
        {
            *top = m0 + m1 + m2;
            *bottom = m1 - m2 - m3;
        }
    }
    // Then along each output row.
    for i in 0..2 {
        let s = |k: usize| &across[(2 * k + i) * tiles..][..tiles];
        let (s0, s1, s2, s3) = (s(0), s(1), s(2), s(3));
        let line = &mut out[i * row..i * row + 2 * tiles];
        let sums = s0.iter().zip(s1).zip(s2.iter().zip(s3));
        for (pair, ((s0, s1), (s2, s3))) in line.chunks_exact_mut(2).zip(sums) {
            pair[0] = (s0 + s1 + s2 + bias).max(floor);
            pair[1] = (s1 - s2 - s3 + bias).max(floor);
        }
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

/// A parameter's values as `f32`, whatever float type the device keeps.
pub(crate) fn values<const D: usize>(param: &Param<Tensor<D>>) -> Vec<f32> {
    param.val().into_data().iter::<f32>().collect()
}

/// A layer's bias values, zeros for a layer without one.
pub(crate) fn bias_values(bias: &Option<Param<Tensor<1>>>, outputs: usize) -> Vec<f32> {
    match bias {
        None => vec![0.0; outputs],
        Some(param) => values(param),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    fn largest_difference(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    #[test]
    fn winograd_and_nine_taps_compute_the_same_convolution() {
        let device = Device::flex();
        let layer = burn::nn::conv::Conv2dConfig::new([5, 7], [3, 3])
            .with_padding(burn::nn::PaddingConfig2d::Same)
            .init(&device);
        let conv = Conv3x3::from_layer(&layer);
        let (h, w) = (6, 10);
        let image: Vec<f32> = (0..5 * h * w)
            .map(|i| ((i * 37) % 23) as f32 / 7.0 - 1.5)
            .collect();
        let mut source = vec![0.0; 5 * plane_len(h, w)];
        fill_padded(&mut source, &image, h, w);
        let mut taps = vec![0.0; 7 * plane_len(h, w)];
        conv.forward_taps(&source, &mut taps, (h, w));
        let mut winograd = vec![0.0; 7 * plane_len(h, w)];
        conv.forward_winograd(&source, &mut winograd, (h, w), &mut TileBuffers::default());
        let positive = taps.iter().filter(|&&v| v > 0.0).count();
        assert!(positive > 100, "only {positive} outputs pass the ReLU");
        let diff = largest_difference(&taps, &winograd);
        assert!(diff < 1e-5, "largest difference {diff}");
    }

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
