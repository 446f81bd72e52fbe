//! The paper's action space, derived from the configured affordances: five
//! navigation actions; per affordance a 3 × 3 grid over the image's centre
//! region where each cell selects its largest object; and, when picking up
//! is configured, drop and six moves of the held object. With pick up
//! alone that is 5 + 9 + 1 + 6 = 21 actions, the paper's head.
//!
//! Each visible map object goes to the grid cell whose centre is nearest
//! its pixel centroid; a cell with no object is masked (the paper's mask).
//! The current U-Net filters the cell's candidates: the cell selects its
//! largest object among those the network is confident about, and when it
//! is confident about none of them, the object it rates highest. The
//! filter never masks a cell: a network that has learnt from few positives
//! rates every object of a rare affordance low, and masking on that would
//! stop the very attempts that could teach it otherwise (measured: a
//! trained policy whose pick-up cells were all masked never tried a
//! pick-up again).
//!
//! IntExp instead has one selection action per affordance: the object most
//! centred in the image ([`centred_target`]).
//!
//! With the task's `selection.within_reach` (the default) every method
//! selects from the pixels within the robot's reach alone
//! ([`super::reach::beyond_reach_hidden`]): a cell whose objects all lie beyond reach is
//! masked, and the robot aims at the part of an object it can reach. The
//! paper's grid offers every object in view, and half of a run's pick-up
//! attempts then failed out of reach and taught nothing (docs/decisions/0012-selection-within-reach.md).

use mapper::Affordance;
use proto::{CellPreference, SelectionRule};
use sim::agent::{Action, HandMove, NavAction};

/// Cells per side of the selection grid.
pub(crate) const GRID: usize = 3;
/// The navigation actions, in index order.
pub(crate) const NAV: [NavAction; 5] = [
    NavAction::MoveAhead,
    NavAction::RotateRight,
    NavAction::RotateLeft,
    NavAction::LookUp,
    NavAction::LookDown,
];

/// One action of the policy's head.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PolicyAction {
    /// Navigate.
    Nav(NavAction),
    /// Try `affordance` on the object of grid cell `cell` (row-major).
    Select {
        /// What to try.
        affordance: Affordance,
        /// Grid cell, 0..9.
        cell: usize,
    },
    /// Drop the held object.
    Drop,
    /// Move the held object.
    MoveHeld(HandMove),
}

pub use proto::Selection;

// The grid's geometry here and its action count in the task agree.
const _: () = assert!(GRID * GRID == proto::GRID_CELLS);

/// The action space for a set of affordances.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionSpace {
    actions: Vec<PolicyAction>,
}

impl ActionSpace {
    /// The actions for `affordances` (each listed once, in the given order),
    /// with `selection`'s slots per affordance.
    pub fn new(affordances: &[Affordance], selection: Selection) -> Self {
        let mut actions: Vec<PolicyAction> = NAV.iter().map(|&a| PolicyAction::Nav(a)).collect();
        for &affordance in affordances {
            actions.extend(
                (0..selection.slots()).map(|cell| PolicyAction::Select { affordance, cell }),
            );
        }
        if affordances.contains(&Affordance::PickUp) {
            actions.push(PolicyAction::Drop);
            actions.extend(HandMove::ALL.iter().map(|&m| PolicyAction::MoveHeld(m)));
        }
        Self { actions }
    }

    /// Number of actions (the policy head's width).
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    /// True if there are no actions (never: navigation is always there).
    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }

    /// The action at `index`, if any.
    pub fn get(&self, index: usize) -> Option<PolicyAction> {
        self.actions.get(index).copied()
    }

    /// All actions in index order.
    pub fn actions(&self) -> &[PolicyAction] {
        &self.actions
    }

    /// The mask (1 = allowed): drop and moves need a held object, pick up
    /// needs an empty hand, a selection needs a target in its cell.
    pub fn mask(&self, holding: bool, targets: &CellTargets) -> Vec<u8> {
        self.actions
            .iter()
            .map(|a| {
                let allowed = match *a {
                    PolicyAction::Nav(_) => true,
                    PolicyAction::Select { affordance, cell } => {
                        !(holding && affordance == Affordance::PickUp)
                            && targets.target(affordance, cell).is_some()
                    }
                    PolicyAction::Drop | PolicyAction::MoveHeld(_) => holding,
                };
                u8::from(allowed)
            })
            .collect()
    }

    /// The simulator action for a policy action; `None` for a selection
    /// whose cell has no target.
    pub(crate) fn to_sim(&self, action: PolicyAction, targets: &CellTargets) -> Option<Action> {
        Some(match action {
            PolicyAction::Nav(a) => Action::Nav(a),
            PolicyAction::Select { affordance, cell } => {
                let t = targets.target(affordance, cell)?;
                match affordance {
                    Affordance::PickUp => Action::PickUp { u: t.u, v: t.v },
                    Affordance::Push => Action::Push { u: t.u, v: t.v },
                }
            }
            PolicyAction::Drop => Action::Drop,
            PolicyAction::MoveHeld(m) => Action::MoveHeld(m),
        })
    }
}

/// A random allowed action, an interaction (anything but navigation) with
/// probability `interaction_share` whenever one is allowed: the scripted
/// explorer of tests and benchmarks.
pub fn random_allowed_action(
    space: &ActionSpace,
    mask: &[u8],
    interaction_share: f64,
    rng: &mut impl rand::Rng,
) -> usize {
    let allowed: Vec<usize> = (0..mask.len()).filter(|&i| mask[i] == 1).collect();
    let interactions: Vec<usize> = allowed
        .iter()
        .copied()
        .filter(|&i| !matches!(space.get(i), Some(PolicyAction::Nav(_))))
        .collect();
    if !interactions.is_empty() && rng.random_bool(interaction_share) {
        interactions[rng.random_range(0..interactions.len())]
    } else {
        allowed[rng.random_range(0..allowed.len())]
    }
}

/// The object a grid cell selects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Map object id.
    pub object: u32,
    /// The object's pixel nearest its centroid (where the robot aims).
    pub u: usize,
    /// Row of that pixel.
    pub v: usize,
    /// The object's pixel count in the frame.
    pub pixels: usize,
    /// The U-Net's mean probability of the cell's affordance over the
    /// object's pixels (0 without a network).
    pub rating: f32,
}

/// Per affordance and grid cell, the selected object.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CellTargets {
    cells: Vec<(Affordance, [Option<Target>; GRID * GRID])>,
}

impl CellTargets {
    /// The target of `cell` for `affordance`.
    pub fn target(&self, affordance: Affordance, cell: usize) -> Option<Target> {
        self.cells
            .iter()
            .find(|(a, _)| *a == affordance)
            .and_then(|(_, t)| t.get(cell).copied().flatten())
    }

    /// Per affordance of `affordances` (in that order) and cell, the
    /// offered object's rating, 0 for an empty cell: the policy's
    /// cell-ratings input.
    pub fn ratings(&self, affordances: &[Affordance]) -> Vec<f32> {
        affordances
            .iter()
            .flat_map(|&a| (0..GRID * GRID).map(move |cell| (a, cell)))
            .map(|(a, cell)| self.target(a, cell).map_or(0.0, |t| t.rating))
            .collect()
    }
}

/// Pixel statistics of one object in a frame.
#[derive(Debug, Clone, Default)]
struct Blob {
    pixels: usize,
    sum_u: f64,
    sum_v: f64,
    /// Per affordance, the sum of the predicted probability over its pixels.
    sum_probability: Vec<f64>,
}

impl Blob {
    fn centroid(&self) -> (f32, f32) {
        (
            (self.sum_u / self.pixels as f64) as f32,
            (self.sum_v / self.pixels as f64) as f32,
        )
    }
}

/// How strongly a cell prefers one of its objects: any object ranked by its
/// size (without a network, or confident under a rule by size) over any
/// ranked by its mean probability.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd)]
enum Preference {
    /// Its mean probability of the affordance.
    Probability(f32),
    /// Its pixel count under `largest`, the count negated under `smallest`
    /// (the higher preferred).
    Size(i64),
}

impl Preference {
    /// An object of `pixels` ranked by its size under `prefer`.
    fn by_size(prefer: CellPreference, pixels: usize) -> Self {
        let pixels = pixels as i64;
        match prefer {
            CellPreference::Smallest => Preference::Size(-pixels),
            _ => Preference::Size(pixels),
        }
    }
}

/// The grid targets for a frame: `map_ids` is the frame's map-id image
/// (`width` wide); `probabilities[k]`, when given, is the U-Net's plane for
/// `affordances[k]`, used to prefer objects it is confident about: an
/// object whose mean probability is below `min_confidence` (the task's
/// `selection_confidence`) loses its cell to any object above it.
pub(crate) fn cell_targets(
    map_ids: &[u32],
    width: usize,
    affordances: &[Affordance],
    probabilities: Option<&[Vec<f32>]>,
    min_confidence: f32,
    rule: &SelectionRule,
) -> CellTargets {
    let height = map_ids.len() / width.max(1);
    let min_pixels = mapper::scaled_px(rule.min_pixels, map_ids.len());
    // One pass over the image gathers every object's statistics.
    let mut blobs: std::collections::BTreeMap<u32, Blob> = Default::default();
    for (p, &id) in map_ids.iter().enumerate() {
        if id == 0 {
            continue;
        }
        let b = blobs.entry(id).or_insert_with(|| Blob {
            sum_probability: vec![0.0; affordances.len()],
            ..Blob::default()
        });
        b.pixels += 1;
        b.sum_u += (p % width) as f64;
        b.sum_v += (p / width) as f64;
        if let Some(planes) = probabilities {
            for (sum, plane) in b.sum_probability.iter_mut().zip(planes) {
                *sum += f64::from(plane[p]);
            }
        }
    }
    let region = |n: usize| {
        let span = rule.centre_fraction * n as f32;
        ((n as f32 - span) / 2.0, span / GRID as f32)
    };
    let ((u0, cell_w), (v0, cell_h)) = (region(width), region(height));
    let centre = |cell: usize| {
        (
            u0 + cell_w * ((cell % GRID) as f32 + 0.5),
            v0 + cell_h * ((cell / GRID) as f32 + 0.5),
        )
    };
    // The pixel of object `id` nearest its centroid (the first on ties).
    let aim = |id: u32, (cu, cv): (f32, f32)| {
        map_ids
            .iter()
            .enumerate()
            .filter(|(_, &m)| m == id)
            .map(|(p, _)| p)
            .min_by(|&a, &b| {
                let d = |p: usize| {
                    ((p % width) as f32 - cu).powi(2) + ((p / width) as f32 - cv).powi(2)
                };
                d(a).total_cmp(&d(b))
            })
            .expect("the blob has pixels")
    };
    let mut cells = Vec::with_capacity(affordances.len());
    for (k, &affordance) in affordances.iter().enumerate() {
        // Per cell, the largest confident object, failing any the most
        // probable one (`largest`; `smallest` the smallest); or the most
        // probable one (`most_probable`); the lowest id on ties.
        let mut best: [Option<(u32, &Blob, Preference)>; GRID * GRID] = [None; GRID * GRID];
        for (&id, blob) in &blobs {
            if blob.pixels < min_pixels {
                continue;
            }
            let preference = match probabilities {
                None => Preference::by_size(rule.prefer, blob.pixels),
                Some(_) => {
                    let mean = (blob.sum_probability[k] / blob.pixels as f64) as f32;
                    match rule.prefer {
                        CellPreference::Largest | CellPreference::Smallest
                            if mean >= min_confidence =>
                        {
                            Preference::by_size(rule.prefer, blob.pixels)
                        }
                        CellPreference::Largest
                        | CellPreference::Smallest
                        | CellPreference::MostProbable
                        | CellPreference::MostProbableInView => Preference::Probability(mean),
                    }
                }
            };
            let (cu, cv) = blob.centroid();
            let cell = (0..GRID * GRID)
                .min_by(|&a, &b| {
                    let d = |c: usize| {
                        let (x, y) = centre(c);
                        (x - cu).powi(2) + (y - cv).powi(2)
                    };
                    d(a).total_cmp(&d(b))
                })
                .expect("nine cells");
            if best[cell].is_none_or(|(_, _, p)| p < preference) {
                best[cell] = Some((id, blob, preference));
            }
        }
        if probabilities.is_some() && rule.prefer == CellPreference::MostProbableInView {
            // Each occupied cell offers the best of all (the lowest id on ties).
            let overall = best.iter().flatten().copied().reduce(|a, b| {
                if b.2 > a.2 || (b.2 == a.2 && b.0 < a.0) {
                    b
                } else {
                    a
                }
            });
            for cell in best.iter_mut().filter(|c| c.is_some()) {
                *cell = overall;
            }
        }
        let targets = best.map(|chosen| {
            chosen.map(|(id, blob, _)| {
                let p = aim(id, blob.centroid());
                Target {
                    object: id,
                    u: p % width,
                    v: p / width,
                    pixels: blob.pixels,
                    rating: (blob.sum_probability[k] / blob.pixels as f64) as f32,
                }
            })
        });
        cells.push((affordance, targets));
    }
    CellTargets { cells }
}

/// IntExp's target for a frame: the object under the pixel nearest the
/// image's centre, looked for within the grid's middle cell, for every
/// affordance in selection slot 0 (no confidence filter: IntExp has none).
/// `ids` is the frame's object-id image, `width` wide.
pub(crate) fn centred_target(
    ids: &[u32],
    width: usize,
    affordances: &[Affordance],
    rule: &SelectionRule,
) -> CellTargets {
    let height = ids.len() / width.max(1);
    let (cu, cv) = ((width as f32 - 1.0) / 2.0, (height as f32 - 1.0) / 2.0);
    let (half_w, half_h) = (
        rule.centre_fraction * width as f32 / (2 * GRID) as f32,
        rule.centre_fraction * height as f32 / (2 * GRID) as f32,
    );
    let nearest = ids
        .iter()
        .enumerate()
        .filter(|&(p, &id)| {
            let (du, dv) = ((p % width) as f32 - cu, (p / width) as f32 - cv);
            id != 0 && du.abs() <= half_w && dv.abs() <= half_h
        })
        .min_by(|&(a, _), &(b, _)| {
            let d =
                |p: usize| ((p % width) as f32 - cu).powi(2) + ((p / width) as f32 - cv).powi(2);
            d(a).total_cmp(&d(b))
        });
    let target = nearest.and_then(|(p, &id)| {
        let pixels = ids.iter().filter(|&&m| m == id).count();
        (pixels >= mapper::scaled_px(rule.min_pixels, ids.len())).then_some(Target {
            object: id,
            u: p % width,
            v: p / width,
            pixels,
            rating: 0.0,
        })
    });
    let mut slots = [None; GRID * GRID];
    slots[0] = target;
    CellTargets {
        cells: affordances.iter().map(|&a| (a, slots)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The task's default `selection_confidence`.
    const MIN_CONFIDENCE: f32 = 0.05;

    /// A 30 × 30 id image with rectangles `(id, u0, v0, u1, v1)` (exclusive ends).
    fn image(rects: &[(u32, usize, usize, usize, usize)]) -> Vec<u32> {
        let mut ids = vec![0; 900];
        for &(id, u0, v0, u1, v1) in rects {
            for v in v0..v1 {
                for u in u0..u1 {
                    ids[v * 30 + u] = id;
                }
            }
        }
        ids
    }

    #[test]
    fn the_action_count_follows_the_affordances() {
        let grid = |a: &[Affordance]| ActionSpace::new(a, Selection::Grid).len();
        assert_eq!(grid(&[Affordance::PickUp]), 21);
        assert_eq!(grid(&[Affordance::Push]), 14);
        assert_eq!(grid(&[Affordance::PickUp, Affordance::Push]), 30);
        let centred = ActionSpace::new(&[Affordance::PickUp, Affordance::Push], Selection::Centred);
        assert_eq!(centred.len(), 5 + 2 + 7);
        // The task and the space agree for every method.
        for method in [
            proto::Method::Ours,
            proto::Method::NomapSeg,
            proto::Method::NomapNoseg,
            proto::Method::Intexp,
        ] {
            let task = proto::TaskSpec {
                method,
                ..proto::TaskSpec::default()
            };
            let space = ActionSpace::new(&task.affordances, method.spec().selection);
            assert_eq!(space.len(), task.n_actions(), "{method:?}");
        }
    }

    #[test]
    fn intexp_selects_the_object_at_the_centre_or_nothing() {
        let rule = SelectionRule::default();
        // A big object off-centre (2) and a small one over the centre (3).
        let ids = image(&[(2, 0, 0, 12, 30), (3, 14, 13, 18, 17)]);
        let t = centred_target(&ids, 30, &[Affordance::PickUp, Affordance::Push], &rule);
        for a in [Affordance::PickUp, Affordance::Push] {
            let target = t.target(a, 0).unwrap();
            assert_eq!(target.object, 3);
            assert_eq!(
                (target.u, target.v),
                (14, 14),
                "the pixel nearest (14.5, 14.5)"
            );
            assert!(t.target(a, 1).is_none());
        }
        let space = ActionSpace::new(&[Affordance::PickUp], Selection::Centred);
        assert_eq!(space.mask(false, &t)[5], 1);
        // Only the off-centre object: nothing to select, the action is masked.
        let t = centred_target(
            &image(&[(2, 0, 0, 8, 30)]),
            30,
            &[Affordance::PickUp],
            &rule,
        );
        assert!(t.target(Affordance::PickUp, 0).is_none());
        assert_eq!(space.mask(false, &t)[5], 0);
    }

    #[test]
    fn the_mask_follows_the_hand_and_the_cells() {
        let space = ActionSpace::new(&[Affordance::PickUp, Affordance::Push], Selection::Grid);
        // One object in the middle cell.
        let targets = cell_targets(
            &image(&[(7, 12, 12, 18, 18)]),
            30,
            &[Affordance::PickUp, Affordance::Push],
            None,
            MIN_CONFIDENCE,
            &SelectionRule::default(),
        );
        for holding in [false, true] {
            let mask = space.mask(holding, &targets);
            for (a, &m) in space.actions().iter().zip(&mask) {
                let expected = match *a {
                    PolicyAction::Nav(_) => true,
                    PolicyAction::Select { affordance, cell } => {
                        cell == 4 && !(holding && affordance == Affordance::PickUp)
                    }
                    PolicyAction::Drop | PolicyAction::MoveHeld(_) => holding,
                };
                assert_eq!(m == 1, expected, "{a:?} holding={holding}");
            }
        }
        let pick = space
            .to_sim(
                PolicyAction::Select {
                    affordance: Affordance::PickUp,
                    cell: 4,
                },
                &targets,
            )
            .unwrap();
        assert_eq!(
            pick,
            Action::PickUp { u: 14, v: 14 },
            "aims at the centroid (14.5, 14.5)"
        );
        assert!(space
            .to_sim(
                PolicyAction::Select {
                    affordance: Affordance::Push,
                    cell: 0
                },
                &targets
            )
            .is_none());
    }

    #[test]
    fn a_cell_selects_its_largest_confident_object_and_is_masked_only_when_empty() {
        // Top-left: a big object (2) and a small one (3); bottom-right: object 5.
        let ids = image(&[(2, 3, 3, 10, 10), (3, 10, 3, 12, 8), (5, 22, 22, 27, 27)]);
        let rule = SelectionRule::default();
        let push_targets = |planes: Option<&[Vec<f32>]>| {
            cell_targets(&ids, 30, &[Affordance::Push], planes, MIN_CONFIDENCE, &rule)
        };
        let t = push_targets(None);
        assert_eq!(t.target(Affordance::Push, 0).unwrap().object, 2);
        assert_eq!(t.target(Affordance::Push, 8).unwrap().object, 5);
        assert!(t.target(Affordance::Push, 4).is_none());
        // The U-Net is sure object 2 cannot be pushed: the small one takes the cell.
        let plane: Vec<f32> = ids
            .iter()
            .map(|&id| if id == 2 { 0.01 } else { 0.6 })
            .collect();
        let t = push_targets(Some(&[plane]));
        assert_eq!(t.target(Affordance::Push, 0).unwrap().object, 3);
        // The policy's cell ratings: the offered object's mean, 0 where empty.
        let ratings = t.ratings(&[Affordance::Push]);
        assert_eq!(ratings.len(), GRID * GRID);
        assert!((ratings[0] - 0.6).abs() < 1e-6 && (ratings[8] - 0.6).abs() < 1e-6);
        assert!(ratings[1..8].iter().all(|&r| r == 0.0));
        // Sure of nothing in the cell: the cell stays selectable and takes
        // the object rated highest, however small.
        let plane: Vec<f32> = ids
            .iter()
            .map(|&id| match id {
                2 => 0.001,
                3 => 0.03,
                _ => 0.0,
            })
            .collect();
        let t = push_targets(Some(&[plane]));
        assert_eq!(t.target(Affordance::Push, 0).unwrap().object, 3);
        assert_eq!(t.target(Affordance::Push, 8).unwrap().object, 5);
        assert!(t.target(Affordance::Push, 4).is_none());
    }

    /// Top-left: a big object (2) and a small one (3); bottom-right: object 5.
    fn big_small_and_far() -> Vec<u32> {
        image(&[(2, 3, 3, 10, 10), (3, 10, 3, 12, 8), (5, 22, 22, 27, 27)])
    }

    /// The pick-up targets of `ids` (30 wide) under the default rule with `prefer`.
    fn pick_up_targets(
        ids: &[u32],
        prefer: CellPreference,
        planes: Option<&[Vec<f32>]>,
    ) -> CellTargets {
        let rule = SelectionRule {
            prefer,
            ..SelectionRule::default()
        };
        cell_targets(
            ids,
            30,
            &[Affordance::PickUp],
            planes,
            MIN_CONFIDENCE,
            &rule,
        )
    }

    #[test]
    fn in_view_every_occupied_cell_offers_the_object_rated_likeliest_in_the_frame() {
        let ids = big_small_and_far();
        let targets = |planes: Option<&[Vec<f32>]>| {
            pick_up_targets(&ids, CellPreference::MostProbableInView, planes)
        };
        let rated = |best: u32| -> Vec<f32> {
            ids.iter()
                .map(|&id| match id {
                    0 => 0.0,
                    id if id == best => 0.9,
                    _ => 0.4,
                })
                .collect()
        };
        for best in [3, 5] {
            let t = targets(Some(&[rated(best)]));
            for cell in [0, 8] {
                assert_eq!(t.target(Affordance::PickUp, cell).unwrap().object, best);
            }
            assert!(
                t.target(Affordance::PickUp, 4).is_none(),
                "empty cells stay empty"
            );
        }
        // Without a network each cell offers its largest object, as the paper's.
        let t = targets(None);
        assert_eq!(t.target(Affordance::PickUp, 0).unwrap().object, 2);
        assert_eq!(t.target(Affordance::PickUp, 8).unwrap().object, 5);
    }

    #[test]
    fn a_most_probable_cell_offers_the_object_rated_likeliest_whatever_its_size() {
        let ids = big_small_and_far();
        let targets = |planes: Option<&[Vec<f32>]>| {
            pick_up_targets(&ids, CellPreference::MostProbable, planes)
        };
        // Both confident: the paper's rule would offer the big one.
        let plane: Vec<f32> = ids
            .iter()
            .map(|&id| match id {
                2 => 0.6,
                3 => 0.9,
                _ => 0.2,
            })
            .collect();
        let t = targets(Some(std::slice::from_ref(&plane)));
        assert_eq!(t.target(Affordance::PickUp, 0).unwrap().object, 3);
        assert_eq!(t.target(Affordance::PickUp, 8).unwrap().object, 5);
        let paper = pick_up_targets(&ids, CellPreference::Largest, Some(&[plane]));
        assert_eq!(paper.target(Affordance::PickUp, 0).unwrap().object, 2);
        // Without a network the cell offers its largest object.
        assert_eq!(
            targets(None).target(Affordance::PickUp, 0).unwrap().object,
            2
        );
    }

    #[test]
    fn a_smallest_cell_offers_its_smallest_confident_object_also_before_the_network() {
        let ids = big_small_and_far();
        let targets =
            |planes: Option<&[Vec<f32>]>| pick_up_targets(&ids, CellPreference::Smallest, planes);
        let offered =
            |t: &CellTargets| [0, 8].map(|cell| t.target(Affordance::PickUp, cell).unwrap().object);
        // Before the network: the small object, where the paper's rule
        // offers the big one.
        assert_eq!(offered(&targets(None)), [3, 5]);
        let paper = pick_up_targets(&ids, CellPreference::Largest, None);
        assert_eq!(offered(&paper), [2, 5]);
        // Both confident, the big one rated higher: still the small one.
        let rated = |big: f32, small: f32| -> Vec<f32> {
            ids.iter()
                .map(|&id| match id {
                    2 => big,
                    3 => small,
                    _ => 0.5,
                })
                .collect()
        };
        assert_eq!(offered(&targets(Some(&[rated(0.9, 0.3)]))), [3, 5]);
        // The small one below the confidence filter: the big one, confident.
        assert_eq!(offered(&targets(Some(&[rated(0.9, 0.01)]))), [2, 5]);
        // Neither confident: the more probable.
        assert_eq!(offered(&targets(Some(&[rated(0.02, 0.04)]))), [3, 5]);
        assert_eq!(offered(&targets(Some(&[rated(0.04, 0.02)]))), [2, 5]);
    }

    #[test]
    fn the_smallest_selectable_object_is_the_same_share_of_any_image() {
        let rule = SelectionRule::default();
        // 10 px at 128 × 128 are 2.5 px at 64 × 64, rounded to 3.
        for (width, smallest) in [(128, rule.min_pixels), (64, 3)] {
            for (pixels, selectable) in [(smallest - 1, false), (smallest, true)] {
                let mut ids = vec![0; width * width];
                let centre = width / 2 * width + width / 2;
                ids[centre..centre + pixels].fill(4);
                let t = cell_targets(
                    &ids,
                    width,
                    &[Affordance::Push],
                    None,
                    MIN_CONFIDENCE,
                    &rule,
                );
                assert_eq!(
                    t.target(Affordance::Push, 4).is_some(),
                    selectable,
                    "{pixels} px at {width} × {width}"
                );
            }
        }
    }
}
