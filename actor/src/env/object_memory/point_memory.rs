//! Interaction points as an episode's memory (the methods without a map):
//! objects are the simulator's segmentation, each interaction leaves a 3-D
//! point stuck to its object (where the object was when the agent aimed),
//! and labels come from those points: the whole segment under a point in
//! view (`nomap-seg`), or a sphere around it (`nomap-noseg`, `intexp`).

use mapper::{Affordance, Intrinsics, Pose};
use sim::agent::{Outcome, Simulator};
use sim::raycast::Frame;

use super::{tells_the_affordance, Interaction, ObjectMemory};
use crate::labeler::{segment_labels, sphere_labels, EpisodeFrame, InteractionPoint};
use crate::mapping::intrinsics;
use proto::SphereRule;

/// How points become labels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PointLabels {
    /// The whole segment under a point, in every frame where it is in view.
    Segments,
    /// The pixels within a sphere around a point.
    Spheres,
}

/// The points and the objects' poses they move with.
pub(crate) struct PointMemory {
    labels: PointLabels,
    affordances: Vec<Affordance>,
    sphere: SphereRule,
    /// Every interaction that told its object's affordance, as a point on it.
    points: Vec<InteractionPoint>,
    /// Every scene object's pose in every frame.
    object_poses: Vec<Vec<Pose>>,
    /// The point the interaction announced left, if its pixel saw the object.
    pending: Option<InteractionPoint>,
}

impl PointMemory {
    /// No points yet; labels made as `labels` says.
    pub fn new(labels: PointLabels, affordances: &[Affordance], sphere: SphereRule) -> Self {
        Self {
            labels,
            affordances: affordances.to_vec(),
            sphere,
            points: Vec::new(),
            object_poses: Vec::new(),
            pending: None,
        }
    }

    /// The point `interaction` leaves on its object: the aimed pixel
    /// back-projected with the last of `frames`' depth, in the object's
    /// frame as it was then. `None` where the pixel saw nothing.
    fn point_on_object(
        &self,
        frames: &[EpisodeFrame],
        k: &Intrinsics,
        interaction: Interaction,
    ) -> Option<InteractionPoint> {
        let target = interaction.target;
        let frame = frames.last()?;
        let object = (target.object as usize).checked_sub(1)?;
        let pose = self.object_poses.last()?.get(object)?;
        let z = *frame.depth_m.get(target.v * k.width + target.u)?;
        if !(z.is_finite() && z > 0.0) {
            return None;
        }
        let p_world = frame.t_world_camera * k.back_project(target.u as f32, target.v as f32, z);
        Some(InteractionPoint {
            object,
            affordance: self
                .affordances
                .iter()
                .position(|&a| a == interaction.affordance)?,
            success: false,
            p_object: pose.inverse() * p_world,
        })
    }
}

impl ObjectMemory for PointMemory {
    fn take_in(&mut self, sim: &Simulator, frame: &Frame) -> anyhow::Result<Vec<u32>> {
        self.object_poses.push(
            sim.scene()
                .objects
                .iter()
                .map(|o| Pose::from_parts(o.bounds.center.coords.into(), o.bounds.rotation))
                .collect(),
        );
        Ok(frame.ids.clone())
    }

    /// The point is taken where the object is before the action moves it.
    fn before_interaction(
        &mut self,
        sim: &Simulator,
        frames: &[EpisodeFrame],
        interaction: Interaction,
    ) {
        self.pending = self.point_on_object(frames, &intrinsics(&sim.camera()), interaction);
    }

    fn after_interaction(&mut self, _sim: &Simulator, outcome: &Outcome) {
        if let Some(mut point) = self
            .pending
            .take()
            .filter(|_| tells_the_affordance(outcome))
        {
            point.success = outcome.success;
            self.points.push(point);
        }
    }

    /// The points already move with their objects' poses.
    fn put_down(&mut self, _sim: &Simulator, _object: usize) {}

    fn labels(&self, frames: &[EpisodeFrame], k: &Intrinsics) -> Vec<Vec<u8>> {
        let planes = self.affordances.len();
        let poses = &self.object_poses;
        let pose_of = |frame: usize, object: usize| poses[frame][object];
        match self.labels {
            PointLabels::Segments => {
                segment_labels(frames, k, &self.points, planes, &pose_of, &self.sphere)
            }
            PointLabels::Spheres => {
                sphere_labels(frames, k, &self.points, planes, &pose_of, &self.sphere)
            }
        }
    }
}
