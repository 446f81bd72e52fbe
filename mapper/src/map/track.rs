//! The tracking step of [`Map::integrate`]: which objects may have moved,
//! which segment shows each of them now, and the pose update.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Point3, Translation3, Unit, Vector3};

use super::{Map, ObjectId, Whereabouts};
use crate::association::Segment;
use crate::camera::{Frame, Intrinsics};
use crate::icp::{
    align, evaluate, measured_normals, motion_size, refine_against_sdf, Fit, MotionModel,
    SegmentView, TrackingFailure, TrackingOutcome, TrackingParams, TrackingReport, TrackingTrigger,
};
use crate::render::{raycast_layer, Pixels, RenderTarget};
use crate::Pose;

/// Camera-frame centroid of the pixels `pixels` at their depths.
pub(super) fn centroid(
    k: &Intrinsics,
    depth: &[f32],
    pixels: impl Iterator<Item = usize>,
) -> Option<Point3<f32>> {
    let (sum, n) = pixels.fold((Vector3::zeros(), 0usize), |(sum, n), px| {
        let p = k.back_project((px % k.width) as f32, (px / k.width) as f32, depth[px]);
        (sum + p.coords, n + 1)
    });
    (n > 0).then(|| Point3::from(sum / n as f32))
}

/// The mask of a segment's `pixels` and the normals measured on it: what a
/// [`SegmentView`] of the segment borrows.
pub(super) fn mask_and_normals(
    k: &Intrinsics,
    depth_m: &[f32],
    pixels: &[usize],
) -> (Vec<bool>, Vec<Option<Vector3<f32>>>) {
    let mut mask = vec![false; k.pixels()];
    for &px in pixels {
        mask[px] = true;
    }
    let normals = measured_normals(k, depth_m, &mask);
    (mask, normals)
}

/// Why the fit of an aligned pose is not accepted, if it is not: too few
/// inliers, too small a share of the visible model, or too large an RMSE.
pub(super) fn acceptance_failure(fit: &Fit, params: &TrackingParams) -> Option<TrackingFailure> {
    if fit.inliers < params.min_inliers {
        Some(TrackingFailure::TooFewInliers {
            inliers: fit.inliers,
        })
    } else if fit.inlier_ratio() < params.min_inlier_ratio || fit.rmse_m > params.max_rmse_m {
        Some(TrackingFailure::PoorFit {
            inlier_ratio: fit.inlier_ratio(),
            rmse_m: fit.rmse_m,
        })
    } else {
        None
    }
}

/// What the caller said about an object that may have moved
/// ([`Map::notify_moved`], [`Map::notify_pushed`]).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Notice {
    /// A world-frame motion guess.
    pub(super) motion: Option<Pose>,
    /// The world-frame direction the robot pushed it along.
    pub(super) push: Option<Unit<Vector3<f32>>>,
    /// The robot put it down where it is, by a motion it knows
    /// ([`Map::release`]).
    pub(super) released: bool,
}

/// Whether a tracking failure means that nothing was seen where the object
/// was predicted: no segment overlaps it there or lies near (out of view,
/// or hidden). For an object the robot put down by a motion it knows, that
/// says nothing against the motion, so it stays where it was put.
fn nothing_seen_there(failure: TrackingFailure) -> bool {
    matches!(
        failure,
        TrackingFailure::NoSegment | TrackingFailure::BeyondGate { .. }
    )
}

/// Whether an object's `shift` (camera frame, from where it was predicted
/// to the segment's centroid) is a motion tracking follows: within
/// [`TrackingParams::max_motion_m`], or, for an object pushed along `push`
/// (camera frame), up to [`TrackingParams::max_push_m`] ahead along it.
/// Returns the failure, naming the gate that applies, when it is not.
fn beyond_gate(
    shift: &Vector3<f32>,
    push: Option<&Unit<Vector3<f32>>>,
    params: &TrackingParams,
) -> Option<TrackingFailure> {
    let within = match push {
        Some(d) => {
            let along = shift.dot(d);
            let sideways = (shift - d.into_inner() * along).norm();
            (-params.max_motion_m..=params.max_push_m).contains(&along)
                && sideways <= params.max_motion_m
        }
        None => shift.norm() <= params.max_motion_m,
    };
    (!within).then(|| TrackingFailure::BeyondGate {
        distance_m: shift.norm(),
        gate_m: if push.is_some() {
            params.max_push_m
        } else {
            params.max_motion_m
        },
    })
}

/// How many of an object's rendered pixels agree with the measured depth
/// and how many disagree (see `Map::residual_candidates`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct ResidualCounts {
    agree: usize,
    disagree: usize,
}

impl ResidualCounts {
    /// Whether both counts are within a tenth of the rendered pixels (at
    /// least two) of `other`'s: depth noise and carving, not a new view.
    fn close_to(self, other: Self) -> bool {
        let n = (self.agree + self.disagree).max(other.agree + other.disagree);
        let tolerance = (n / 10).max(2);
        self.agree.abs_diff(other.agree) <= tolerance
            && self.disagree.abs_diff(other.disagree) <= tolerance
    }
}

/// A residual-triggered tracking failure and the view it happened in. The
/// same object seen again from the same camera pose with the same residual
/// fails the same way, so tracking it again would only cost time (an
/// object that disagrees with a still camera triggers every frame); the
/// remembered failure is reported instead until the camera moves, the
/// residual jumps from one frame to the next, the object stops triggering
/// or the caller notifies it.
#[derive(Debug, Clone, Copy)]
pub(super) struct FailedView {
    t_world_camera: Pose,
    counts: ResidualCounts,
    failure: TrackingFailure,
}

impl Map {
    /// Objects whose rendered surface disagrees with the frame: among their
    /// rendered pixels that are not hidden by something nearer, too few have
    /// the measured depth. Seeing farther (or nothing at all) where the
    /// object should be counts against it; nearer measurements count only on
    /// the segment that overlaps it most, when no other object claimed that
    /// segment (the object moved towards the camera, not behind an occluder).
    fn residual_candidates(
        &self,
        segments: &[Segment],
        matches: &[Option<u32>],
        rendered: &RenderTarget,
        frame: &Frame<'_>,
    ) -> BTreeMap<ObjectId, ResidualCounts> {
        let depth_m = frame.depth_m;
        let min_px = frame
            .intrinsics
            .scaled_px(self.config.settings.min_segment_px);
        let tol = self.config.depth_tolerance_m();
        let mut segment_of = vec![usize::MAX; depth_m.len()];
        for (s, segment) in segments.iter().enumerate() {
            for &px in &segment.pixels {
                segment_of[px] = s;
            }
        }
        // Per object: rendered pixels per overlapping segment, counted one
        // run of pixels with the same object and segment at a time.
        let mut overlap: BTreeMap<u32, BTreeMap<usize, usize>> = BTreeMap::new();
        let mut px = 0;
        while px < segment_of.len() {
            let (id, s, first) = (rendered.ids[px], segment_of[px], px);
            while px < segment_of.len() && (rendered.ids[px], segment_of[px]) == (id, s) {
                px += 1;
            }
            if id != 0 && s != usize::MAX && matches[s].is_none_or(|m| m == id) {
                *overlap.entry(id).or_default().entry(s).or_default() += px - first;
            }
        }
        // Per object: the segment it overlaps most (ties: the first).
        let best_segment: BTreeMap<u32, usize> = overlap
            .iter()
            .filter_map(|(&id, m)| {
                let best = m.iter().max_by_key(|(s, n)| (**n, std::cmp::Reverse(**s)));
                best.map(|(s, _)| (id, *s))
            })
            .collect();
        // Agreement per object, counted one run of pixels of one object at
        // a time.
        let mut counts: BTreeMap<u32, ResidualCounts> = BTreeMap::new();
        let mut first = 0;
        for run in rendered.ids.chunk_by(|a, b| a == b) {
            let (id, pixels) = (run[0], first..first + run.len());
            first = pixels.end;
            if id == 0 {
                continue;
            }
            let best = best_segment.get(&id).copied();
            let mut c = ResidualCounts::default();
            for px in pixels {
                let d = depth_m[px];
                let nothing_seen = !(d.is_finite() && d > 0.0);
                if !nothing_seen && !self.config.integration().valid_depth(d) {
                    continue;
                }
                let d = if nothing_seen { f32::INFINITY } else { d };
                let r = rendered.depth_m[px];
                if (d - r).abs() <= tol {
                    c.agree += 1;
                } else if d > r + tol || best == Some(segment_of[px]) {
                    c.disagree += 1;
                }
            }
            let total = counts.entry(id).or_default();
            total.agree += c.agree;
            total.disagree += c.disagree;
        }
        let trigger = self.config.tracking.residual_trigger;
        counts
            .into_iter()
            .filter(|(_, c)| {
                let n = c.agree + c.disagree;
                n >= min_px && (c.agree as f32) < trigger * n as f32
            })
            .map(|(id, c)| (ObjectId(id), c))
            .collect()
    }

    /// The failure of the last residual-triggered tracking of `id` when
    /// this frame shows the object the same way (see [`FailedView`]); the
    /// remembered residual then follows this frame's, so that the slow
    /// change of carving does not count as a new view.
    fn repeat_failure(
        &mut self,
        id: ObjectId,
        t_world_camera: &Pose,
        counts: ResidualCounts,
    ) -> Option<TrackingFailure> {
        let params = self.config.tracking;
        let seen = self.failed_views.get_mut(&id)?;
        let (translation_m, rotation_deg) =
            motion_size(&(seen.t_world_camera.inverse() * t_world_camera));
        let camera_still =
            translation_m < params.min_translation_m && rotation_deg < params.min_rotation_deg;
        let same = camera_still && seen.counts.close_to(counts);
        if same {
            seen.counts = counts;
        }
        same.then_some(seen.failure)
    }

    /// Tracks the objects that may have moved; claims the segment each one
    /// was found on (`matches`). When tracking fails, a notified object
    /// gives up the segments association gave it (they may become new
    /// objects, but never smear into its model); an object that only
    /// disagreed keeps them. Returns the notified objects whose
    /// tracking failed: they are not integrated at all this frame, so the
    /// model survives a bad report intact; the others are still carved,
    /// which clears ghosts.
    pub(super) fn track_objects(
        &mut self,
        frame: &Frame<'_>,
        segments: &[Segment],
        matches: &mut [Option<u32>],
        rendered: &RenderTarget,
    ) -> BTreeSet<ObjectId> {
        let residual = self.residual_candidates(segments, matches, rendered, frame);
        let mut candidates: BTreeMap<ObjectId, (TrackingTrigger, Notice)> = residual
            .keys()
            .map(|&id| (id, (TrackingTrigger::Residual, Notice::default())))
            .collect();
        for (id, notice) in std::mem::take(&mut self.notified) {
            if self
                .objects
                .get(&id)
                .is_some_and(|o| o.whereabouts != Whereabouts::Held)
            {
                candidates.insert(id, (TrackingTrigger::Notified, notice));
            }
        }
        let objects = &self.objects;
        self.failed_views
            .retain(|id, _| objects.contains_key(id) && residual.contains_key(id));
        let mut failed = BTreeSet::new();
        self.last_tracking.clear();
        for (id, (trigger, notice)) in candidates {
            let repeated = match trigger {
                TrackingTrigger::Residual => {
                    self.repeat_failure(id, &frame.t_world_camera, residual[&id])
                }
                TrackingTrigger::Notified => {
                    self.failed_views.remove(&id);
                    None
                }
            };
            let tracked = match repeated {
                Some(failure) => Err(failure),
                None => self.track_one(id, notice, trigger, frame, segments, matches),
            };
            if repeated.is_none() && trigger == TrackingTrigger::Residual {
                match tracked {
                    Err(failure) => {
                        let view = FailedView {
                            t_world_camera: frame.t_world_camera,
                            counts: residual[&id],
                            failure,
                        };
                        self.failed_views.insert(id, view);
                    }
                    Ok(_) => {
                        self.failed_views.remove(&id);
                    }
                }
            }
            let outcome = match tracked {
                Ok(outcome) => {
                    if let Some(object) = self.objects.get_mut(&id) {
                        object.whereabouts = Whereabouts::Placed;
                    }
                    outcome
                }
                Err(failure) => {
                    // A notified object moved, so what association matched to
                    // its old pose is stale. An object that only disagreed
                    // keeps it: association counts only pixels where the
                    // model at its old pose has the measured depth, evidence
                    // that it is still there; released, those segments would
                    // become copies of it. The notified object is no longer
                    // where the map has it: lost, until a new segment turns
                    // out to be it (`Map::reidentify`); unless the robot put
                    // it down by a motion it knows and nothing contradicts it.
                    if trigger == TrackingTrigger::Notified {
                        for m in matches.iter_mut().filter(|m| **m == Some(id.0)) {
                            *m = None;
                        }
                        failed.insert(id);
                        let next_id = ObjectId(self.next_id);
                        let stays = notice.released && nothing_seen_there(failure);
                        if let Some(object) = self.objects.get_mut(&id).filter(|_| !stays) {
                            object.whereabouts = Whereabouts::Lost;
                            object.lost_before = next_id;
                        }
                    }
                    TrackingOutcome::Failed(failure)
                }
            };
            self.last_tracking.push(TrackingReport {
                object: id,
                trigger,
                outcome,
                repeated: repeated.is_some(),
            });
        }
        failed
    }

    fn track_one(
        &mut self,
        id: ObjectId,
        notice: Notice,
        trigger: TrackingTrigger,
        frame: &Frame<'_>,
        segments: &[Segment],
        matches: &mut [Option<u32>],
    ) -> Result<TrackingOutcome, TrackingFailure> {
        let params = self.config.tracking;
        let k = frame.intrinsics;
        let object = &self.objects[&id];
        let t_camera_world = frame.t_world_camera.inverse();
        let old = t_camera_world * object.t_world_object;
        let predicted =
            t_camera_world * notice.motion.unwrap_or_else(Pose::identity) * object.t_world_object;
        let push = notice
            .push
            .map(|d| Unit::new_unchecked(t_camera_world.rotation * d.into_inner()));

        let mut silhouette = RenderTarget::new(&k);
        raycast_layer(
            &object.volume,
            &predicted,
            &k,
            id.0,
            self.config.settings.min_depth_m,
            &mut silhouette,
            Pixels::All,
        );
        let rendered_px: Vec<usize> = (0..k.pixels())
            .filter(|&px| silhouette.ids[px] != 0)
            .collect();
        let predicted_centre = centroid(&k, &silhouette.depth_m, rendered_px.iter().copied())
            .unwrap_or_else(|| {
                predicted
                    * object
                        .volume
                        .block_bounds()
                        .map_or(Point3::origin(), |(lo, hi)| nalgebra::center(&lo, &hi))
            });
        let segment_centre =
            |s: usize| centroid(&k, frame.depth_m, segments[s].pixels.iter().copied());
        // A pushed object may have slid far along the push, past other
        // segments: only those it can have reached are considered.
        let free: Vec<usize> = (0..segments.len())
            .filter(|&s| matches[s].is_none_or(|m| m == id.0))
            .filter(|&s| {
                push.is_none()
                    || segment_centre(s).is_some_and(|c| {
                        beyond_gate(&(c - predicted_centre), push.as_ref(), &params).is_none()
                    })
            })
            .collect();
        // The segment that overlaps the predicted silhouette most; for a
        // notified object with no overlap, the one whose centroid is nearest.
        let by_overlap = free
            .iter()
            .map(|&s| {
                let n = segments[s]
                    .pixels
                    .iter()
                    .filter(|&&px| silhouette.ids[px] != 0)
                    .count();
                (n, s)
            })
            .filter(|(n, _)| *n > 0)
            .max_by_key(|(n, s)| (*n, std::cmp::Reverse(*s)))
            .map(|(_, s)| s);
        let chosen = match by_overlap {
            Some(s) => s,
            None if trigger == TrackingTrigger::Notified => free
                .iter()
                .filter_map(|&s| segment_centre(s).map(|c| ((c - predicted_centre).norm(), s)))
                .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
                .map(|(_, s)| s)
                .ok_or(TrackingFailure::NoSegment)?,
            None => return Err(TrackingFailure::NoSegment),
        };
        let observed_centre = segment_centre(chosen).ok_or(TrackingFailure::NoSegment)?;
        let shift = observed_centre - predicted_centre;
        if let Some(failure) = beyond_gate(&shift, push.as_ref(), &params) {
            return Err(failure);
        }

        let model = object
            .volume
            .surface_samples(2.0 * self.config.settings.voxel_size_m);
        let (mask, normals) = mask_and_normals(&k, frame.depth_m, &segments[chosen].pixels);
        let view = SegmentView {
            k: &k,
            depth_m: frame.depth_m,
            mask: &mask,
            normals: &normals,
        };
        let align_within = |motion, guess: &Pose| {
            let coarse = align(&model, guess, &view, &params, motion);
            let found = refine_against_sdf(
                &object.volume,
                &coarse,
                &view,
                self.config.settings.truncation_m,
                &params,
                motion,
            );
            (found, evaluate(&model, &found, &view, &params))
        };
        // A motion on a horizontal support first, from the centroids'
        // horizontal offset (a segment's centroid lies off its model's where
        // the views differ, which must not lift a sliding object). Any
        // motion only where none fits and the robot moved the object (it
        // may have tipped over or fallen), or where no up direction is
        // known. An object that only disagreed with the frame was not
        // touched: its fit stays planar, which spares a second alignment
        // in most tracking runs and gives still objects one freedom less to
        // slide into a better-looking fit.
        let planar = params.unit_up().map(|up| {
            let up = t_camera_world.rotation * up;
            let level = Translation3::from(shift - up * up.dot(&shift)) * predicted;
            align_within(MotionModel::Planar { up }, &level)
        });
        let (found, fit) = match planar {
            Some(planar)
                if trigger == TrackingTrigger::Residual
                    || acceptance_failure(&planar.1, &params).is_none() =>
            {
                planar
            }
            _ => align_within(MotionModel::Free, &(Translation3::from(shift) * predicted)),
        };
        let before = evaluate(&model, &old, &view, &params);
        let failure = acceptance_failure(&fit, &params);
        // The old pose explaining the frame about as well is no evidence of motion.
        let shows_motion = fit.shows_motion_from(&before, &params);
        if let Some(failure) = failure {
            // An object that only disagreed with the frame, whose old pose
            // fits the segment about as well as anything alignment found
            // (and at least half as well as acceptance asks), has not been
            // shown to move: its model is what falls short (a part never
            // seen before, a ghost not yet carved). It stays and claims the
            // segment it was aligned to, so the model learns from it; left
            // unclaimed, that segment would become a copy of the object.
            let stays = trigger == TrackingTrigger::Residual
                && !shows_motion
                && before.inliers >= params.min_inliers
                && before.inlier_ratio() >= 0.5 * params.min_inlier_ratio;
            if !stays {
                return Err(failure);
            }
        }
        matches[chosen] = Some(id.0);
        let (translation_m, rotation_deg) = motion_size(&(old.inverse() * found));
        let small =
            translation_m < params.min_translation_m && rotation_deg < params.min_rotation_deg;
        if small || !shows_motion {
            return Ok(TrackingOutcome::Unmoved);
        }
        let t_world_object = frame.t_world_camera * found;
        let object = self.objects.get_mut(&id).expect("tracked object exists");
        let moved = object.t_world_object.inverse() * t_world_object;
        object.t_world_object = t_world_object;
        let (translation_m, rotation_deg) = motion_size(&moved);
        Ok(TrackingOutcome::Moved {
            translation_m,
            rotation_deg,
        })
    }
}
