//! Episode recordings: one MCAP file per episode with what the actor saw,
//! what the map and the U-Net made of it, the labels it sent, and what it
//! did, in Foxglove's typed schemas (`foxglove::messages`, protobuf), so a
//! file opens in Foxglove as it is and places everything in 3-D
//! (`deploy/foxglove-layout.json` arranges the panels).
//!
//! Topics (frames: `world`, z up; `camera`, the optical frame):
//! - `/tf` (`foxglove.FrameTransform`): `world` → `camera`, every frame;
//! - `/camera/calibration` (`foxglove.CameraCalibration`): the intrinsics;
//! - `/camera/rgb` (rgb8) and `/camera/depth` (32FC1, metres), `foxglove.RawImage`;
//! - `/camera/instance_ids` and `/map/object_ids`: the simulator's and the
//!   map's ids in a visible colour map (rgb8; the same colour as the
//!   object's mesh), and as numbers in `…/raw` (16UC1);
//! - `/labels/<affordance>` (mono8: 255 positive, 0 negative, 128 unknown);
//! - `/unet/<affordance>` (mono8: the U-Net's calibrated probability × 255);
//! - `/map/global` and `/map/local` (`foxglove.Grid`, methods with a map):
//!   the policy's egocentric map planes, one float field per plane, laid on
//!   the floor around the agent;
//! - `/map/objects` (`foxglove.SceneUpdate`, methods with a map): every map
//!   object's mesh at the end of the episode, with its labels;
//! - `/policy/step` (`afx.PolicyStep`, JSON): action, reward, outcome.

mod id_colours;
mod messages;

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use foxglove::messages::SceneUpdate;
use foxglove::{Encode, Schema};
use mapper::{Affordance, Intrinsics, Mesh, Pose};
use mcap::records::MessageHeader;
use proto::{LABEL_NEGATIVE, LABEL_POSITIVE};
use serde::Serialize;

pub(crate) use id_colours::{colour_ids, id_colour};

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub(crate) enum RecordingError {
    /// The file could not be created or written.
    #[error("writing recording {path}: {message}")]
    Write {
        /// The file.
        path: String,
        /// What failed.
        message: String,
    },
}

/// What the agent did in one step.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct StepRecord {
    /// Index of the action in the action space.
    pub action: usize,
    /// The action, readable.
    pub action_name: String,
    /// Reward.
    pub reward: f32,
    /// Whether it succeeded.
    pub success: bool,
    /// Why not, readable (empty on success).
    pub failure: String,
    /// The agent after the step: x, y (metres), heading (degrees).
    pub agent: (f32, f32, f32),
}

/// The policy's map planes of one frame (methods with a map).
#[derive(Debug, Clone, Copy)]
pub(crate) struct MapPlanesRecord<'a> {
    /// The agent the planes are centred on: x, y (metres), heading (radians).
    pub agent: (f32, f32, f32),
    /// The planes at the global extent, `[planes, cells, cells]`, as bytes
    /// (`proto::unit_to_byte`).
    pub global: &'a [u8],
    /// The planes at the local extent, as bytes.
    pub local: &'a [u8],
}

/// One frame of the episode.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FrameRecord<'a> {
    /// Wall-clock time of the frame, nanoseconds since the Unix epoch.
    pub stamp_ns: u64,
    /// RGB, interleaved.
    pub rgb: &'a [u8],
    /// Z-depth, metres.
    pub depth_m: &'a [f32],
    /// The simulator's instance ids.
    pub instance_ids: &'a [u32],
    /// The map's object ids.
    pub map_ids: &'a [u32],
    /// Label planes, one per affordance.
    pub labels: &'a [u8],
    /// The U-Net's calibrated probabilities as bytes, one plane per affordance.
    pub predictions: &'a [u8],
    /// The camera in the world.
    pub t_world_camera: &'a Pose,
    /// The policy's map planes, where the method has a map.
    pub map_planes: Option<MapPlanesRecord<'a>>,
}

/// How the policy's map planes are laid out (methods with a map).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct MapLayout {
    /// Name of every plane, in order.
    pub plane_names: Vec<String>,
    /// Cells per edge.
    pub cells: usize,
    /// Edge length of the global and the local map, metres.
    pub extents_m: [f32; 2],
    /// Height of the floor, metres.
    pub floor_z: f32,
}

/// One map object at the end of the episode.
#[derive(Debug, Clone)]
pub(crate) struct ObjectRecord {
    /// Its map id (the ids of `/map/object_ids`).
    pub id: u32,
    /// Its surface, world frame.
    pub mesh: Mesh,
    /// What Foxglove shows when it is selected (labels, class).
    pub metadata: Vec<(String, String)>,
}

/// Everything one recording holds.
#[derive(Debug, Clone, Copy)]
pub(crate) struct EpisodeRecord<'a> {
    /// The camera.
    pub intrinsics: &'a Intrinsics,
    /// The affordances, in plane order.
    pub affordances: &'a [Affordance],
    /// Every frame.
    pub frames: &'a [FrameRecord<'a>],
    /// Every step (between frame i and frame i + 1).
    pub steps: &'a [StepRecord],
    /// The map planes' layout, where the method has a map.
    pub map_layout: Option<&'a MapLayout>,
    /// The map's objects at the end, where the method has a map.
    pub objects: &'a [ObjectRecord],
}

/// Counts of what a recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct RecordingSummary {
    /// Messages written.
    pub messages: u64,
    /// Frames written.
    pub frames: usize,
}

/// One policy step, our own JSON message.
#[derive(Serialize)]
struct PolicyStep<'a> {
    step: usize,
    action: usize,
    action_name: &'a str,
    reward: f32,
    success: bool,
    failure: &'a str,
    agent: AgentPose,
}

#[derive(Serialize)]
struct AgentPose {
    x: f32,
    y: f32,
    yaw_deg: f32,
}

impl Encode for PolicyStep<'_> {
    type Error = serde_json::Error;

    fn get_schema() -> Option<Schema> {
        Some(Schema::new(
            "afx.PolicyStep",
            "jsonschema",
            br#"{"type":"object","properties":{"step":{"type":"integer"},"action":{"type":"integer"},"action_name":{"type":"string"},"reward":{"type":"number"},"success":{"type":"boolean"},"failure":{"type":"string"},"agent":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"yaw_deg":{"type":"number"}}}}}"#.as_slice(),
        ))
    }

    fn get_message_encoding() -> String {
        "json".into()
    }

    fn encode(&self, buf: &mut impl foxglove::bytes::BufMut) -> Result<(), Self::Error> {
        let json = serde_json::to_vec(self)?;
        buf.put_slice(&json);
        Ok(())
    }
}

/// An MCAP file that takes typed messages, adding each schema and topic
/// the first time it is used.
struct McapOut<'p> {
    path: &'p Path,
    out: mcap::Writer<BufWriter<File>>,
    schemas: BTreeMap<String, u16>,
    channels: BTreeMap<String, u16>,
    messages: u64,
}

impl<'p> McapOut<'p> {
    fn create(path: &'p Path) -> Result<Self, RecordingError> {
        let file = File::create(path).map_err(|e| fail(path, &e))?;
        let out = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .profile("")
            .create(BufWriter::new(file))
            .map_err(|e| fail(path, &e))?;
        Ok(Self {
            path,
            out,
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            messages: 0,
        })
    }

    fn channel<T: Encode>(&mut self, topic: &str) -> Result<u16, RecordingError> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let schema_id = match T::get_schema() {
            None => 0,
            Some(schema) => match self.schemas.get(&schema.name) {
                Some(&id) => id,
                None => {
                    let id = self
                        .out
                        .add_schema(&schema.name, &schema.encoding, &schema.data)
                        .map_err(|e| fail(self.path, &e))?;
                    self.schemas.insert(schema.name, id);
                    id
                }
            },
        };
        let id = self
            .out
            .add_channel(
                schema_id,
                topic,
                &T::get_message_encoding(),
                &BTreeMap::new(),
            )
            .map_err(|e| fail(self.path, &e))?;
        self.channels.insert(topic.to_owned(), id);
        Ok(id)
    }

    fn log<T: Encode>(&mut self, topic: &str, ns: u64, message: &T) -> Result<(), RecordingError> {
        let channel_id = self.channel::<T>(topic)?;
        let mut data = Vec::with_capacity(message.encoded_len().unwrap_or(256));
        message.encode(&mut data).map_err(|e| fail(self.path, &e))?;
        self.messages += 1;
        self.out
            .write_to_known_channel(
                &MessageHeader {
                    channel_id,
                    sequence: self.messages as u32,
                    log_time: ns,
                    publish_time: ns,
                },
                &data,
            )
            .map_err(|e| fail(self.path, &e))
    }

    fn finish(mut self) -> Result<u64, RecordingError> {
        self.out.finish().map_err(|e| fail(self.path, &e))?;
        Ok(self.messages)
    }
}

fn fail(path: &Path, e: &dyn std::fmt::Display) -> RecordingError {
    RecordingError::Write {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// Ids as 16-bit pixels (ids above 65 535 saturate).
fn ids16(ids: &[u32]) -> Vec<u8> {
    ids.iter()
        .flat_map(|&id| (id.min(u32::from(u16::MAX)) as u16).to_le_bytes())
        .collect()
}

/// A label plane as mono8: positive white, negative black, unknown grey.
fn label_pixels(plane: &[u8]) -> Vec<u8> {
    plane
        .iter()
        .map(|&l| match l {
            LABEL_POSITIVE => 255,
            LABEL_NEGATIVE => 0,
            _ => 128,
        })
        .collect()
}

/// Writes one episode to `path` (lz4-compressed chunks).
pub(crate) fn write_episode(
    path: &Path,
    episode: &EpisodeRecord<'_>,
) -> Result<RecordingSummary, RecordingError> {
    let mut out = McapOut::create(path)?;
    let k = episode.intrinsics;
    let size = (k.width, k.height);
    let pixels = k.width * k.height;
    let image = messages::camera_image;
    for f in episode.frames {
        let ns = f.stamp_ns;
        out.log("/tf", ns, &messages::world_to_camera(ns, f.t_world_camera))?;
        out.log("/camera/calibration", ns, &messages::calibration(ns, k))?;
        out.log(
            "/camera/rgb",
            ns,
            &image(ns, size, "rgb8", 3, f.rgb.to_vec()),
        )?;
        let depth = f.depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
        out.log("/camera/depth", ns, &image(ns, size, "32FC1", 4, depth))?;
        for (topic, ids) in [
            ("/camera/instance_ids", f.instance_ids),
            ("/map/object_ids", f.map_ids),
        ] {
            out.log(topic, ns, &image(ns, size, "rgb8", 3, colour_ids(ids)))?;
            let raw = image(ns, size, "16UC1", 2, ids16(ids));
            out.log(&format!("{topic}/raw"), ns, &raw)?;
        }
        for (a, plane) in episode.affordances.iter().zip(f.labels.chunks(pixels)) {
            let mono = image(ns, size, "mono8", 1, label_pixels(plane));
            out.log(&format!("/labels/{}", a.as_str()), ns, &mono)?;
        }
        for (a, plane) in episode.affordances.iter().zip(f.predictions.chunks(pixels)) {
            let mono = image(ns, size, "mono8", 1, plane.to_vec());
            out.log(&format!("/unet/{}", a.as_str()), ns, &mono)?;
        }
        if let (Some(layout), Some(planes)) = (episode.map_layout, f.map_planes) {
            for (topic, extent_m, values) in [
                ("/map/global", layout.extents_m[0], planes.global),
                ("/map/local", layout.extents_m[1], planes.local),
            ] {
                let placement = messages::GridPlacement {
                    agent: planes.agent,
                    floor_z: layout.floor_z,
                    extent_m,
                    cells: layout.cells,
                };
                let values: Vec<f32> = values.iter().map(|&b| proto::byte_to_unit(b)).collect();
                let grid = messages::agent_grid(ns, &placement, &layout.plane_names, &values);
                out.log(topic, ns, &grid)?;
            }
        }
    }
    for (i, s) in episode.steps.iter().enumerate() {
        // A step happens between frame i and frame i + 1.
        let ns = episode
            .frames
            .get(i + 1)
            .or(episode.frames.last())
            .map_or(0, |f| f.stamp_ns);
        let step = PolicyStep {
            step: i,
            action: s.action,
            action_name: &s.action_name,
            reward: s.reward,
            success: s.success,
            failure: &s.failure,
            agent: AgentPose {
                x: s.agent.0,
                y: s.agent.1,
                yaw_deg: s.agent.2,
            },
        };
        out.log("/policy/step", ns, &step)?;
    }
    if episode.map_layout.is_some() {
        let ns = episode.frames.last().map_or(0, |f| f.stamp_ns);
        let update = SceneUpdate {
            deletions: Vec::new(),
            entities: episode
                .objects
                .iter()
                .map(|o| messages::object_entity(ns, o.id, &o.mesh, id_colour(o.id), &o.metadata))
                .collect(),
        };
        out.log("/map/objects", ns, &update)?;
    }
    let messages = out.finish()?;
    Ok(RecordingSummary {
        messages,
        frames: episode.frames.len(),
    })
}
