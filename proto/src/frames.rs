//! Labelled frames of one finished episode (actor → learner).
//!
//! Layout after the message header (little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 8 | episode_id u64 |
//! | 4 | n_frames u32 |
//! | 4 | height u32 |
//! | 4 | width u32 |
//! | 4 | n_affordances u32 |
//! | 4·N·H·W | depth f32, metres, finite and ≥ 0 |
//! | 3·N·H·W | RGB u8, row-major, interleaved |
//! | A·N·H·W | labels u8 per affordance plane: [`LABEL_NEGATIVE`], [`LABEL_POSITIVE`] or [`LABEL_UNKNOWN`] |

use crate::arrays::{check_floats, put_f32s, read_u32, read_u64, F32Array, Splitter, SplitterMut};
use crate::payload::{check_layout, check_range, checked_total, Payload};
use crate::{MessageKind, ProtoError};

const SUB_HEADER_LEN: usize = 24;
/// Label value: the affordance is absent at this pixel.
pub const LABEL_NEGATIVE: u8 = 0;
/// Label value: the affordance is present at this pixel.
pub const LABEL_POSITIVE: u8 = 1;
/// Label value: no label; the pixel does not enter the loss.
pub const LABEL_UNKNOWN: u8 = 255;

/// Owned labelled frames, as the labeler builds them.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameBatch {
    /// Episode the frames come from.
    pub episode_id: u64,
    /// Image height in pixels.
    pub height: u32,
    /// Image width in pixels.
    pub width: u32,
    /// Affordance planes per frame.
    pub n_affordances: u32,
    /// `n · h · w` depths in metres.
    pub depth_m: Vec<f32>,
    /// `n · h · w · 3` RGB bytes.
    pub rgb: Vec<u8>,
    /// `n · a · h · w` labels, frame-major then affordance-major.
    pub labels: Vec<u8>,
}

impl FrameBatch {
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.whole().n_frames()
    }

    /// The whole batch, borrowed.
    fn whole(&self) -> FrameSlices<'_> {
        FrameSlices {
            episode_id: self.episode_id,
            height: self.height,
            width: self.width,
            n_affordances: self.n_affordances,
            depth_m: &self.depth_m,
            rgb: &self.rgb,
            labels: &self.labels,
        }
    }

    /// Frames `range` of the batch, borrowed: a message of its own without
    /// copying them first (an episode's frames at 128 px are tens of MB,
    /// sent in parts that fit the transport).
    ///
    /// # Panics
    /// If `range` reaches past the last frame.
    pub fn frames(&self, range: std::ops::Range<usize>) -> FrameSlices<'_> {
        let pixels = (self.height * self.width) as usize;
        let planes = self.n_affordances as usize;
        FrameSlices {
            episode_id: self.episode_id,
            height: self.height,
            width: self.width,
            n_affordances: self.n_affordances,
            depth_m: &self.depth_m[range.start * pixels..range.end * pixels],
            rgb: &self.rgb[3 * range.start * pixels..3 * range.end * pixels],
            labels: &self.labels[planes * range.start * pixels..planes * range.end * pixels],
        }
    }
}

/// Labelled frames borrowed from a [`FrameBatch`] ([`FrameBatch::frames`]):
/// the same message, written straight from the batch's buffers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSlices<'a> {
    /// Episode the frames come from.
    pub episode_id: u64,
    /// Image height in pixels.
    pub height: u32,
    /// Image width in pixels.
    pub width: u32,
    /// Affordance planes per frame.
    pub n_affordances: u32,
    /// `n · h · w` depths in metres.
    pub depth_m: &'a [f32],
    /// `n · h · w · 3` RGB bytes.
    pub rgb: &'a [u8],
    /// `n · a · h · w` labels, frame-major then affordance-major.
    pub labels: &'a [u8],
}

impl FrameSlices<'_> {
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        let pixels = (self.height * self.width) as usize;
        self.depth_m.len().checked_div(pixels).unwrap_or(0)
    }
}

impl Payload for FrameSlices<'_> {
    const KIND: MessageKind = MessageKind::Frames;

    fn payload_len(&self) -> usize {
        SUB_HEADER_LEN + 4 * self.depth_m.len() + self.rgb.len() + self.labels.len()
    }

    fn write_payload(&self, out: &mut [u8]) {
        let mut w = SplitterMut::new(out);
        let head = w.take(SUB_HEADER_LEN);
        head[0..8].copy_from_slice(&self.episode_id.to_le_bytes());
        head[8..12].copy_from_slice(&(self.n_frames() as u32).to_le_bytes());
        head[12..16].copy_from_slice(&self.height.to_le_bytes());
        head[16..20].copy_from_slice(&self.width.to_le_bytes());
        head[20..24].copy_from_slice(&self.n_affordances.to_le_bytes());
        put_f32s(w.take(4 * self.depth_m.len()), self.depth_m);
        w.take(self.rgb.len()).copy_from_slice(self.rgb);
        w.take(self.labels.len()).copy_from_slice(self.labels);
    }
}

impl Payload for FrameBatch {
    const KIND: MessageKind = MessageKind::Frames;

    fn payload_len(&self) -> usize {
        self.whole().payload_len()
    }

    fn write_payload(&self, out: &mut [u8]) {
        self.whole().write_payload(out);
    }
}

/// A validated, zero-copy view of labelled frames.
#[derive(Debug, Clone, Copy)]
pub struct FrameBatchView<'a> {
    /// Episode the frames come from.
    pub episode_id: u64,
    /// Number of frames.
    pub n_frames: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Image width in pixels.
    pub width: u32,
    /// Affordance planes per frame.
    pub n_affordances: u32,
    /// All depths, frame-major.
    pub depth_m: F32Array<'a>,
    /// All RGB bytes, frame-major.
    pub rgb: &'a [u8],
    /// All labels, frame-major then affordance-major.
    pub labels: &'a [u8],
}

impl<'a> FrameBatchView<'a> {
    /// Converts back to an owned batch.
    pub fn to_owned(&self) -> FrameBatch {
        FrameBatch {
            episode_id: self.episode_id,
            height: self.height,
            width: self.width,
            n_affordances: self.n_affordances,
            depth_m: self.depth_m.to_vec(),
            rgb: self.rgb.to_vec(),
            labels: self.labels.to_vec(),
        }
    }

    pub(crate) fn parse(payload: &'a [u8]) -> Result<Self, ProtoError> {
        if payload.len() < SUB_HEADER_LEN {
            return Err(ProtoError::Truncated {
                what: "frames sub-header",
                needed: SUB_HEADER_LEN,
                got: payload.len(),
            });
        }
        let episode_id = read_u64(payload, 0);
        let n_frames = read_u32(payload, 8);
        let height = read_u32(payload, 12);
        let width = read_u32(payload, 16);
        let n_affordances = read_u32(payload, 20);
        check_range("n_frames", n_frames.into(), 1, 4096, "1..=4096")?;
        check_range("height", height.into(), 1, 2048, "1..=2048")?;
        check_range("width", width.into(), 1, 2048, "1..=2048")?;
        check_range("n_affordances", n_affordances.into(), 1, 16, "1..=16")?;
        let pixels = u64::from(n_frames) * u64::from(height) * u64::from(width);
        let expected = checked_total(
            "frames",
            &[
                (SUB_HEADER_LEN as u64, 1),
                (pixels, 4),
                (pixels, 3),
                (pixels, n_affordances.into()),
            ],
            payload.len(),
        )?;
        check_layout("frames", expected, payload.len())?;
        let pixels = pixels as usize;
        let mut r = Splitter::new(&payload[SUB_HEADER_LEN..]);
        let truncated = || ProtoError::Truncated {
            what: "frame arrays",
            needed: expected as usize,
            got: payload.len(),
        };
        let depth_m = F32Array::new(r.take(4 * pixels).ok_or_else(truncated)?);
        let rgb = r.take(3 * pixels).ok_or_else(truncated)?;
        let labels = r
            .take(n_affordances as usize * pixels)
            .ok_or_else(truncated)?;
        check_floats("depth_m", depth_m, Some((0.0, f32::MAX)), ", >= 0")?;
        if let Some(&bad) = labels
            .iter()
            .find(|&&l| l != LABEL_NEGATIVE && l != LABEL_POSITIVE && l != LABEL_UNKNOWN)
        {
            return Err(ProtoError::OutOfRange {
                field: "labels",
                value: bad.into(),
                allowed: "0, 1 or 255",
            });
        }
        Ok(Self {
            episode_id,
            n_frames,
            height,
            width,
            n_affordances,
            depth_m,
            rgb,
            labels,
        })
    }
}
