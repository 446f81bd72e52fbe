//! The rules an episode's targets, labels and map are made by. They are part
//! of the run's task ([`crate::TaskSpec`]: `[task.selection]`,
//! `[task.confidence]`, `[task.sphere]`, `[task.map]`), so every actor of a
//! run uses the same ones, a resumed run keeps them, and `learner
//! print-config` shows each with its default. Values of the map that follow
//! from these (the free-space margin, the depth tolerance of association,
//! tracking's gates) are derived from them by the map (`mapper::MapConfig`,
//! which holds these settings as they are).

use serde::{Deserialize, Serialize};

/// A rule's setting outside what it can mean.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("task.{setting} = {value} {allowed}")]
pub struct RuleError {
    /// The setting, `table.key` under `[task]`.
    pub setting: &'static str,
    /// Its value.
    pub value: f32,
    /// What it must be.
    pub allowed: &'static str,
}

/// `Err` naming `setting` unless `ok`.
fn check(
    ok: bool,
    setting: &'static str,
    value: f32,
    allowed: &'static str,
) -> Result<(), RuleError> {
    if ok {
        Ok(())
    } else {
        Err(RuleError {
            setting,
            value,
            allowed,
        })
    }
}

/// Whether `x` is a probability (0 to 1).
fn unit(x: f32) -> bool {
    (0.0..=1.0).contains(&x)
}

/// Whether `x` is a finite length above zero.
fn positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

/// Object selection's grid (`ours`, `nomap-*`) and most-centred object
/// (`intexp`). The confidence filter is the task's `selection_confidence`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct SelectionRule {
    /// Fraction of the image's width and height that the grid covers, centred.
    pub centre_fraction: f32,
    /// Objects with fewer pixels are ignored; pixels of a 128 × 128 image,
    /// scaled to the frame's area.
    pub min_pixels: usize,
    /// Whether selection sees only the pixels within the robot's reach
    /// (measured from the agent's depth and pose, as the simulator judges
    /// reach): a cell whose objects all lie beyond reach is masked and the
    /// robot aims at an object's part within reach. `false` is the paper's
    /// grid, which offers every object in view (docs/decisions/0012-selection-within-reach.md).
    pub within_reach: bool,
    /// Which of a cell's objects it offers (before the U-Net runs, the
    /// largest, or under `smallest` the smallest).
    pub prefer: CellPreference,
    /// Whether the policy's state holds, per affordance and grid cell, the
    /// U-Net's mean probability over the object the cell offers (0 for an
    /// empty cell): the network's rating, per action, of the objects the
    /// camera input shows as a probability image, so that the policy need
    /// not learn which image region each cell covers before it can choose
    /// likely objects. Needs the grid (`ours`, `nomap-*`). `false` is the
    /// paper's state.
    pub ratings_in_state: bool,
}

/// Which object a grid cell offers among those assigned to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CellPreference {
    /// The paper's rule: the largest object whose mean probability is at
    /// least the task's `selection_confidence`; failing any, the most
    /// probable one.
    #[default]
    Largest,
    /// The object with the highest mean probability of the affordance, so
    /// that an attempt goes to what the network rates likeliest to afford
    /// it rather than to the largest object (a sofa, a table) in the cell.
    MostProbable,
    /// Every cell that holds an object offers the one object in view (and
    /// within reach, with `within_reach`) that the network rates likeliest
    /// to afford the action: the policy decides when to try, the network's
    /// ranking what (the paper's "filter out objects with a low confidence
    /// score" taken to its end; docs/ladder.md). Without a network yet, the
    /// paper's `largest`.
    MostProbableInView,
    /// The smallest object whose mean probability is at least the task's
    /// `selection_confidence` (failing any, the most probable one), also
    /// before the U-Net runs: the paper's rule with its order of sizes
    /// turned round, so that the key chain on a sofa is offered rather
    /// than the sofa. Under `largest` the policy's pick-up attempts go
    /// mostly to furniture and the objects small enough to pick up are
    /// rarely tried (`learner summary`'s tries by type; docs/ladder.md).
    Smallest,
}

impl SelectionRule {
    /// Checks that the rule can select anything.
    pub fn validate(&self) -> Result<(), RuleError> {
        let f = self.centre_fraction;
        check(
            f > 0.0 && f <= 1.0,
            "selection.centre_fraction",
            f,
            "must be above 0 and at most 1",
        )
    }
}

impl Default for SelectionRule {
    fn default() -> Self {
        Self {
            centre_fraction: 0.75,
            min_pixels: 10,
            within_reach: true,
            prefer: CellPreference::Largest,
            ratings_in_state: false,
        }
    }
}

/// Thresholds of annotation by confidence (`ours`, once the run has taken
/// the task's `confidence_after_steps`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct ConfidenceRule {
    /// ξ_T: an object is positive when its largest per-frame P95 exceeds this.
    pub positive_above: f32,
    /// ξ_F: an object is negative when its smallest per-frame P5 is below this.
    pub negative_below: f32,
    /// Fewest pixels of an object in a frame for that frame to count; pixels
    /// of a 128 × 128 image, scaled to the frame's area.
    pub min_pixels: usize,
}

impl ConfidenceRule {
    /// Checks that both thresholds are probabilities, the negative one below the positive.
    pub fn validate(&self) -> Result<(), RuleError> {
        check(
            unit(self.positive_above),
            "confidence.positive_above",
            self.positive_above,
            "must be a probability, between 0 and 1",
        )?;
        check(
            unit(self.negative_below) && self.negative_below < self.positive_above,
            "confidence.negative_below",
            self.negative_below,
            "must be a probability below confidence.positive_above",
        )
    }
}

impl Default for ConfidenceRule {
    fn default() -> Self {
        Self {
            positive_above: 0.9,
            negative_below: 0.1,
            min_pixels: 10,
        }
    }
}

/// The point labels of the methods without a map (`nomap-*`, `intexp`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct SphereRule {
    /// Pixels whose 3-D point lies within this distance of an interaction
    /// point are labelled, metres (the paper's 0.2).
    pub radius_m: f32,
    /// A point counts as in view if the frame's depth at its pixel is not
    /// nearer than the point by more than this, metres.
    pub occlusion_tolerance_m: f32,
}

impl SphereRule {
    /// Checks that the sphere has a size.
    pub fn validate(&self) -> Result<(), RuleError> {
        check(
            positive(self.radius_m),
            "sphere.radius_m",
            self.radius_m,
            "must be a length above 0",
        )?;
        let t = self.occlusion_tolerance_m;
        check(
            t.is_finite() && t >= 0.0,
            "sphere.occlusion_tolerance_m",
            t,
            "must be a length of at least 0",
        )
    }
}

impl Default for SphereRule {
    fn default() -> Self {
        Self {
            radius_m: 0.2,
            occlusion_tolerance_m: 0.1,
        }
    }
}

/// Where the map's instance masks come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MapSegmentation {
    /// The simulator's instance masks (the paper's setting).
    GroundTruth,
    /// A geometric segmentation of the depth image; the simulator's masks are ignored.
    Geometric,
}

/// The object-level map's settings (`ours`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct MapSettings {
    /// Voxel edge of object volumes, metres; the free-space margin, the
    /// depth tolerance of association and tracking's gates follow from it.
    pub voxel_size_m: f32,
    /// Voxel edge of the background volume (floor, walls), metres: coarser
    /// than objects, as the background only occludes and feeds the 2-D maps.
    pub background_voxel_size_m: f32,
    /// TSDF truncation distance, metres.
    pub truncation_m: f32,
    /// Largest weight a voxel accumulates (how slowly old views fade).
    pub max_weight: f32,
    /// Depths nearer than this are ignored, metres.
    pub min_depth_m: f32,
    /// Depths farther than this are ignored, metres.
    pub max_depth_m: f32,
    /// Segments with fewer pixels are not associated (of a 128 × 128
    /// frame, scaled to the frame's area).
    pub min_segment_px: usize,
    /// Fewest pixels of an unmatched segment to start a new object (of a
    /// 128 × 128 frame, scaled).
    pub new_object_min_px: usize,
    /// Smallest IoU of a segment with an object's rendering for a match.
    pub min_iou: f32,
    /// Smallest share of a segment an object's rendering must cover for a match.
    pub min_coverage: f32,
    /// Share of a segment inside one object's rendering above which it
    /// joins that object instead of starting a new one.
    pub min_containment: f32,
    /// An object expected in view but not matched this many frames in a row is deleted.
    pub max_misses: u32,
    /// Rendered pixels that make an object expected in view (of a 128 × 128
    /// frame, scaled).
    pub miss_min_rendered_px: usize,
    /// Where instance masks come from: `ground-truth` or `geometric`.
    pub segmentation: MapSegmentation,
}

impl MapSettings {
    /// Checks that the map can be built and integrate frames.
    pub fn validate(&self) -> Result<(), RuleError> {
        let lengths = [
            ("map.voxel_size_m", self.voxel_size_m),
            ("map.background_voxel_size_m", self.background_voxel_size_m),
            ("map.truncation_m", self.truncation_m),
            ("map.max_weight", self.max_weight),
            ("map.max_depth_m", self.max_depth_m),
        ];
        for (setting, value) in lengths {
            check(positive(value), setting, value, "must be above 0")?;
        }
        check(
            self.min_depth_m.is_finite()
                && self.min_depth_m >= 0.0
                && self.min_depth_m < self.max_depth_m,
            "map.min_depth_m",
            self.min_depth_m,
            "must be at least 0 and below map.max_depth_m",
        )?;
        let shares = [
            ("map.min_iou", self.min_iou),
            ("map.min_coverage", self.min_coverage),
            ("map.min_containment", self.min_containment),
        ];
        for (setting, value) in shares {
            check(unit(value), setting, value, "must be between 0 and 1")?;
        }
        Ok(())
    }
}

impl Default for MapSettings {
    fn default() -> Self {
        Self {
            voxel_size_m: 0.04,
            background_voxel_size_m: 0.08,
            truncation_m: 0.12,
            max_weight: 50.0,
            min_depth_m: 0.1,
            max_depth_m: 8.0,
            min_segment_px: 20,
            new_object_min_px: 50,
            min_iou: 0.3,
            min_coverage: 0.5,
            min_containment: 0.8,
            max_misses: 10,
            miss_min_rendered_px: 50,
            segmentation: MapSegmentation::GroundTruth,
        }
    }
}

/// Every rule of a task, checked.
pub(crate) fn validate_all(
    selection: &SelectionRule,
    confidence: &ConfidenceRule,
    sphere: &SphereRule,
    map: &MapSettings,
) -> Result<(), RuleError> {
    selection.validate()?;
    confidence.validate()?;
    sphere.validate()?;
    map.validate()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_a_bad_value_is_named() {
        validate_all(
            &SelectionRule::default(),
            &ConfidenceRule::default(),
            &SphereRule::default(),
            &MapSettings::default(),
        )
        .unwrap();
        let crossed = ConfidenceRule {
            negative_below: 0.95,
            ..ConfidenceRule::default()
        };
        let error = crossed.validate().unwrap_err();
        assert_eq!(error.setting, "confidence.negative_below");
        assert!(error
            .to_string()
            .contains("task.confidence.negative_below = 0.95"));
        let no_voxel = MapSettings {
            voxel_size_m: 0.0,
            ..MapSettings::default()
        };
        assert_eq!(no_voxel.validate().unwrap_err().setting, "map.voxel_size_m");
        let depth = MapSettings {
            min_depth_m: 9.0,
            ..MapSettings::default()
        };
        assert_eq!(depth.validate().unwrap_err().setting, "map.min_depth_m");
        let sphere = SphereRule {
            radius_m: f32::NAN,
            ..SphereRule::default()
        };
        assert_eq!(sphere.validate().unwrap_err().setting, "sphere.radius_m");
        let grid = SelectionRule {
            centre_fraction: 1.5,
            ..SelectionRule::default()
        };
        assert_eq!(
            grid.validate().unwrap_err().setting,
            "selection.centre_fraction"
        );
    }
}
