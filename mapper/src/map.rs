//! The map: objects with their own volumes and poses, a background volume,
//! and the per-frame pipeline (segments → render → associate → track →
//! re-identify lost objects or add new ones → integrate → book-keeping).

mod interactions;
mod merge;
mod object;
mod reidentify;
mod track;
mod views;

pub use object::{MapObject, ObjectId, Whereabouts};

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::association::{associate, extract_segments, Association, AssociationParams, Segment};
use crate::camera::{Frame, Intrinsics};
use crate::icp::{TrackingParams, TrackingReport};
use crate::integrate::{
    integrate, pixels_by_label, DepthView, FramePixels, IntegrationParams, Owned,
};
use crate::labels::ObjectLabels;
use crate::layer::Layer;
use crate::render::RenderTarget;
use crate::segmentation::{segment_geometric, GeometricParams, Segmentation};
use crate::Pose;

/// Why a frame or a request was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MapError {
    /// An image's length does not match the intrinsics.
    #[error("{what} has {got} pixels, the intrinsics say {expected} ({width} x {height})")]
    FrameSize {
        /// Which image.
        what: &'static str,
        /// Its length.
        got: usize,
        /// Width × height.
        expected: usize,
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
    /// No object has this id (never existed or was deleted).
    #[error("no map object {0:?}")]
    UnknownObject(ObjectId),
}

/// The map's configuration: the run's `[task.map]` settings (the one
/// definition of every setting a run can change) and tracking's gates, which
/// a run does not set. The parameters of integration and association follow
/// from the settings ([`MapConfig::integration`], [`MapConfig::association`]),
/// with the values the voxel size implies; the defaults are those the map was
/// measured with (docs/notebook/2026-11-22-mapper.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapConfig {
    /// The run's map settings.
    pub settings: proto::MapSettings,
    /// Tracking settings (objects that moved); they scale with the voxel.
    pub tracking: TrackingParams,
}

impl Default for MapConfig {
    /// The run config's defaults ([`proto::MapSettings`]).
    fn default() -> Self {
        Self::from_settings(proto::MapSettings::default())
    }
}

impl MapConfig {
    /// The map a run's `[task.map]` describes, with tracking's gates scaled
    /// to its voxel.
    pub fn from_settings(settings: proto::MapSettings) -> Self {
        Self {
            settings,
            tracking: TrackingParams::for_voxel(settings.voxel_size_m),
        }
    }

    /// Integration's parameters: the free-space margin is one voxel.
    pub fn integration(&self) -> IntegrationParams {
        let s = &self.settings;
        IntegrationParams {
            truncation_m: s.truncation_m,
            max_weight: s.max_weight,
            min_depth_m: s.min_depth_m,
            max_depth_m: s.max_depth_m,
            free_space_margin_m: s.voxel_size_m,
        }
    }

    /// Association's parameters.
    pub fn association(&self) -> AssociationParams {
        let s = &self.settings;
        AssociationParams {
            min_segment_px: s.min_segment_px,
            new_object_min_px: s.new_object_min_px,
            min_iou: s.min_iou,
            min_coverage: s.min_coverage,
            depth_tolerance_m: self.depth_tolerance_m(),
            min_containment: s.min_containment,
        }
    }

    /// How far measured and rendered depth may differ and still agree: two
    /// voxels, but at least 3 cm.
    pub fn depth_tolerance_m(&self) -> f32 {
        (2.0 * self.settings.voxel_size_m).max(0.03)
    }

    /// Where instance masks come from.
    pub fn segmentation(&self) -> Segmentation {
        match self.settings.segmentation {
            proto::MapSegmentation::GroundTruth => Segmentation::Provided,
            proto::MapSegmentation::Geometric => {
                Segmentation::Geometric(GeometricParams::default())
            }
        }
    }
}

/// Rendered pixels an object must be glimpsed on to escape a miss
/// (`Map::book_keeping`).
const MIN_GLIMPSED_PX: usize = 5;

/// What becomes of a segment association matched to no object
/// (`Map::place_unmatched`).
enum Placement {
    /// A new object.
    New,
    /// The object already holding most of it.
    Existing(ObjectId),
    /// Nothing this frame.
    Wait,
}

/// Where the time of the last [`Map::integrate`] went, in seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct IntegrateTimings {
    /// Segment extraction and rendering the map into the camera.
    pub render_s: f64,
    /// Association of segments with rendered objects, new objects.
    pub associate_s: f64,
    /// Tracking of objects that may have moved (ICP).
    pub tracking_s: f64,
    /// TSDF integration of objects (parallel), with carving.
    pub integrate_s: f64,
    /// TSDF integration of the background.
    pub background_s: f64,
    /// Book-keeping (misses, deletion).
    pub book_keeping_s: f64,
}

/// The object-level map.
#[derive(Debug, Clone)]
pub struct Map {
    config: MapConfig,
    background: Layer,
    objects: BTreeMap<ObjectId, MapObject>,
    next_id: u32,
    last_timings: IntegrateTimings,
    /// Objects the caller said may have moved, with an optional motion guess.
    notified: BTreeMap<ObjectId, track::Notice>,
    last_tracking: Vec<TrackingReport>,
    /// The last residual-triggered tracking failure of each object that
    /// has triggered ever since, to skip repeating it from the same view.
    failed_views: BTreeMap<ObjectId, track::FailedView>,
    /// The last frame's pixels prepared for integration; kept so that each
    /// frame refills its buffers instead of allocating them afresh.
    frame_pixels: FramePixels,
    /// Copies merged into another object: copy → the object it became.
    merged_into: BTreeMap<ObjectId, ObjectId>,
    /// The labels of deleted objects that had any.
    retired: BTreeMap<ObjectId, ObjectLabels>,
}

fn check_len(what: &'static str, got: usize, k: &Intrinsics) -> Result<(), MapError> {
    if got != k.pixels() {
        return Err(MapError::FrameSize {
            what,
            got,
            expected: k.pixels(),
            width: k.width,
            height: k.height,
        });
    }
    Ok(())
}

impl Map {
    /// An empty map.
    pub fn new(config: MapConfig) -> Self {
        Self {
            config,
            background: Layer::new(config.settings.background_voxel_size_m),
            objects: BTreeMap::new(),
            next_id: 1,
            last_timings: IntegrateTimings::default(),
            notified: BTreeMap::new(),
            last_tracking: Vec::new(),
            failed_views: BTreeMap::new(),
            frame_pixels: FramePixels::default(),
            merged_into: BTreeMap::new(),
            retired: BTreeMap::new(),
        }
    }

    /// The settings.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }

    /// Objects by id.
    pub fn objects(&self) -> &BTreeMap<ObjectId, MapObject> {
        &self.objects
    }

    /// One object.
    pub fn object(&self, id: ObjectId) -> Option<&MapObject> {
        self.objects.get(&id)
    }

    /// Time split of the most recent [`Map::integrate`].
    pub fn last_timings(&self) -> IntegrateTimings {
        self.last_timings
    }

    /// What tracking did in the most recent [`Map::integrate`], by object id.
    pub fn last_tracking(&self) -> &[TrackingReport] {
        &self.last_tracking
    }

    /// The background (world-frame) volume.
    pub fn background(&self) -> &Layer {
        &self.background
    }

    /// Integrates one frame; returns the map object id of every pixel (0 = no object).
    pub fn integrate(&mut self, frame: &Frame<'_>) -> Result<Vec<u32>, MapError> {
        let k = frame.intrinsics;
        check_len("depth", frame.depth_m.len(), &k)?;
        check_len("instance mask", frame.instance.len(), &k)?;
        if let Some(class) = frame.class {
            check_len("class image", class.len(), &k)?;
        }
        let params = self.config.integration();
        let started = std::time::Instant::now();
        let geometric;
        let instance = match self.config.segmentation() {
            Segmentation::Provided => frame.instance,
            Segmentation::Geometric(p) => {
                geometric = segment_geometric(&k, frame.depth_m, &frame.t_world_camera, &p);
                &geometric[..]
            }
        };
        let segments = extract_segments(
            instance,
            frame.depth_m,
            |d| params.valid_depth(d),
            k.scaled_px(self.config.settings.min_segment_px),
        );
        let far_m = self.visible_depth_limits(frame);
        let rendered = self.render_objects(&frame.t_world_camera, &k, Some(&far_m));
        let rendered_at = std::time::Instant::now();
        let Association {
            mut matches,
            candidates,
        } = associate(
            &segments,
            &rendered,
            frame.depth_m,
            &self.config.association(),
        );

        let associated_at = std::time::Instant::now();
        let failed = self.track_objects(frame, &segments, &mut matches, &rendered);
        let tracked_at = std::time::Instant::now();
        let merged = self.merge_copies(&candidates, &matches, &failed);

        let new_object_min_px = k.scaled_px(self.config.settings.new_object_min_px);
        let mut owner = vec![0u32; k.pixels()];
        let mut matched: BTreeMap<ObjectId, usize> = BTreeMap::new();
        for (segment, matched_id) in segments.iter().zip(&matches) {
            let id = match matched_id {
                Some(id) => {
                    let id = self.current_id(ObjectId(*id));
                    self.reidentify_later(id, segment, frame).unwrap_or(id)
                }
                None if segment.pixels.len() >= new_object_min_px => {
                    match self.place_unmatched(segment, &rendered, frame.depth_m, &failed) {
                        Placement::New => match self.reidentify(segment, frame, None) {
                            Some(id) => id,
                            None => self.add_object(segment, frame),
                        },
                        Placement::Existing(id) => id,
                        Placement::Wait => continue,
                    }
                }
                None => continue,
            };
            *matched.entry(id).or_default() += segment.pixels.len();
            for &px in &segment.pixels {
                owner[px] = id.0;
            }
            if let (Some(class), Some(object)) = (frame.class, self.objects.get_mut(&id)) {
                // One histogram update per run of pixels of one class.
                let mut runs = segment.pixels.iter().map(|&px| class[px]).peekable();
                while let Some(c) = runs.next() {
                    let mut n = 1;
                    while runs.next_if_eq(&c).is_some() {
                        n += 1;
                    }
                    *object.class_histogram.entry(c).or_default() += n;
                }
            }
        }

        let new_objects_at = std::time::Instant::now();
        // Pixels per rendered object, counted a run of one id at a time.
        let mut visible: BTreeMap<u32, usize> = BTreeMap::new();
        for run in rendered.ids.chunk_by(|a, b| a == b) {
            let id = run[0];
            if id != 0 && !merged.contains(&ObjectId(id)) {
                *visible.entry(id).or_default() += run.len();
            }
        }
        self.frame_pixels.prepare(&k, frame.depth_m, &params);
        let pixels = &self.frame_pixels;
        let by_owner = pixels_by_label(&owner);
        let work: Vec<&mut MapObject> = self
            .objects
            .values_mut()
            .filter(|o| !failed.contains(&o.id))
            .filter(|o| matched.contains_key(&o.id) || visible.contains_key(&o.id.0))
            .collect();
        work.into_par_iter().for_each(|object| {
            let t_object_camera = object.t_world_object.inverse() * frame.t_world_camera;
            let id = object.id.0;
            let view = DepthView {
                t_layer_camera: &t_object_camera,
                k: &k,
                pixels,
            };
            integrate(
                &mut object.volume,
                &view,
                Owned {
                    labels: &owner,
                    id,
                    pixels: by_owner.get(&id).map_or(&[], Vec::as_slice),
                },
                &params,
                true,
            );
        });
        let objects_at = std::time::Instant::now();
        let background_pixels: Vec<u32> = (0..instance.len() as u32)
            .filter(|&i| instance[i as usize] == 0)
            .collect();
        let view = DepthView {
            t_layer_camera: &frame.t_world_camera,
            k: &k,
            pixels,
        };
        integrate(
            &mut self.background,
            &view,
            Owned {
                labels: instance,
                id: 0,
                pixels: &background_pixels,
            },
            &params,
            false,
        );

        let integrated_at = std::time::Instant::now();
        let glimpsed = self.glimpsed(&rendered, frame.depth_m, instance, &owner);
        self.book_keeping(&k, &matched, &visible, &glimpsed);
        self.last_timings = IntegrateTimings {
            render_s: (rendered_at - started).as_secs_f64(),
            associate_s: (associated_at - rendered_at).as_secs_f64()
                + (new_objects_at - tracked_at).as_secs_f64(),
            tracking_s: (tracked_at - associated_at).as_secs_f64(),
            integrate_s: (objects_at - new_objects_at).as_secs_f64(),
            background_s: (integrated_at - objects_at).as_secs_f64(),
            book_keeping_s: integrated_at.elapsed().as_secs_f64(),
        };
        Ok(owner)
    }

    /// Where an unmatched segment goes ([`Placement`]). Mostly seen
    /// through a surface the map renders in front of it (measured farther by
    /// more than the association tolerance), it waits: that surface is a
    /// ghost or an object that moved away, which carving clears over the
    /// next frames, while a new object made now would lie behind it, hidden
    /// from the next frame's association, and a new one would be made every
    /// frame until then. Mostly on surfaces of the map with the measured
    /// depth, spread over objects none of which it matches alone, it goes to
    /// the one holding most of it: the map already has it, in pieces, and a
    /// new object would be one more piece, every frame. Notified objects
    /// whose tracking failed (`failed`) hold nothing: their segments were
    /// taken from them on purpose.
    fn place_unmatched(
        &self,
        segment: &Segment,
        rendered: &RenderTarget,
        depth_m: &[f32],
        failed: &BTreeSet<ObjectId>,
    ) -> Placement {
        let tolerance = self.config.depth_tolerance_m();
        let (mut behind, mut on_map) = (0, 0);
        let mut holders: BTreeMap<u32, usize> = BTreeMap::new();
        for &px in &segment.pixels {
            let id = rendered.ids[px];
            if id == 0 || failed.contains(&ObjectId(id)) {
                continue;
            }
            let (d, r) = (depth_m[px], rendered.depth_m[px]);
            if d > r + tolerance {
                behind += 1;
            } else if (d - r).abs() <= tolerance {
                on_map += 1;
                *holders.entry(id).or_default() += 1;
            }
        }
        let n = segment.pixels.len();
        if 2 * behind > n {
            return Placement::Wait;
        }
        if 2 * on_map >= n {
            let holder = holders
                .into_iter()
                .max_by_key(|&(id, count)| (count, std::cmp::Reverse(id)))
                .map(|(id, _)| ObjectId(id));
            if let Some(id) = holder {
                return Placement::Existing(id);
            }
        }
        Placement::New
    }

    fn add_object(&mut self, segment: &Segment, frame: &Frame<'_>) -> ObjectId {
        let k = frame.intrinsics;
        let sum = segment.pixels.iter().fold(Vector3::zeros(), |acc, &px| {
            let p = k.back_project(
                (px % k.width) as f32,
                (px / k.width) as f32,
                frame.depth_m[px],
            );
            acc + (frame.t_world_camera * p).coords
        });
        let centroid = sum / segment.pixels.len() as f32;
        let id = ObjectId(self.next_id);
        self.next_id += 1;
        let object = MapObject {
            id,
            t_world_object: Pose::from_parts(
                Translation3::from(centroid),
                UnitQuaternion::identity(),
            ),
            volume: Layer::new(self.config.settings.voxel_size_m),
            class_histogram: BTreeMap::new(),
            observations: 0,
            misses: 0,
            labels: ObjectLabels::default(),
            whereabouts: Whereabouts::Placed,
            lost_before: id,
            reidentify_tried_px: segment.pixels.len(),
        };
        self.objects.insert(id, object);
        id
    }

    /// Per object, its rendered pixels where the frame sees some object's
    /// surface at the rendered depth but no map object took the pixel (its
    /// segment too small to count, or waiting): a glimpse of the object
    /// where it should be, not evidence that it is gone.
    fn glimpsed(
        &self,
        rendered: &RenderTarget,
        depth_m: &[f32],
        instance: &[u32],
        owner: &[u32],
    ) -> BTreeMap<u32, usize> {
        let tolerance = self.config.depth_tolerance_m();
        let mut glimpsed = BTreeMap::new();
        for (px, &id) in rendered.ids.iter().enumerate() {
            if id != 0
                && owner[px] == 0
                && instance[px] != 0
                && (depth_m[px] - rendered.depth_m[px]).abs() <= tolerance
            {
                *glimpsed.entry(id).or_default() += 1;
            }
        }
        glimpsed
    }

    /// Counts observations and misses, and deletes objects missed too
    /// often. An object predicted visible but matched to no segment is
    /// missed, unless it was glimpsed on at least [`MIN_GLIMPSED_PX`]
    /// pixels ([`Map::glimpsed`]): seen as a sliver too thin to segment
    /// while its model (with parts not yet carved) renders wider, it was
    /// deleted after a few still frames and made anew when seen properly.
    fn book_keeping(
        &mut self,
        k: &Intrinsics,
        matched: &BTreeMap<ObjectId, usize>,
        visible: &BTreeMap<u32, usize>,
        glimpsed: &BTreeMap<u32, usize>,
    ) {
        let max_misses = self.config.settings.max_misses;
        let min_px = k.scaled_px(self.config.settings.miss_min_rendered_px);
        for object in self.objects.values_mut() {
            let id = object.id.0;
            if matched.contains_key(&object.id) {
                object.observations += 1;
                object.misses = 0;
            } else if visible.get(&id).is_some_and(|&n| n >= min_px)
                && glimpsed.get(&id).is_none_or(|&n| n < MIN_GLIMPSED_PX)
            {
                object.misses += 1;
            }
        }
        let deleted: Vec<ObjectId> = self
            .objects
            .values()
            .filter(|o| o.misses > max_misses)
            .map(|o| o.id)
            .collect();
        for id in deleted {
            if let Some(object) = self.objects.remove(&id) {
                self.retire(id, object.labels);
            }
        }
    }
}
