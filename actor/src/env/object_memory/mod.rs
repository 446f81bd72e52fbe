//! What an episode remembers of its objects, behind one interface: the
//! object-level map for `ours` ([`MapMemory`]), interaction points stuck to
//! the simulator's objects for the methods without a map ([`PointMemory`]).
//! The memory names the objects of every frame, keeps every interaction's
//! outcome on its object, and turns those outcomes into the episode's label
//! planes; the environment's step only says what happened
//! ([`ObjectMemory::take_in`], [`ObjectMemory::before_interaction`],
//! [`ObjectMemory::after_interaction`], [`ObjectMemory::put_down`]), so a
//! new kind of memory is a new implementation, not edits along the step.

mod map_memory;
mod point_memory;

pub(crate) use map_memory::MapMemory;
pub(crate) use point_memory::{PointLabels, PointMemory};

use mapper::{Affordance, IntegrateTimings, Intrinsics, Map, MapConfig};
use proto::{ConfidenceRule, LabelSource, MethodSpec, SphereRule};
use sim::agent::{Failure, Outcome, Simulator};
use sim::raycast::Frame;

use crate::env::actions::Target;
use crate::labeler::EpisodeFrame;
use crate::ladder_labels::TriedObjects;
use crate::recording::ObjectRecord;

/// An interaction the agent is about to try.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Interaction {
    /// What it tries.
    pub affordance: Affordance,
    /// The object it aims at: its id in the last frame's ids
    /// ([`ObjectMemory::take_in`]) and the pixel aimed at.
    pub target: Target,
}

/// An episode's memory of its objects.
pub(crate) trait ObjectMemory: Send {
    /// Takes in the frame just rendered from `sim`'s camera and returns the
    /// id of the object under each pixel (0: none): map ids, or the
    /// simulator's segmentation without a map.
    fn take_in(&mut self, sim: &Simulator, frame: &Frame) -> anyhow::Result<Vec<u32>>;

    /// Where the last [`ObjectMemory::take_in`]'s time went (zero without a map).
    fn integrate_timings(&self) -> IntegrateTimings {
        IntegrateTimings::default()
    }

    /// Called before `sim` tries `interaction` on an object of the last of
    /// `frames` (the frames observed so far this episode).
    fn before_interaction(
        &mut self,
        sim: &Simulator,
        frames: &[EpisodeFrame],
        interaction: Interaction,
    );

    /// Called after the interaction announced last: `sim` as the action left
    /// it, and what came of it.
    fn after_interaction(&mut self, sim: &Simulator, outcome: &Outcome);

    /// Called after the agent put down the object it held, `object` being
    /// its index among `sim`'s scene objects.
    fn put_down(&mut self, sim: &Simulator, object: usize);

    /// The object-level map, for the state's map planes; `None` without one.
    fn map(&self) -> Option<&Map> {
        None
    }

    /// Adds a confidence label to every object nobody touched that the
    /// calibrated U-Net is sure about over the episode's `frames`
    /// (`probabilities`: one byte per pixel and affordance per frame, planes
    /// in order). The paper annotates by confidence through its map only: a
    /// memory without objects of its own leaves this alone.
    fn annotate_by_confidence(
        &mut self,
        _frames: &[EpisodeFrame],
        _probabilities: &[Vec<u8>],
    ) -> anyhow::Result<()> {
        Ok(())
    }

    /// Every frame's label planes (one byte per pixel and affordance,
    /// `proto::LABEL_*`), from the outcomes remembered.
    fn labels(&self, frames: &[EpisodeFrame], k: &Intrinsics) -> Vec<Vec<u8>>;

    /// How consistently the memory named the scene's objects across the
    /// episode (`truth_ids`: the simulator's instance ids of every frame);
    /// `None` where the memory's ids are the simulator's own.
    fn id_consistency(&self, _truth_ids: &[Vec<u32>], _frames: &[EpisodeFrame]) -> Option<f32> {
        None
    }

    /// The objects the agent tried, and every one of `frames`' objects as
    /// the memory knows them at the episode's end, for the label ladder's
    /// dataset ([`crate::ladder_labels`]); `None` for a memory without
    /// objects of its own.
    fn tried_objects(&self, _frames: &[EpisodeFrame]) -> Option<TriedObjects> {
        None
    }

    /// The remembered objects with their meshes and labels, for a recording
    /// (none without a map).
    fn object_records(&self) -> anyhow::Result<Vec<ObjectRecord>> {
        Ok(Vec::new())
    }
}

/// The rules a memory labels by, from the run's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct MemoryRules {
    /// The map's settings.
    pub map: MapConfig,
    /// The thresholds of annotation by confidence.
    pub confidence: ConfidenceRule,
    /// The point labels of the methods without a map.
    pub sphere: SphereRule,
}

/// The memory `spec`'s method keeps in an episode on a scene whose instance
/// ids have the classes `classes` ([`crate::mapping::instance_classes`]).
pub(crate) fn object_memory(
    spec: &MethodSpec,
    rules: &MemoryRules,
    affordances: &[Affordance],
    classes: Vec<u16>,
) -> Box<dyn ObjectMemory> {
    match spec.labels {
        LabelSource::Map => Box::new(MapMemory::new(
            rules.map,
            classes,
            affordances,
            rules.confidence,
        )),
        LabelSource::Segments => Box::new(PointMemory::new(
            PointLabels::Segments,
            affordances,
            rules.sphere,
        )),
        LabelSource::Spheres => Box::new(PointMemory::new(
            PointLabels::Spheres,
            affordances,
            rules.sphere,
        )),
    }
}

/// Whether an interaction's outcome says anything about its object's
/// affordance, so that labels may follow from it: a success, or a failure of
/// the object itself. An arm that never reached the object (beyond reach, no
/// room to lift it, nothing under the pixel) learnt nothing about it; the
/// robot knows this from its own arm, and labelling such objects negative
/// taught the U-Net that reachable pickupable objects cannot be picked up
/// (most of a trained policy's failed pick-ups were beyond reach:
/// docs/ladder.md, "Selection within reach").
pub(crate) fn tells_the_affordance(outcome: &Outcome) -> bool {
    outcome.success
        || outcome
            .failure
            .as_ref()
            .is_some_and(Failure::object_does_not_afford)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_successes_and_failures_of_the_object_itself_make_labels() {
        let failed = |failure| Outcome {
            success: false,
            failure: Some(failure),
        };
        let succeeded = Outcome {
            success: true,
            failure: None,
        };
        assert!(tells_the_affordance(&succeeded));
        for evidence in [
            Failure::NotPickupable,
            Failure::TooHeavy { mass_kg: 30.0 },
            Failure::TooWide { width_m: 0.5 },
            Failure::NotPushable,
            Failure::DidNotMove { moved_m: 0.01 },
        ] {
            assert!(
                tells_the_affordance(&failed(evidence.clone())),
                "{evidence:?}"
            );
        }
        for no_evidence in [
            Failure::OutOfReach { distance_m: 1.4 },
            Failure::NothingThere,
            Failure::NoRoom {
                blocked_by: "Shelf".into(),
            },
        ] {
            assert!(
                !tells_the_affordance(&failed(no_evidence.clone())),
                "{no_evidence:?}"
            );
        }
    }
}
