//! Each placed object's surface points in the world frame, kept by the map
//! while neither the object's volume ([`crate::layer::Layer::revision`]) nor its pose
//! changes: a frame touches few of a mapped room's objects, and
//! transforming every object's points every step was most of what the
//! state's map planes cost over 600-step episodes beyond the blocks' own
//! points (docs/notebook/2026-11-27-actor-loop-chores.md).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use nalgebra::Point3;
use rustc_hash::FxHashMap;

use super::{MapObject, ObjectId};
use crate::Pose;

/// One object's surface points in the world frame, and what they were
/// worked out from.
#[derive(Debug, Clone)]
pub(crate) struct WorldPoints {
    /// The volume's [`crate::layer::Layer::revision`].
    revision: u64,
    pose: Pose,
    /// The points.
    pub(crate) points: Arc<[Point3<f32>]>,
    /// The box they span on the floor plane ([`floor_box`]).
    pub(crate) lo: [f32; 2],
    /// See `lo`.
    pub(crate) hi: [f32; 2],
}

impl WorldPoints {
    fn of(object: &MapObject) -> Self {
        let volume = &object.volume;
        let blocks: Vec<&[Point3<f32>]> = volume
            .block_indices()
            .into_iter()
            .filter_map(|b| volume.surface_points(b))
            .collect();
        let mut points = Vec::with_capacity(blocks.iter().map(|p| p.len()).sum());
        for block_points in blocks {
            points.extend(block_points.iter().map(|p| object.t_world_object * p));
        }
        let (lo, hi) = floor_box(&points);
        Self {
            revision: volume.revision(),
            pose: object.t_world_object,
            points: points.into(),
            lo,
            hi,
        }
    }

    /// Whether these are still `object`'s points (its volume and pose as
    /// they were).
    fn shows(&self, object: &MapObject) -> bool {
        self.revision == object.volume.revision() && self.pose == object.t_world_object
    }
}

/// The map's kept [`WorldPoints`], per object.
#[derive(Default)]
pub(crate) struct WorldPointsCache(Mutex<FxHashMap<ObjectId, WorldPoints>>);

impl WorldPointsCache {
    fn lock(&self) -> MutexGuard<'_, FxHashMap<ObjectId, WorldPoints>> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The world-frame points of every placed object of `objects`, in id
    /// order: kept ones where they still show the object, worked out (and
    /// kept) otherwise; objects no longer placed are forgotten.
    pub(crate) fn of_placed<'m>(
        &self,
        objects: &'m BTreeMap<ObjectId, MapObject>,
    ) -> Vec<(&'m MapObject, WorldPoints)> {
        let mut kept = self.lock();
        kept.retain(|id, _| objects.get(id).is_some_and(MapObject::is_placed));
        objects
            .values()
            .filter(|o| o.is_placed())
            .map(|object| {
                let points = match kept.get(&object.id).filter(|w| w.shows(object)) {
                    Some(points) => points.clone(),
                    None => {
                        let fresh = WorldPoints::of(object);
                        kept.insert(object.id, fresh.clone());
                        fresh
                    }
                };
                (object, points)
            })
            .collect()
    }
}

/// A copy of a map works its points out afresh.
impl Clone for WorldPointsCache {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl std::fmt::Debug for WorldPointsCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "WorldPointsCache({} objects)", self.lock().len())
    }
}

/// The box `points` span on the floor plane: least and greatest x and y.
pub(crate) fn floor_box(points: &[Point3<f32>]) -> ([f32; 2], [f32; 2]) {
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for p in points {
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    (lo, hi)
}
