//! Episode recordings: one MCAP file per episode with what the actor saw,
//! what the map made of it, the labels it sent, and what it did. Images use
//! Foxglove's `foxglove.RawImage` and poses `foxglove.PoseInFrame` (JSON
//! encoding with their JSON schemas), so the files open in Foxglove as they
//! are; the step log is a small JSON schema of our own.
//!
//! Topics: `/camera/rgb` (rgb8), `/camera/depth` (32FC1, metres),
//! `/camera/instance_ids` (16UC1, the simulator's ids), `/map/object_ids`
//! (16UC1), `/labels/<affordance>` (mono8: 255 positive, 0 negative, 128
//! unknown), `/camera/pose` (camera in the world frame), `/policy/step`.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use base64::Engine;
use mapper::{Affordance, Pose};
use mcap::records::MessageHeader;
use proto::{LABEL_NEGATIVE, LABEL_POSITIVE};
use serde_json::{json, Value};

/// Foxglove's RawImage, as a JSON schema.
const RAW_IMAGE_SCHEMA: &str = r#"{"type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"},"width":{"type":"integer"},"height":{"type":"integer"},"encoding":{"type":"string"},"step":{"type":"integer"},"data":{"type":"string","contentEncoding":"base64"}}}"#;
/// Foxglove's PoseInFrame, as a JSON schema.
const POSE_SCHEMA: &str = r#"{"type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"},"pose":{"type":"object","properties":{"position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}}}}"#;
/// One policy step.
const STEP_SCHEMA: &str = r#"{"type":"object","properties":{"step":{"type":"integer"},"action":{"type":"integer"},"action_name":{"type":"string"},"reward":{"type":"number"},"success":{"type":"boolean"},"failure":{"type":"string"},"agent":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"yaw_deg":{"type":"number"}}}}}"#;

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
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
pub struct StepRecord {
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

/// One frame of the episode.
#[derive(Debug, Clone, Copy)]
pub struct FrameRecord<'a> {
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
    /// The camera in the world.
    pub t_world_camera: &'a Pose,
}

/// Counts of what a recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordingSummary {
    /// Messages written.
    pub messages: u64,
    /// Frames written.
    pub frames: usize,
}

fn stamp(ns: u64) -> Value {
    json!({ "sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000 })
}

fn image(
    ns: u64,
    width: usize,
    height: usize,
    encoding: &str,
    bytes_per_pixel: usize,
    data: &[u8],
) -> Value {
    json!({
        "timestamp": stamp(ns),
        "frame_id": "camera",
        "width": width,
        "height": height,
        "encoding": encoding,
        "step": width * bytes_per_pixel,
        "data": base64::engine::general_purpose::STANDARD.encode(data),
    })
}

/// Ids as 16-bit pixels (ids above 65 535 saturate).
fn ids16(ids: &[u32]) -> Vec<u8> {
    ids.iter()
        .flat_map(|&id| (id.min(u32::from(u16::MAX)) as u16).to_le_bytes())
        .collect()
}

/// Writes one episode to `path` (lz4-compressed chunks).
pub fn write_episode(
    path: &Path,
    size: (usize, usize),
    affordances: &[Affordance],
    frames: &[FrameRecord<'_>],
    steps: &[StepRecord],
) -> Result<RecordingSummary, RecordingError> {
    let fail = |e: &dyn std::fmt::Display| RecordingError::Write {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let file = File::create(path).map_err(|e| fail(&e))?;
    let mut out = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Lz4))
        .profile("")
        .create(BufWriter::new(file))
        .map_err(|e| fail(&e))?;
    let no_metadata = BTreeMap::new();
    let image_schema = out
        .add_schema(
            "foxglove.RawImage",
            "jsonschema",
            RAW_IMAGE_SCHEMA.as_bytes(),
        )
        .map_err(|e| fail(&e))?;
    let pose_schema = out
        .add_schema("foxglove.PoseInFrame", "jsonschema", POSE_SCHEMA.as_bytes())
        .map_err(|e| fail(&e))?;
    let step_schema = out
        .add_schema("afx.PolicyStep", "jsonschema", STEP_SCHEMA.as_bytes())
        .map_err(|e| fail(&e))?;
    let mut channel =
        |schema: u16, topic: &str| out.add_channel(schema, topic, "json", &no_metadata);
    let rgb = channel(image_schema, "/camera/rgb").map_err(|e| fail(&e))?;
    let depth = channel(image_schema, "/camera/depth").map_err(|e| fail(&e))?;
    let instances = channel(image_schema, "/camera/instance_ids").map_err(|e| fail(&e))?;
    let objects = channel(image_schema, "/map/object_ids").map_err(|e| fail(&e))?;
    let pose = channel(pose_schema, "/camera/pose").map_err(|e| fail(&e))?;
    let step_channel = channel(step_schema, "/policy/step").map_err(|e| fail(&e))?;
    let label_channels = affordances
        .iter()
        .map(|a| channel(image_schema, &format!("/labels/{}", a.as_str())))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| fail(&e))?;

    let (width, height) = size;
    let pixels = width * height;
    let mut messages = 0u64;
    let mut sequence = 0u32;
    let mut write =
        |out: &mut mcap::Writer<BufWriter<File>>, channel_id: u16, ns: u64, value: &Value| {
            sequence += 1;
            messages += 1;
            let data = serde_json::to_vec(value).map_err(|e| fail(&e))?;
            out.write_to_known_channel(
                &MessageHeader {
                    channel_id,
                    sequence,
                    log_time: ns,
                    publish_time: ns,
                },
                &data,
            )
            .map_err(|e| fail(&e))
        };
    for f in frames {
        let ns = f.stamp_ns;
        write(
            &mut out,
            rgb,
            ns,
            &image(ns, width, height, "rgb8", 3, f.rgb),
        )?;
        let depth_bytes: Vec<u8> = f.depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
        write(
            &mut out,
            depth,
            ns,
            &image(ns, width, height, "32FC1", 4, &depth_bytes),
        )?;
        write(
            &mut out,
            instances,
            ns,
            &image(ns, width, height, "16UC1", 2, &ids16(f.instance_ids)),
        )?;
        write(
            &mut out,
            objects,
            ns,
            &image(ns, width, height, "16UC1", 2, &ids16(f.map_ids)),
        )?;
        for (plane, &channel_id) in f.labels.chunks(pixels).zip(&label_channels) {
            let mono: Vec<u8> = plane
                .iter()
                .map(|&l| match l {
                    LABEL_POSITIVE => 255,
                    LABEL_NEGATIVE => 0,
                    _ => 128,
                })
                .collect();
            write(
                &mut out,
                channel_id,
                ns,
                &image(ns, width, height, "mono8", 1, &mono),
            )?;
        }
        let t = f.t_world_camera.translation.vector;
        let q = f.t_world_camera.rotation;
        write(
            &mut out,
            pose,
            ns,
            &json!({
                "timestamp": stamp(ns),
                "frame_id": "world",
                "pose": {
                    "position": { "x": t.x, "y": t.y, "z": t.z },
                    "orientation": { "x": q.i, "y": q.j, "z": q.k, "w": q.w },
                },
            }),
        )?;
    }
    for (i, s) in steps.iter().enumerate() {
        // A step happens between frame i and frame i + 1.
        let ns = frames
            .get(i + 1)
            .or(frames.last())
            .map_or(0, |f| f.stamp_ns);
        write(
            &mut out,
            step_channel,
            ns,
            &json!({
                "step": i,
                "action": s.action,
                "action_name": s.action_name,
                "reward": s.reward,
                "success": s.success,
                "failure": s.failure,
                "agent": { "x": s.agent.0, "y": s.agent.1, "yaw_deg": s.agent.2 },
            }),
        )?;
    }
    out.finish().map_err(|e| fail(&e))?;
    Ok(RecordingSummary {
        messages,
        frames: frames.len(),
    })
}
