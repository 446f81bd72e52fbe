//! An episode as a Foxglove recording (`crate::recording`): its frames,
//! the policy's maps, and the map's objects with their meshes and labels.

use super::*;

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

/// One frame's map planes as the policy saw them, kept for a recording.
pub(super) struct RecordedMapPlanes {
    /// x, y (metres), heading (radians).
    pub(super) agent: (f32, f32, f32),
    /// The planes as bytes (`proto::unit_to_byte`, as the wire carries
    /// them): a quarter of the floats' memory for every frame of the episode.
    pub(super) global: Vec<u8>,
    pub(super) local: Vec<u8>,
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

    /// Writes the episode to an MCAP file at `path`.
    pub(super) fn record(
        &self,
        episode: &Episode,
        labels: &[Vec<u8>],
        k: &mapper::Intrinsics,
        path: &std::path::Path,
    ) -> anyhow::Result<()> {
        let records: Vec<FrameRecord<'_>> = (0..episode.frames.len())
            .map(|i| {
                let frame = &episode.frames[i];
                FrameRecord {
                    stamp_ns: episode.stamps[i],
                    rgb: &frame.rgb,
                    depth_m: &frame.depth_m,
                    instance_ids: &episode.truth_ids[i],
                    map_ids: &frame.map_ids,
                    labels: &labels[i],
                    predictions: &episode.probabilities[i],
                    t_world_camera: &frame.t_world_camera,
                    map_planes: episode.map_planes.get(i).map(|p| MapPlanesRecord {
                        agent: p.agent,
                        global: &p.global,
                        local: &p.local,
                    }),
                }
            })
            .collect();
        let with_map = !episode.map_planes.is_empty();
        let layout = MapLayout {
            plane_names: self.state_config.map_plane_names(),
            cells: self.state_config.map_cells,
            extents_m: [
                self.state_config.global_extent_m,
                self.state_config.local_extent_m,
            ],
            floor_z: episode.sim.scene().floor_top_m,
        };
        let objects = if with_map {
            self.object_records(&episode.map)?
        } else {
            Vec::new()
        };
        write_episode(
            path,
            &EpisodeRecord {
                intrinsics: k,
                affordances: &self.config.affordances,
                frames: &records,
                steps: &episode.step_log,
                map_layout: with_map.then_some(&layout),
                objects: &objects,
            },
        )?;
        Ok(())
    }

    /// The map's objects with their meshes and labels, for a recording.
    fn object_records(&self, map: &Map) -> anyhow::Result<Vec<ObjectRecord>> {
        map.objects()
            .values()
            .map(|object| {
                let mesh = map
                    .object_mesh(object.id)
                    .context("meshing a map object for the recording")?;
                let mut metadata = vec![(
                    "class".to_owned(),
                    object
                        .class()
                        .map_or_else(|| "unknown".to_owned(), |c| c.to_string()),
                )];
                for &a in &self.config.affordances {
                    let label = match object.labels.label(a) {
                        Some(true) => "positive",
                        Some(false) => "negative",
                        None => "unknown",
                    };
                    metadata.push((a.as_str().to_owned(), label.to_owned()));
                }
                Ok(ObjectRecord {
                    id: object.id.0,
                    mesh,
                    metadata,
                })
            })
            .collect()
    }
}
