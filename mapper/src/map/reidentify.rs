//! Finding lost objects again. A push can slide an object metres away,
//! turned, out of view or past where tracking looks for it the next frame;
//! tracking then fails and the object is lost ([`Whereabouts::Lost`]). When
//! a segment that would become a new object appears later, each lost object
//! near enough is aligned to it from several headings; one that fits takes
//! the segment back, with its id, volume and labels, instead of a copy
//! without them.

use std::f32::consts::TAU;

use nalgebra::{Point3, Translation3, Unit, UnitQuaternion};

use super::track::{acceptance_failure, centroid};
use super::{Map, ObjectId, Whereabouts};
use crate::association::Segment;
use crate::camera::Frame;
use crate::tracking::{
    align, evaluate, measured_normals, refine_against_sdf, MotionModel, SegmentView,
};
use crate::Pose;

/// Headings (turns about the world's up direction) each alignment starts
/// from: a pushed object may come to rest turned any way.
const HEADINGS: usize = 8;

/// The best alignment of one lost object found so far: its inliers, id and
/// camera-frame pose.
type Candidate = (usize, ObjectId, Pose);

impl Map {
    /// The lost object that `segment` shows, if one fits it: within
    /// [`crate::TrackingParams::max_reidentify_m`] of where it was lost, no
    /// smaller than half the segment's spread, and aligned to it (sliding
    /// and turning on a horizontal support, from [`HEADINGS`] headings)
    /// well enough for tracking's acceptance tests. Of several, the one
    /// with the most inliers. It is placed at the aligned pose and its id
    /// returned. Needs the world's up direction; without one, nothing is
    /// found.
    pub(super) fn reidentify(&mut self, segment: &Segment, frame: &Frame<'_>) -> Option<ObjectId> {
        let params = self.config.tracking;
        let up = Unit::new_normalize(params.unit_up()?);
        if !self
            .objects
            .values()
            .any(|o| o.whereabouts == Whereabouts::Lost)
        {
            return None;
        }
        let k = frame.intrinsics;
        let pixels = || segment.pixels.iter().copied();
        let seen_at = centroid(&k, frame.depth_m, pixels())?;
        let spread = pixels()
            .map(|px| {
                let p = k.back_project(
                    (px % k.width) as f32,
                    (px / k.width) as f32,
                    frame.depth_m[px],
                );
                (p - seen_at).norm()
            })
            .fold(0.0f32, f32::max);
        let seen_at_world = frame.t_world_camera * seen_at;
        let mut mask = vec![false; k.pixels()];
        for px in pixels() {
            mask[px] = true;
        }
        let normals = measured_normals(&k, frame.depth_m, &mask);
        let view = SegmentView {
            k: &k,
            depth_m: frame.depth_m,
            mask: &mask,
            normals: &normals,
        };
        let t_camera_world = frame.t_world_camera.inverse();
        let motion = MotionModel::Planar {
            up: t_camera_world.rotation * up.into_inner(),
        };
        let mut best: Option<Candidate> = None;
        for object in self
            .objects
            .values()
            .filter(|o| o.whereabouts == Whereabouts::Lost)
        {
            let model = object
                .volume
                .surface_samples(2.0 * self.config.voxel_size_m);
            if model.len() < params.min_inliers {
                continue;
            }
            let centre = Point3::from(
                model
                    .iter()
                    .map(|(p, _)| p.coords)
                    .sum::<nalgebra::Vector3<f32>>()
                    / model.len() as f32,
            );
            let radius = model
                .iter()
                .map(|(p, _)| (p - centre).norm())
                .fold(0.0f32, f32::max);
            let lost_at = object.t_world_object * centre;
            let shift = seen_at_world - lost_at;
            if shift.norm() > params.max_reidentify_m || 2.0 * radius < spread {
                continue;
            }
            // Slid level to where the segment is seen, turned about its centre.
            let level = shift - up.into_inner() * up.dot(&shift);
            for heading in 0..HEADINGS {
                let turn =
                    UnitQuaternion::from_axis_angle(&up, heading as f32 * TAU / HEADINGS as f32);
                let t_world_guess = Translation3::from(lost_at.coords + level)
                    * turn
                    * Translation3::from(-lost_at.coords)
                    * object.t_world_object;
                let coarse = align(
                    &model,
                    &(t_camera_world * t_world_guess),
                    &view,
                    &params,
                    motion,
                );
                let found = refine_against_sdf(
                    &object.volume,
                    &coarse,
                    &view,
                    self.config.integration.truncation_m,
                    &params,
                    motion,
                );
                let fit = evaluate(&model, &found, &view, &params);
                if acceptance_failure(&fit, &params).is_none()
                    && best
                        .as_ref()
                        .is_none_or(|(inliers, _, _)| fit.inliers > *inliers)
                {
                    best = Some((fit.inliers, object.id, found));
                }
            }
        }
        let (_, id, t_camera_object) = best?;
        let object = self.objects.get_mut(&id)?;
        object.t_world_object = frame.t_world_camera * t_camera_object;
        object.whereabouts = Whereabouts::Placed;
        object.misses = 0;
        Some(id)
    }
}
