//! One object of the map: its id, volume, pose, class votes, labels and
//! where the map believes it is.

use std::collections::BTreeMap;

use crate::labels::ObjectLabels;
use crate::layer::Layer;
use crate::Pose;

/// A map object's id; stable across frames. 0 is never used (it means "none").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ObjectId(pub u32);

/// One object of the map.
#[derive(Debug, Clone)]
pub struct MapObject {
    /// Its id.
    pub id: ObjectId,
    /// Pose of its volume's frame in the world.
    pub t_world_object: Pose,
    /// TSDF volume in the object's frame.
    pub volume: Layer,
    /// Semantic class votes (class id → pixels seen).
    pub class_histogram: BTreeMap<u16, u64>,
    /// Frames it was matched in.
    pub observations: u32,
    /// Consecutive frames it should have been seen but was not.
    pub misses: u32,
    /// Interaction outcomes and confidence labels.
    pub labels: ObjectLabels,
    /// Where the map believes the object is.
    pub whereabouts: Whereabouts,
    /// While lost: the first id issued after it was lost. Objects from this
    /// id on appeared while it was away, so one of them may be it, seen
    /// again too little to be recognised (see `Map::reidentify`).
    pub(super) lost_before: ObjectId,
    /// The largest segment it was compared with lost objects on
    /// (`Map::reidentify`); a later segment is compared again only when
    /// clearly larger, a better view.
    pub(super) reidentify_tried_px: usize,
}

/// Where the map believes an object is. Only a [`Whereabouts::Placed`]
/// object is rendered, associated, integrated, projected or counted as
/// missed; the others keep their volume and labels unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Whereabouts {
    /// At its pose in the world.
    Placed,
    /// In the robot's hand ([`Map::hold`](super::Map::hold)) until released.
    Held,
    /// The robot moved it and tracking did not find it: somewhere unknown
    /// until a new segment turns out to be it (see `Map::reidentify`).
    Lost,
}

impl MapObject {
    /// Whether the map knows where the object is ([`Whereabouts::Placed`]).
    pub fn is_placed(&self) -> bool {
        self.whereabouts == Whereabouts::Placed
    }

    /// The most voted class, if any.
    pub fn class(&self) -> Option<u16> {
        self.class_histogram
            .iter()
            .max_by_key(|(c, n)| (**n, std::cmp::Reverse(**c)))
            .map(|(c, _)| *c)
    }
}
