//! The label ladder's upper rungs (`proto::LabelRung`): label planes for an
//! episode's frames from the simulator's ground truth, beside the run's own
//! labels, so that an offline U-Net trained on each says where the signal
//! is lost (`docs/ladder.md`).
//!
//! - **L0, ground truth**: every pixel of an object in view gets whether
//!   that object affords the affordance for the run's robot.
//! - **L1, tried truth**: only the objects the agent tried get a label, on
//!   their map object's pixels in every frame (as the labeler spreads an
//!   outcome), and the label is the ground truth of the scene object the
//!   map object mostly showed: the outcomes made perfect, the choice of
//!   objects and the map's spread kept.
//!
//! Both leave the background to the caller, which labels it as the run
//! labels it (`labeler::label_background_negative`).

use std::collections::{BTreeMap, BTreeSet};

use proto::{Affordance, LABEL_NEGATIVE, LABEL_POSITIVE, LABEL_UNKNOWN};

/// What the episode's memory knows of the objects the agent tried, as the
/// map knows them at the episode's end.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriedObjects {
    /// Per frame, the object each pixel showed, by the id it has at the
    /// episode's end (merged copies under the id they were merged into; 0:
    /// none).
    pub objects: Vec<Vec<u32>>,
    /// The (object, affordance) pairs the agent tried, whatever came of it.
    pub tried: BTreeSet<(u32, Affordance)>,
}

/// `truth[i][a]`: whether scene object `i` (instance id `i + 1`) affords
/// plane `a`; instance 0 and unknown ids afford nothing.
fn affords(truth: &[Vec<bool>], instance: u32, plane: usize) -> Option<bool> {
    let index = (instance as usize).checked_sub(1)?;
    truth.get(index).map(|t| t[plane])
}

fn label(affords: bool) -> u8 {
    if affords {
        LABEL_POSITIVE
    } else {
        LABEL_NEGATIVE
    }
}

/// L0: per frame, `planes` label planes from the simulator's instance ids
/// (`truth_ids`, instance = scene object index + 1, 0 = nothing) and each
/// object's ground truth; pixels of no object stay unknown.
pub fn ground_truth_labels(
    truth_ids: &[Vec<u32>],
    truth: &[Vec<bool>],
    planes: usize,
) -> Vec<Vec<u8>> {
    truth_ids
        .iter()
        .map(|ids| {
            (0..planes)
                .flat_map(|plane| {
                    ids.iter()
                        .map(move |&id| affords(truth, id, plane).map_or(LABEL_UNKNOWN, label))
                })
                .collect()
        })
        .collect()
}

/// L1: per frame, one plane per affordance of `affordances` in which every
/// pixel of a tried map object gets the ground truth of the scene object
/// that map object showed most often over the episode (the majority of
/// `truth_ids` under it); everything else stays unknown, as does an object
/// that mostly showed nothing.
pub fn tried_truth_labels(
    tried: &TriedObjects,
    truth_ids: &[Vec<u32>],
    truth: &[Vec<bool>],
    affordances: &[Affordance],
) -> Vec<Vec<u8>> {
    let tried_ids: BTreeSet<u32> = tried.tried.iter().map(|&(object, _)| object).collect();
    let mut votes: BTreeMap<u32, BTreeMap<u32, usize>> = BTreeMap::new();
    for (objects, ids) in tried.objects.iter().zip(truth_ids) {
        for (&object, &id) in objects.iter().zip(ids) {
            if tried_ids.contains(&object) {
                *votes.entry(object).or_default().entry(id).or_default() += 1;
            }
        }
    }
    let shown: BTreeMap<u32, u32> = votes
        .into_iter()
        .filter_map(|(object, counts)| {
            // Most pixels; a tie goes to the smaller instance id, so the
            // labels do not depend on iteration order.
            let (&id, _) = counts
                .iter()
                .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)))?;
            Some((object, id))
        })
        .collect();
    tried
        .objects
        .iter()
        .map(|objects| {
            affordances
                .iter()
                .enumerate()
                .flat_map(|(plane, &affordance)| {
                    let shown = &shown;
                    objects.iter().map(move |&object| {
                        if object == 0 || !tried.tried.contains(&(object, affordance)) {
                            return LABEL_UNKNOWN;
                        }
                        shown
                            .get(&object)
                            .and_then(|&id| affords(truth, id, plane))
                            .map_or(LABEL_UNKNOWN, label)
                    })
                })
                .collect()
        })
        .collect()
}

/// Per frame, the rungs' planes one after the other (`proto::LabelRung`'s
/// order: L0, L1, L2), as a dataset frame holds them.
pub fn stack_rungs(rungs: [&[Vec<u8>]; 3]) -> Vec<Vec<u8>> {
    let frames = rungs[0].len();
    (0..frames)
        .map(|f| rungs.iter().flat_map(|r| r[f].iter().copied()).collect())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const U: u8 = LABEL_UNKNOWN;
    const P: u8 = LABEL_POSITIVE;
    const N: u8 = LABEL_NEGATIVE;

    /// Scene objects 1 (a book: pickable, pushable) and 2 (a sofa: neither).
    fn truth() -> Vec<Vec<bool>> {
        vec![vec![true, true], vec![false, false]]
    }

    #[test]
    fn ground_truth_labels_every_object_in_view_and_leaves_the_rest() {
        let labels = ground_truth_labels(&[vec![0, 1, 2, 9]], &truth(), 2);
        assert_eq!(labels, vec![vec![U, P, N, U, U, P, N, U]]);
    }

    #[test]
    fn tried_truth_labels_only_tried_objects_by_the_instance_they_mostly_showed() {
        // Map object 5 mostly shows the book (one pixel bleeds onto the
        // sofa); map object 6 shows the sofa and was never tried.
        let tried = TriedObjects {
            objects: vec![vec![5, 5, 6, 0], vec![5, 0, 6, 5]],
            tried: [(5, Affordance::PickUp)].into_iter().collect(),
        };
        let truth_ids = vec![vec![1, 1, 2, 0], vec![2, 0, 2, 1]];
        let labels = tried_truth_labels(
            &tried,
            &truth_ids,
            &truth(),
            &[Affordance::PickUp, Affordance::Push],
        );
        // Pick-up: object 5's pixels all positive (the book), also where it
        // bleeds onto the sofa, as the labeler spreads a map label; push:
        // nobody tried it.
        assert_eq!(labels[0], vec![P, P, U, U, U, U, U, U]);
        assert_eq!(labels[1], vec![P, U, U, P, U, U, U, U]);
    }

    #[test]
    fn a_tried_object_of_the_sofa_is_negative_whatever_its_outcome() {
        let tried = TriedObjects {
            objects: vec![vec![3, 3]],
            tried: [(3, Affordance::Push)].into_iter().collect(),
        };
        let labels = tried_truth_labels(&tried, &[vec![2, 2]], &truth(), &[Affordance::Push]);
        assert_eq!(labels, vec![vec![N, N]]);
    }

    #[test]
    fn rungs_stack_in_plane_order() {
        let (a, b, c) = (vec![vec![1u8]], vec![vec![2u8]], vec![vec![3u8]]);
        assert_eq!(stack_rungs([&a, &b, &c]), vec![vec![1, 2, 3]]);
    }
}
