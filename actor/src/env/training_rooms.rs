//! The rooms an actor trains in. Always the training split: the iTHOR
//! living rooms FloorPlan201–220 (or the generated rooms' training seeds).
//! The validation rooms (221–225) choose checkpoints and the test rooms
//! (226–230) score them; an actor that explored either would make both
//! choices and scores dishonest, so nothing here takes a split as input.

use std::path::Path;

use sim::ithor::SceneSet;
use sim::profile::RobotProfile;
use sim::scenes::{SceneSource, SceneSourceError};

/// The training rooms under `data_dir`: iTHOR's (`ithor-livingrooms/`)
/// when `ithor` is set, otherwise rooms generated from the object
/// catalogue (`ithor-object-types.tsv`) with the training seeds.
pub fn training_rooms(
    data_dir: &Path,
    ithor: bool,
    profile: &RobotProfile,
) -> Result<SceneSource, SceneSourceError> {
    let rooms = data_dir.join("ithor-livingrooms");
    SceneSource::open(
        ithor.then_some(rooms.as_path()),
        SceneSet::Train,
        &data_dir.join("ithor-object-types.tsv"),
        profile,
    )
}
