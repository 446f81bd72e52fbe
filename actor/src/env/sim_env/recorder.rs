//! An episode as a Foxglove recording (`crate::recording`): its frames,
//! the policy's maps, and the map's objects with their meshes and labels.
//! While episodes are recorded, each has an [`EpisodeRecorder`] that
//! observes its steps and observations for what the episode does not keep
//! itself.

use super::*;
use crate::recording::{write_episode, EpisodeRecord, FrameRecord, MapLayout, MapPlanesRecord};

/// Which episodes go to MCAP files, and where.
#[derive(Debug, Clone)]
pub(super) struct Recording {
    /// The directory the files go to.
    pub(super) dir: std::path::PathBuf,
    /// File-name prefix (the actor's).
    prefix: String,
    /// Every how many episodes one is recorded.
    pub(super) every: u64,
}

impl Recording {
    /// The file for episode `id` ending at the run's `global_steps`: named
    /// by both, and never one that exists (a restarted actor counts its
    /// episodes from 0 again).
    pub(super) fn path(&self, global_steps: u64, id: u64) -> std::path::PathBuf {
        let stem = format!("{}step{global_steps:09}_episode{id:06}", self.prefix);
        let mut path = self.dir.join(format!("{stem}.mcap"));
        let mut n = 1;
        while path.exists() {
            n += 1;
            path = self.dir.join(format!("{stem}_{n}.mcap"));
        }
        path
    }
}

/// What a recording needs of an episode beyond what the episode keeps:
/// when each frame was observed, what each step did, and the policy's map
/// planes.
#[derive(Default)]
pub(super) struct EpisodeRecorder {
    /// Wall-clock time of every frame, nanoseconds since the Unix epoch.
    stamps: Vec<u64>,
    /// What every step did.
    steps: Vec<StepRecord>,
    /// The policy's map planes of every frame (methods with a map).
    map_planes: Vec<RecordedMapPlanes>,
}

impl EpisodeRecorder {
    /// A step done.
    pub(super) fn step(&mut self, record: StepRecord) {
        self.steps.push(record);
    }

    /// A frame observed, with the state the policy got from it and where
    /// the agent was (x, y in metres, heading in radians).
    pub(super) fn observation(&mut self, state: &State, agent: (f32, f32, f32)) {
        self.stamps.push(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64),
        );
        if !state.global_map().is_empty() {
            self.map_planes.push(RecordedMapPlanes {
                agent,
                global: state.global_map().to_vec(),
                local: state.local_map().to_vec(),
            });
        }
    }
}

/// One frame's map planes as the policy saw them, kept for a recording.
struct RecordedMapPlanes {
    /// x, y (metres), heading (radians).
    agent: (f32, f32, f32),
    /// The planes as bytes (`proto::unit_to_byte`, as the wire carries
    /// them): a quarter of the floats' memory for every frame of the episode.
    global: Vec<u8>,
    local: Vec<u8>,
}

impl SimEnv {
    /// Records every `every`-th episode (by id) from now on to
    /// `dir/{prefix}step{run steps:09}_episode{id:06}.mcap`, the run's
    /// steps being those the learner last reported ([`SimEnv::set_global_steps`]).
    pub fn record_to(&mut self, dir: std::path::PathBuf, prefix: String, every: u64) {
        self.recording = Some(Recording {
            dir,
            prefix,
            every: every.max(1),
        });
    }

    /// Writes the episode, observed by `recorder`, to an MCAP file at `path`.
    pub(super) fn record(
        &self,
        episode: &Episode,
        recorder: &EpisodeRecorder,
        labels: &[Vec<u8>],
        k: &mapper::Intrinsics,
        path: &std::path::Path,
    ) -> anyhow::Result<()> {
        let truth_ids = episode.metrics.truth_ids();
        let records: Vec<FrameRecord<'_>> = (0..episode.frames.len())
            .map(|i| {
                let frame = &episode.frames[i];
                FrameRecord {
                    stamp_ns: recorder.stamps.get(i).copied().unwrap_or(0),
                    rgb: &frame.rgb,
                    depth_m: &frame.depth_m,
                    instance_ids: &truth_ids[i],
                    map_ids: &frame.map_ids,
                    labels: &labels[i],
                    predictions: &episode.probabilities[i],
                    t_world_camera: &frame.t_world_camera,
                    map_planes: recorder.map_planes.get(i).map(|p| MapPlanesRecord {
                        agent: p.agent,
                        global: &p.global,
                        local: &p.local,
                    }),
                }
            })
            .collect();
        let with_map = !recorder.map_planes.is_empty();
        let layout = MapLayout {
            plane_names: self.state_config.map_plane_names(),
            cells: self.state_config.map_cells,
            extents_m: [
                self.state_config.global_extent_m,
                self.state_config.local_extent_m,
            ],
            floor_z: episode.sim.scene().floor_top_m,
        };
        write_episode(
            path,
            &EpisodeRecord {
                intrinsics: k,
                affordances: &self.config.affordances,
                frames: &records,
                steps: &recorder.steps,
                map_layout: with_map.then_some(&layout),
                objects: &episode.memory.object_records()?,
            },
        )?;
        Ok(())
    }
}
