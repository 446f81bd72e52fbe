//! The four methods of the paper's comparison, and what each is made of.
//!
//! Everything that differs between methods (the state's inputs, the memory,
//! how an interaction picks its object, where labels come from) reads a
//! [`MethodSpec`], built in one place ([`Method::spec`]) instead of matching
//! on the method's name wherever it matters: a fifth method is one more
//! arm there, and a new combination of parts needs no other edit.

use serde::{Deserialize, Serialize};

/// Cells of the object-selection grid per affordance (3 × 3).
pub const GRID_CELLS: usize = 9;

/// The four methods of the paper's comparison (README, "The methods").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Map-based state and labels: annotation by interaction and by confidence.
    Ours,
    /// No map: GRU memory, labels from segmentation masks.
    NomapSeg,
    /// No map: GRU memory, 20 cm sphere labels.
    NomapNoseg,
    /// IntExp: RGB + affordances, most-centred object, sphere labels.
    Intexp,
}

impl Method {
    /// What the method is made of.
    pub fn spec(self) -> MethodSpec {
        match self {
            Method::Ours => MethodSpec {
                map: true,
                segmentation: true,
                distance: true,
                history: true,
                selection: Selection::Grid,
                labels: LabelSource::Map,
            },
            Method::NomapSeg => MethodSpec {
                map: false,
                segmentation: true,
                distance: true,
                history: true,
                selection: Selection::Grid,
                labels: LabelSource::Segments,
            },
            Method::NomapNoseg => MethodSpec {
                map: false,
                segmentation: false,
                distance: true,
                history: true,
                selection: Selection::Grid,
                labels: LabelSource::Spheres,
            },
            Method::Intexp => MethodSpec {
                map: false,
                segmentation: false,
                distance: false,
                history: false,
                selection: Selection::Centred,
                labels: LabelSource::Spheres,
            },
        }
    }

    /// Whether the method sees an instance segmentation (and so knows the
    /// background from the objects).
    pub fn segments(self) -> bool {
        self.spec().segmentation
    }

    /// kebab-case name, as on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Ours => "ours",
            Method::NomapSeg => "nomap-seg",
            Method::NomapNoseg => "nomap-noseg",
            Method::Intexp => "intexp",
        }
    }
}

/// The parts of a method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MethodSpec {
    /// Keeps the object-level map: its 2-D maps and interaction masks in the
    /// state, interactions recorded on map objects, labels from the map and
    /// annotation by confidence. Without it the policy remembers through a
    /// GRU.
    pub map: bool,
    /// Sees an instance segmentation (knows the background from objects).
    pub segmentation: bool,
    /// The camera input carries the distance channel.
    pub distance: bool,
    /// The state carries the history of recent actions.
    pub history: bool,
    /// How an interaction picks its object.
    pub selection: Selection,
    /// Where the labelled frames' labels come from.
    pub labels: LabelSource,
}

/// Actions remembered in the policy's history input.
pub const HISTORY_STEPS: usize = 5;

impl MethodSpec {
    /// Channels of the camera input for `affordances` affordances: RGB, the
    /// distance if the method has it, per affordance the U-Net's
    /// probability, and with a map the interacted (success, failure) masks.
    pub fn camera_channels(&self, affordances: usize) -> usize {
        3 + usize::from(self.distance) + affordances + if self.map { 2 * affordances } else { 0 }
    }

    /// Channels of each 2-D map (visited, occupancy, and per affordance
    /// interacted with success, with failure, and not interacted); 0
    /// without a map.
    pub fn map_channels(&self, affordances: usize) -> usize {
        if self.map {
            2 + 3 * affordances
        } else {
            0
        }
    }

    /// Length of the action-history input with `n_actions` actions: per
    /// remembered action its one-hot, success and reward; 0 without one.
    pub fn history_len(&self, n_actions: usize) -> usize {
        if self.history {
            HISTORY_STEPS * (n_actions + 2)
        } else {
            0
        }
    }
}

/// How an interaction action picks its object.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// One action per cell of the 3 × 3 grid (the paper's).
    Grid,
    /// One action: the most-centred object (IntExp's).
    Centred,
}

impl Selection {
    /// Selection actions per affordance.
    pub fn slots(self) -> usize {
        match self {
            Selection::Grid => GRID_CELLS,
            Selection::Centred => 1,
        }
    }
}

/// Where an episode's labels come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LabelSource {
    /// The map's objects: every view of an object interacted with (and,
    /// later in a run, of objects the U-Net is confident about).
    Map,
    /// The segmentation masks of the objects interacted with, in the frames
    /// of the episode.
    Segments,
    /// Spheres around the points interacted with.
    Spheres,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_methods_are_the_papers() {
        // Ours is the only one with a map; the segmenting ones are ours and
        // NoMap+Seg; IntExp alone picks the centred object and has neither
        // distance nor history.
        let all = [
            Method::Ours,
            Method::NomapSeg,
            Method::NomapNoseg,
            Method::Intexp,
        ];
        let with = |f: fn(MethodSpec) -> bool| -> Vec<Method> {
            all.into_iter().filter(|m| f(m.spec())).collect()
        };
        assert_eq!(with(|s| s.map), [Method::Ours]);
        assert_eq!(with(|s| s.segmentation), [Method::Ours, Method::NomapSeg]);
        assert_eq!(
            with(|s| s.selection == Selection::Centred),
            [Method::Intexp]
        );
        assert_eq!(
            with(|s| s.distance && s.history),
            [Method::Ours, Method::NomapSeg, Method::NomapNoseg]
        );
        assert_eq!(
            with(|s| s.labels == LabelSource::Spheres),
            [Method::NomapNoseg, Method::Intexp]
        );
    }
}
