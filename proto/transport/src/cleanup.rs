//! Removal of resources left behind by crashed processes.

use iceoryx2::prelude::*;

use crate::{Ipc, TransportError};

/// Removes the shared-memory resources of every node whose process has died.
/// Returns how many dead nodes were cleaned. Safe to call while other runs are
/// alive: live nodes are never touched.
pub fn remove_dead_nodes() -> Result<usize, TransportError> {
    let config = Config::default();
    let mut dead = Vec::new();
    Node::<Ipc>::list(&config, |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    })
    .map_err(|e| TransportError::new("list nodes", "all", e))?;
    let mut removed = 0;
    for view in dead {
        if view.try_remove_stale_resources().is_ok() {
            removed += 1;
        }
    }
    Ok(removed)
}
