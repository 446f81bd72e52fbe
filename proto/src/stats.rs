//! Per-episode metrics (actor → learner).
//!
//! Layout after the message header: episode_id u64, steps u32, scene_index
//! u32, present u32 (bit i set = episode-wide field i carries a value),
//! reserved u32 (0), one f32 per [`StatField`] in order; then the number of
//! affordance records u32 (at most one per [`Affordance`]), and per record:
//! the affordance's code u32 (records in increasing code order), present
//! u32 (bit i set = [`AffordanceStat`] i carries a value), one f32 per
//! [`AffordanceStat`] in order. A new affordance adds records, not fields.
//! Last, the tries by object type ([`crate::type_tries`] gives their
//! layout).

use std::borrow::Cow;

use crate::arrays::{read_u32, read_u64};
use crate::payload::{check_layout, Payload};
use crate::task::Affordance;
use crate::type_tries::{self, TypeTries};
use crate::{MessageKind, ProtoError};

const FIXED_LEN: usize = 24;
const EPISODE_LEN: usize = FIXED_LEN + 4 * StatField::COUNT;
const RECORD_LEN: usize = 8 + 4 * AffordanceStat::COUNT;
/// The shortest stats message's payload.
const MIN_PAYLOAD_LEN: usize = EPISODE_LEN + 4 + type_tries::section_len(&[]);
// A stranger may send only a join's exact length (the transport's
// membership screen); no stats message may have it.
const _: () = assert!(MIN_PAYLOAD_LEN > crate::join::JOIN_PAYLOAD_LEN);

/// The episode-wide metrics an episode can report. Rates lie in `[0, 1]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
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
}

impl StatField {
    /// Number of fields.
    pub const COUNT: usize = 12;
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

/// A metric an episode reports for each affordance of its task. Rates lie
/// in `[0, 1]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum AffordanceStat {
    /// Attempts of this affordance / steps.
    AttemptRate = 0,
    /// Successful attempts / attempts: each success is an object whose
    /// every view gets positive labels. Reported when the episode tried any.
    SuccessRate = 1,
    /// [`StatField::AffordanceIou`] of this affordance's plane alone (the
    /// paper's Fig. 3 shows pick up).
    Iou = 2,
    /// [`StatField::ObjectAccuracy`] of this affordance's plane alone.
    ObjectAccuracy = 3,
    /// [`StatField::InteractionOutOfReachRate`] of this affordance's
    /// attempts alone. Reported when the episode tried any.
    OutOfReachRate = 4,
    /// [`StatField::InteractionUnaffordedRate`] of this affordance's
    /// attempts alone (for pick up: objects that cannot be picked up, or are
    /// too heavy or wide; for push: static objects, or objects that did not
    /// move). Reported when the episode tried any.
    UnaffordedRate = 5,
    /// Of this affordance's attempts, the share that failed for want of
    /// room to lift or put the object (the arm reached it; no label
    /// follows). Reported when the episode tried any.
    NoRoomRate = 6,
    /// Of the episode's frames' pixels, the share its labels call
    /// positive in this affordance's plane: what the U-Net gets to learn
    /// from (docs/ladder.md).
    PositiveLabelShare = 7,
    /// Of the episode's frames' pixels, the share its labels call negative
    /// in this affordance's plane (the floor and walls too, where they are
    /// labelled).
    NegativeLabelShare = 8,
    /// Of the pixels the episode's labels call positive in this plane, the
    /// share the simulator's ground truth agrees with (an object there
    /// that affords it): how much of what the U-Net is told is so is so
    /// (the map's spread of an outcome, merged objects). Reported when the
    /// labels hold a positive.
    PositiveLabelPrecision = 9,
    /// Of the pixels the labels call negative in this plane, the share the
    /// ground truth agrees with (no object there, or one that does not
    /// afford it). Reported when the labels hold a negative.
    NegativeLabelPrecision = 10,
    /// Of the episode's frames' pixels of objects that afford this
    /// plane's affordance (ground truth), the share the labels call
    /// positive: how much of what could be learnt the episode taught
    /// (docs/ladder.md's tried-objects rung). Reported when a frame showed
    /// such an object.
    PositiveLabelRecall = 11,
    /// Of the episode's frames' pixels of objects that do not afford this
    /// plane's affordance (ground truth; the floor and walls left out), the
    /// share the labels call negative: how much of the hard negatives the
    /// U-Net is shown. Reported when a frame showed such an object.
    NegativeLabelRecall = 12,
}

impl AffordanceStat {
    /// Number of per-affordance metrics.
    pub const COUNT: usize = 13;
    /// All of them in wire order.
    pub const ALL: [AffordanceStat; Self::COUNT] = [
        AffordanceStat::AttemptRate,
        AffordanceStat::SuccessRate,
        AffordanceStat::Iou,
        AffordanceStat::ObjectAccuracy,
        AffordanceStat::OutOfReachRate,
        AffordanceStat::UnaffordedRate,
        AffordanceStat::NoRoomRate,
        AffordanceStat::PositiveLabelShare,
        AffordanceStat::NegativeLabelShare,
        AffordanceStat::PositiveLabelPrecision,
        AffordanceStat::NegativeLabelPrecision,
        AffordanceStat::PositiveLabelRecall,
        AffordanceStat::NegativeLabelRecall,
    ];

    /// snake_case name, after the affordance's in metrics and JSON
    /// (`pick_up_attempt_rate`).
    pub fn as_str(self) -> &'static str {
        match self {
            AffordanceStat::AttemptRate => "attempt_rate",
            AffordanceStat::SuccessRate => "success_rate",
            AffordanceStat::Iou => "iou",
            AffordanceStat::ObjectAccuracy => "object_accuracy",
            AffordanceStat::OutOfReachRate => "out_of_reach_rate",
            AffordanceStat::UnaffordedRate => "unafforded_rate",
            AffordanceStat::NoRoomRate => "no_room_rate",
            AffordanceStat::PositiveLabelShare => "positive_label_share",
            AffordanceStat::NegativeLabelShare => "negative_label_share",
            AffordanceStat::PositiveLabelPrecision => "positive_label_precision",
            AffordanceStat::NegativeLabelPrecision => "negative_label_precision",
            AffordanceStat::PositiveLabelRecall => "positive_label_recall",
            AffordanceStat::NegativeLabelRecall => "negative_label_recall",
        }
    }
}

/// What one number of an episode's metrics measures: an episode-wide
/// field, or a metric of one affordance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum StatKey {
    /// See [`StatField`].
    Episode(StatField),
    /// See [`AffordanceStat`].
    Affordance(Affordance, AffordanceStat),
}

impl StatKey {
    /// Every key, in wire order: the episode-wide fields, then each
    /// affordance's metrics.
    pub fn all() -> impl Iterator<Item = StatKey> {
        let episode = StatField::ALL.into_iter().map(StatKey::Episode);
        let per_affordance = Affordance::ALL.into_iter().flat_map(|affordance| {
            AffordanceStat::ALL
                .into_iter()
                .map(move |stat| StatKey::Affordance(affordance, stat))
        });
        episode.chain(per_affordance)
    }

    /// snake_case name used in metrics and JSON: the field's, or the
    /// affordance's then the metric's (`pick_up_success_rate`).
    pub fn name(self) -> Cow<'static, str> {
        match self {
            StatKey::Episode(field) => Cow::Borrowed(field.as_str()),
            StatKey::Affordance(affordance, stat) => {
                Cow::Owned(format!("{}_{}", affordance.as_str(), stat.as_str()))
            }
        }
    }

    /// The inclusive range a value must lie in.
    fn range(self) -> (f32, f32) {
        match self {
            StatKey::Episode(field) => field.range(),
            StatKey::Affordance(..) => (0.0, 1.0),
        }
    }
}

impl From<StatField> for StatKey {
    fn from(field: StatField) -> Self {
        StatKey::Episode(field)
    }
}

/// Values of one affordance's metrics, by [`AffordanceStat`].
type AffordanceValues = [Option<f32>; AffordanceStat::COUNT];

/// Metrics of one finished episode.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EpisodeStats {
    /// Episode id (unique per actor).
    pub episode_id: u64,
    /// Environment steps in the episode.
    pub steps: u32,
    /// Index of the scene the episode ran in.
    pub scene_index: u32,
    values: [Option<f32>; StatField::COUNT],
    /// By [`Affordance`] code.
    per_affordance: [AffordanceValues; Affordance::COUNT],
    /// Tries by object type, in wire order.
    tries: Vec<TypeTries>,
}

impl EpisodeStats {
    /// An empty record for an episode.
    pub fn new(episode_id: u64, steps: u32, scene_index: u32) -> Self {
        Self {
            episode_id,
            steps,
            scene_index,
            ..Self::default()
        }
    }

    /// Sets a metric; builder style.
    pub fn with(mut self, key: impl Into<StatKey>, value: f32) -> Self {
        *self.slot(key.into()) = Some(value);
        self
    }

    /// Sets the tries by object type; builder style. Records are kept in
    /// wire order (by affordance code, then type name); for a type given
    /// twice under one affordance the counts add up. What the wire cannot
    /// carry is made so rather than lost with the episode's other metrics:
    /// a name's other characters become `_` (cut to [`crate::MAX_TYPE_NAME`]
    /// bytes, `unknown` if empty), counts are clamped (successes and
    /// objects to the attempts, at least one object), records without
    /// attempts are left out, and beyond [`crate::MAX_TYPE_TRIES`] records the
    /// least tried are.
    pub fn with_tries(mut self, tries: impl IntoIterator<Item = TypeTries>) -> Self {
        self.tries = type_tries::merged(std::mem::take(&mut self.tries), tries);
        self
    }

    /// Keeps the `n` records of tries by object type with the most attempts
    /// (the first in wire order on ties), for a message that must fit a
    /// smaller limit.
    pub fn keep_most_tried(&mut self, n: usize) {
        type_tries::keep_most_tried(&mut self.tries, n);
    }

    /// Tries by object type, by affordance code then type name.
    pub fn tries(&self) -> &[TypeTries] {
        &self.tries
    }

    /// The metric's value, if the episode reported it.
    pub fn get(&self, key: impl Into<StatKey>) -> Option<f32> {
        match key.into() {
            StatKey::Episode(field) => self.values[field as usize],
            StatKey::Affordance(affordance, stat) => {
                self.per_affordance[affordance.code() as usize][stat as usize]
            }
        }
    }

    fn slot(&mut self, key: StatKey) -> &mut Option<f32> {
        match key {
            StatKey::Episode(field) => &mut self.values[field as usize],
            StatKey::Affordance(affordance, stat) => {
                &mut self.per_affordance[affordance.code() as usize][stat as usize]
            }
        }
    }

    /// All reported metrics, in wire order.
    pub fn present(&self) -> impl Iterator<Item = (StatKey, f32)> + '_ {
        StatKey::all().filter_map(|key| self.get(key).map(|v| (key, v)))
    }

    /// The affordances with at least one metric, as records go on the wire.
    fn records(&self) -> impl Iterator<Item = (Affordance, &AffordanceValues)> {
        Affordance::ALL
            .into_iter()
            .map(|a| (a, &self.per_affordance[a.code() as usize]))
            .filter(|(_, values)| values.iter().any(Option::is_some))
    }

    pub(crate) fn parse(payload: &[u8]) -> Result<Self, ProtoError> {
        if payload.len() < MIN_PAYLOAD_LEN {
            return Err(ProtoError::Truncated {
                what: "stats",
                needed: MIN_PAYLOAD_LEN,
                got: payload.len(),
            });
        }
        let count = read_u32(payload, EPISODE_LEN);
        if count as usize > Affordance::COUNT {
            return Err(ProtoError::OutOfRange {
                field: "affordance records",
                value: count.into(),
                allowed: "at most one per affordance",
            });
        }
        let tries_at = EPISODE_LEN + 4 + count as usize * RECORD_LEN;
        if payload.len() < tries_at + type_tries::section_len(&[]) {
            return Err(ProtoError::Truncated {
                what: "stats' tries by object type",
                needed: tries_at + type_tries::section_len(&[]),
                got: payload.len(),
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
        let fields = StatField::ALL.map(StatKey::Episode);
        stats.read_values(payload, (16, FIXED_LEN), &fields, "present")?;
        let mut previous: Option<u32> = None;
        for record in 0..count as usize {
            let at = EPISODE_LEN + 4 + record * RECORD_LEN;
            let code = read_u32(payload, at);
            let affordance = Affordance::from_code(code)
                .filter(|_| previous.is_none_or(|p| code > p))
                .ok_or(ProtoError::OutOfRange {
                    field: "affordance code",
                    value: code.into(),
                    allowed: "a known affordance, records in increasing code order",
                })?;
            previous = Some(code);
            let keys = AffordanceStat::ALL.map(|stat| StatKey::Affordance(affordance, stat));
            stats.read_values(payload, (at + 4, at + 8), &keys, "affordance present")?;
        }
        let (tries, end) = type_tries::read_section(payload, tries_at)?;
        stats.tries = tries;
        check_layout("stats", end as u64, payload.len())?;
        Ok(stats)
    }

    /// Reads a present-bits word and one f32 per key of `keys`, at the
    /// offsets `(present, values)`, checking each present value is finite
    /// and in its range.
    fn read_values(
        &mut self,
        payload: &[u8],
        (present_at, values_at): (usize, usize),
        keys: &[StatKey],
        present_name: &'static str,
    ) -> Result<(), ProtoError> {
        let present = read_u32(payload, present_at);
        if present >> keys.len() != 0 {
            return Err(ProtoError::OutOfRange {
                field: present_name,
                value: present.into(),
                allowed: "only the bits of known metrics",
            });
        }
        for (i, &key) in keys.iter().enumerate() {
            if present & (1 << i) == 0 {
                continue;
            }
            let value = f32::from_bits(read_u32(payload, values_at + 4 * i));
            let (lo, hi) = key.range();
            if !value.is_finite() || value < lo || value > hi {
                return Err(ProtoError::BadFloat {
                    field: match key {
                        StatKey::Episode(field) => field.as_str(),
                        StatKey::Affordance(_, stat) => stat.as_str(),
                    },
                    index: 0,
                    value,
                    extra: " and in its range",
                });
            }
            *self.slot(key) = Some(value);
        }
        Ok(())
    }
}

/// Writes the present bits of `values` into `present_at` and the values
/// (0 where absent) into `values_at`.
fn write_values(values: &[Option<f32>], present_at: &mut [u8], values_at: &mut [u8]) {
    let present = values
        .iter()
        .enumerate()
        .filter(|(_, v)| v.is_some())
        .fold(0u32, |acc, (i, _)| acc | (1 << i));
    present_at[..4].copy_from_slice(&present.to_le_bytes());
    for (i, v) in values.iter().enumerate() {
        values_at[4 * i..4 * i + 4].copy_from_slice(&v.unwrap_or(0.0).to_le_bytes());
    }
}

impl Payload for EpisodeStats {
    const KIND: MessageKind = MessageKind::Stats;

    fn payload_len(&self) -> usize {
        EPISODE_LEN + 4 + self.records().count() * RECORD_LEN + type_tries::section_len(&self.tries)
    }

    fn write_payload(&self, out: &mut [u8]) {
        out[0..8].copy_from_slice(&self.episode_id.to_le_bytes());
        out[8..12].copy_from_slice(&self.steps.to_le_bytes());
        out[12..16].copy_from_slice(&self.scene_index.to_le_bytes());
        out[20..24].copy_from_slice(&0u32.to_le_bytes());
        let (head, fields) = out.split_at_mut(FIXED_LEN);
        write_values(&self.values, &mut head[16..20], fields);
        let records: Vec<_> = self.records().collect();
        let records_len = records.len();
        out[EPISODE_LEN..EPISODE_LEN + 4].copy_from_slice(&(records_len as u32).to_le_bytes());
        for (i, (affordance, values)) in records.into_iter().enumerate() {
            let at = EPISODE_LEN + 4 + i * RECORD_LEN;
            let record = &mut out[at..at + RECORD_LEN];
            record[0..4].copy_from_slice(&affordance.code().to_le_bytes());
            let (present, rest) = record[4..].split_at_mut(4);
            write_values(values, present, rest);
        }
        type_tries::write_section(
            &self.tries,
            &mut out[EPISODE_LEN + 4 + records_len * RECORD_LEN..],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{
        decode, encode, Limits, Message, MessageHeader, HEADER_LEN, MAX_TYPE_NAME, MAX_TYPE_TRIES,
    };

    const LIMITS: Limits = Limits {
        max_actors: 4,
        max_payload_len: 1 << 20,
    };

    fn decoded(bytes: &[u8]) -> Result<EpisodeStats, ProtoError> {
        match decode(bytes, &LIMITS)?.1 {
            Message::Stats(stats) => Ok(*stats),
            other => panic!("not stats: {:?}", other.kind()),
        }
    }

    /// Re-encodes `bytes` after `edit` with a checksum that matches again.
    fn edited(mut bytes: Vec<u8>, edit: impl FnOnce(&mut [u8])) -> Vec<u8> {
        edit(&mut bytes[HEADER_LEN..]);
        let crc = crc32fast::hash(&bytes[HEADER_LEN..]);
        bytes[12..16].copy_from_slice(&crc.to_le_bytes());
        bytes
    }

    #[test]
    fn names_are_those_metrics_and_dashboards_already_read() {
        let names: Vec<_> = StatKey::all().map(StatKey::name).collect();
        for name in [
            "episode_return",
            "interaction_unafforded_rate",
            "pick_up_attempt_rate",
            "pick_up_success_rate",
            "push_attempt_rate",
            "push_success_rate",
            "pick_up_iou",
            "push_iou",
            "pick_up_object_accuracy",
            "push_object_accuracy",
            "pick_up_out_of_reach_rate",
            "pick_up_unafforded_rate",
            "push_out_of_reach_rate",
            "push_unafforded_rate",
            "pick_up_no_room_rate",
            "pick_up_positive_label_share",
            "push_negative_label_share",
        ] {
            assert!(names.iter().any(|n| n == name), "{name}");
        }
        let unique: std::collections::BTreeSet<_> = names.iter().collect();
        assert_eq!(unique.len(), names.len());
    }

    #[test]
    fn only_affordances_with_a_metric_take_a_record() {
        let episode_only = EpisodeStats::new(1, 10, 0).with(StatField::EpisodeReturn, 2.0);
        // The affordance records' count, then the (empty) tries' section.
        assert_eq!(episode_only.payload_len(), MIN_PAYLOAD_LEN);
        let push = episode_only.with(
            StatKey::Affordance(Affordance::Push, AffordanceStat::SuccessRate),
            0.5,
        );
        assert_eq!(push.payload_len(), MIN_PAYLOAD_LEN + RECORD_LEN);
        let got = decoded(&encode(&push, MessageHeader::default())).unwrap();
        assert_eq!(got, push);
        assert_eq!(
            got.present().collect::<Vec<_>>(),
            vec![
                (StatKey::Episode(StatField::EpisodeReturn), 2.0),
                (
                    StatKey::Affordance(Affordance::Push, AffordanceStat::SuccessRate),
                    0.5
                ),
            ]
        );
    }

    #[test]
    fn bad_affordance_records_are_refused() {
        let stats = EpisodeStats::new(1, 10, 0)
            .with(
                StatKey::Affordance(Affordance::PickUp, AffordanceStat::AttemptRate),
                0.25,
            )
            .with(
                StatKey::Affordance(Affordance::Push, AffordanceStat::Iou),
                0.5,
            );
        let bytes = encode(&stats, MessageHeader::default());
        assert_eq!(decoded(&bytes).unwrap(), stats);
        let first = EPISODE_LEN + 4;
        let second = first + RECORD_LEN;
        let put = |at: usize, value: u32| {
            move |p: &mut [u8]| p[at..at + 4].copy_from_slice(&value.to_le_bytes())
        };
        let cases: Vec<(&str, Vec<u8>)> = vec![
            ("unknown affordance", edited(bytes.clone(), put(first, 7))),
            (
                "the same affordance twice",
                edited(bytes.clone(), put(second, Affordance::PickUp.code())),
            ),
            (
                "records out of order",
                edited(bytes.clone(), |p| {
                    p[first..first + 4].copy_from_slice(&Affordance::Push.code().to_le_bytes());
                    p[second..second + 4].copy_from_slice(&Affordance::PickUp.code().to_le_bytes());
                }),
            ),
            (
                "more records than affordances",
                edited(bytes.clone(), put(EPISODE_LEN, 3)),
            ),
            (
                "a count the length disagrees with",
                edited(bytes.clone(), put(EPISODE_LEN, 1)),
            ),
            (
                "present bits of no metric",
                edited(bytes.clone(), put(first + 4, 1 << AffordanceStat::COUNT)),
            ),
            (
                "a rate above 1",
                edited(bytes.clone(), |p| {
                    p[first + 8..first + 12].copy_from_slice(&1.5f32.to_le_bytes());
                }),
            ),
        ];
        for (what, bytes) in cases {
            assert!(decoded(&bytes).is_err(), "{what} was accepted");
        }
    }

    fn tries(affordance: Affordance, name: &str, counts: [u32; 3]) -> TypeTries {
        let [attempts, successes, objects] = counts;
        TypeTries {
            affordance,
            object_type: name.into(),
            attempts,
            successes,
            objects,
        }
    }

    #[test]
    fn tries_by_object_type_travel_in_order_and_merge() {
        let stats = EpisodeStats::new(4, 100, 1)
            .with(StatField::EpisodeReturn, 1.0)
            .with_tries([
                tries(Affordance::Push, "Chair", [2, 2, 1]),
                tries(Affordance::PickUp, "KeyChain", [1, 1, 1]),
                tries(Affordance::PickUp, "Drawer", [3, 0, 2]),
                tries(Affordance::PickUp, "KeyChain", [2, 0, 1]),
            ]);
        let order: Vec<_> = stats
            .tries()
            .iter()
            .map(|t| (t.affordance, t.object_type.as_str(), t.attempts, t.objects))
            .collect();
        assert_eq!(
            order,
            vec![
                (Affordance::PickUp, "Drawer", 3, 2),
                (Affordance::PickUp, "KeyChain", 3, 2),
                (Affordance::Push, "Chair", 2, 1),
            ]
        );
        // "Drawer" and "Chair" pad to 8 bytes, "KeyChain" is 8 already.
        assert_eq!(stats.payload_len(), MIN_PAYLOAD_LEN + 3 * (20 + 8));
        let got = decoded(&encode(&stats, MessageHeader::default())).unwrap();
        assert_eq!(got, stats);
    }

    #[test]
    fn tries_the_wire_cannot_carry_are_made_so_rather_than_lost() {
        let long = "A".repeat(MAX_TYPE_NAME + 10);
        let stats = EpisodeStats::new(1, 10, 0).with_tries([
            tries(Affordance::PickUp, "Credit Card", [2, 5, 0]),
            tries(Affordance::PickUp, "", [1, 0, 1]),
            tries(Affordance::PickUp, &long, [1, 0, 1]),
            tries(Affordance::Push, "Sofa", [0, 0, 0]),
        ]);
        let got: Vec<_> = stats
            .tries()
            .iter()
            .map(|t| (t.object_type.clone(), t.successes, t.objects))
            .collect();
        assert_eq!(
            got,
            vec![
                ("A".repeat(MAX_TYPE_NAME), 0, 1),
                ("Credit_Card".into(), 2, 1),
                ("unknown".into(), 0, 1),
            ]
        );
        assert_eq!(
            decoded(&encode(&stats, MessageHeader::default())).unwrap(),
            stats
        );
    }

    #[test]
    fn the_least_tried_types_give_way_when_records_must_be_fewer() {
        let mut stats = EpisodeStats::new(1, 10, 0).with_tries([
            tries(Affordance::PickUp, "Box", [1, 0, 1]),
            tries(Affordance::PickUp, "Chair", [5, 0, 1]),
            tries(Affordance::PickUp, "Drawer", [1, 0, 1]),
            tries(Affordance::Push, "Sofa", [3, 1, 1]),
        ]);
        stats.keep_most_tried(3);
        let names: Vec<_> = stats
            .tries()
            .iter()
            .map(|t| t.object_type.as_str())
            .collect();
        assert_eq!(names, ["Box", "Chair", "Sofa"], "wire order kept");
        let many = (0..MAX_TYPE_TRIES + 5).map(|i| {
            let attempts = if i < 5 { 1 } else { 2 };
            tries(Affordance::PickUp, &format!("T{i:03}"), [attempts, 0, 1])
        });
        let capped = EpisodeStats::new(1, 10, 0).with_tries(many);
        assert_eq!(capped.tries().len(), MAX_TYPE_TRIES);
        assert!(capped.tries().iter().all(|t| t.attempts == 2));
    }

    #[test]
    fn bad_tries_records_are_refused() {
        let stats = EpisodeStats::new(1, 10, 0).with_tries([
            tries(Affordance::PickUp, "Box", [2, 1, 1]),
            tries(Affordance::PickUp, "Vase", [1, 0, 1]),
        ]);
        let bytes = encode(&stats, MessageHeader::default());
        assert_eq!(decoded(&bytes).unwrap(), stats);
        let count_at = EPISODE_LEN + 4;
        let first = count_at + type_tries::section_len(&[]);
        let second = first + 20 + 4;
        let put = |at: usize, value: u32| {
            move |p: &mut [u8]| p[at..at + 4].copy_from_slice(&value.to_le_bytes())
        };
        let cases: Vec<(&str, Vec<u8>)> = vec![
            ("unknown affordance", edited(bytes.clone(), put(first, 9))),
            (
                "more successes than attempts",
                edited(bytes.clone(), put(first + 8, 3)),
            ),
            ("no object", edited(bytes.clone(), put(first + 12, 0))),
            (
                "more objects than attempts",
                edited(bytes.clone(), put(first + 12, 3)),
            ),
            (
                "a name past the message",
                edited(bytes.clone(), put(second + 16, 9)),
            ),
            ("an empty name", edited(bytes.clone(), put(first + 16, 0))),
            (
                "a name with a space",
                edited(bytes.clone(), |p| p[first + 20] = b' '),
            ),
            (
                "padding that is not zero",
                edited(bytes.clone(), |p| p[first + 23] = b'x'),
            ),
            (
                "records out of order",
                edited(bytes.clone(), |p| {
                    p[second + 20..second + 24].copy_from_slice(b"Ant\0")
                }),
            ),
            (
                "more records than sent",
                edited(bytes.clone(), put(count_at, 3)),
            ),
            (
                "a reserved word not 0",
                edited(bytes.clone(), put(count_at + 4, 1)),
            ),
            (
                "more records than allowed",
                edited(bytes.clone(), put(count_at, MAX_TYPE_TRIES as u32 + 1)),
            ),
            ("bytes left over", {
                let mut longer = bytes.clone();
                longer.extend_from_slice(&[0; 4]);
                let len = (longer.len() - HEADER_LEN) as u64;
                longer[40..48].copy_from_slice(&len.to_le_bytes());
                edited(longer, |_| {})
            }),
        ];
        for (what, bytes) in cases {
            assert!(decoded(&bytes).is_err(), "{what} was accepted");
        }
    }
}
