//! The policy's state. For method `ours`, as the paper lists it, three
//! image-like inputs (one conv encoder each) and two vectors:
//!
//! - **camera** `[3 + 1 + 3A, S, S]`: RGB in 0..1; the distance image (each
//!   pixel's horizontal distance from the agent's vertical axis over twice
//!   the reach, clamped to 1: below 0.5 is within reach); the U-Net's
//!   probability per affordance; per affordance the interacted-objects mask
//!   in the image (successful, unsuccessful).
//! - **global map** and **local map** `[2 + 3A, M, M]`: egocentric grids
//!   (agent at the centre, heading up) of 10 m and 2 m: visited positions,
//!   occupancy, and per affordance objects interacted with successfully,
//!   unsuccessfully, and not yet.
//! - **history** `[5 · (n_actions + 2)]`: the last five actions one-hot
//!   with their success (0/1) and reward (mapped from [-1, 2] onto [0, 1]),
//!   newest first, zeros before the episode's start. Every input lies in
//!   0..1, so the state travels to the learner as bytes.
//! - **inventory** `[1]`: 1 while holding an object.
//! - **cell ratings** `[9 · A]`, only with `[task.selection]
//!   ratings_in_state`: per affordance and grid cell the U-Net's mean
//!   probability over the object the cell offers, 0 for an empty cell.
//!
//! The methods without a map keep only what needs no map: `nomap-seg` and
//! `nomap-noseg` the camera's RGB, distance and probabilities, the history
//! and the inventory; `intexp` the RGB and probabilities and the inventory.
//! Their map inputs (and `intexp`'s history) are empty.

use std::collections::VecDeque;

use mapper::projection::{mark_visited, SurfacePoints};
use mapper::{Affordance, GridSpec, Map, ObjectId, ProjectionKind};
use nalgebra::Point2;
use proto::{Method, HISTORY_STEPS};

/// Sizes and extents of the state.
#[derive(Debug, Clone, PartialEq)]
pub struct StateConfig {
    /// What the state holds.
    pub method: Method,
    /// The configured affordances, in plane order.
    pub affordances: Vec<Affordance>,
    /// Number of actions (for the history's one-hot).
    pub n_actions: usize,
    /// Side of the camera images, pixels.
    pub image_size: usize,
    /// Cells per side of the map grids.
    pub map_cells: usize,
    /// Edge of the global map, metres.
    pub global_extent_m: f32,
    /// Edge of the local map, metres.
    pub local_extent_m: f32,
    /// Heights above the floor that count as occupied, metres.
    pub occupancy_heights_m: (f32, f32),
    /// Length of the cell-ratings input (0: the paper's state, without it).
    pub ratings_len: usize,
}

impl StateConfig {
    /// The paper's state of `method` for `affordances` and an action space of `n_actions`.
    pub fn paper(method: Method, affordances: &[Affordance], n_actions: usize) -> Self {
        Self {
            method,
            affordances: affordances.to_vec(),
            n_actions,
            image_size: 128,
            map_cells: 128,
            global_extent_m: 10.0,
            local_extent_m: 2.0,
            occupancy_heights_m: (0.05, 1.8),
            ratings_len: 0,
        }
    }

    /// Channels of the camera input ([`proto::MethodSpec::camera_channels`]).
    pub fn camera_channels(&self) -> usize {
        self.method.spec().camera_channels(self.affordances.len())
    }

    /// Channels of each map input (0 without a map).
    pub fn map_channels(&self) -> usize {
        self.method.spec().map_channels(self.affordances.len())
    }

    /// Names of the map planes in their order ([`build_state`]'s): where
    /// the agent has been, occupancy, then per affordance the objects
    /// tried with success, tried with failure, and not tried. Empty
    /// without a map.
    pub fn map_plane_names(&self) -> Vec<String> {
        if self.map_channels() == 0 {
            return Vec::new();
        }
        let mut names = vec!["visited".to_owned(), "occupancy".to_owned()];
        for a in &self.affordances {
            for kind in ["success", "failure", "not_tried"] {
                names.push(format!("{}_{kind}", a.as_str()));
            }
        }
        names
    }

    /// Length of the history vector (0 for `intexp`).
    pub fn history_len(&self) -> usize {
        self.method.spec().history_len(self.n_actions)
    }

    /// Image-like inputs' channels and vector inputs' lengths, in the
    /// policy's input order (empty inputs left out).
    pub(crate) fn input_shapes(&self) -> (Vec<usize>, Vec<usize>) {
        let images = [
            self.camera_channels(),
            self.map_channels(),
            self.map_channels(),
        ];
        let vectors = [self.history_len(), 1, self.ratings_len];
        (
            images.into_iter().filter(|&c| c > 0).collect(),
            vectors.into_iter().filter(|&d| d > 0).collect(),
        )
    }
}

/// The last actions of the episode, newest first.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ActionHistory {
    entries: VecDeque<(usize, bool, f32)>,
}

impl ActionHistory {
    /// Remembers an action, its success and its reward, keeping the newest `keep`.
    pub fn push(&mut self, action: usize, success: bool, reward: f32, keep: usize) {
        self.entries.push_front((action, success, reward));
        self.entries.truncate(keep);
    }
}

/// What one step's state is built from.
#[derive(Debug, Clone, Copy)]
pub struct StateInputs<'a> {
    /// Row-major RGB of the frame.
    pub rgb: &'a [u8],
    /// Each pixel's horizontal distance from the agent's axis, metres
    /// ([`crate::env::reach::horizontal_distances`]; infinite without a depth).
    pub horizontal_m: &'a [f32],
    /// Object id per pixel for this frame (map ids for `ours`).
    pub map_ids: &'a [u32],
    /// The agent on the floor: x, y (metres) and heading (radians from +x).
    pub agent: (f32, f32, f32),
    /// The floor's height, metres.
    pub floor_z: f32,
    /// The robot's reach, metres.
    pub reach_m: f32,
    /// Positions visited this episode.
    pub visited: &'a [Point2<f32>],
    /// The U-Net's calibrated probability planes, one per affordance.
    pub probabilities: &'a [Vec<f32>],
    /// The map (method `ours`; `None` for the methods without one).
    pub map: Option<&'a Map>,
    /// Recent actions.
    pub history: &'a ActionHistory,
    /// Whether the hand holds an object.
    pub holding: bool,
    /// Per affordance and grid cell the offered object's rating
    /// ([`crate::env::actions::CellTargets::ratings`]); empty when the state
    /// has no cell-ratings input.
    pub ratings: &'a [f32],
}

/// One state as the policy reads it and the wire carries it: every input in
/// the policy's order (camera, global map, local map, history, inventory,
/// cell ratings; a method's missing inputs empty), each value a byte
/// ([`proto::unit_to_byte`] of a value in 0..1, so 1 is 255). Built in bytes
/// from the start: a state of `f32` planes flattened into bytes afterwards
/// wrote, zeroed and read four times the memory a step (docs/performance.md).
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    values: Vec<u8>,
    /// Where each input ends in `values`, in the order above.
    ends: [usize; 6],
}

impl State {
    /// `[camera_channels, S, S]`.
    pub fn camera(&self) -> &[u8] {
        self.input(0)
    }

    /// `[map_channels, M, M]`, 10 m.
    pub fn global_map(&self) -> &[u8] {
        self.input(1)
    }

    /// `[map_channels, M, M]`, 2 m.
    pub fn local_map(&self) -> &[u8] {
        self.input(2)
    }

    /// `[history_len]`.
    pub fn history(&self) -> &[u8] {
        self.input(3)
    }

    /// `[1]`.
    pub fn inventory(&self) -> &[u8] {
        self.input(4)
    }

    /// `[ratings_len]`.
    pub fn ratings(&self) -> &[u8] {
        self.input(5)
    }

    /// Every input, one after another (the policy's flat observation).
    pub fn into_values(self) -> Vec<u8> {
        self.values
    }

    fn input(&self, index: usize) -> &[u8] {
        let start = index.checked_sub(1).map_or(0, |i| self.ends[i]);
        &self.values[start..self.ends[index]]
    }
}

/// A byte that means "yes" in a 0 / 1 input ([`proto::unit_to_byte`]`(1.0)`).
const YES: u8 = u8::MAX;

/// Builds the state of `config.method`: inputs the method does not have
/// (and every map input when `input.map` is `None`) stay empty.
pub fn build_state(config: &StateConfig, input: &StateInputs<'_>) -> State {
    let map = input.map.filter(|_| config.map_channels() > 0);
    let map_len = map.map_or(0, |_| {
        config.map_channels() * config.map_cells * config.map_cells
    });
    let lens = [
        config.camera_channels() * input.horizontal_m.len(),
        map_len,
        map_len,
        config.history_len(),
        1,
        input.ratings.len(),
    ];
    let mut ends = lens;
    for i in 1..ends.len() {
        ends[i] += ends[i - 1];
    }
    let mut values = vec![0; ends[5]];
    let (camera, rest) = values.split_at_mut(lens[0]);
    let (global_map, rest) = rest.split_at_mut(lens[1]);
    let (local_map, rest) = rest.split_at_mut(lens[2]);
    let (history, rest) = rest.split_at_mut(lens[3]);
    let (inventory, ratings) = rest.split_at_mut(lens[4]);
    camera_planes(config, input, map, camera);
    if let Some(map) = map {
        map_planes(
            config,
            input,
            &map.surface_points(),
            [config.global_extent_m, config.local_extent_m],
            [global_map, local_map],
        );
    }
    history_vector(config, input.history, history);
    inventory[0] = if input.holding { YES } else { 0 };
    for (byte, &rating) in ratings.iter_mut().zip(input.ratings) {
        *byte = proto::unit_to_byte(rating);
    }
    State { values, ends }
}

fn camera_planes(config: &StateConfig, input: &StateInputs<'_>, map: Option<&Map>, out: &mut [u8]) {
    let n = input.horizontal_m.len();
    // The planes in the order of the doc comment above, each written in place.
    let mut planes = out.chunks_exact_mut(n.max(1));
    let mut next_plane = || planes.next().expect("camera_channels counts every plane");
    for channel in 0..3 {
        // A colour byte is its own value: `unit_to_byte(c / 255) == c`
        // (test `colour_bytes_are_their_own_values`).
        let pixels = input.rgb.chunks_exact(3);
        for (d, pixel) in next_plane().iter_mut().zip(pixels) {
            *d = pixel[channel];
        }
    }
    if config.method.spec().distance {
        let scale = 1.0 / (2.0 * input.reach_m);
        for (d, &h) in next_plane().iter_mut().zip(input.horizontal_m) {
            *d = proto::unit_to_byte((h * scale).min(1.0));
        }
    }
    for plane in input.probabilities.iter().take(config.affordances.len()) {
        for (d, &p) in next_plane().iter_mut().zip(plane) {
            *d = proto::unit_to_byte(p);
        }
    }
    let Some(map) = map else {
        return;
    };
    for &affordance in &config.affordances {
        // The label of each pixel's object (none for id 0), looked up once
        // per run of equal ids along the rows: a lookup per pixel and plane
        // was a visible share of a 128-px step (docs/performance.md, "One actor").
        let label_of = |id: u32| {
            if id == 0 {
                return None; // no object
            }
            // A frame's id may be of an object merged into another
            // since (`Map::current_id`), in this very frame even.
            map.object(map.current_id(ObjectId(id)))
                .filter(|o| o.labels.interacted(affordance))
                .and_then(|o| o.labels.label(affordance))
        };
        let (success, failure) = (next_plane(), next_plane());
        let mut last: Option<(u32, Option<bool>)> = None;
        for (p, &id) in input.map_ids.iter().enumerate().take(n) {
            let label = match last {
                Some((seen, label)) if seen == id => label,
                _ => {
                    let label = label_of(id);
                    last = Some((id, label));
                    label
                }
            };
            success[p] = if label == Some(true) { YES } else { 0 };
            failure[p] = if label == Some(false) { YES } else { 0 };
        }
    }
}

/// The egocentric map planes at the global and the local extent, every
/// projection of both rasterised in one pass over the map's surface points.
fn map_planes(
    config: &StateConfig,
    input: &StateInputs<'_>,
    surface: &SurfacePoints<'_>,
    [global_m, local_m]: [f32; 2],
    maps: [&mut [u8]; 2],
) {
    let (x, y, heading) = input.agent;
    let grid = |extent_m| GridSpec {
        center: Point2::new(x, y),
        up_heading_rad: heading,
        extent_m,
        cells: config.map_cells,
    };
    let (lo, hi) = config.occupancy_heights_m;
    // In the order of `StateConfig::map_plane_names`.
    let mut kinds = vec![ProjectionKind::Occupancy {
        min_height_m: input.floor_z + lo,
        max_height_m: input.floor_z + hi,
    }];
    for &a in &config.affordances {
        kinds.extend([
            ProjectionKind::InteractedSuccess(a),
            ProjectionKind::InteractedFailure(a),
            ProjectionKind::NotInteracted(a),
        ]);
    }
    let grids = [grid(global_m), grid(local_m)];
    let requests: Vec<_> = grids
        .iter()
        .flat_map(|g| kinds.iter().map(|&k| (k, *g)))
        .collect();
    // Each map: the visited plane, then its projections, written in place.
    let side = config.map_cells * config.map_cells;
    let mut projections: Vec<&mut [u8]> = Vec::with_capacity(requests.len());
    for (map, grid) in maps.into_iter().zip(&grids) {
        let (visited_plane, rest) = map.split_at_mut(side);
        mark_visited(input.visited, grid, visited_plane, YES);
        projections.extend(rest.chunks_exact_mut(side));
    }
    surface.project_all_into(&requests, &mut projections, YES);
}

/// A reward as the history holds it: `[-1, 2]` mapped onto `[0, 1]` (clamped),
/// so that every input of the state lies in 0..1 and travels as a byte.
pub(crate) fn encode_reward(reward: f32) -> f32 {
    ((reward + 1.0) / 3.0).clamp(0.0, 1.0)
}

fn history_vector(config: &StateConfig, history: &ActionHistory, out: &mut [u8]) {
    let width = config.n_actions + 2;
    for (slot, &(action, success, reward)) in history.entries.iter().take(HISTORY_STEPS).enumerate()
    {
        let Some(row) = out.get_mut(slot * width..(slot + 1) * width) else {
            return; // no history (`intexp`)
        };
        if action < config.n_actions {
            row[action] = YES;
        }
        row[config.n_actions] = if success { YES } else { 0 };
        row[config.n_actions + 1] = proto::unit_to_byte(encode_reward(reward));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_bytes_are_their_own_values() {
        for c in 0..=u8::MAX {
            assert_eq!(proto::unit_to_byte(f32::from(c) / 255.0), c);
        }
        assert_eq!(proto::unit_to_byte(1.0), YES);
    }
}
