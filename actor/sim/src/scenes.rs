//! Where an episode's room comes from: the imported iTHOR living rooms of a
//! split (train / val / test) when a scene directory is given, otherwise
//! procedural rooms from the split's seed range. Episode seeds pick the
//! room deterministically.

use std::path::Path;

use crate::catalogue::{Catalogue, CatalogueError};
use crate::ithor::{load_set, ImportError, SceneSet};
use crate::procgen::{generate, TEST_SEEDS, TRAIN_SEEDS, VAL_SEEDS};
use crate::profile::RobotProfile;
use crate::scene::Scene;

/// A source of rooms for episodes.
#[derive(Debug, Clone)]
pub enum SceneSource {
    /// Imported iTHOR rooms of one split, loaded once.
    Ithor {
        /// The rooms.
        scenes: Vec<Scene>,
    },
    /// Procedural rooms.
    Generated {
        /// What they are furnished from.
        catalogue: Catalogue,
        /// Seeds of the split's rooms.
        seeds: std::ops::Range<u64>,
        /// The agent the rooms must leave room for.
        profile: RobotProfile,
    },
}

/// Why a scene source could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum SceneSourceError {
    /// An iTHOR room failed to import.
    #[error(transparent)]
    Import(#[from] ImportError),
    /// The catalogue for generated rooms failed to load.
    #[error(transparent)]
    Catalogue(#[from] CatalogueError),
}

impl SceneSource {
    /// iTHOR rooms of `set` from `scene_dir` when it is given; otherwise
    /// rooms generated from the catalogue `catalogue_path` (the iTHOR
    /// object-type table or a TOML catalogue) with the split's seeds.
    pub fn open(
        scene_dir: Option<&Path>,
        set: SceneSet,
        catalogue_path: &Path,
        profile: &RobotProfile,
    ) -> Result<Self, SceneSourceError> {
        Ok(match scene_dir {
            Some(dir) => Self::Ithor {
                scenes: load_set(dir, set)?,
            },
            None => Self::Generated {
                catalogue: Catalogue::load(catalogue_path)?,
                seeds: match set {
                    SceneSet::Train => TRAIN_SEEDS,
                    SceneSet::Val => VAL_SEEDS,
                    SceneSet::Test => TEST_SEEDS,
                },
                profile: profile.clone(),
            },
        })
    }

    /// How many distinct rooms the source holds.
    pub fn len(&self) -> u64 {
        match self {
            Self::Ithor { scenes } => scenes.len() as u64,
            Self::Generated { seeds, .. } => seeds.end - seeds.start,
        }
    }

    /// True if the source holds no room.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The room for an episode seed, with its index in the source.
    pub fn pick(&self, episode_seed: u64) -> (u64, Scene) {
        let index = episode_seed % self.len().max(1);
        match self {
            Self::Ithor { scenes } => (index, scenes[index as usize].clone()),
            Self::Generated {
                catalogue,
                seeds,
                profile,
            } => (index, generate(catalogue, seeds.start + index, profile)),
        }
    }
}
