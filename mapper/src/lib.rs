//! An object-level TSDF map (TSDF++ style, with its known faults fixed).
//!
//! Every object owns a block-hashed TSDF volume **in its own frame** plus a
//! pose `t_world_object`, so moving an object is a pose update, never a
//! resampling. Static structure (floor, walls) lives in a world-frame
//! background volume. [`Map::integrate`] takes a posed depth frame with an
//! instance mask and returns, per pixel, the id of the map object it belongs
//! to — an id that stays the same across viewpoints. Interaction outcomes are
//! stored on objects and can be rendered back into any past frame.
//!
//! This crate knows nothing of reinforcement learning, simulators or
//! transport; it takes frames and answers geometric questions.

pub mod association;
pub mod camera;
pub mod icp;
pub mod integrate;
pub mod labels;
pub mod layer;
mod map;
pub mod mesh;
pub mod projection;
pub mod render;
mod sdf_sample;
pub mod segmentation;

pub use camera::{scaled_px, Frame, Intrinsics, REFERENCE_PIXELS};
pub use icp::{TrackingFailure, TrackingOutcome, TrackingReport, TrackingTrigger};
pub use labels::{Affordance, ObjectLabels, Outcome};
pub use layer::{BlockIndex, Layer, Voxel, VoxelIndex};
pub use map::{IntegrateTimings, Map, MapConfig, MapError, MapObject, ObjectId, Whereabouts};
pub use mesh::Mesh;
pub use projection::{GridSpec, ProjectionKind};
pub use segmentation::{GeometricParams, Segmentation};

/// Poses are rigid transforms in metres.
pub type Pose = nalgebra::Isometry3<f32>;
