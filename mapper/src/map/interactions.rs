//! What the robot tells the map between frames: an object may have moved
//! or was pushed (the next frame tracks it), was picked up and released,
//! and what trying it taught (interaction outcomes and confidence labels).

use nalgebra::Vector3;

use super::{track, Map, MapError, MapObject, ObjectId, Whereabouts};
use crate::labels::{Affordance, Outcome};
use crate::Pose;

impl Map {
    /// Says that an object may have moved (the robot pushed or picked it
    /// up): the next frame tracks it, starting from `motion * t_world_object`
    /// when a world-frame motion guess is given. If tracking fails, the
    /// object is left untouched for that frame and the failure is reported in
    /// [`Map::last_tracking`].
    pub fn notify_moved(&mut self, id: ObjectId, motion: Option<Pose>) -> Result<(), MapError> {
        if !self.objects.contains_key(&id) {
            return Err(MapError::UnknownObject(id));
        }
        self.notified.insert(
            id,
            track::Notice {
                motion,
                ..Default::default()
            },
        );
        Ok(())
    }

    /// Says that the robot pushed an object along `direction` (world frame;
    /// its horizontal part counts): the next frame tracks it, looking for it
    /// up to [`max_push_m`] ahead along the push, where a push can slide it,
    /// but no further sideways or back than any other motion
    /// ([`max_motion_m`]). A direction of about zero length, or not finite,
    /// is no direction: then this is [`Map::notify_moved`] without a motion
    /// guess.
    ///
    /// [`max_push_m`]: crate::icp::TrackingParams::max_push_m
    /// [`max_motion_m`]: crate::icp::TrackingParams::max_motion_m
    pub fn notify_pushed(&mut self, id: ObjectId, direction: Vector3<f32>) -> Result<(), MapError> {
        if !self.objects.contains_key(&id) {
            return Err(MapError::UnknownObject(id));
        }
        let up = self.config.tracking.unit_up();
        let level = up.map_or(direction, |up| direction - up * up.dot(&direction));
        self.notified.insert(
            id,
            track::Notice {
                motion: None,
                // `try_new` also refuses a NaN norm.
                push: nalgebra::Unit::try_new(level, 1e-6),
                ..Default::default()
            },
        );
        Ok(())
    }

    /// Records an interaction outcome on an object.
    pub fn record_interaction(
        &mut self,
        id: ObjectId,
        affordance: Affordance,
        outcome: Outcome,
    ) -> Result<(), MapError> {
        self.object_mut(id)?.labels.record(affordance, outcome);
        Ok(())
    }

    /// Sets an object's label from annotation by confidence.
    pub fn set_confidence_label(
        &mut self,
        id: ObjectId,
        affordance: Affordance,
        label: Option<bool>,
    ) -> Result<(), MapError> {
        self.object_mut(id)?
            .labels
            .set_confidence_label(affordance, label);
        Ok(())
    }

    /// Objects whose label for `affordance` is `label` (ascending ids).
    pub fn objects_labelled(&self, affordance: Affordance, label: Option<bool>) -> Vec<ObjectId> {
        self.objects
            .values()
            .filter(|o| o.labels.label(affordance) == label)
            .map(|o| o.id)
            .collect()
    }

    /// The robot picked the object up: the map stops expecting to see it
    /// where it was (it is neither rendered nor missed) and keeps its
    /// volume and labels until [`Map::release`].
    pub fn hold(&mut self, id: ObjectId) -> Result<(), MapError> {
        self.object_mut(id)?.whereabouts = Whereabouts::Held;
        Ok(())
    }

    /// The robot let go of a held object, which moved rigidly by `motion`
    /// (world frame) between pick-up and release. The next frame tracks it
    /// from there, as after [`Map::notify_moved`]: a model seen from one
    /// side may not match its new view well enough for association alone.
    /// Where tracking finds nothing there (put down out of view or behind
    /// something), it stays where the motion put it; where a segment there
    /// fits it poorly, it is lost, as a pushed object would be.
    pub fn release(&mut self, id: ObjectId, motion: Pose) -> Result<(), MapError> {
        let object = self.object_mut(id)?;
        object.whereabouts = Whereabouts::Placed;
        object.t_world_object = motion * object.t_world_object;
        object.misses = 0;
        let notice = track::Notice {
            released: true,
            ..Default::default()
        };
        self.notified.insert(id, notice);
        Ok(())
    }

    /// Moves an object (e.g. after the robot pushed it): a pose update, no resampling.
    pub fn set_object_pose(&mut self, id: ObjectId, t_world_object: Pose) -> Result<(), MapError> {
        self.object_mut(id)?.t_world_object = t_world_object;
        Ok(())
    }

    /// The object `id`, to change; an error if the map has none.
    fn object_mut(&mut self, id: ObjectId) -> Result<&mut MapObject, MapError> {
        self.objects.get_mut(&id).ok_or(MapError::UnknownObject(id))
    }
}
