//! The object-level map as an episode's memory (`ours`): frames are
//! integrated into it, interactions recorded on its objects (a pushed object
//! is tracked along the push, a picked-up one held unseen until it is put
//! down), and labels come from every view of an object it holds an outcome
//! for, by interaction and, later in a run, by confidence.

use std::collections::BTreeSet;

use anyhow::Context;
use mapper::{
    Affordance, IntegrateTimings, Intrinsics, Map, MapConfig, ObjectId, Outcome as MapOutcome, Pose,
};
use proto::ConfidenceRule;
use sim::agent::{Failure, Outcome, Simulator};
use sim::raycast::Frame;
use sim::scene::OrientedBox;

use super::{tells_the_affordance, Interaction, ObjectMemory};
use crate::frame_scores::map_id_consistency;
use crate::labeler::{apply_confidence_labels, confidence_labels, map_labels, EpisodeFrame};
use crate::ladder_labels::TriedObjects;
use crate::mapping::{class_image, map_frame};
use crate::recording::ObjectRecord;

/// The map and what the episode's step needs around it.
pub(crate) struct MapMemory {
    map: Map,
    /// The class of every instance id of the scene, for the map's frames.
    classes: Vec<u16>,
    affordances: Vec<Affordance>,
    confidence: ConfidenceRule,
    /// The interaction announced, with every scene object's box before it
    /// when it is a pick-up (where the held object was).
    pending: Option<(Interaction, Vec<OrientedBox>)>,
    /// The object in the hand: its map id and its box when it was picked up.
    in_hand: Option<(ObjectId, OrientedBox)>,
    /// Every (object, affordance) the agent tried on an object, whatever
    /// came of it (by the id the object had then).
    tried: BTreeSet<(ObjectId, Affordance)>,
}

impl MapMemory {
    /// An empty map with `config`, for a scene whose instance ids have the
    /// classes `classes`, labelling `affordances` (planes in order).
    pub fn new(
        config: MapConfig,
        classes: Vec<u16>,
        affordances: &[Affordance],
        confidence: ConfidenceRule,
    ) -> Self {
        Self {
            map: Map::new(config),
            classes,
            affordances: affordances.to_vec(),
            confidence,
            pending: None,
            in_hand: None,
            tried: BTreeSet::new(),
        }
    }
}

impl ObjectMemory for MapMemory {
    fn take_in(&mut self, sim: &Simulator, frame: &Frame) -> anyhow::Result<Vec<u32>> {
        let class = class_image(&frame.ids, &self.classes);
        self.map
            .integrate(&map_frame(&sim.camera(), frame, &class))
            .context("integrating the frame into the map")
    }

    fn integrate_timings(&self) -> IntegrateTimings {
        self.map.last_timings()
    }

    fn before_interaction(
        &mut self,
        sim: &Simulator,
        _frames: &[EpisodeFrame],
        interaction: Interaction,
    ) {
        let boxes = match interaction.affordance {
            Affordance::PickUp => sim.scene().objects.iter().map(|o| o.bounds).collect(),
            Affordance::Push => Vec::new(),
        };
        self.pending = Some((interaction, boxes));
    }

    fn after_interaction(&mut self, sim: &Simulator, outcome: &Outcome) {
        let Some((interaction, boxes_before)) = self.pending.take() else {
            return;
        };
        if !matches!(outcome.failure, Some(Failure::NothingThere)) {
            self.tried
                .insert((ObjectId(interaction.target.object), interaction.affordance));
        }
        if !tells_the_affordance(outcome) {
            return;
        }
        let id = ObjectId(interaction.target.object);
        let result = if outcome.success {
            MapOutcome::Success
        } else {
            MapOutcome::Failure
        };
        // Only ids of the frame's objects are selectable, so the object
        // exists; labels of objects the map deletes later stay with it.
        let _ = self
            .map
            .record_interaction(id, interaction.affordance, result);
        if !outcome.success {
            return;
        }
        match interaction.affordance {
            Affordance::Push => {
                // The map tracks the pushed object from the next frame on,
                // looking along the push (the camera's heading) for it.
                let yaw = sim.agent().yaw_deg.to_radians();
                let along = nalgebra::Vector3::new(yaw.cos(), yaw.sin(), 0.0);
                let _ = self.map.notify_pushed(id, along);
            }
            Affordance::PickUp => {
                // The map keeps the object, unseen, until it is put down.
                if let Some(index) = sim.held() {
                    if self.map.hold(id).is_ok() {
                        self.in_hand = Some((id, boxes_before[index]));
                    }
                }
            }
        }
    }

    fn put_down(&mut self, sim: &Simulator, object: usize) {
        if let Some((id, before)) = self.in_hand.take() {
            let after = sim.scene().objects[object].bounds;
            let pose = |b: &OrientedBox| Pose::from_parts(b.center.coords.into(), b.rotation);
            let _ = self.map.release(id, pose(&after) * pose(&before).inverse());
        }
    }

    fn map(&self) -> Option<&Map> {
        Some(&self.map)
    }

    fn annotate_by_confidence(
        &mut self,
        frames: &[EpisodeFrame],
        probabilities: &[Vec<u8>],
    ) -> anyhow::Result<()> {
        let Some(first) = frames.first() else {
            return Ok(());
        };
        let pixels = first.depth_m.len();
        for (plane, &affordance) in self.affordances.iter().enumerate() {
            let planes: Vec<Vec<f32>> = probabilities
                .iter()
                .map(|p| {
                    p[plane * pixels..(plane + 1) * pixels]
                        .iter()
                        .map(|&b| proto::byte_to_unit(b))
                        .collect()
                })
                .collect();
            let decided =
                confidence_labels(&self.map, frames, &planes, affordance, &self.confidence);
            apply_confidence_labels(&mut self.map, affordance, &decided)
                .context("storing confidence labels on the map")?;
        }
        Ok(())
    }

    fn labels(&self, frames: &[EpisodeFrame], _k: &Intrinsics) -> Vec<Vec<u8>> {
        map_labels(&self.map, frames, &self.affordances)
    }

    fn id_consistency(&self, truth_ids: &[Vec<u32>], frames: &[EpisodeFrame]) -> Option<f32> {
        let pairs = truth_ids
            .iter()
            .zip(frames)
            .map(|(truth, frame)| (truth.as_slice(), frame.map_ids.as_slice()));
        map_id_consistency(pairs, |id| self.map.current_id(ObjectId(id)).0)
    }

    fn tried_objects(&self, frames: &[EpisodeFrame]) -> Option<TriedObjects> {
        let current = |id: u32| {
            if id == 0 {
                0
            } else {
                self.map.current_id(ObjectId(id)).0
            }
        };
        Some(TriedObjects {
            objects: frames
                .iter()
                .map(|frame| frame.map_ids.iter().map(|&id| current(id)).collect())
                .collect(),
            tried: self
                .tried
                .iter()
                .map(|&(id, affordance)| (current(id.0), affordance))
                .collect(),
        })
    }

    fn object_records(&self) -> anyhow::Result<Vec<ObjectRecord>> {
        self.map
            .objects()
            .values()
            .map(|object| {
                let mesh = self
                    .map
                    .object_mesh(object.id)
                    .context("meshing a map object for the recording")?;
                let mut metadata = vec![(
                    "class".to_owned(),
                    object
                        .class()
                        .map_or_else(|| "unknown".to_owned(), |c| c.to_string()),
                )];
                for &a in &self.affordances {
                    let label = match object.labels.label(a) {
                        Some(true) => "positive",
                        Some(false) => "negative",
                        None => "unknown",
                    };
                    metadata.push((a.as_str().to_owned(), label.to_owned()));
                }
                Ok(ObjectRecord {
                    id: object.id.0,
                    mesh,
                    metadata,
                })
            })
            .collect()
    }
}
