//! Copies of one object merged into one.
//!
//! With provided instance masks a segment shows one object (or part of one,
//! where a mask over-segments), so two map objects that each pass
//! association's test on the same segment, and whose surfaces coincide,
//! are two copies of it: one made from a view that association could not
//! match to the first (a tracking failure, a part never seen before),
//! living on beside it. (Objects that merely share a segment, where a mask
//! under-segments, lie side by side: their surfaces do not coincide.) Left
//! alone, the copies take the segment in turns from frame
//! to frame (neither is ever missed long enough to be deleted) and split
//! the object's interaction labels between two ids, so labels reach only
//! the frames where the object carried the id it was interacted under.

use std::collections::BTreeSet;

use super::{Map, ObjectId};
use crate::icp::TrackingOutcome;
use crate::labels::ObjectLabels;
use crate::layer::CachedReader;
use crate::sdf_sample::sdf_at;
use crate::segmentation::Segmentation;

impl Map {
    /// Merges into each segment's match the other objects that passed
    /// association on that segment (`candidates`), when no segment is
    /// matched to them after tracking (`matches`), tracking neither failed
    /// for them (`failed`) nor moved them this frame (their rendering is
    /// stale), and masks are provided (a geometric segment may hold two
    /// touching objects). Returns the merged copies.
    pub(super) fn merge_copies(
        &mut self,
        candidates: &[Vec<u32>],
        matches: &[Option<u32>],
        failed: &BTreeSet<ObjectId>,
    ) -> BTreeSet<ObjectId> {
        let mut merged = BTreeSet::new();
        if !matches!(self.config.segmentation(), Segmentation::Provided) {
            return merged;
        }
        let matched: BTreeSet<u32> = matches.iter().flatten().copied().collect();
        let moved: BTreeSet<ObjectId> = self
            .last_tracking
            .iter()
            .filter(|r| matches!(r.outcome, TrackingOutcome::Moved { .. }))
            .map(|r| r.object)
            .collect();
        for (found, keep) in candidates.iter().zip(matches) {
            let Some(keep) = *keep else { continue };
            for &copy in found {
                let id = ObjectId(copy);
                if copy == keep
                    || matched.contains(&copy)
                    || failed.contains(&id)
                    || moved.contains(&id)
                    || merged.contains(&id)
                    || !self.surfaces_coincide(ObjectId(keep), id)
                {
                    continue;
                }
                self.merge(ObjectId(keep), id);
                merged.insert(id);
            }
        }
        merged
    }

    /// Merges into `found`, a lost object just found again
    /// (`Map::reidentify`), the objects that appeared while it was lost and
    /// whose surfaces coincide with its own where it stands now: copies of
    /// it, made from views it could not be recognised in (from a side its
    /// model never saw, say), which would otherwise live on beside it and
    /// keep the frames that showed them from its labels.
    pub(super) fn absorb_copies(&mut self, found: ObjectId) {
        let Some(since) = self.objects.get(&found).map(|o| o.lost_before) else {
            return;
        };
        let copies: Vec<ObjectId> = self
            .objects
            .values()
            .filter(|o| o.id >= since && o.id != found && o.is_placed())
            .map(|o| o.id)
            .filter(|&id| self.surfaces_coincide(found, id))
            .collect();
        for copy in copies {
            self.merge(found, copy);
        }
    }

    /// Whether `copy`'s surface lies on `keep`'s where `keep` knows the
    /// space: most of `copy`'s voxels at its surface, placed in `keep`'s
    /// frame, read about the same distance from `keep`'s volume (within a
    /// voxel), and enough of them to tell. Two models of one object
    /// coincide; a ghost of another object just in front of it (within
    /// association's depth tolerance, a few centimetres off its surface)
    /// does not.
    fn surfaces_coincide(&self, keep: ObjectId, copy: ObjectId) -> bool {
        const MIN_COMPARED: usize = 10;
        const MIN_AGREEING: f32 = 0.6;
        let (Some(kept), Some(copied)) = (self.objects.get(&keep), self.objects.get(&copy)) else {
            return false;
        };
        let voxel = self.config.settings.voxel_size_m;
        let t_keep_copy = kept.t_world_object.inverse() * copied.t_world_object;
        let mut reader = CachedReader::new(&kept.volume);
        let (mut compared, mut agreeing) = (0usize, 0usize);
        for (p, sdf) in copied.volume.near_surface_voxels(0.5 * voxel) {
            if let Some(kept_sdf) = sdf_at(&mut reader, &(t_keep_copy * p)) {
                compared += 1;
                agreeing += usize::from((kept_sdf - sdf).abs() <= voxel);
            }
        }
        compared >= MIN_COMPARED && agreeing as f32 >= MIN_AGREEING * compared as f32
    }

    /// Merges object `copy` into `keep`: `keep` takes its labels, class
    /// votes and observation count, and `copy`'s id redirects to `keep`
    /// ([`Map::current_id`]). The copy's volume is dropped, not fused: it
    /// may lie at a pose the object has left (the copy a failed tracking
    /// left behind), and `keep` matched this frame best.
    pub(super) fn merge(&mut self, keep: ObjectId, copy: ObjectId) {
        if !self.objects.contains_key(&keep) {
            return;
        }
        let Some(copied) = self.objects.remove(&copy) else {
            return;
        };
        let kept = self.objects.get_mut(&keep).expect("checked above");
        kept.labels.absorb(&copied.labels);
        for (class, votes) in copied.class_histogram {
            *kept.class_histogram.entry(class).or_default() += votes;
        }
        kept.observations += copied.observations;
        self.merged_into.insert(copy, keep);
        self.failed_views.remove(&copy);
        self.notified.remove(&copy);
    }

    /// Keeps the labels of an object about to be deleted, so that frames
    /// that showed it can still be labelled ([`Map::labels_of`]).
    pub(super) fn retire(&mut self, id: ObjectId, labels: ObjectLabels) {
        if labels != ObjectLabels::default() {
            self.retired.insert(id, labels);
        }
    }

    /// The id an object is known by now: its own, or, if it was merged into
    /// another (a copy of the same object), that one's.
    pub fn current_id(&self, id: ObjectId) -> ObjectId {
        let mut id = id;
        // Ids are never reused and a copy is merged into an object alive at
        // the time, so the chain ends.
        while let Some(&next) = self.merged_into.get(&id) {
            id = next;
        }
        id
    }

    /// The labels of the object an id returned by [`Map::integrate`] stood
    /// for: of the object it is now ([`Map::current_id`]), also after that
    /// object was deleted (an object carried away stops being seen, but the
    /// frames that showed it still need its labels). `None` for ids never
    /// issued, or deleted without labels.
    pub fn labels_of(&self, id: ObjectId) -> Option<&ObjectLabels> {
        let id = self.current_id(id);
        self.objects
            .get(&id)
            .map(|o| &o.labels)
            .or_else(|| self.retired.get(&id))
    }
}
