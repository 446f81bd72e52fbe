//! Importer for AI2-THOR object metadata (`event.metadata["objects"]`, one
//! JSON object per scene keyed by `objectId`), as in
//! `../shared/data/ithor-livingrooms/FloorPlan2NN.json`. Users can bring their
//! own dumps in the same format.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use nalgebra::{Point2, Point3, Rotation3, UnitQuaternion};
use serde::Deserialize;

use crate::scene::{points_aabb, walls_around, OrientedBox, Scene, SceneObject};

/// Why a scene could not be imported.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not AI2-THOR object metadata.
    #[error("{path} is not AI2-THOR object metadata (an object keyed by objectId): {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// Parser error with line and column.
        source: serde_json::Error,
    },
    /// An object's data is unusable.
    #[error("{path}: object {object:?}: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The object id.
        object: String,
        /// What is wrong.
        reason: String,
    },
    /// No object of type `Floor`: the room's extent is unknown.
    #[error("{path} has no Floor object, so the room's extent is unknown")]
    NoFloor {
        /// The file.
        path: PathBuf,
    },
}

#[derive(Debug, Deserialize)]
struct Xyz {
    x: f32,
    y: f32,
    z: f32,
}

#[derive(Debug, Deserialize)]
struct RawBox {
    #[serde(rename = "cornerPoints")]
    corner_points: Vec<[f32; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
struct RawObject {
    object_type: String,
    position: Xyz,
    rotation: Xyz,
    axis_aligned_bounding_box: RawBox,
    object_oriented_bounding_box: Option<RawBox>,
    #[serde(default)]
    mass: f32,
    #[serde(default)]
    pickupable: bool,
    #[serde(default)]
    moveable: bool,
    #[serde(default)]
    receptacle: bool,
    #[serde(default)]
    openable: bool,
    #[serde(default)]
    salient_materials: Option<Vec<String>>,
    #[serde(default)]
    parent_receptacles: Option<Vec<String>>,
}

/// Unity (left-handed, y up) to world (right-handed, z up).
fn point(x: f32, y: f32, z: f32) -> Point3<f32> {
    Point3::new(x, z, y)
}

/// Unity Euler angles (degrees; applied z, then x, then y about the fixed
/// axes) to a world-frame rotation. Swapping y and z is a reflection `S`, so
/// the world rotation is `S · R_unity · S`.
fn rotation(r: &Xyz) -> UnitQuaternion<f32> {
    let (x, y, z) = (r.x.to_radians(), r.y.to_radians(), r.z.to_radians());
    let unity = Rotation3::from_axis_angle(&nalgebra::Vector3::y_axis(), y)
        * Rotation3::from_axis_angle(&nalgebra::Vector3::x_axis(), x)
        * Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), z);
    let s = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0);
    let world = s * unity.matrix() * s;
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(world))
}

fn corners(raw: &RawBox) -> Option<[Point3<f32>; 8]> {
    let c: Vec<Point3<f32>> = raw
        .corner_points
        .iter()
        .map(|p| point(p[0], p[1], p[2]))
        .collect();
    c.try_into().ok()
}

/// Corner points of AI2-THOR boxes are rounded; this much slack is allowed.
const CORNER_TOLERANCE_M: f32 = 0.01;

/// Imports one scene file. The scene is named after the file stem.
pub fn load_scene(path: &Path) -> Result<Scene, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Io {
        path: path.to_owned(),
        source,
    })?;
    parse_scene(path, &text)
}

/// Imports a scene from the text of a scene file at `path` (which names the
/// scene, after its stem, and the errors).
pub fn parse_scene(path: &Path, text: &str) -> Result<Scene, ImportError> {
    let raw: BTreeMap<String, RawObject> =
        serde_json::from_str(text).map_err(|source| ImportError::Json {
            path: path.to_owned(),
            source,
        })?;
    let invalid = |object: &str, reason: String| ImportError::Invalid {
        path: path.to_owned(),
        object: object.to_string(),
        reason,
    };
    let mut objects = Vec::with_capacity(raw.len());
    for (id, o) in raw {
        let aabb = corners(&o.axis_aligned_bounding_box)
            .ok_or_else(|| invalid(&id, "axisAlignedBoundingBox needs 8 corner points".into()))?;
        let (min, max) = points_aabb(&aabb);
        if !(min.iter().chain(max.iter()).all(|v| v.is_finite())) {
            return Err(invalid(&id, "non-finite bounding box".into()));
        }
        let bounds = match &o.object_oriented_bounding_box {
            Some(b) => {
                let c = corners(b).ok_or_else(|| {
                    invalid(
                        &id,
                        "objectOrientedBoundingBox needs 8 corner points".into(),
                    )
                })?;
                OrientedBox::from_corners(&c, CORNER_TOLERANCE_M).ok_or_else(|| {
                    invalid(
                        &id,
                        "objectOrientedBoundingBox corners do not form a box".into(),
                    )
                })?
            }
            None => OrientedBox::axis_aligned(min, max),
        };
        objects.push(SceneObject {
            id,
            object_type: o.object_type,
            position: point(o.position.x, o.position.y, o.position.z),
            rotation: rotation(&o.rotation),
            bounds,
            aabb_min: min,
            aabb_max: max,
            mass_kg: o.mass,
            pickupable: o.pickupable,
            moveable: o.moveable,
            receptacle: o.receptacle,
            openable: o.openable,
            materials: o.salient_materials.unwrap_or_default(),
            parent_receptacles: o.parent_receptacles.unwrap_or_default(),
        });
    }
    let floor = objects
        .iter()
        .find(|o| o.is_floor())
        .ok_or_else(|| ImportError::NoFloor {
            path: path.to_owned(),
        })?;
    let (lo, hi) = floor.bounds.world_aabb();
    let tallest = objects
        .iter()
        .flat_map(|o| o.bounds.corners())
        .map(|c| c.z)
        .fold(hi.z, f32::max);
    let (floor_min, floor_max) = (Point2::new(lo.x, lo.y), Point2::new(hi.x, hi.y));
    Ok(Scene {
        name: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        walls: walls_around(floor_min, floor_max, hi.z, tallest),
        objects,
        floor_min,
        floor_max,
        floor_top_m: hi.z,
    })
}

/// The paper's split of the 30 iTHOR living rooms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneSet {
    /// FloorPlan201–220.
    Train,
    /// FloorPlan221–225.
    Val,
    /// FloorPlan226–230.
    Test,
}

impl SceneSet {
    /// Scene names of the set.
    pub fn scene_names(self) -> Vec<String> {
        let range = match self {
            Self::Train => 201..=220,
            Self::Val => 221..=225,
            Self::Test => 226..=230,
        };
        range.map(|n| format!("FloorPlan{n}")).collect()
    }
}

impl FromStr for SceneSet {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "train" => Ok(Self::Train),
            "val" => Ok(Self::Val),
            "test" => Ok(Self::Test),
            other => Err(format!(
                "unknown scene set {other:?}: use train, val or test"
            )),
        }
    }
}

/// Imports every scene of `set` from `dir` (files `<name>.json`).
pub fn load_set(dir: &Path, set: SceneSet) -> Result<Vec<Scene>, ImportError> {
    set.scene_names()
        .iter()
        .map(|name| load_scene(&dir.join(format!("{name}.json"))))
        .collect()
}
