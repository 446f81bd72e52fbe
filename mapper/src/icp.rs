//! Tracking of objects that moved: projective point-to-plane ICP of an
//! object's surface against one segment of the current frame.
//!
//! The model is the object's TSDF surface (zero crossings with SDF-gradient
//! normals) in its own frame. Each iteration projects the front-facing model
//! points into the image, pairs each with the measured point of the pixel it
//! lands on (projective association, no search), keeps pairs within a gate
//! that shrinks over the iterations, and solves the linearised point-to-plane
//! problem for a twist in the camera frame. Unlike TSDF++, which aligns every
//! object every frame against a mesh rebuilt from scratch with a 100 m gate,
//! this runs only for objects that may have moved, with a real gate and an
//! acceptance test, and the result is a pose update (no resampling).
//! Where the world's up direction is known, motions are first sought on a
//! horizontal support ([`MotionModel`]).

use nalgebra::{Point3, Vector3};

use crate::camera::Intrinsics;
use crate::layer::{CachedReader, Layer};
use crate::sdf_sample::sdf_with_gradient;
use crate::Pose;

mod normal_equations;

pub use normal_equations::MotionModel;
use normal_equations::NormalEquations;

/// Settings of tracking.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingParams {
    /// Largest motion between two frames that tracking will follow, metres
    /// (from the initial guess to the segment's centroid).
    pub max_motion_m: f32,
    /// How far ahead along the push a pushed object is followed
    /// ([`crate::Map::notify_pushed`]), metres: a push slides an object
    /// much further than anything moves unannounced between two frames.
    /// One pushed further, or out of view, is lost and found again later
    /// ([`TrackingParams::max_reidentify_m`]).
    pub max_push_m: f32,
    /// How far from where it was lost a lost object may be found again
    /// (`Map::reidentify`), metres: pushes in the simulator's rooms slide
    /// objects up to 4.5 m, bouncing off walls and furniture.
    pub max_reidentify_m: f32,
    /// Correspondence gate at the first iteration, metres.
    pub initial_gate_m: f32,
    /// Correspondences closer than this are inliers (and the gate never gets tighter).
    pub inlier_distance_m: f32,
    /// Point-to-plane residuals beyond this get Huber weights, metres.
    pub huber_m: f32,
    /// ICP iterations at most.
    pub max_iterations: usize,
    /// Accept only if at least this fraction of the visible model matches the frame.
    pub min_inlier_ratio: f32,
    /// Accept only if the inliers' point-to-plane RMSE is below this, metres.
    pub max_rmse_m: f32,
    /// Fewer inliers than this is a failure.
    pub min_inliers: usize,
    /// Motions smaller than this (and than `min_rotation_deg`) are not applied.
    pub min_translation_m: f32,
    /// See `min_translation_m`.
    pub min_rotation_deg: f32,
    /// A matched object whose rendered pixels agree with the measured depth
    /// on less than this fraction is checked for motion.
    pub residual_trigger: f32,
    /// The world's up direction, where known: tracking looks for a motion
    /// that slides and turns the object on a horizontal support
    /// ([`MotionModel::Planar`]); for an object the caller said it moved
    /// ([`crate::Map::notify_moved`]) it allows any motion when no such
    /// motion fits (it tipped over or fell). `None` (or a vector of about
    /// zero length, which names no direction) always allows any motion.
    pub world_up: Option<Vector3<f32>>,
}

impl TrackingParams {
    /// [`TrackingParams::world_up`] as a unit vector; `None` where it names
    /// no direction.
    pub fn unit_up(&self) -> Option<Vector3<f32>> {
        self.world_up.and_then(|up| up.try_normalize(1e-6))
    }

    /// Defaults for a given voxel size.
    pub fn for_voxel(voxel_size_m: f32) -> Self {
        Self {
            max_motion_m: 0.3,
            max_push_m: 2.0,
            max_reidentify_m: 5.0,
            initial_gate_m: 0.15,
            inlier_distance_m: 1.5 * voxel_size_m,
            huber_m: 0.25 * voxel_size_m,
            max_iterations: 100,
            min_inlier_ratio: 0.5,
            max_rmse_m: 0.5 * voxel_size_m,
            min_inliers: 30,
            min_translation_m: 0.01,
            min_rotation_deg: 1.0,
            residual_trigger: 0.7,
            world_up: Some(Vector3::z()),
        }
    }
}

/// Why tracking an object failed. The object's volume and pose are left as they were.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum TrackingFailure {
    /// No segment of the frame could be the object.
    #[error("no segment of the frame is near the object")]
    NoSegment,
    /// The nearest candidate segment is further than the motion gate.
    #[error("the object would have moved {distance_m:.2} m, beyond the {gate_m:.2} m gate")]
    BeyondGate {
        /// Distance from the predicted to the observed centroid.
        distance_m: f32,
        /// The gate.
        gate_m: f32,
    },
    /// Too few model points found a partner in the frame.
    #[error("only {inliers} model points matched the frame")]
    TooFewInliers {
        /// Inliers after alignment.
        inliers: usize,
    },
    /// The alignment converged to a poor fit.
    #[error("poor fit: {:.0} % inliers, RMSE {:.1} mm", inlier_ratio * 100.0, rmse_m * 1e3)]
    PoorFit {
        /// Fraction of the visible model that matched.
        inlier_ratio: f32,
        /// Point-to-plane RMSE of the inliers.
        rmse_m: f32,
    },
}

/// What tracking concluded for one object in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrackingOutcome {
    /// It moved; the pose was updated.
    Moved {
        /// Translation of the object's origin, metres.
        translation_m: f32,
        /// Rotation angle, degrees.
        rotation_deg: f32,
    },
    /// The best alignment is within the no-motion thresholds (or no better
    /// than the old pose); nothing changed.
    Unmoved,
    /// Tracking failed; nothing changed and the object was not integrated.
    Failed(TrackingFailure),
}

/// Why an object was tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingTrigger {
    /// The caller said it may have moved ([`crate::Map::notify_moved`]).
    Notified,
    /// Its rendered surface disagreed with the measured depth.
    Residual,
}

/// One object's tracking result for the last frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingReport {
    /// The object.
    pub object: crate::ObjectId,
    /// Why it was tracked.
    pub trigger: TrackingTrigger,
    /// What happened.
    pub outcome: TrackingOutcome,
    /// The outcome is the failure of an earlier frame that showed the object
    /// from the same camera pose with the same residual; no alignment ran.
    pub repeated: bool,
}

/// The measured side of an alignment: a depth image and the pixels of the
/// segment the object is aligned to.
#[derive(Debug, Clone, Copy)]
pub struct SegmentView<'a> {
    /// Camera model.
    pub k: &'a Intrinsics,
    /// Z-depth per pixel.
    pub depth_m: &'a [f32],
    /// True for the segment's pixels.
    pub mask: &'a [bool],
    /// Camera-frame unit normals of the segment's pixels ([`measured_normals`]).
    pub normals: &'a [Option<Vector3<f32>>],
}

/// Unit normals (camera frame, facing the camera) of the masked pixels, from
/// central differences of their back-projected neighbours inside the mask.
pub fn measured_normals(
    k: &Intrinsics,
    depth_m: &[f32],
    mask: &[bool],
) -> Vec<Option<Vector3<f32>>> {
    let (w, h) = (k.width, k.height);
    let point = |u: usize, v: usize| {
        let px = v * w + u;
        mask[px].then(|| k.back_project(u as f32, v as f32, depth_m[px]))
    };
    let mut out = vec![None; w * h];
    for v in 1..h.saturating_sub(1) {
        for u in 1..w.saturating_sub(1) {
            let Some(c) = point(u, v) else { continue };
            let (Some(l), Some(r), Some(t), Some(b)) = (
                point(u - 1, v),
                point(u + 1, v),
                point(u, v - 1),
                point(u, v + 1),
            ) else {
                continue;
            };
            let Some(n) = (r - l).cross(&(b - t)).try_normalize(1e-12) else {
                continue;
            };
            out[v * w + u] = Some(if n.dot(&c.coords) > 0.0 { -n } else { n });
        }
    }
    out
}

/// Quality of an alignment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    /// Model points that matched within the inlier distance.
    pub inliers: usize,
    /// Model points that should be visible: front-facing, on the segment or
    /// where the frame sees *behind* them (a free-space violation).
    pub visible: usize,
    /// Point-to-plane RMSE of the inliers, metres.
    pub rmse_m: f32,
}

impl Fit {
    /// Inliers over visible points (0 when nothing is visible).
    pub fn inlier_ratio(&self) -> f32 {
        if self.visible == 0 {
            0.0
        } else {
            self.inliers as f32 / self.visible as f32
        }
    }

    /// Whether this fit, of an aligned pose, is evidence that the object
    /// moved from the pose `before` was measured at (on the same segment):
    /// the aligned pose matches clearly more of the segment
    /// ([`MIN_INLIER_GAIN`] times the inliers, and at least
    /// [`TrackingParams::min_inliers`] more), or about as many points
    /// [`MIN_TIGHTENING`] times more tightly (a move along the surface's
    /// normal, within the inlier distance of both poses). The share of
    /// visible points is no evidence: it changes with what each pose hides.
    ///
    /// The bar is high because the two mistakes cost differently: moving a
    /// still object shifts its model and every label drawn from it, while a
    /// missed motion costs little (the object is seen where its model was
    /// not, and triggers again). Partial views of large objects (a painting,
    /// a shelf, a table top: mostly out of view or occluded, their surfaces
    /// flat enough for ICP to slide along) fit slightly better somewhere
    /// else.
    pub fn shows_motion_from(&self, before: &Fit, params: &TrackingParams) -> bool {
        let (inliers, inliers_before) = (self.inliers as f32, before.inliers as f32);
        let more_matched = inliers >= MIN_INLIER_GAIN * inliers_before
            && self.inliers >= before.inliers + params.min_inliers;
        let tighter =
            inliers >= 0.95 * inliers_before && MIN_TIGHTENING * self.rmse_m <= before.rmse_m;
        more_matched || tighter
    }
}

/// Least factor by which an aligned pose must multiply the inliers to count
/// as evidence of motion ([`Fit::shows_motion_from`]). Over 2 400-step
/// `ours` episodes, the motions of still objects that weaker tests let
/// through multiplied them by 0.86 to 1.23, adding at most 8; the real
/// motions of the mapper's tests and of those episodes, by 1.29 and more,
/// adding 43 and more (or they fit [`MIN_TIGHTENING`]).
pub const MIN_INLIER_GAIN: f32 = 1.2;

/// Least factor by which the RMSE must drop, at about the same inliers, to
/// count as evidence of motion ([`Fit::shows_motion_from`]): the still
/// objects of [`MIN_INLIER_GAIN`]'s episodes reached at most 1.9, the
/// tests' real motions that matched no more points 2.7 and more.
pub const MIN_TIGHTENING: f32 = 2.5;

/// Pairs whose model and measured normals differ by more than ~37° are not used.
const MIN_NORMAL_COSINE: f32 = 0.8;

/// One model point's partner in the frame.
enum Pairing {
    /// Back-facing, outside the image, or hidden behind something nearer.
    Hidden,
    /// Should be visible but the frame shows no segment surface near it.
    Unmatched,
    /// Camera-frame model point, the normal of the plane it is pulled to, and the measured point.
    Matched(Point3<f32>, Vector3<f32>, Point3<f32>),
}

fn pair(
    point: &Point3<f32>,
    normal: &Vector3<f32>,
    t_camera_object: &Pose,
    view: &SegmentView<'_>,
    tolerance_m: f32,
) -> Pairing {
    let p = t_camera_object * point;
    let n = t_camera_object.rotation * normal;
    if n.dot(&p.coords) >= 0.0 {
        return Pairing::Hidden;
    }
    let Some((u, v, z)) = view.k.project(&p) else {
        return Pairing::Hidden;
    };
    let Some(px) = view.k.pixel_index(u, v) else {
        return Pairing::Hidden;
    };
    let d = view.depth_m[px];
    if !(d.is_finite() && d > 0.0) {
        return Pairing::Hidden;
    }
    if !view.mask[px] {
        return if d > z + tolerance_m {
            Pairing::Unmatched
        } else {
            Pairing::Hidden
        };
    }
    if view.normals[px].is_some_and(|m| m.dot(&n) < MIN_NORMAL_COSINE) {
        // A different side of the object (or a rounded edge of the model).
        return Pairing::Hidden;
    }
    let q = view
        .k
        .back_project((px % view.k.width) as f32, (px / view.k.width) as f32, d);
    // Point-to-plane against the measured surface's normal where known.
    Pairing::Matched(p, view.normals[px].unwrap_or(n), q)
}

/// How well `model` (object frame: points and outward normals) placed at
/// `t_camera_object` explains the segment.
pub fn evaluate(
    model: &[(Point3<f32>, Vector3<f32>)],
    t_camera_object: &Pose,
    view: &SegmentView<'_>,
    params: &TrackingParams,
) -> Fit {
    let (mut inliers, mut visible, mut squares) = (0, 0, 0.0f32);
    for (point, normal) in model {
        match pair(
            point,
            normal,
            t_camera_object,
            view,
            params.inlier_distance_m,
        ) {
            Pairing::Hidden => {}
            Pairing::Unmatched => visible += 1,
            Pairing::Matched(p, n, q) => {
                visible += 1;
                if (p - q).norm() <= params.inlier_distance_m {
                    inliers += 1;
                    squares += ((p - q).dot(&n)).powi(2);
                }
            }
        }
    }
    Fit {
        inliers,
        visible,
        rmse_m: if inliers == 0 {
            f32::INFINITY
        } else {
            (squares / inliers as f32).sqrt()
        },
    }
}

fn model_centre(model: &[(Point3<f32>, Vector3<f32>)]) -> Point3<f32> {
    let sum = model
        .iter()
        .fold(Vector3::zeros(), |sum, (p, _)| sum + p.coords);
    Point3::from(sum / model.len().max(1) as f32)
}

/// Aligns `model` to the segment starting from `guess` (camera ← object) by
/// projective point-to-plane ICP, within `motion`. Returns the refined
/// pose; judge it with [`evaluate`].
pub fn align(
    model: &[(Point3<f32>, Vector3<f32>)],
    guess: &Pose,
    view: &SegmentView<'_>,
    params: &TrackingParams,
    motion: MotionModel,
) -> Pose {
    let mut t = *guess;
    let mut gate = params.initial_gate_m;
    let centre_object = model_centre(model);
    for _ in 0..params.max_iterations {
        let mut equations = NormalEquations::new(t * centre_object);
        for (point, normal) in model {
            let Pairing::Matched(p, n, q) = pair(point, normal, &t, view, gate) else {
                continue;
            };
            if (p - q).norm() > gate {
                continue;
            }
            let arm = (p - equations.centre).cross(&n);
            equations.add((p - q).dot(&n), arm, n, params.huber_m);
        }
        let Some((step, size)) = equations.solve(motion) else {
            break;
        };
        t = step * t;
        gate = (gate * 0.7).max(params.inlier_distance_m);
        if size < 1e-5 && gate <= params.inlier_distance_m {
            break;
        }
    }
    t
}

/// Refines an alignment against the object's TSDF itself: minimises the
/// interpolated SDF at the segment's measured points (dense, sub-voxel, no
/// correspondences), in the spirit of SDF tracking (Bylow et al., 2013).
/// Each point's residual and gradient come from the one trilinear cell it
/// lies in: central differences read six cells more, which cost a fifth of
/// the map's time a step over 600-step 128-px episodes and made
/// re-identification's bursts several times longer
/// (docs/notebook/2026-11-28-sdf-refinement-audit.md). Points where the SDF
/// is unknown (any of the cell's eight voxels unobserved), truncated, or
/// beyond the inlier distance are left out. Converges only from within about
/// the truncation distance, which is why [`align`] runs first. Stays within
/// `motion`. Stops early when a step undoes the last one: counted over `ours`
/// episodes, a quarter of re-identification's refinements cycled between two
/// poses or slid across a surface until the last iteration, and the cycles
/// were a third of them (docs/notebook/2026-11-30-policy-pass-phases.md).
pub fn refine_against_sdf(
    layer: &Layer,
    start: &Pose,
    view: &SegmentView<'_>,
    truncation_m: f32,
    params: &TrackingParams,
    motion: MotionModel,
) -> Pose {
    let k = view.k;
    let points: Vec<Point3<f32>> = (0..k.pixels())
        .filter(|&px| view.mask[px])
        .map(|px| {
            k.back_project(
                (px % k.width) as f32,
                (px / k.width) as f32,
                view.depth_m[px],
            )
        })
        .collect();
    let mut t = *start;
    let centre_camera = points
        .iter()
        .fold(Vector3::zeros(), |sum, p| sum + p.coords)
        / points.len().max(1) as f32;
    let mut reader = CachedReader::new(layer);
    let mut last_step: Option<(Pose, f32)> = None;
    for _ in 0..params.max_iterations {
        let t_object_camera = t.inverse();
        let mut equations = NormalEquations::new(Point3::from(centre_camera));
        for q in &points {
            let x = t_object_camera * q;
            let Some((r, g)) = sdf_with_gradient(&mut reader, &x) else {
                continue;
            };
            if r.abs() > params.inlier_distance_m.min(0.9 * truncation_m) {
                continue;
            }
            // Moving the object by the twist moves q the other way in its frame.
            let g_camera = t.rotation * g;
            let arm = (q - equations.centre).cross(&g_camera);
            equations.add(r, -arm, -g_camera, params.huber_m);
        }
        let Some((step, size)) = equations.solve(motion) else {
            break;
        };
        t = step * t;
        if size < 1e-6 {
            break;
        }
        // A step that undoes the last one: the refinement cycles between
        // two poses and would until the last iteration.
        if let Some((last, last_size)) = last_step {
            let (moved_m, turned_deg) = motion_size(&(step * last));
            if moved_m.max(turned_deg.to_radians()) < 0.1 * size.min(last_size) {
                break;
            }
        }
        last_step = Some((step, size));
    }
    t
}

/// Translation (metres) and rotation (degrees) of a motion.
pub fn motion_size(motion: &Pose) -> (f32, f32) {
    (
        motion.translation.vector.norm(),
        motion.rotation.angle().to_degrees(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn fit(inliers: usize, visible: usize, rmse_mm: f32) -> Fit {
        Fit {
            inliers,
            visible,
            rmse_m: rmse_mm * 1e-3,
        }
    }

    /// Fits measured in `ours` episodes and in the mapper's tests: (old
    /// pose, aligned pose) of objects that had not moved and of objects
    /// that had.
    #[test]
    fn motion_needs_more_matches_or_a_much_tighter_fit() {
        let params = TrackingParams::for_voxel(0.04);
        let still = [
            ("painting", fit(28, 47, 5.7), fit(30, 57, 3.6)),
            ("dining table", fit(40, 66, 5.3), fit(43, 63, 6.1)),
            ("dining table again", fit(31, 68, 7.1), fit(38, 74, 8.5)),
            ("television", fit(61, 133, 8.8), fit(68, 133, 7.1)),
            ("painting, far", fit(185, 366, 18.3), fit(193, 371, 9.8)),
            ("shelf", fit(132, 225, 4.4), fit(114, 161, 3.3)),
            ("cabinet", fit(65, 115, 4.1), fit(70, 96, 4.0)),
        ];
        for (what, before, after) in still {
            assert!(!after.shows_motion_from(&before, &params), "{what}");
        }
        let moved = [
            ("pushed chair", fit(1, 37, 3.3), fit(51, 55, 7.0)),
            ("box moved 10 cm", fit(50, 136, 8.9), fit(180, 204, 5.9)),
            ("box sliding sideways", fit(90, 90, 1.8), fit(169, 172, 1.7)),
            (
                "box sliding, same matches",
                fit(191, 199, 11.5),
                fit(191, 255, 1.3),
            ),
            (
                "box sliding, one match less",
                fit(188, 190, 8.8),
                fit(187, 241, 3.3),
            ),
        ];
        for (what, before, after) in moved {
            assert!(after.shows_motion_from(&before, &params), "{what}");
        }
    }

    /// Points and normals of the three visible faces of a unit-ish box corner.
    fn corner_model() -> Vec<(Point3<f32>, Vector3<f32>)> {
        let mut model = Vec::new();
        for i in 0..15 {
            for j in 0..15 {
                let (a, b) = (-0.2 + 0.02 * i as f32, -0.2 + 0.02 * j as f32);
                model.push((Point3::new(-0.2, a, b), -Vector3::x()));
                model.push((Point3::new(a, -0.2, b), -Vector3::y()));
                model.push((Point3::new(a, b, -0.2), -Vector3::z()));
            }
        }
        model
    }

    /// Depth image of the planes x = y = z = -0.2 (object frame) seen by a camera.
    fn render_planes(t_camera_object: &Pose, k: &Intrinsics) -> Vec<f32> {
        let t_object_camera = t_camera_object.inverse();
        let o = t_object_camera * Point3::origin();
        (0..k.pixels())
            .map(|px| {
                let d =
                    t_object_camera.rotation * k.ray((px % k.width) as f32, (px / k.width) as f32);
                let mut best = f32::INFINITY;
                for a in 0..3 {
                    if d[a].abs() < 1e-9 {
                        continue;
                    }
                    let s = (-0.2 - o[a]) / d[a];
                    let hit = o + d * s;
                    let inside = (0..3).all(|b| b == a || (-0.2..=0.1).contains(&hit[b]));
                    if s > 0.0 && inside {
                        best = best.min(s);
                    }
                }
                if best.is_finite() {
                    best
                } else {
                    0.0
                }
            })
            .collect()
    }

    #[test]
    fn icp_recovers_a_small_motion_of_three_planes() {
        let k = Intrinsics::from_fov(128, 128, 90.0);
        // Camera looking at the corner (-0.2, -0.2, -0.2) from outside.
        let eye = Vector3::new(-1.2, -1.1, -1.0);
        let forward = -eye.normalize();
        let right = forward.cross(&Vector3::z()).normalize();
        let down = forward.cross(&right);
        let rot = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
            right, down, forward,
        ]));
        let t_object_camera =
            Pose::from_parts(eye.into(), UnitQuaternion::from_rotation_matrix(&rot));
        let truth = t_object_camera.inverse();
        let depth = render_planes(&truth, &k);
        let mask: Vec<bool> = depth.iter().map(|&d| d > 0.0).collect();
        let normals = measured_normals(&k, &depth, &mask);
        let view = SegmentView {
            k: &k,
            depth_m: &depth,
            mask: &mask,
            normals: &normals,
        };
        let params = TrackingParams::for_voxel(0.04);
        let model = corner_model();
        let offset = Pose::from_parts(
            Vector3::new(0.05, -0.04, 0.03).into(),
            UnitQuaternion::from_euler_angles(0.05, -0.08, 0.12),
        );
        let guess = truth * offset; // a motion of the object about its own origin
        let before = evaluate(&model, &guess, &view, &params);
        let found = align(&model, &guess, &view, &params, MotionModel::Free);
        let after = evaluate(&model, &found, &view, &params);
        let (dt, dr) = motion_size(&(truth.inverse() * found));
        assert!(dt < 0.002 && dr < 0.2, "error {dt} m, {dr} deg");
        assert!(after.inlier_ratio() > 0.9, "{after:?}");
        assert!(after.rmse_m < 0.003, "{after:?}");
        assert!(after.inlier_ratio() > before.inlier_ratio());
    }
}
