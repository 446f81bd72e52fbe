//! Per-episode metrics (actor → learner): a fixed 120-byte record.
//!
//! Layout after the message header: episode_id u64, steps u32, scene_index u32,
//! present u32 (bit i set = field i carries a value), reserved u32 (0), then one
//! f32 per [`StatField`], in order.

use crate::arrays::{read_u32, read_u64};
use crate::payload::{check_layout, Payload};
use crate::{MessageKind, ProtoError};

const FIXED_LEN: usize = 24;
const PAYLOAD_LEN: usize = FIXED_LEN + 4 * StatField::COUNT;

/// The metrics an episode can report. Rates lie in `[0, 1]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum StatField {
    /// Sum of rewards.
    EpisodeReturn = 0,
    /// Successful interactions / attempted interactions.
    InteractionSuccessRate = 1,
    /// Objects interacted with / interactable objects in the scene.
    InteractedObjectRate = 2,
    /// Pixels correctly annotated interactable / all pixels.
    InteractableAnnotationRate = 3,
    /// Pixels correctly annotated non-interactable / all pixels.
    NonInteractableAnnotationRate = 4,
    /// Affordance IoU against ground truth, mean over frames and the
    /// task's affordance planes.
    AffordanceIou = 5,
    /// Object-level accuracy against ground truth, mean over frames and the
    /// task's affordance planes.
    ObjectAccuracy = 6,
    /// Environment steps per second of the actor over the episode.
    StepsPerSecond = 7,
    /// Of the scene objects' pixels that got a map object id, the share
    /// carrying the id most of that object's pixels got over the episode
    /// (ids of copies merged since count as the id they became): 1 when
    /// the map re-identifies every object in every frame. Methods with a
    /// map only.
    MapIdConsistency = 8,
    /// Interactions attempted (an object selected for pick up or push) /
    /// steps: how much the policy still tries, which the success rate alone
    /// hides when attempts stop.
    InteractionAttemptRate = 9,
    /// Of the interactions attempted, the share that failed because the
    /// object was beyond the arm's reach: the policy chose well but did not
    /// get close. Reported when the episode attempted any.
    InteractionOutOfReachRate = 10,
    /// Of the interactions attempted, the share that failed because the
    /// object does not afford the action (not pickupable, too heavy, too
    /// wide, static, or did not move when pushed): the policy chose the
    /// wrong object. Reported when the episode attempted any.
    InteractionUnaffordedRate = 11,
    /// Pick-up attempts / steps (when the task has pick up).
    PickUpAttemptRate = 12,
    /// Successful pick-ups / pick-up attempts: each success is an object
    /// whose every view gets positive pick-up labels. Reported when the
    /// episode tried any.
    PickUpSuccessRate = 13,
    /// Push attempts / steps (when the task has push).
    PushAttemptRate = 14,
    /// Successful pushes / push attempts. Reported when the episode tried any.
    PushSuccessRate = 15,
    /// [`StatField::AffordanceIou`] of the pick-up plane alone (the paper's
    /// Fig. 3 shows pick up); reported when the task has pick up.
    PickUpIou = 16,
    /// [`StatField::AffordanceIou`] of the push plane alone.
    PushIou = 17,
    /// [`StatField::ObjectAccuracy`] of the pick-up plane alone.
    PickUpObjectAccuracy = 18,
    /// [`StatField::ObjectAccuracy`] of the push plane alone.
    PushObjectAccuracy = 19,
    /// [`StatField::InteractionOutOfReachRate`] of the pick-up attempts
    /// alone. Reported when the episode tried any.
    PickUpOutOfReachRate = 20,
    /// [`StatField::InteractionUnaffordedRate`] of the pick-up attempts
    /// alone: objects that cannot be picked up, or are too heavy or wide.
    PickUpUnaffordedRate = 21,
    /// [`StatField::InteractionOutOfReachRate`] of the push attempts alone.
    PushOutOfReachRate = 22,
    /// [`StatField::InteractionUnaffordedRate`] of the push attempts alone:
    /// static objects, or objects that did not move.
    PushUnaffordedRate = 23,
}

impl StatField {
    /// Number of fields.
    pub const COUNT: usize = 24;
    /// All fields in wire order.
    pub const ALL: [StatField; Self::COUNT] = [
        StatField::EpisodeReturn,
        StatField::InteractionSuccessRate,
        StatField::InteractedObjectRate,
        StatField::InteractableAnnotationRate,
        StatField::NonInteractableAnnotationRate,
        StatField::AffordanceIou,
        StatField::ObjectAccuracy,
        StatField::StepsPerSecond,
        StatField::MapIdConsistency,
        StatField::InteractionAttemptRate,
        StatField::InteractionOutOfReachRate,
        StatField::InteractionUnaffordedRate,
        StatField::PickUpAttemptRate,
        StatField::PickUpSuccessRate,
        StatField::PushAttemptRate,
        StatField::PushSuccessRate,
        StatField::PickUpIou,
        StatField::PushIou,
        StatField::PickUpObjectAccuracy,
        StatField::PushObjectAccuracy,
        StatField::PickUpOutOfReachRate,
        StatField::PickUpUnaffordedRate,
        StatField::PushOutOfReachRate,
        StatField::PushUnaffordedRate,
    ];

    /// snake_case name used in metrics and JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            StatField::EpisodeReturn => "episode_return",
            StatField::InteractionSuccessRate => "interaction_success_rate",
            StatField::InteractedObjectRate => "interacted_object_rate",
            StatField::InteractableAnnotationRate => "interactable_annotation_rate",
            StatField::NonInteractableAnnotationRate => "non_interactable_annotation_rate",
            StatField::AffordanceIou => "affordance_iou",
            StatField::ObjectAccuracy => "object_accuracy",
            StatField::StepsPerSecond => "steps_per_second",
            StatField::MapIdConsistency => "map_id_consistency",
            StatField::InteractionAttemptRate => "interaction_attempt_rate",
            StatField::InteractionOutOfReachRate => "interaction_out_of_reach_rate",
            StatField::InteractionUnaffordedRate => "interaction_unafforded_rate",
            StatField::PickUpAttemptRate => "pick_up_attempt_rate",
            StatField::PickUpSuccessRate => "pick_up_success_rate",
            StatField::PushAttemptRate => "push_attempt_rate",
            StatField::PushSuccessRate => "push_success_rate",
            StatField::PickUpIou => "pick_up_iou",
            StatField::PushIou => "push_iou",
            StatField::PickUpObjectAccuracy => "pick_up_object_accuracy",
            StatField::PushObjectAccuracy => "push_object_accuracy",
            StatField::PickUpOutOfReachRate => "pick_up_out_of_reach_rate",
            StatField::PickUpUnaffordedRate => "pick_up_unafforded_rate",
            StatField::PushOutOfReachRate => "push_out_of_reach_rate",
            StatField::PushUnaffordedRate => "push_unafforded_rate",
        }
    }

    /// The inclusive range a value must lie in.
    fn range(self) -> (f32, f32) {
        match self {
            StatField::EpisodeReturn => (f32::MIN, f32::MAX),
            StatField::StepsPerSecond => (0.0, f32::MAX),
            _ => (0.0, 1.0),
        }
    }
}

/// Metrics of one finished episode.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EpisodeStats {
    /// Episode id (unique per actor).
    pub episode_id: u64,
    /// Environment steps in the episode.
    pub steps: u32,
    /// Index of the scene the episode ran in.
    pub scene_index: u32,
    values: [Option<f32>; StatField::COUNT],
}

impl EpisodeStats {
    /// An empty record for an episode.
    pub fn new(episode_id: u64, steps: u32, scene_index: u32) -> Self {
        Self {
            episode_id,
            steps,
            scene_index,
            values: [None; StatField::COUNT],
        }
    }

    /// Sets a metric; builder style.
    pub fn with(mut self, field: StatField, value: f32) -> Self {
        self.values[field as usize] = Some(value);
        self
    }

    /// The metric's value, if the episode reported it.
    pub fn get(&self, field: StatField) -> Option<f32> {
        self.values[field as usize]
    }

    /// All reported metrics.
    pub fn present(&self) -> impl Iterator<Item = (StatField, f32)> + '_ {
        StatField::ALL
            .into_iter()
            .filter_map(|f| self.get(f).map(|v| (f, v)))
    }

    pub(crate) fn parse(payload: &[u8]) -> Result<Self, ProtoError> {
        check_layout("stats", PAYLOAD_LEN as u64, payload.len())?;
        let present = read_u32(payload, 16);
        if present >> StatField::COUNT != 0 {
            return Err(ProtoError::OutOfRange {
                field: "present",
                value: present.into(),
                allowed: "only the bits of known fields, 0..StatField::COUNT",
            });
        }
        let reserved = read_u32(payload, 20);
        if reserved != 0 {
            return Err(ProtoError::OutOfRange {
                field: "reserved",
                value: reserved.into(),
                allowed: "0",
            });
        }
        let mut stats = Self::new(
            read_u64(payload, 0),
            read_u32(payload, 8),
            read_u32(payload, 12),
        );
        for field in StatField::ALL {
            let i = field as usize;
            let value = f32::from_bits(read_u32(payload, FIXED_LEN + 4 * i));
            if present & (1 << i) == 0 {
                continue;
            }
            let (lo, hi) = field.range();
            if !value.is_finite() || value < lo || value > hi {
                return Err(ProtoError::BadFloat {
                    field: field.as_str(),
                    index: 0,
                    value,
                    extra: " and in its range",
                });
            }
            stats.values[i] = Some(value);
        }
        Ok(stats)
    }
}

impl Payload for EpisodeStats {
    const KIND: MessageKind = MessageKind::Stats;

    fn payload_len(&self) -> usize {
        PAYLOAD_LEN
    }

    fn write_payload(&self, out: &mut [u8]) {
        out[0..8].copy_from_slice(&self.episode_id.to_le_bytes());
        out[8..12].copy_from_slice(&self.steps.to_le_bytes());
        out[12..16].copy_from_slice(&self.scene_index.to_le_bytes());
        let present = self
            .values
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_some())
            .fold(0u32, |acc, (i, _)| acc | (1 << i));
        out[16..20].copy_from_slice(&present.to_le_bytes());
        out[20..24].copy_from_slice(&0u32.to_le_bytes());
        for (i, v) in self.values.iter().enumerate() {
            let at = FIXED_LEN + 4 * i;
            out[at..at + 4].copy_from_slice(&v.unwrap_or(0.0).to_le_bytes());
        }
    }
}
