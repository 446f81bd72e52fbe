//! Object identity over viewpoints: consistent ids, no objects from noise,
//! one id for an over-segmented object, ids rendered back into frames, and
//! determinism for any thread count.

mod common;

use std::collections::{BTreeMap, BTreeSet};

use common::{k128, look_at, OwnedFrame, Shape};
use mapper::{Intrinsics, Map, MapConfig};
use nalgebra::{Isometry3, Point3, Vector3};

fn scene() -> Vec<Shape> {
    vec![
        Shape::Box {
            t_world_box: Isometry3::translation(0.0, 0.0, 0.4),
            half: Vector3::new(0.4, 0.3, 0.4),
            id: 11,
        },
        Shape::Sphere {
            center: Point3::new(0.9, 0.6, 0.25),
            radius: 0.25,
            id: 12,
        },
        Shape::Box {
            t_world_box: Isometry3::translation(-0.8, 0.7, 0.15),
            half: Vector3::new(0.15, 0.15, 0.15),
            id: 13,
        },
    ]
}

/// Ten viewpoints around the scene; some see only part of it.
fn viewpoints() -> Vec<Isometry3<f32>> {
    let target = Point3::new(0.0, 0.3, 0.3);
    (0..10)
        .map(|i| {
            let a = i as f32 / 10.0 * std::f32::consts::TAU;
            let r = if i % 3 == 0 { 1.3 } else { 2.6 }; // close views cut objects off
            look_at(Point3::new(r * a.cos(), 0.3 + r * a.sin(), 1.4), target)
        })
        .collect()
}

/// The map of [`scene`] after all of [`viewpoints`].
fn mapped_scene() -> Map {
    let shapes = scene();
    let mut map = Map::new(MapConfig::default());
    for pose in viewpoints() {
        map.integrate(&OwnedFrame::capture(&shapes, pose, k128()).frame())
            .unwrap();
    }
    map
}

/// Per input instance, the set of map ids its pixels got over all frames.
fn ids_per_instance(frames: &[(OwnedFrame, Vec<u32>)]) -> BTreeMap<u32, BTreeSet<u32>> {
    let mut out: BTreeMap<u32, BTreeSet<u32>> = BTreeMap::new();
    for (frame, map_ids) in frames {
        for (&instance, &id) in frame.ids.iter().zip(map_ids) {
            if instance != 0 && id != 0 {
                out.entry(instance).or_default().insert(id);
            }
        }
    }
    out
}

#[test]
fn ids_are_consistent_over_ten_viewpoints_with_partial_views() {
    let shapes = scene();
    let mut map = Map::new(MapConfig::default());
    let frames: Vec<_> = viewpoints()
        .into_iter()
        .map(|pose| {
            let f = OwnedFrame::capture(&shapes, pose, k128());
            let ids = map.integrate(&f.frame()).unwrap();
            (f, ids)
        })
        .collect();
    assert_eq!(
        map.objects().len(),
        3,
        "objects: {:?}",
        map.objects().keys().collect::<Vec<_>>()
    );
    let per_instance = ids_per_instance(&frames);
    assert_eq!(per_instance.len(), 3);
    for (instance, ids) in &per_instance {
        assert_eq!(ids.len(), 1, "instance {instance} got map ids {ids:?}");
    }
    let distinct: BTreeSet<_> = per_instance.values().flatten().collect();
    assert_eq!(distinct.len(), 3, "two instances share a map id");
}

#[test]
fn a_noise_segment_creates_no_object_and_an_over_segmented_object_keeps_one_id() {
    let shapes = scene();
    let mut map = Map::new(MapConfig::default());
    let views = viewpoints();
    for pose in &views[..4] {
        map.integrate(&OwnedFrame::capture(&shapes, *pose, k128()).frame())
            .unwrap();
    }
    let before = map.objects().len();
    // A 5-pixel blob with its own instance id in front of the background.
    let mut noisy = OwnedFrame::capture(&shapes, views[4], k128());
    let blob: Vec<usize> = (0..noisy.ids.len())
        .filter(|&p| noisy.ids[p] == 0)
        .take(5)
        .collect();
    for &p in &blob {
        noisy.ids[p] = 99;
        noisy.depth[p] = 1.5;
    }
    map.integrate(&noisy.frame()).unwrap();
    assert_eq!(
        map.objects().len(),
        before,
        "the noise segment became an object"
    );

    // Split the big box's mask in two instance ids (left / right halves).
    let mut split = OwnedFrame::capture(&shapes, views[5], k128());
    for (p, id) in split.ids.iter_mut().enumerate() {
        if *id == 11 && p % split.k.width < split.k.width / 2 {
            *id = 21;
        }
    }
    let map_ids = map.integrate(&split.frame()).unwrap();
    let got: BTreeSet<u32> = split
        .ids
        .iter()
        .zip(&map_ids)
        .filter(|(i, _)| **i == 11 || **i == 21)
        .map(|(_, m)| *m)
        .collect();
    assert_eq!(got.len(), 1, "over-segmented box got map ids {got:?}");
    assert_eq!(map.objects().len(), before);
}

#[test]
fn an_object_hidden_behind_an_unmapped_surface_is_not_missed() {
    let shapes = scene();
    let mut map = mapped_scene();
    let ids_before: BTreeSet<_> = map.objects().keys().copied().collect();
    // A screen (background: instance 0) between the camera and the scene
    // hides every object, for more frames than the map lets an object that
    // should be seen go unseen.
    let pose = look_at(Point3::new(2.6, 0.3, 1.0), Point3::new(0.0, 0.3, 0.3));
    let mut hidden = shapes.clone();
    hidden.push(Shape::Box {
        t_world_box: Isometry3::translation(1.9, 0.3, 1.0),
        half: Vector3::new(0.05, 3.0, 3.0),
        id: 0,
    });
    let frame = OwnedFrame::capture(&hidden, pose, k128());
    assert!(
        frame.ids.iter().all(|&i| i == 0),
        "the screen hides everything"
    );
    for _ in 0..=MapConfig::default().settings.max_misses + 2 {
        map.integrate(&frame.frame()).unwrap();
    }
    let ids_after: BTreeSet<_> = map.objects().keys().copied().collect();
    assert_eq!(
        ids_after, ids_before,
        "objects behind the screen were deleted"
    );
    // Without the screen, the camera sees them again under their ids.
    let seen = OwnedFrame::capture(&shapes, pose, k128());
    let map_ids = map.integrate(&seen.frame()).unwrap();
    let got: BTreeSet<_> = map_ids.iter().filter(|&&id| id != 0).copied().collect();
    assert!(!got.is_empty());
    assert!(got
        .iter()
        .all(|id| ids_before.contains(&mapper::ObjectId(*id))));
}

#[test]
fn ids_rendered_into_a_training_frame_match_ground_truth() {
    let shapes = scene();
    let mut map = Map::new(MapConfig::default());
    let mut instance_to_map = BTreeMap::new();
    for pose in viewpoints() {
        let f = OwnedFrame::capture(&shapes, pose, k128());
        let ids = map.integrate(&f.frame()).unwrap();
        for (&i, &m) in f.ids.iter().zip(&ids) {
            if i != 0 && m != 0 {
                instance_to_map.insert(i, m);
            }
        }
    }
    // A frame the map never integrated.
    let pose = look_at(Point3::new(-1.6, -1.7, 1.2), Point3::new(0.0, 0.3, 0.3));
    let truth = OwnedFrame::capture(&shapes, pose, k128());
    let rendered = map.render_ids(&pose, &truth.k);
    for (&instance, &map_id) in &instance_to_map {
        let gt: BTreeSet<usize> = (0..truth.ids.len())
            .filter(|&p| truth.ids[p] == instance)
            .collect();
        let pred: BTreeSet<usize> = (0..rendered.ids.len())
            .filter(|&p| rendered.ids[p] == map_id)
            .collect();
        if gt.is_empty() {
            continue;
        }
        let iou = gt.intersection(&pred).count() as f32 / gt.union(&pred).count() as f32;
        eprintln!(
            "instance {instance}: {} px, IoU {iou:.3}, missed {}, extra {}",
            gt.len(),
            gt.difference(&pred).count(),
            pred.difference(&gt).count()
        );
        // Boundary pixels dominate small masks: a 0.3 m cube at 2.5 m is ~90 px,
        // and a one-pixel ring of errors costs ~12 % IoU. The 0.9 bar is
        // asserted for objects of 200+ px; smaller ones must reach 0.8.
        let bound = if gt.len() >= 200 { 0.9 } else { 0.8 };
        assert!(iou > bound, "instance {instance} IoU {iou} (bound {bound})");
    }
}

#[test]
fn quarter_ray_rendering_matches_a_ray_through_every_pixel() {
    use mapper::render::{render_layers, Pixels, RenderTarget};

    let map = mapped_scene();
    let k = k128();
    let mut agreement = common::RenderAgreement::default();
    for pose in [
        look_at(Point3::new(-1.6, -1.7, 1.2), Point3::new(0.0, 0.3, 0.3)),
        look_at(Point3::new(2.0, -0.5, 0.9), Point3::new(0.2, 0.4, 0.3)),
    ] {
        let layers = map.objects_in_camera(&pose);
        // Depths within one voxel (the map's setting) are interpolated.
        let fast = render_layers(&layers, &k, 0.1, 0.04, None);
        let mut exact = RenderTarget::new(&k);
        for l in &layers {
            l.raycast(&k, 0.1, &mut exact, Pixels::All);
        }
        agreement.add(&fast, &exact);
    }
    let (p99, max) = agreement.depth_p99_and_max();
    let common::RenderAgreement {
        compared,
        other_id: id_mismatch,
        depth_errors,
    } = agreement;
    eprintln!(
        "quarter-ray render: {id_mismatch} of {compared} pixels with another id; depth error p99 {p99:.4} m, max {max:.4} m over {} object pixels",
        depth_errors.len()
    );
    assert!(
        depth_errors.len() > 1000,
        "the views should show the objects"
    );
    assert!(
        id_mismatch * 1000 <= compared,
        "{id_mismatch} of {compared} ids differ"
    );
    // Half a voxel for nearly all pixels; the largest errors are where the
    // every-pixel render itself has a ray slip through a crack (3.4 cm here),
    // all far inside association's 8 cm depth tolerance.
    assert!(
        p99 < 0.02 && max < 0.05,
        "depth error p99 {p99} m, max {max} m"
    );
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let shapes = scene();
            let mut map = Map::new(MapConfig::default());
            let mut outputs = Vec::new();
            for pose in viewpoints() {
                outputs.push(
                    map.integrate(&OwnedFrame::capture(&shapes, pose, k128()).frame())
                        .unwrap(),
                );
            }
            let volumes: Vec<_> = map
                .objects()
                .values()
                .map(|o| {
                    (
                        o.id,
                        o.volume
                            .near_surface_voxels(1.0)
                            .into_iter()
                            .map(|(p, s)| (p.coords.map(f32::to_bits), s.to_bits()))
                            .collect::<Vec<_>>(),
                    )
                })
                .collect();
            (outputs, volumes)
        })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn ids_stay_consistent_with_geometric_segmentation() {
    let mut shapes = scene();
    // Floor and a wall: background that the segmentation must recognise.
    shapes.push(Shape::Box {
        t_world_box: Isometry3::translation(0.0, 0.0, -0.05),
        half: Vector3::new(4.0, 4.0, 0.05),
        id: 0,
    });
    shapes.push(Shape::Box {
        t_world_box: Isometry3::translation(0.0, 3.0, 1.2),
        half: Vector3::new(4.0, 0.05, 1.2),
        id: 0,
    });
    let config = MapConfig::from_settings(proto::MapSettings {
        segmentation: proto::MapSegmentation::Geometric,
        ..Default::default()
    });
    let mut map = Map::new(config);
    // Per true instance: the map id holding most of its pixels, per frame.
    let mut majority: BTreeMap<u32, BTreeSet<u32>> = BTreeMap::new();
    for pose in viewpoints() {
        let frame = OwnedFrame::capture(&shapes, pose, k128());
        let map_ids = map.integrate(&frame.frame()).unwrap();
        let mut votes: BTreeMap<u32, BTreeMap<u32, usize>> = BTreeMap::new();
        for (&instance, &id) in frame.ids.iter().zip(&map_ids) {
            if instance != 0 {
                *votes.entry(instance).or_default().entry(id).or_default() += 1;
            }
        }
        for (instance, counts) in votes {
            let total: usize = counts.values().sum();
            let (id, n) = counts.into_iter().max_by_key(|(_, n)| *n).unwrap();
            if total >= 50 {
                assert_ne!(id, 0, "instance {instance} ({total} px) got no map id");
                assert!(
                    n * 2 >= total,
                    "instance {instance}: only {n} of {total} px on its main id"
                );
                majority.entry(instance).or_default().insert(id);
            }
        }
    }
    eprintln!(
        "geometric segmentation: {:?}; map objects {:?}",
        majority,
        map.objects().keys().collect::<Vec<_>>()
    );
    assert_eq!(majority.len(), 3);
    for (instance, ids) in &majority {
        assert_eq!(ids.len(), 1, "instance {instance} got ids {ids:?}");
    }
    let distinct: BTreeSet<_> = majority.values().flatten().collect();
    assert_eq!(distinct.len(), 3, "two instances share an id");
    assert_eq!(
        map.objects().len(),
        3,
        "spurious objects from the background"
    );
}

/// A segment that the map already holds in pieces, none of which it matches
/// alone (here four boxes under one instance id, as a mask that merges them
/// gives; in a room, an object whose model was split over several map
/// objects), goes to the piece holding most of it instead of becoming a new
/// object. As a new object it was one more piece, hidden behind the others
/// in the next frame's rendering, and a new one was made every frame.
#[test]
fn a_segment_the_map_holds_in_pieces_makes_no_new_object() {
    let boxes: Vec<Shape> = (0..4)
        .map(|i| Shape::Box {
            t_world_box: Isometry3::translation(0.0, -0.6 + 0.4 * i as f32, 0.15),
            half: Vector3::new(0.15, 0.15, 0.15),
            id: 21 + i,
        })
        .collect();
    let eye = Point3::new(2.0, 0.0, 1.2);
    let target = Point3::new(0.0, 0.0, 0.15);
    let mut map = Map::new(MapConfig::default());
    for dy in [-0.3, 0.0, 0.3] {
        let pose = look_at(Point3::new(eye.x, dy, eye.z), target);
        map.integrate(&OwnedFrame::capture(&boxes, pose, k128()).frame())
            .unwrap();
    }
    assert_eq!(map.objects().len(), 4, "four boxes mapped");
    let merged: Vec<Shape> = boxes
        .iter()
        .map(|shape| match *shape {
            Shape::Box {
                t_world_box, half, ..
            } => Shape::Box {
                t_world_box,
                half,
                id: 21,
            },
            other => other,
        })
        .collect();
    let frame = OwnedFrame::capture(&merged, look_at(eye, target), k128());
    for _ in 0..5 {
        let owner = map.integrate(&frame.frame()).unwrap();
        assert!(
            frame
                .ids
                .iter()
                .zip(&owner)
                .all(|(&i, &o)| i == 0 || o != 0),
            "every pixel of the merged segment has an owner"
        );
    }
    assert_eq!(
        map.objects().len(),
        4,
        "{:?}",
        map.objects().keys().collect::<Vec<_>>()
    );
}

/// The map id instance `instance` got in a frame (the one most of its
/// pixels got).
fn id_of(frame: &OwnedFrame, map_ids: &[u32], instance: u32) -> mapper::ObjectId {
    let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
    for (&i, &id) in frame.ids.iter().zip(map_ids) {
        if i == instance && id != 0 {
            *counts.entry(id).or_default() += 1;
        }
    }
    let (&id, _) = counts
        .iter()
        .max_by_key(|(_, &n)| n)
        .expect("the instance has map ids");
    mapper::ObjectId(id)
}

/// [`scene`], its map, a frame from the second viewpoint (integrated) and
/// the map id of the small box (instance 13) in it.
fn small_box_in_view() -> (Vec<Shape>, Map, OwnedFrame, mapper::ObjectId) {
    let shapes = scene();
    let mut map = mapped_scene();
    let frame = OwnedFrame::capture(&shapes, viewpoints()[1], k128());
    let id = id_of(&frame, &map.integrate(&frame.frame()).unwrap(), 13);
    (shapes, map, frame, id)
}

#[test]
fn two_copies_of_one_object_become_one_that_keeps_both_labels() {
    use mapper::{Affordance, Outcome};
    let (shapes, mut map, frame, first) = small_box_in_view();
    let at = map.object(first).unwrap().t_world_object;
    // The first model lifted out of view (a tracking failure's stale copy):
    // the box's next views make a second object of it.
    map.set_object_pose(first, Isometry3::translation(0.0, 0.0, 5.0) * at)
        .unwrap();
    let mut second = first;
    for _ in 0..3 {
        second = id_of(&frame, &map.integrate(&frame.frame()).unwrap(), 13);
    }
    assert_ne!(second, first, "the box was mapped a second time");
    map.record_interaction(first, Affordance::PickUp, Outcome::Success)
        .unwrap();
    map.record_interaction(second, Affordance::Push, Outcome::Failure)
        .unwrap();
    // Both copies back on the box: the next frame shows one object.
    map.set_object_pose(first, at).unwrap();
    map.integrate(&frame.frame()).unwrap();
    assert_eq!(map.objects().len(), 3, "one copy is merged into the other");
    let kept = map.current_id(first);
    assert_eq!(map.current_id(second), kept);
    for id in [first, second] {
        let labels = map.labels_of(id).expect("labels of a merged copy");
        assert_eq!(labels.label(Affordance::PickUp), Some(true));
        assert_eq!(labels.label(Affordance::Push), Some(false));
    }
    for pose in viewpoints() {
        let frame = OwnedFrame::capture(&shapes, pose, k128());
        let map_ids = map.integrate(&frame.frame()).unwrap();
        if frame.ids.iter().filter(|&&i| i == 13).count() >= 50 {
            assert_eq!(id_of(&frame, &map_ids, 13), kept);
        }
    }
}

#[test]
fn a_deleted_object_keeps_its_labels_for_the_frames_that_showed_it() {
    use mapper::{Affordance, Outcome};
    let (shapes, mut map, frame, id) = small_box_in_view();
    let pose = frame.pose;
    map.record_interaction(id, Affordance::PickUp, Outcome::Failure)
        .unwrap();
    // The box is gone (carried away unseen); the map sees it missing.
    let without: Vec<Shape> = shapes.into_iter().filter(|s| s.id() != 13).collect();
    let empty = OwnedFrame::capture(&without, pose, k128());
    for _ in 0..=MapConfig::default().settings.max_misses + 1 {
        map.integrate(&empty.frame()).unwrap();
    }
    assert!(map.object(id).is_none(), "the missing box was deleted");
    assert_eq!(
        map.labels_of(id).and_then(|l| l.label(Affordance::PickUp)),
        Some(false)
    );
}

/// An object seen from a side the map never saw: most of its segment is
/// new surface, so it matches its object on neither IoU nor coverage, but
/// the object's model lies within the segment, and the segment keeps its id
/// rather than becoming a second object.
#[test]
fn an_object_seen_from_a_new_side_keeps_its_id() {
    let known = Shape::Box {
        t_world_box: Isometry3::translation(0.0, 0.0, 0.2),
        half: Vector3::new(0.2, 0.2, 0.2),
        id: 5,
    };
    // The rest of the same object, hidden until now (an L-shaped sofa's
    // other wing, behind the first from where the map looked).
    let hidden = Shape::Box {
        t_world_box: Isometry3::translation(-0.2, 0.8, 0.2),
        half: Vector3::new(0.4, 0.6, 0.2),
        id: 5,
    };
    let target = Point3::new(0.0, 0.0, 0.2);
    let mut map = Map::new(MapConfig::default());
    let first = look_at(Point3::new(1.8, -0.3, 1.0), target);
    let seen = OwnedFrame::capture(&[known], first, k128());
    let first_ids = map.integrate(&seen.frame()).unwrap();
    let id = id_of(&seen, &first_ids, 5);
    let whole = OwnedFrame::capture(
        &[known, hidden],
        look_at(Point3::new(0.6, -1.6, 1.2), Point3::new(-0.1, 0.4, 0.2)),
        k128(),
    );
    let rendered = map.render_ids(&whole.pose, &k128());
    let segment = whole.ids.iter().filter(|&&i| i == 5).count();
    let on_model = rendered.ids.iter().filter(|&&i| i == id.0).count();
    assert!(
        (on_model as f32) < 0.3 * segment as f32,
        "the known part is {on_model} of {segment} px: too much to test a new side"
    );
    let ids = map.integrate(&whole.frame()).unwrap();
    assert_eq!(map.objects().len(), 1, "no second object for the new side");
    assert!(whole
        .ids
        .iter()
        .zip(&ids)
        .all(|(&i, &o)| i != 5 || o == id.0));
}

/// An object mostly gone from where its model stands (the rest of it not
/// yet carved) whose remaining part shows as a sliver too small to be a
/// segment is glimpsed, not missed: a still camera looking at it for longer
/// than the map's miss budget does not delete it.
#[test]
fn an_object_glimpsed_as_a_sliver_is_not_deleted() {
    let floor = Shape::Box {
        t_world_box: Isometry3::translation(0.0, 0.0, -0.05),
        half: Vector3::new(3.0, 3.0, 0.05),
        id: 0,
    };
    let long = Shape::Box {
        t_world_box: Isometry3::translation(0.0, 0.0, 0.1),
        half: Vector3::new(0.4, 0.1, 0.1),
        id: 7,
    };
    let target = Point3::new(0.0, 0.0, 0.1);
    let mut map = Map::new(MapConfig::default());
    for pose in common::orbit(target, 1.6, 1.0, 8) {
        map.integrate(&OwnedFrame::capture(&[floor, long], pose, k128()).frame())
            .unwrap();
    }
    assert_eq!(map.objects().len(), 1);
    let id = *map.objects().keys().next().unwrap();
    // All but one end of it is gone; from this view the end is a sliver.
    let end = Shape::Box {
        t_world_box: Isometry3::translation(0.36, 0.0, 0.1),
        half: Vector3::new(0.04, 0.06, 0.06),
        id: 7,
    };
    let view = look_at(Point3::new(-1.2, -1.6, 1.6), target);
    let frame = OwnedFrame::capture(&[floor, end], view, k128());
    let sliver = frame.ids.iter().filter(|&&i| i == 7).count();
    let model = map.render_ids(&view, &k128());
    let rendered = model.ids.iter().filter(|&&i| i == id.0).count();
    eprintln!("sliver {sliver} px, model rendered on {rendered} px");
    assert!(
        (10..20).contains(&sliver) && rendered >= 50,
        "sliver {sliver} px, model {rendered} px: not the case tested"
    );
    for _ in 0..=MapConfig::default().settings.max_misses + 2 {
        map.integrate(&frame.frame()).unwrap();
    }
    assert!(map.object(id).is_some(), "the glimpsed object was deleted");
}

#[test]
fn a_small_object_is_mapped_at_the_papers_resolution_and_at_a_quarter_of_it() {
    // A book-sized box a metre ahead of the camera, looked down at.
    let book = vec![Shape::Box {
        t_world_box: Isometry3::translation(1.0, 0.0, 0.05),
        half: Vector3::new(0.12, 0.08, 0.03),
        id: 7,
    }];
    let pose = look_at(Point3::new(0.0, 0.0, 0.9), Point3::new(1.0, 0.0, 0.05));
    let defaults = MapConfig::default().settings;
    for size in [128, 64] {
        let frame = OwnedFrame::capture(&book, pose, Intrinsics::from_fov(size, size, 90.0));
        let pixels: Vec<usize> = (0..frame.ids.len())
            .filter(|&p| frame.ids[p] == 7)
            .collect();
        // The same share of the view: enough for an object at 128 × 128,
        // under the unscaled threshold at 64 × 64.
        assert_eq!(
            pixels.len() >= defaults.new_object_min_px,
            size == 128,
            "{} px at {size} × {size}",
            pixels.len()
        );
        let mut map = Map::new(MapConfig::default());
        let map_ids = map.integrate(&frame.frame()).unwrap();
        assert_eq!(map.objects().len(), 1, "at {size} × {size}");
        assert!(
            pixels.iter().all(|&p| map_ids[p] != 0),
            "at {size} × {size} the object's pixels have no map id"
        );
    }
}
