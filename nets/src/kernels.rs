//! The CPU kernels both U-Net paths use: padded-plane layout helpers, the
//! GEMM wrapper, the 3 × 3 convolution by Winograd's F(2 × 2, 3 × 3) or nine
//! taps ([`Conv3x3`]), max pooling, and reading a layer's parameters. The
//! inference pass (`unet_cpu`) and the training convolution
//! (`unet_conv_cpu`) build on them; this module depends on neither.
//!
//! Layout: a "padded plane" of an `h × w` image is `(h + 2) × (w + 2)` floats
//! with a zero border; channels follow each other. The nine-tap convolution
//! computes a "wide" output of `h` rows of `w + 2` columns, whose two extra
//! columns land on the border and are zeroed again afterwards.

use burn::module::Param;
use burn::prelude::*;

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
pub(crate) fn max_pool_2x2(source: &[f32], pooled: &mut [f32], h: usize, w: usize) {
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
pub(crate) fn matmul(
    dst: &mut [f32],
    dst_rows: usize,
    lhs: &[f32],
    rhs: &[f32],
    rhs_rows: usize,
    (m, n, k): (usize, usize, usize),
    accumulate: bool,
) {
    matmul_lhs_rows(
        dst,
        dst_rows,
        (lhs, k),
        rhs,
        rhs_rows,
        (m, n, k),
        accumulate,
    );
}

/// As [`matmul`], with row `i` of `lhs` starting at `i · lhs_rows` (`lhs`
/// given as the slice and that stride): `k` columns of a wider matrix.
pub(crate) fn matmul_lhs_rows(
    dst: &mut [f32],
    dst_rows: usize,
    (lhs, lhs_rows): (&[f32], usize),
    rhs: &[f32],
    rhs_rows: usize,
    (m, n, k): (usize, usize, usize),
    accumulate: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        k == 0 || lhs.len() >= (m - 1) * lhs_rows + k,
        "matmul: lhs too short"
    );
    assert!(
        dst.len() >= (m - 1) * dst_rows + n,
        "matmul: destination too short"
    );
    assert!(
        k == 0 || rhs.len() >= (k - 1) * rhs_rows + n,
        "matmul: rhs too short"
    );
    // SAFETY: the asserts above keep every element gemm touches
    // (dst[i · dst_rows + j], lhs[i · lhs_rows + kk], rhs[kk · rhs_rows + j])
    // inside its slice; `dst` is borrowed mutably, so nothing else aliases it.
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
            lhs_rows as isize,
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
    pub(crate) fn from_layer(layer: &burn::nn::conv::Conv2d) -> Self {
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
        let diff = taps
            .iter()
            .zip(&winograd)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(diff < 1e-5, "largest difference {diff}");
    }
}
