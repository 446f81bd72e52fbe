//! Data association: which map object does each segment of a frame show?
//!
//! Segments are compared with the map rendered into the same camera. Only
//! pixels whose measured and rendered depths agree count, so an object seen
//! through a gap or in front of another is not confused with it.

use rustc_hash::FxHashMap;

use crate::render::RenderTarget;

/// Settings of association.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AssociationParams {
    /// Segments smaller than this are ignored (noise); pixels of a
    /// 128 × 128 frame, scaled by [`crate::Intrinsics::scaled_px`].
    pub min_segment_px: usize,
    /// Unmatched segments at least this large become new objects; pixels of
    /// a 128 × 128 frame, scaled like `min_segment_px`.
    pub new_object_min_px: usize,
    /// Accept a match with at least this IoU…
    pub min_iou: f32,
    /// …or when this fraction of the segment lies on the object.
    pub min_coverage: f32,
    /// Measured and rendered depth agree within this many metres.
    pub depth_tolerance_m: f32,
    /// A segment no object matches on IoU or coverage goes to an object
    /// with at least this fraction of its rendered pixels on the segment
    /// (and at least [`MIN_CONTAINED_PX`] of them): the object is all of
    /// what the map knows of the segment (an object seen from a new side,
    /// where most of the segment is surface the map never saw; a small
    /// object whose coarse model renders on few of its pixels).
    pub min_containment: f32,
}

/// Fewest rendered pixels on a segment for [`AssociationParams::min_containment`]
/// to count: fewer say little about where an object is.
pub const MIN_CONTAINED_PX: usize = 5;

/// The pixels of one instance id in a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Instance id in the input mask.
    pub instance: u32,
    /// Pixel indices, ascending.
    pub pixels: Vec<usize>,
}

/// Groups pixels by instance (0 = background is skipped), keeping pixels whose
/// depth passes `valid` and segments of at least `min_px` pixels; sorted by instance.
pub fn extract_segments(
    instance: &[u32],
    depth_m: &[f32],
    valid: impl Fn(f32) -> bool,
    min_px: usize,
) -> Vec<Segment> {
    let mut by_instance: FxHashMap<u32, Vec<usize>> = FxHashMap::default();
    for (px, (&id, &d)) in instance.iter().zip(depth_m).enumerate() {
        if id != 0 && valid(d) {
            by_instance.entry(id).or_default().push(px);
        }
    }
    let mut segments: Vec<Segment> = by_instance
        .into_iter()
        .filter(|(_, p)| p.len() >= min_px)
        .map(|(instance, pixels)| Segment { instance, pixels })
        .collect();
    segments.sort_unstable_by_key(|s| s.instance);
    segments
}

/// What association found for a frame's segments.
#[derive(Debug, Clone, PartialEq)]
pub struct Association {
    /// For each segment, the map object id it shows, or `None`.
    pub matches: Vec<Option<u32>>,
    /// For each segment, every object that passes the test on it on its
    /// own, best IoU first (the match, when there is one, is among them).
    pub candidates: Vec<Vec<u32>>,
}

/// For each segment, the map object id it shows ([`Association::matches`]),
/// and every object that could have been it ([`Association::candidates`]).
///
/// Candidate pairs pass on IoU or on coverage; the best IoU is taken first.
/// A segment no pair matches goes to the object lying most within it
/// ([`AssociationParams::min_containment`]); such objects are not
/// candidates (a thin object lying on a larger one lies within its
/// segment, too, and is no copy of it). A segment gets at most one object;
/// an object may take several segments (an over-segmented object keeps one
/// id).
pub fn associate(
    segments: &[Segment],
    rendered: &RenderTarget,
    depth_m: &[f32],
    params: &AssociationParams,
) -> Association {
    let mut rendered_px: FxHashMap<u32, usize> = FxHashMap::default();
    for &id in &rendered.ids {
        if id != 0 {
            *rendered_px.entry(id).or_default() += 1;
        }
    }
    let mut pairs = Vec::new();
    // Per segment, the objects that lie within it, for segments that no
    // pair matches.
    let mut contained: Vec<Vec<(f32, u32)>> = vec![Vec::new(); segments.len()];
    for (s, segment) in segments.iter().enumerate() {
        let mut overlap: FxHashMap<u32, usize> = FxHashMap::default();
        for &px in &segment.pixels {
            let id = rendered.ids[px];
            if id != 0 && (rendered.depth_m[px] - depth_m[px]).abs() <= params.depth_tolerance_m {
                *overlap.entry(id).or_default() += 1;
            }
        }
        for (id, inter) in overlap {
            let union = segment.pixels.len() + rendered_px[&id] - inter;
            let iou = inter as f32 / union as f32;
            let coverage = inter as f32 / segment.pixels.len() as f32;
            if iou >= params.min_iou || coverage >= params.min_coverage {
                pairs.push((iou, s, id));
            }
            let containment = inter as f32 / rendered_px[&id] as f32;
            if inter >= MIN_CONTAINED_PX && containment >= params.min_containment {
                contained[s].push((containment, id));
            }
        }
    }
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut matches = vec![None; segments.len()];
    let mut candidates = vec![Vec::new(); segments.len()];
    for (_, s, id) in pairs {
        if matches[s].is_none() {
            matches[s] = Some(id);
        }
        candidates[s].push(id);
    }
    for (m, within) in matches.iter_mut().zip(contained) {
        if m.is_none() {
            *m = within
                .into_iter()
                .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
                .map(|(_, id)| id);
        }
    }
    Association {
        matches,
        candidates,
    }
}
