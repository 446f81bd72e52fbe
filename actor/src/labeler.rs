//! The labeler: at the end of an episode it turns what the agent learned by
//! interacting into dense per-pixel labels for the affordance U-Net.
//!
//! - **By interaction, through the map** (method `ours`): the outcome stored
//!   on a map object labels that object's mask in every frame of the episode
//!   where it is visible, before and after the interaction.
//! - **By confidence**: an object nobody touched gets a label when the
//!   calibrated network is sure of it across the episode: positive if the
//!   largest per-frame 95th percentile of its pixels' probability exceeds
//!   ξ_T, negative if the smallest 5th percentile falls below ξ_F (both at
//!   once: the network contradicts itself and the object stays unlabelled).
//! - **Spheres** (baselines `nomap-noseg`, `intexp`): each interaction drops
//!   a 3-D point that moves with its object; pixels within 0.2 m of a point
//!   get its outcome in every frame where the point is in view; a positive
//!   wins over a negative.
//! - **Segments under points** (`nomap-seg`): the same points, but in each
//!   frame where a point is in view the whole segment under it gets the
//!   outcome: segmentation without a map's re-identification.
//!
//! Only frames with both positive and negative pixels (in some affordance)
//! are kept when the balanced filter is on.

use std::collections::BTreeMap;

use mapper::{Affordance, Intrinsics, Map, MapError, ObjectId, Pose};
use nalgebra::Point3;
use proto::{
    ConfidenceRule, FrameBatch, SphereRule, LABEL_NEGATIVE, LABEL_POSITIVE, LABEL_UNKNOWN,
};

/// One frame of an episode as the labeler needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeFrame {
    /// Row-major RGB, 3 bytes per pixel.
    pub rgb: Vec<u8>,
    /// Z-depth, metres (0 where nothing was seen).
    pub depth_m: Vec<f32>,
    /// Map object id per pixel, as [`Map::integrate`] returned it for this frame.
    pub map_ids: Vec<u32>,
    /// Where the camera was.
    pub t_world_camera: Pose,
}

/// The `q`-quantile (0..1) of `values` by nearest rank; `values` is sorted in place.
fn nearest_rank(values: &mut [f32], q: f32) -> f32 {
    values.sort_by(f32::total_cmp);
    let rank = ((q * values.len() as f32).ceil() as usize).clamp(1, values.len());
    values[rank - 1]
}

/// Labels for the objects in the map that were never tried with
/// `affordance`, from the network's calibrated per-pixel probabilities of
/// that affordance (`probabilities[f]` is frame `f`'s `h · w` plane).
/// Returns `(object, label)` for every object the rule decides.
pub fn confidence_labels(
    map: &Map,
    frames: &[EpisodeFrame],
    probabilities: &[Vec<f32>],
    affordance: Affordance,
    rule: &ConfidenceRule,
) -> Vec<(ObjectId, bool)> {
    // Per untouched object: the largest per-frame P95 and the smallest P5.
    let mut extremes: BTreeMap<u32, (f32, f32)> = map
        .objects()
        .values()
        .filter(|o| !o.labels.interacted(affordance))
        .map(|o| (o.id.0, (f32::NEG_INFINITY, f32::INFINITY)))
        .collect();
    for (frame, plane) in frames.iter().zip(probabilities) {
        let min_pixels = mapper::scaled_px(rule.min_pixels, plane.len());
        let mut values: BTreeMap<u32, Vec<f32>> = BTreeMap::new();
        for (&id, &p) in frame.map_ids.iter().zip(plane) {
            let id = map.current_id(ObjectId(id)).0;
            if extremes.contains_key(&id) {
                values.entry(id).or_default().push(p);
            }
        }
        for (id, mut v) in values {
            if v.len() < min_pixels {
                continue;
            }
            let e = extremes
                .get_mut(&id)
                .expect("only untouched objects are gathered");
            e.0 = e.0.max(nearest_rank(&mut v, 0.95));
            e.1 = e.1.min(nearest_rank(&mut v, 0.05));
        }
    }
    extremes
        .into_iter()
        .filter_map(|(id, (best_p95, worst_p5))| {
            let positive = best_p95 > rule.positive_above;
            let negative = worst_p5 < rule.negative_below;
            (positive != negative).then_some((ObjectId(id), positive))
        })
        .collect()
}

/// Stores confidence labels on the map, where interaction labels already live.
pub(crate) fn apply_confidence_labels(
    map: &mut Map,
    affordance: Affordance,
    labels: &[(ObjectId, bool)],
) -> Result<(), MapError> {
    for &(id, label) in labels {
        map.set_confidence_label(id, affordance, Some(label))?;
    }
    Ok(())
}

/// Per frame, `affordances.len()` label planes from the labels stored on
/// the map's objects (interaction outcomes, else confidence labels): each
/// labelled object's mask in each frame gets its label; everything else is
/// [`LABEL_UNKNOWN`]. A frame's ids reach their objects through
/// [`Map::labels_of`]: also objects merged into another since, and objects
/// deleted since (an object carried away stops being seen).
pub fn map_labels(map: &Map, frames: &[EpisodeFrame], affordances: &[Affordance]) -> Vec<Vec<u8>> {
    let label_of = |id: u32, affordance: Affordance| {
        map.labels_of(ObjectId(id))
            .and_then(|labels| labels.label(affordance))
            .map_or(LABEL_UNKNOWN, |l| {
                if l {
                    LABEL_POSITIVE
                } else {
                    LABEL_NEGATIVE
                }
            })
    };
    frames
        .iter()
        .map(|frame| {
            affordances
                .iter()
                .flat_map(|&a| {
                    frame.map_ids.iter().map(move |&id| {
                        if id == 0 {
                            LABEL_UNKNOWN
                        } else {
                            label_of(id, a)
                        }
                    })
                })
                .collect()
        })
        .collect()
}

/// Labels every still-unlabelled pixel that the frame's instance
/// segmentation (`segmentations[f]`, 0 = background) calls background
/// negative in every affordance plane: the robot only ever tries objects,
/// and the floor and walls afford nothing it can do.
pub fn label_background_negative(labels: &mut [Vec<u8>], segmentations: &[Vec<u32>]) {
    for (planes, segmentation) in labels.iter_mut().zip(segmentations) {
        let pixels = segmentation.len();
        for plane in planes.chunks_mut(pixels.max(1)) {
            for (label, &instance) in plane.iter_mut().zip(segmentation) {
                if instance == 0 && *label == LABEL_UNKNOWN {
                    *label = LABEL_NEGATIVE;
                }
            }
        }
    }
}

/// An interaction remembered as a 3-D point on its object (baselines).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InteractionPoint {
    /// The object the point sticks to (the caller's key, e.g. a simulator index).
    pub object: usize,
    /// Index of the affordance plane.
    pub affordance: usize,
    /// Whether the interaction succeeded.
    pub success: bool,
    /// The point in the object's frame.
    pub p_object: Point3<f32>,
}

/// Per frame, `n_affordances` label planes from interaction points:
/// `object_pose(f, object)` is where the point's object was in frame `f`.
pub fn sphere_labels(
    frames: &[EpisodeFrame],
    intrinsics: &Intrinsics,
    points: &[InteractionPoint],
    n_affordances: usize,
    object_pose: &dyn Fn(usize, usize) -> Pose,
    rule: &SphereRule,
) -> Vec<Vec<u8>> {
    point_labels(
        frames,
        intrinsics,
        points,
        n_affordances,
        object_pose,
        rule,
        &|frame, p_camera, _, plane, label| {
            for (px, out) in plane.iter_mut().enumerate() {
                let z = frame.depth_m[px];
                if z.is_nan() || z <= 0.0 {
                    continue;
                }
                let (u, v) = (
                    (px % intrinsics.width) as f32,
                    (px / intrinsics.width) as f32,
                );
                if (intrinsics.back_project(u, v, z) - p_camera).norm() <= rule.radius_m {
                    mark(out, label);
                }
            }
        },
    )
}

/// Per frame, `n_affordances` label planes from interaction points: in each
/// frame where a point is in view, every pixel of the segment under it
/// (`frame.map_ids` holds the frame's segmentation) gets its outcome.
pub fn segment_labels(
    frames: &[EpisodeFrame],
    intrinsics: &Intrinsics,
    points: &[InteractionPoint],
    n_affordances: usize,
    object_pose: &dyn Fn(usize, usize) -> Pose,
    rule: &SphereRule,
) -> Vec<Vec<u8>> {
    point_labels(
        frames,
        intrinsics,
        points,
        n_affordances,
        object_pose,
        rule,
        &|frame, _, pixel, plane, label| {
            let segment = frame.map_ids[pixel];
            if segment == 0 {
                return;
            }
            for (out, &id) in plane.iter_mut().zip(&frame.map_ids) {
                if id == segment {
                    mark(out, label);
                }
            }
        },
    )
}

/// Writes `label` unless the pixel is already positive (positive wins).
fn mark(out: &mut u8, label: u8) {
    if *out != LABEL_POSITIVE {
        *out = label;
    }
}

/// What a point in view labels: given the frame, the point in the camera
/// frame, the pixel it projects to, the affordance's plane and the label.
type LabelPoint<'f> = dyn Fn(&EpisodeFrame, Point3<f32>, usize, &mut [u8], u8) + 'f;

/// The frame loop shared by the point labelers: each point, moved with its
/// object, is projected into every frame; where it is in view, `label`
/// writes its outcome.
fn point_labels(
    frames: &[EpisodeFrame],
    intrinsics: &Intrinsics,
    points: &[InteractionPoint],
    n_affordances: usize,
    object_pose: &dyn Fn(usize, usize) -> Pose,
    rule: &SphereRule,
    label: &LabelPoint<'_>,
) -> Vec<Vec<u8>> {
    let pixels = intrinsics.pixels();
    frames
        .iter()
        .enumerate()
        .map(|(f, frame)| {
            let mut planes = vec![LABEL_UNKNOWN; n_affordances * pixels];
            let t_camera_world = frame.t_world_camera.inverse();
            for point in points {
                let p_camera = t_camera_world * (object_pose(f, point.object) * point.p_object);
                let Some(pixel) = in_view(frame, intrinsics, &p_camera, rule) else {
                    continue;
                };
                let outcome = if point.success {
                    LABEL_POSITIVE
                } else {
                    LABEL_NEGATIVE
                };
                let plane = &mut planes[point.affordance * pixels..][..pixels];
                label(frame, p_camera, pixel, plane, outcome);
            }
            planes
        })
        .collect()
}

/// The pixel a camera-frame point projects to, if it lies in the image and
/// is not hidden behind what the frame saw there.
fn in_view(
    frame: &EpisodeFrame,
    k: &Intrinsics,
    p: &Point3<f32>,
    rule: &SphereRule,
) -> Option<usize> {
    let (u, v, z) = k.project(p)?;
    let (u, v) = (u.round(), v.round());
    if u < 0.0 || v < 0.0 || u >= k.width as f32 || v >= k.height as f32 {
        return None;
    }
    let pixel = v as usize * k.width + u as usize;
    let seen = frame.depth_m[pixel];
    (!(seen > 0.0 && seen < z - rule.occlusion_tolerance_m)).then_some(pixel)
}

/// True if some affordance plane of the frame has both positive and negative pixels.
pub(crate) fn is_balanced(planes: &[u8], pixels: usize) -> bool {
    planes
        .chunks(pixels)
        .any(|plane| plane.contains(&LABEL_POSITIVE) && plane.contains(&LABEL_NEGATIVE))
}

/// The frames worth sending: those with any label, or (with `balanced`)
/// only those with both classes in some affordance; packed for the learner.
pub fn frame_batch(
    episode_id: u64,
    intrinsics: &Intrinsics,
    frames: &[EpisodeFrame],
    labels: &[Vec<u8>],
    n_affordances: usize,
    balanced: bool,
) -> FrameBatch {
    let pixels = intrinsics.pixels();
    let mut batch = FrameBatch {
        episode_id,
        height: intrinsics.height as u32,
        width: intrinsics.width as u32,
        n_affordances: n_affordances as u32,
        depth_m: Vec::new(),
        rgb: Vec::new(),
        labels: Vec::new(),
    };
    for (frame, planes) in frames.iter().zip(labels) {
        let keep = if balanced {
            is_balanced(planes, pixels)
        } else {
            planes.iter().any(|&l| l != LABEL_UNKNOWN)
        };
        if keep {
            batch.depth_m.extend(frame.depth_m.iter().map(|d| {
                if d.is_finite() {
                    d.max(0.0)
                } else {
                    0.0
                }
            }));
            batch.rgb.extend_from_slice(&frame.rgb);
            batch.labels.extend_from_slice(planes);
        }
    }
    batch
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_quantiles() {
        let mut v: Vec<f32> = (1..=20).map(|i| i as f32).collect();
        assert_eq!(nearest_rank(&mut v, 0.95), 19.0);
        assert_eq!(nearest_rank(&mut v, 0.05), 1.0);
        assert_eq!(nearest_rank(&mut [0.3], 0.95), 0.3);
    }
}
