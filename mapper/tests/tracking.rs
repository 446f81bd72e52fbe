//! Tracking of a moved object: the pose follows a box
//! moved 10 cm and turned 15°, no ghost remains, static objects do not drift,
//! and a jump beyond the gate fails without touching the model. Objects the
//! robot moved that tracking loses are found again.

mod common;

use common::{k128, look_at, orbit, OwnedFrame, Shape};
use mapper::{
    Frame, Intrinsics, Map, MapConfig, ObjectId, Pose, TrackingFailure, TrackingOutcome,
    TrackingReport, Whereabouts,
};
use std::collections::BTreeSet;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

const BOX_CENTRE: Point3<f32> = Point3::new(0.0, 0.0, 0.15);

fn floor() -> Shape {
    Shape::Box {
        t_world_box: Isometry3::translation(0.0, 0.0, -0.05),
        half: Vector3::new(3.0, 3.0, 0.05),
        id: 0,
    }
}

fn moving_box(t_world_box: Pose) -> Shape {
    Shape::Box {
        t_world_box,
        half: Vector3::new(0.2, 0.15, 0.15),
        id: 1,
    }
}

fn statics() -> [Shape; 2] {
    [
        Shape::Sphere {
            center: Point3::new(0.9, 0.6, 0.2),
            radius: 0.2,
            id: 2,
        },
        Shape::Box {
            t_world_box: Isometry3::from_parts(
                Translation3::new(-0.8, 0.7, 0.2),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.4),
            ),
            half: Vector3::new(0.15, 0.2, 0.2),
            id: 3,
        },
    ]
}

fn scene(t_world_box: Pose) -> Vec<Shape> {
    let mut shapes = vec![floor(), moving_box(t_world_box)];
    shapes.extend(statics());
    shapes
}

fn views() -> Vec<Pose> {
    orbit(Point3::new(0.0, 0.0, 0.2), 1.4, 1.1, 12)
}

/// A map of the scene with the box at its start pose, and the map id of each instance.
fn mapped_scene() -> (Map, [ObjectId; 3]) {
    let start = Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    mapped(&scene(start))
}

/// A map of still `shapes` seen from every view, and the map id of each of
/// their `N` instances (ids 1 to `N`).
fn mapped<const N: usize>(shapes: &[Shape]) -> (Map, [ObjectId; N]) {
    let mut map = Map::new(MapConfig::default());
    let mut ids = [None; N];
    for pose in views() {
        let frame = OwnedFrame::capture(shapes, pose, k128());
        let owner = map.integrate(&frame.frame()).unwrap();
        for (px, &instance) in frame.ids.iter().enumerate() {
            if instance != 0 && owner[px] != 0 {
                ids[instance as usize - 1].get_or_insert(ObjectId(owner[px]));
            }
        }
        assert!(map.last_tracking().is_empty(), "nothing moved yet");
    }
    (map, ids.map(|i| i.expect("every object mapped")))
}

/// What tracking did with object `id` in the map's last frame, if it ran.
fn tracking_of(map: &Map, id: ObjectId) -> Option<TrackingReport> {
    map.last_tracking().iter().find(|r| r.object == id).copied()
}

/// Rotation angle (degrees) and translation (metres) between two poses.
fn pose_error(a: &Pose, b: &Pose) -> (f32, f32) {
    let d = a.inverse() * b;
    (d.rotation.angle().to_degrees(), d.translation.vector.norm())
}

/// Asserts that the box's model, mapped at the start pose with model pose
/// `before`, now stands (model pose `found`) where the box stands at
/// `landed`: its centre within 2 cm and its heading within 2° (modulo a
/// half turn: the box looks the same turned half a turn). `what` names the
/// case in the printout.
fn assert_box_found_at(landed: &Pose, before: &Pose, found: &Pose, what: &str) {
    let start = Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    let truth = landed * start.inverse() * before;
    let centre = before.inverse() * BOX_CENTRE;
    let angle = (truth.rotation.inverse() * found.rotation)
        .angle()
        .to_degrees();
    let (deg, m) = (
        angle.min(180.0 - angle),
        (truth * centre - found * centre).norm(),
    );
    eprintln!("{what}: {m} m, {deg} deg off");
    assert!(m < 0.02 && deg < 2.0, "{what}: {m} m, {deg} deg off");
}

#[test]
fn a_moved_box_is_tracked_without_ghosts_or_drift() {
    let (mut map, [box_id, sphere_id, static_box_id]) = mapped_scene();
    let statics_before =
        [sphere_id, static_box_id].map(|id| map.object(id).unwrap().t_world_object);
    let box_before = map.object(box_id).unwrap().t_world_object;

    // Move the box 10 cm and turn it 15° about its centre; nobody tells the map.
    let motion = Isometry3::from_parts(
        Translation3::new(BOX_CENTRE.x + 0.06, BOX_CENTRE.y + 0.08, BOX_CENTRE.z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 15f32.to_radians()),
    ) * Isometry3::translation(-BOX_CENTRE.x, -BOX_CENTRE.y, -BOX_CENTRE.z);
    let moved = motion * Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    let shapes = scene(moved);
    let k = k128();
    // Ghost: the map shows the box where the frame sees something else,
    // more than a pixel away from the box's true silhouette (a one-pixel
    // rim is the resolution of rendering, not a ghost).
    let ghost_pixels = |map: &Map, pose: &Pose, frame: &OwnedFrame| {
        let rendered = map.render_ids(pose, &k);
        let near_box = |px: usize| {
            let (u, v) = ((px % k.width) as i64, (px / k.width) as i64);
            (-1..=1).any(|dv| {
                (-1..=1).any(|du| {
                    let (x, y) = (u + du, v + dv);
                    x >= 0
                        && y >= 0
                        && (x as usize) < k.width
                        && (y as usize) < k.height
                        && frame.ids[y as usize * k.width + x as usize] == 1
                })
            })
        };
        (0..k.pixels())
            .filter(|&px| rendered.ids[px] == box_id.0 && !near_box(px))
            .count()
    };
    for (n, pose) in views().into_iter().step_by(4).take(3).enumerate() {
        let frame = OwnedFrame::capture(&shapes, pose, k);
        if n == 0 {
            // The box's model where the box was, before tracking moves it:
            // what a ghost looks like here.
            let untracked = ghost_pixels(&map, &pose, &frame);
            eprintln!("before tracking: {untracked} ghost pixels");
            assert!(untracked >= 20, "{untracked} ghost pixels before tracking");
        }
        map.integrate(&frame.frame()).unwrap();
        eprintln!("frame {n}: {:?}", map.last_tracking());
        // At most a speck: one pixel a few centimetres in front of the floor
        // where the box's bottom edge meets it (a voxel's rim, seen in two
        // or three of the three frames with either SDF gradient).
        let ghost = ghost_pixels(&map, &pose, &frame);
        let box_px = frame.ids.iter().filter(|&&i| i == 1).count();
        eprintln!("frame {n}: {ghost} ghost pixels of {box_px}");
        assert!(ghost <= 1, "frame {n}: {ghost} ghost pixels");
    }
    let box_after = map
        .object(box_id)
        .expect("the box keeps its id")
        .t_world_object;
    let (rotation_deg, translation_m) = pose_error(&(motion * box_before), &box_after);
    eprintln!(
        "box pose error: {translation_m:.4} m, {rotation_deg:.3} deg; centre off by {:?}",
        box_after * (box_before.inverse() * BOX_CENTRE) - moved * Point3::origin()
    );
    assert!(translation_m < 0.01, "translation error {translation_m} m");
    assert!(rotation_deg < 1.0, "rotation error {rotation_deg} deg");
    for (id, before) in [sphere_id, static_box_id].iter().zip(statics_before) {
        let (r, t) = pose_error(&before, &map.object(*id).unwrap().t_world_object);
        assert!(
            t < 0.001 && r < 0.06,
            "static object {id:?} drifted {t} m, {r} deg"
        );
    }
    assert_eq!(map.objects().len(), 3, "no new object for the moved box");
}

#[test]
fn a_jump_beyond_the_gate_fails_without_touching_the_model() {
    let (mut map, [box_id, ..]) = mapped_scene();
    let before = map.object(box_id).unwrap().clone();
    map.notify_moved(box_id, None).unwrap();
    let jumped = Isometry3::translation(BOX_CENTRE.x + 0.5, BOX_CENTRE.y - 0.1, BOX_CENTRE.z);
    let frame = OwnedFrame::capture(&scene(jumped), views()[0], k128());
    map.integrate(&frame.frame()).unwrap();
    let report = tracking_of(&map, box_id).expect("the notified box was tracked");
    assert!(
        matches!(
            report.outcome,
            TrackingOutcome::Failed(TrackingFailure::BeyondGate { .. })
        ),
        "{report:?}"
    );
    let after = map.object(box_id).expect("the box is still in the map");
    assert_eq!(
        after.volume.near_surface_voxels(1.0),
        before.volume.near_surface_voxels(1.0),
        "the model must not change"
    );
    // Lost to tracking, the box is found again where it landed: its segment
    // does not become a new object.
    assert_eq!(after.whereabouts, Whereabouts::Placed);
    assert_box_found_at(
        &jumped,
        &before.t_world_object,
        &after.t_world_object,
        "found again after a 50 cm jump",
    );
    assert_eq!(map.objects().len(), 3, "no new object for the box");
    assert!(matches!(
        map.notify_moved(ObjectId(999), None),
        Err(mapper::MapError::UnknownObject(_))
    ));
}

/// An unannounced jump that tracking cannot follow fails again in every
/// frame from the same view; once the view settles (the first frames carve
/// the box's old place and make a new object of it where it landed, which
/// changes what the box's residual is), those repeats reuse the failure
/// instead of aligning again, and a camera that moves gets a fresh attempt.
#[test]
fn a_failure_seen_again_from_a_still_camera_is_not_recomputed() {
    let (mut map, [box_id, ..]) = mapped_scene();
    let jumped = Isometry3::translation(BOX_CENTRE.x + 0.5, BOX_CENTRE.y - 0.1, BOX_CENTRE.z);
    let shapes = scene(jumped);
    let still = views()[0];
    let nudged = Isometry3::translation(0.05, 0.0, 0.0) * still;
    let mut reports = Vec::new();
    for pose in [still, still, still, still, nudged] {
        let frame = OwnedFrame::capture(&shapes, pose, k128());
        map.integrate(&frame.frame()).unwrap();
        let report = tracking_of(&map, box_id).expect("the box disagrees with every frame");
        assert_eq!(report.trigger, mapper::TrackingTrigger::Residual);
        assert!(
            matches!(report.outcome, TrackingOutcome::Failed(_)),
            "{report:?}"
        );
        reports.push(report);
    }
    let repeated: Vec<bool> = reports.iter().map(|r| r.repeated).collect();
    assert!(!repeated[0] && !repeated[4], "{reports:?}");
    assert!(
        repeated[3],
        "the settled view was aligned again: {reports:?}"
    );
    for pair in reports.windows(2).filter(|pair| pair[1].repeated) {
        assert_eq!(pair[1].outcome, pair[0].outcome, "{reports:?}");
    }
}

/// A picked-up object: while held the map neither expects it where it was
/// nor forgets it, however long the robot looks at the empty spot; released
/// elsewhere with the hand's motion, it is drawn where it now stands and
/// keeps its labels.
#[test]
fn a_held_object_survives_being_out_of_sight_and_returns_where_it_was_put() {
    let (mut map, [box_id, ..]) = mapped_scene();
    map.record_interaction(box_id, mapper::Affordance::PickUp, mapper::Outcome::Success)
        .unwrap();
    map.hold(box_id).unwrap();
    let empty: Vec<Shape> = std::iter::once(floor()).chain(statics()).collect();
    let views = views();
    for round in 0..3 {
        for pose in &views {
            let frame = OwnedFrame::capture(&empty, *pose, k128());
            let owner = map.integrate(&frame.frame()).unwrap();
            assert!(
                !owner.contains(&box_id.0),
                "round {round}: the held box was seen"
            );
        }
    }
    assert!(
        map.object(box_id).is_some(),
        "36 frames without it, still in the map"
    );
    let ids = map.render_ids(&views[0], &k128()).ids;
    assert!(!ids.contains(&box_id.0), "a held object is not drawn");

    // Put down 0.6 m along y, turned 90°.
    let start = Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    let put = Isometry3::from_parts(
        Translation3::new(0.0, -0.6, BOX_CENTRE.z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, std::f32::consts::FRAC_PI_2),
    );
    map.release(box_id, put * start.inverse()).unwrap();
    let mut shapes = vec![floor(), moving_box(put)];
    shapes.extend(statics());
    let frame = OwnedFrame::capture(&shapes, views[3], k128());
    let rendered = map.render_ids(&views[3], &k128()).ids;
    let (mut agree, mut mask) = (0, 0);
    for (px, &instance) in frame.ids.iter().enumerate() {
        if instance == 1 {
            mask += 1;
            agree += usize::from(rendered[px] == box_id.0);
        }
    }
    println!("released box: {agree} of {mask} pixels drawn where it stands");
    assert!(mask > 100 && agree as f32 >= 0.9 * mask as f32);
    let owner = map.integrate(&frame.frame()).unwrap();
    let seen = frame
        .ids
        .iter()
        .zip(&owner)
        .filter(|(&i, &o)| i == 1 && o == box_id.0)
        .count();
    assert!(
        seen as f32 >= 0.9 * mask as f32,
        "re-associated: {seen} of {mask}"
    );
    assert_eq!(
        map.object(box_id)
            .unwrap()
            .labels
            .label(mapper::Affordance::PickUp),
        Some(true)
    );
}

/// A held box put down out of view, with the hand's motion: tracking finds
/// nothing where it was put, which says nothing against the motion, so it
/// stays there, drawn where it stands, and keeps its id when seen.
#[test]
fn an_object_put_down_out_of_view_stays_where_it_was_put() {
    let (mut map, [box_id, ..]) = mapped_scene();
    map.hold(box_id).unwrap();
    let start = Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    let put = Isometry3::translation(0.0, -0.6, BOX_CENTRE.z);
    map.release(box_id, put * start.inverse()).unwrap();
    let mut shapes = vec![floor(), moving_box(put)];
    shapes.extend(statics());
    let away = look_at(Point3::new(0.0, 1.5, 1.1), Point3::new(0.0, 3.0, 0.2));
    let frame = OwnedFrame::capture(&shapes, away, k128());
    assert!(!frame.ids.contains(&1), "the box is out of view");
    map.integrate(&frame.frame()).unwrap();
    let report = tracking_of(&map, box_id).expect("tracked after release");
    assert!(
        matches!(
            report.outcome,
            TrackingOutcome::Failed(TrackingFailure::NoSegment)
        ),
        "{report:?}"
    );
    assert_eq!(
        map.object(box_id).map(|o| o.whereabouts),
        Some(Whereabouts::Placed)
    );
    let views = views();
    let frame = OwnedFrame::capture(&shapes, views[9], k128());
    let rendered = map.render_ids(&views[9], &k128()).ids;
    let owner = map.integrate(&frame.frame()).unwrap();
    let (mut mask, mut drawn, mut seen) = (0, 0, 0);
    for (px, &instance) in frame.ids.iter().enumerate() {
        if instance == 1 {
            mask += 1;
            drawn += usize::from(rendered[px] == box_id.0);
            seen += usize::from(owner[px] == box_id.0);
        }
    }
    eprintln!("put down out of view: {drawn} of {mask} px drawn, {seen} seen with its id");
    assert!(mask > 100 && drawn as f32 >= 0.9 * mask as f32);
    assert!(seen as f32 >= 0.9 * mask as f32);
}

/// A still object whose model shows more than the frame does (here a panel
/// in front of the box, part of the same instance while it was mapped, then
/// gone; in a room, the rim of an opening seen through, a part never seen
/// from here) disagrees with the frame, and alignment finds no pose that
/// fits better than where it stands. It keeps its id and its pixels, which
/// clear the ghost, and no new object is made of them: released, they became
/// a new object every frame, hidden from the next frame's association behind
/// the ghost (10 cm in front of the box, too near it to be carved by others'
/// pixels).
#[test]
fn a_still_object_that_disagrees_keeps_its_pixels_and_spawns_nothing() {
    let start = Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    let panel = Shape::Box {
        t_world_box: Isometry3::translation(0.3, 0.0, 0.25),
        half: Vector3::new(0.01, 0.3, 0.25),
        id: 1,
    };
    let mut with_panel = scene(start);
    with_panel.push(panel);
    let mut map = Map::new(MapConfig::default());
    for pose in views() {
        map.integrate(&OwnedFrame::capture(&with_panel, pose, k128()).frame())
            .unwrap();
    }
    let objects_before = map.objects().len();
    let view = views()[0];
    let frame = OwnedFrame::capture(&scene(start), view, k128());
    let box_id = {
        let rendered = map.render_ids(&view, &k128());
        let mut votes = std::collections::BTreeMap::new();
        for (px, &instance) in frame.ids.iter().enumerate() {
            if instance == 1 && rendered.ids[px] != 0 {
                *votes.entry(rendered.ids[px]).or_insert(0) += 1;
            }
        }
        ObjectId(votes.into_iter().max_by_key(|(_, n)| *n).unwrap().0)
    };
    let pose_before = map.object(box_id).unwrap().t_world_object;
    let mut disagreed = false;
    for _ in 0..6 {
        let owner = map.integrate(&frame.frame()).unwrap();
        disagreed |= map
            .last_tracking()
            .iter()
            .any(|r| r.object == box_id && r.trigger == mapper::TrackingTrigger::Residual);
        let box_pixels = frame.ids.iter().filter(|&&i| i == 1).count();
        let kept = frame
            .ids
            .iter()
            .zip(&owner)
            .filter(|&(&i, &o)| i == 1 && o == box_id.0)
            .count();
        assert!(
            kept * 10 >= box_pixels * 9,
            "the box kept {kept} of its {box_pixels} pixels: {:?}",
            map.last_tracking()
        );
    }
    assert!(disagreed, "the box never disagreed with the map");
    assert_eq!(
        map.objects().len(),
        objects_before,
        "new objects: {:?}",
        map.objects().keys().collect::<Vec<_>>()
    );
    let pose = map.object(box_id).unwrap().t_world_object;
    let (deg, m) = pose_error(&pose, &pose_before);
    assert!(deg < 1.0 && m < 0.01, "the still box moved {m} m, {deg}°");
}

/// `shapes` on the floor.
fn with_floor(mut shapes: Vec<Shape>) -> Vec<Shape> {
    shapes.push(floor());
    shapes
}

fn k64() -> Intrinsics {
    Intrinsics::from_fov(64, 64, 90.0)
}

/// A chair of boxes (seat, back, four legs; one instance) standing at
/// `t_world_chair` (origin on the floor under the seat's centre).
fn chair(t_world_chair: Pose) -> Vec<Shape> {
    let part = |x: f32, y: f32, z: f32, half: Vector3<f32>| Shape::Box {
        t_world_box: t_world_chair * Isometry3::translation(x, y, z),
        half,
        id: 1,
    };
    let leg = Vector3::new(0.02, 0.02, 0.22);
    vec![
        part(0.0, 0.0, 0.46, Vector3::new(0.22, 0.22, 0.02)),
        part(0.0, 0.2, 0.75, Vector3::new(0.22, 0.02, 0.28)),
        part(-0.19, -0.19, 0.22, leg),
        part(0.19, -0.19, 0.22, leg),
        part(-0.19, 0.19, 0.22, leg),
        part(0.19, 0.19, 0.22, leg),
    ]
}

/// Mapped from all round, then pushed 18 cm while turning 5° and seen from
/// the front at 64 px (100 pixels of seat, back and legs): tracking follows
/// it on the floor. A free alignment lifted it 7 cm and tilted it 3° here
/// (printed for comparison), and tilted pushed chairs by 10° and 18.6° in
/// `ours` episodes where the simulator's chair tilted 2.5°.
#[test]
fn a_pushed_chair_seen_from_the_front_slides_on_the_floor() {
    let seat_centre = Point3::new(0.0, 0.0, 0.46);
    let push = Isometry3::from_parts(
        Translation3::new(0.05, -0.17, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 5f32.to_radians()),
    );
    let track = |config: MapConfig| {
        let mut map = Map::new(config);
        let k = k64();
        let standing = with_floor(chair(Isometry3::identity()));
        for pose in orbit(Point3::new(0.0, 0.0, 0.4), 1.8, 1.2, 36) {
            map.integrate(&OwnedFrame::capture(&standing, pose, k).frame())
                .unwrap();
        }
        assert_eq!(map.objects().len(), 1, "one chair");
        let id = *map.objects().keys().next().unwrap();
        let before = map.object(id).unwrap().t_world_object;
        map.notify_moved(id, None).unwrap();
        let view = look_at(Point3::new(0.3, -2.0, 0.8), Point3::new(0.0, -0.2, 0.3));
        let frame = OwnedFrame::capture(&with_floor(chair(push)), view, k);
        map.integrate(&frame.frame()).unwrap();
        let after = map.object(id).unwrap().t_world_object;
        let (rotation_deg, _) = pose_error(&(push * before), &after);
        let centre_error = after * (before.inverse() * seat_centre) - push * seat_centre;
        eprintln!(
            "world up {:?}: {} px, {:?}; seat centre off by {centre_error:?}, rotation off by {rotation_deg:.2} deg",
            config.tracking.world_up,
            frame.ids.iter().filter(|&&i| i == 1).count(),
            map.last_tracking()
        );
        let report = tracking_of(&map, id).expect("the notified chair was tracked");
        (report.outcome, centre_error, rotation_deg)
    };
    let mut free = MapConfig::default();
    free.tracking.world_up = None;
    track(free);
    let (outcome, centre_error, rotation_deg) = track(MapConfig::default());
    assert!(
        matches!(outcome, TrackingOutcome::Moved { .. }),
        "{outcome:?}"
    );
    assert!(
        centre_error.norm() < 0.02 && rotation_deg < 1.0,
        "seat centre off by {centre_error:?}, rotation by {rotation_deg} deg"
    );
}

/// A box the robot pushed that tipped onto an edge (turned 20° about the
/// bottom edge): no motion on the floor fits it, so tracking falls back to
/// any motion and follows the tilt.
#[test]
fn a_pushed_box_that_tipped_is_followed_by_a_free_alignment() {
    let (mut map, [box_id, ..]) = mapped_scene();
    let before = map.object(box_id).unwrap().t_world_object;
    // Box half extents (0.2, 0.15, 0.15) at BOX_CENTRE: its bottom edge
    // along x at y = 0.15 lies on the floor.
    let edge = Translation3::new(0.0, BOX_CENTRE.y + 0.15, 0.0);
    let tip =
        edge * UnitQuaternion::from_euler_angles(20f32.to_radians(), 0.0, 0.0) * edge.inverse();
    let tipped =
        Isometry3::from(tip) * Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    map.notify_moved(box_id, None).unwrap();
    let frame = OwnedFrame::capture(&scene(tipped), views()[9], k128());
    map.integrate(&frame.frame()).unwrap();
    let report = tracking_of(&map, box_id);
    let after = map.object(box_id).unwrap().t_world_object;
    let (rotation_deg, translation_m) = pose_error(&(Isometry3::from(tip) * before), &after);
    eprintln!("{report:?}: error {translation_m:.4} m, {rotation_deg:.2} deg");
    assert!(
        matches!(
            report.map(|r| r.outcome),
            Some(TrackingOutcome::Moved { .. })
        ),
        "{report:?}"
    );
    assert!(
        translation_m < 0.01 && rotation_deg < 1.0,
        "error {translation_m} m, {rotation_deg} deg"
    );
}

/// A push slides an object far, beyond the gate of unannounced motion.
/// Told the push's direction, the map follows a box pushed a metre away
/// from the camera and turned 10°; told only that it moved, tracking
/// reports the motion beyond its gate, and told a direction across the
/// motion, that no segment lies within its reach: then the box is lost and
/// found again where it landed, with its id. Told a direction that is not a
/// number, it acts as if told none.
#[test]
fn a_box_pushed_a_metre_is_followed_along_the_push() {
    let view = views()[3];
    let forward = view.rotation * Vector3::z();
    let push = Vector3::new(forward.x, forward.y, 0.0).normalize();
    let pushed = Isometry3::from_parts(
        Translation3::from(BOX_CENTRE.coords + push),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 10f32.to_radians()),
    );
    let frame = OwnedFrame::capture(&scene(pushed), view, k128());
    let across = Vector3::z().cross(&push);
    for (told, along_push) in [(Some(push), true), (None, false), (Some(across), false)] {
        let (mut map, [box_id, ..]) = mapped_scene();
        let before = map.object(box_id).unwrap().t_world_object;
        match told {
            Some(direction) => map.notify_pushed(box_id, direction).unwrap(),
            None => map.notify_moved(box_id, None).unwrap(),
        }
        map.integrate(&frame.frame()).unwrap();
        let report = tracking_of(&map, box_id).expect("the pushed box was tracked");
        let after = map.object(box_id).unwrap().t_world_object;
        // The model's frame moved as the box did: followed along the push,
        // or lost to tracking and found again where it landed.
        let what = format!("pushed a metre, told {told:?}");
        assert_box_found_at(&pushed, &before, &after, &what);
        assert_eq!(map.objects().len(), 3, "no new object for the box");
        if along_push {
            assert!(
                matches!(report.outcome, TrackingOutcome::Moved { .. }),
                "{report:?}"
            );
        } else {
            assert!(
                matches!(
                    report.outcome,
                    TrackingOutcome::Failed(
                        TrackingFailure::BeyondGate { .. } | TrackingFailure::NoSegment
                    )
                ),
                "told {told:?}: {report:?}"
            );
        }
    }
    // A direction that is not a number is no direction.
    let outcome_when_told = |direction: Option<Vector3<f32>>| {
        let (mut map, [box_id, ..]) = mapped_scene();
        match direction {
            Some(direction) => map.notify_pushed(box_id, direction).unwrap(),
            None => map.notify_moved(box_id, None).unwrap(),
        }
        map.integrate(&frame.frame()).unwrap();
        tracking_of(&map, box_id).expect("tracked").outcome
    };
    assert_eq!(
        outcome_when_told(Some(Vector3::new(f32::NAN, 1.0, 0.0))),
        outcome_when_told(None)
    );
}

/// A pushed box that slid out of view is lost to tracking, and neither
/// expected where it was nor forgotten. A smaller cube that appears meanwhile
/// is not taken for it; when the box comes into view again, 1.2 m from
/// where it was and turned 90°, it is found again with its id and labels.
#[test]
fn a_box_pushed_out_of_view_is_found_again_and_nothing_else_is_taken_for_it() {
    let (mut map, [box_id, ..]) = mapped_scene();
    let labels = mapper::ObjectLabels::default();
    map.record_interaction(box_id, mapper::Affordance::Push, mapper::Outcome::Success)
        .unwrap();
    let before = map.object(box_id).unwrap().clone();
    map.notify_pushed(box_id, Vector3::new(0.0, -1.0, 0.0))
        .unwrap();
    let cube = Shape::Box {
        t_world_box: Isometry3::translation(0.1, 0.7, 0.1),
        half: Vector3::new(0.1, 0.1, 0.1),
        id: 4,
    };
    let without_box: Vec<Shape> = [floor(), cube].into_iter().chain(statics()).collect();
    let views = views();
    let mut cube_id = None;
    for pose in &views {
        let frame = OwnedFrame::capture(&without_box, *pose, k128());
        let owner = map.integrate(&frame.frame()).unwrap();
        assert!(!owner.contains(&box_id.0), "the lost box was seen");
        for (px, &instance) in frame.ids.iter().enumerate() {
            if instance == 4 && owner[px] != 0 {
                cube_id.get_or_insert(ObjectId(owner[px]));
            }
        }
    }
    let cube_id = cube_id.expect("the cube became an object");
    assert_ne!(cube_id, box_id, "the cube was taken for the lost box");
    assert_eq!(
        map.object(box_id).map(|o| o.whereabouts),
        Some(Whereabouts::Lost)
    );

    let landed = Isometry3::from_parts(
        Translation3::new(0.0, -1.2, BOX_CENTRE.z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, std::f32::consts::FRAC_PI_2),
    );
    let mut shapes = vec![floor(), moving_box(landed), cube];
    shapes.extend(statics());
    let mut seen = 0;
    for pose in &views[..4] {
        let frame = OwnedFrame::capture(&shapes, *pose, k128());
        let owner = map.integrate(&frame.frame()).unwrap();
        seen += frame
            .ids
            .iter()
            .zip(&owner)
            .filter(|(&i, &o)| i == 1 && o == box_id.0)
            .count();
    }
    let found = map.object(box_id).expect("the box keeps its id");
    assert_eq!(found.whereabouts, Whereabouts::Placed);
    assert!(seen > 100, "{seen} pixels of the box got its id");
    assert_box_found_at(
        &landed,
        &before.t_world_object,
        &found.t_world_object,
        "found again 1.2 m away, turned 90°",
    );
    assert_ne!(found.labels, labels, "the box keeps its labels");
    assert_eq!(found.labels, before.labels);
    assert_eq!(map.objects().len(), 4, "box, sphere, static box and cube");
}

/// A chair mapped from the front only (five views at 64 px), its
/// interaction recorded, then pushed and lost: the map, the chair's id and
/// the chair as the map had it before the push.
fn chair_mapped_from_the_front_and_lost() -> (Map, ObjectId, mapper::MapObject) {
    let mut map = Map::new(MapConfig::default());
    let standing = with_floor(chair(Isometry3::identity()));
    for angle in [-120.0f32, -105.0, -90.0, -75.0, -60.0] {
        let a = angle.to_radians();
        let eye = Point3::new(1.6 * a.cos(), 1.6 * a.sin(), 1.2);
        let pose = look_at(eye, Point3::new(0.0, 0.0, 0.4));
        map.integrate(&OwnedFrame::capture(&standing, pose, k64()).frame())
            .unwrap();
    }
    assert_eq!(map.objects().len(), 1, "one chair");
    let chair_id = *map.objects().keys().next().unwrap();
    map.record_interaction(chair_id, mapper::Affordance::Push, mapper::Outcome::Success)
        .unwrap();
    let before = map.object(chair_id).unwrap().clone();
    map.notify_pushed(chair_id, Vector3::new(1.0, 0.0, 0.0))
        .unwrap();
    let away = look_at(Point3::new(0.0, -1.6, 1.2), Point3::new(-1.0, -3.0, 0.4));
    map.integrate(&OwnedFrame::capture(&with_floor(vec![]), away, k64()).frame())
        .unwrap();
    assert_eq!(
        map.object(chair_id).map(|o| o.whereabouts),
        Some(Whereabouts::Lost)
    );
    (map, chair_id, before)
}

/// Where the lost chair of [`chair_mapped_from_the_front_and_lost`] lands:
/// 1.5 m along the push.
const CHAIR_LANDED: Translation3<f32> = Translation3::new(1.5, 0.0, 0.0);

/// Looking at the landed chair's seat from `eye`.
fn at_landed_chair(eye: Point3<f32>) -> Pose {
    look_at(eye, Point3::new(1.5, 0.0, 0.4))
}

/// Integrates a view of the landed chair and returns the map id its pixels
/// got (0: none), after checking they all got one id.
fn chair_seen_from(map: &mut Map, pose: Pose) -> ObjectId {
    let frame = OwnedFrame::capture(&with_floor(chair(CHAIR_LANDED.into())), pose, k64());
    let owner = map.integrate(&frame.frame()).unwrap();
    let ids: BTreeSet<u32> = (0..owner.len())
        .filter(|&px| frame.ids[px] == 1)
        .map(|px| owner[px])
        .collect();
    eprintln!(
        "{} px of the chair seen, map ids {ids:?}",
        frame.ids.iter().filter(|&&i| i == 1).count()
    );
    assert_eq!(ids.len(), 1, "{ids:?}");
    ObjectId(ids.into_iter().next().unwrap())
}

/// Asserts that the lost chair (`before`) was found where it landed, with
/// its labels, and that `newcomer` was merged into it.
fn assert_chair_found(map: &Map, before: &mapper::MapObject, newcomer: ObjectId) {
    assert_eq!(map.current_id(newcomer), before.id, "merged into the chair");
    assert!(map.object(newcomer).is_none());
    let found = map.object(before.id).expect("the chair keeps its id");
    assert_eq!(found.whereabouts, Whereabouts::Placed);
    let truth = Isometry3::from(CHAIR_LANDED) * before.t_world_object;
    let (deg, m) = pose_error(&truth, &found.t_world_object);
    eprintln!("found {m} m, {deg} deg off");
    assert!(m < 0.03 && deg < 2.0, "found {m} m, {deg} deg off");
    assert_eq!(found.labels, before.labels);
    assert_eq!(map.objects().len(), 1, "one chair");
}

/// A lost chair first seen again far away (60 pixels, 2.5 m) fits too
/// poorly to be recognised and becomes a new object. Seen nearer, that
/// object's segment grows; at 1.6 m (132 pixels, more than 1.5 times the
/// first) it is compared with the lost chair again, fits, and is merged
/// into it: its id now stands for the chair's, and the chair stands where
/// it landed, with its labels.
#[test]
fn a_lost_chair_first_seen_far_away_is_recognised_nearer() {
    let (mut map, chair_id, before) = chair_mapped_from_the_front_and_lost();
    let front = |distance: f32| at_landed_chair(Point3::new(1.5, -distance, 1.0));
    let newcomer = chair_seen_from(&mut map, front(2.5));
    assert!(
        newcomer.0 != 0 && newcomer != chair_id,
        "seen far away, the chair became an object of its own"
    );
    assert_eq!(
        chair_seen_from(&mut map, front(2.0)),
        newcomer,
        "not yet a better view"
    );
    for distance in [1.6, 1.3] {
        assert_eq!(chair_seen_from(&mut map, front(distance)), chair_id);
    }
    assert_chair_found(&map, &before, newcomer);
}

/// A lost chair first seen again from behind, which its model never saw,
/// cannot be recognised and becomes a new object. Seen from the front, it
/// is found again; the object made from behind lies on its surface, a copy
/// of it, and is merged into it.
#[test]
fn a_copy_made_while_an_object_was_lost_is_merged_into_it_when_found() {
    let (mut map, chair_id, before) = chair_mapped_from_the_front_and_lost();
    let newcomer = chair_seen_from(&mut map, at_landed_chair(Point3::new(1.9, 1.8, 1.0)));
    assert!(
        newcomer.0 != 0 && newcomer != chair_id,
        "seen from behind, the chair became an object of its own"
    );
    for eye in [Point3::new(1.8, -1.1, 1.1), Point3::new(1.3, -1.0, 1.0)] {
        assert_eq!(chair_seen_from(&mut map, at_landed_chair(eye)), chair_id);
    }
    assert_chair_found(&map, &before, newcomer);
}

/// A lost box may come to rest higher or lower than it stood (off a table,
/// onto a shelf): found again standing 30 cm higher, on a block that was not
/// there before, turned 45°.
#[test]
fn a_lost_box_is_found_again_at_another_height() {
    let block = Shape::Box {
        t_world_box: Isometry3::translation(0.0, -0.9, 0.15),
        half: Vector3::new(0.4, 0.4, 0.15),
        id: 4,
    };
    let landed = Isometry3::from_parts(
        Translation3::new(0.0, -0.9, 0.3 + BOX_CENTRE.z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, std::f32::consts::FRAC_PI_4),
    );
    assert_lost_box_found_again(landed, &[block], "found again 30 cm higher, turned 45°");
}

/// A box pushed over out of view lies on its side when seen again: its long
/// edge now stands upright. It is found with its id, not made anew.
#[test]
fn a_lost_box_that_tipped_over_is_found_again() {
    // Turned 30° and tipped onto an end: 0.4 m tall instead of 0.3 m.
    let landed = Isometry3::from_parts(
        Translation3::new(0.1, -0.9, 0.2),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 30f32.to_radians())
            * UnitQuaternion::from_euler_angles(0.0, std::f32::consts::FRAC_PI_2, 0.0),
    );
    assert_lost_box_found_again(landed, &[], "found again tipped onto an end, turned 30°");
}

/// Maps the scene, moves the box away unannounced (lost: a frame without
/// it), then shows it standing at `landed` among `extra` shapes (present
/// since it was lost) from four views: it must be found with its id where
/// it stands, and no object made anew.
fn assert_lost_box_found_again(landed: Pose, extra: &[Shape], what: &str) {
    let (mut map, [box_id, ..]) = mapped_scene();
    let before = map.object(box_id).unwrap().clone();
    map.notify_moved(box_id, None).unwrap();
    let views = views();
    let without_box: Vec<Shape> = [floor()]
        .into_iter()
        .chain(extra.iter().copied())
        .chain(statics())
        .collect();
    let frame = OwnedFrame::capture(&without_box, views[0], k128());
    map.integrate(&frame.frame()).unwrap();
    assert_eq!(
        map.object(box_id).map(|o| o.whereabouts),
        Some(Whereabouts::Lost)
    );
    let shapes: Vec<Shape> = [moving_box(landed)]
        .into_iter()
        .chain(without_box)
        .collect();
    for pose in &views[..4] {
        let frame = OwnedFrame::capture(&shapes, *pose, k128());
        map.integrate(&frame.frame()).unwrap();
    }
    let found = map.object(box_id).expect("the box keeps its id");
    assert_eq!(found.whereabouts, Whereabouts::Placed);
    assert_box_found_at(&landed, &before.t_world_object, &found.t_world_object, what);
    assert_eq!(
        map.objects().len(),
        3 + extra.len(),
        "box, sphere, static box and the extra shapes"
    );
}

/// Two lost boxes of one size and shape both fit a box seen later: which
/// one it is cannot be told, so it becomes a new object rather than take
/// one of their labels, and both stay lost.
#[test]
fn a_segment_two_lost_objects_fit_becomes_a_new_object() {
    let twin = |id: u32, x: f32| Shape::Box {
        t_world_box: Isometry3::translation(x, 0.0, BOX_CENTRE.z),
        half: Vector3::new(0.2, 0.15, 0.15),
        id,
    };
    let (mut map, ids) = mapped::<2>(&[floor(), twin(1, -0.35), twin(2, 0.35)]);
    for id in ids {
        map.notify_moved(id, None).unwrap();
    }
    let views = views();
    let frame = OwnedFrame::capture(&[floor()], views[0], k128());
    map.integrate(&frame.frame()).unwrap();
    let lost = |map: &Map| ids.map(|id| map.object(id).map(|o| o.whereabouts));
    assert_eq!(lost(&map), [Some(Whereabouts::Lost); 2]);

    // One of them stands 1 m away, turned 90°.
    let one = Shape::Box {
        t_world_box: Isometry3::from_parts(
            Translation3::new(0.0, -1.0, BOX_CENTRE.z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f32::consts::FRAC_PI_2),
        ),
        half: Vector3::new(0.2, 0.15, 0.15),
        id: 1,
    };
    let mut seen_as = None;
    for pose in &views[..4] {
        let frame = OwnedFrame::capture(&[floor(), one], *pose, k128());
        let owner = map.integrate(&frame.frame()).unwrap();
        for (px, &instance) in frame.ids.iter().enumerate() {
            if instance == 1 && owner[px] != 0 {
                seen_as.get_or_insert(ObjectId(owner[px]));
            }
        }
    }
    let seen_as = seen_as.expect("the box became an object");
    assert!(!ids.contains(&seen_as), "taken for one of the lost twins");
    assert_eq!(lost(&map), [Some(Whereabouts::Lost); 2]);
}

/// Where frames carry classes, a lost object is looked for only in
/// segments of its class: a box of its shape but another class becomes a
/// new object; the lost box, seen again, is found.
#[test]
fn a_lost_object_is_found_only_in_its_own_class() {
    const BOX_CLASS: u16 = 7;
    // Integrates `frame` with the box's pixels of class `class_of_box`
    // (the others of their instance's), and returns the box's map id.
    let integrate_classed = |map: &mut Map, frame: &OwnedFrame, class_of_box: u16| {
        let class: Vec<u16> = frame
            .ids
            .iter()
            .map(|&i| if i == 1 { class_of_box } else { i as u16 })
            .collect();
        let owner = map
            .integrate(&Frame {
                class: Some(&class),
                ..frame.frame()
            })
            .unwrap();
        let px = frame.ids.iter().position(|&i| i == 1).unwrap();
        ObjectId(owner[px])
    };
    let start = Isometry3::translation(BOX_CENTRE.x, BOX_CENTRE.y, BOX_CENTRE.z);
    let mut map = Map::new(MapConfig::default());
    let mut box_id = None;
    for pose in views() {
        let frame = OwnedFrame::capture(&scene(start), pose, k128());
        let seen_as = integrate_classed(&mut map, &frame, BOX_CLASS);
        box_id.get_or_insert(seen_as);
    }
    let box_id = box_id.unwrap();
    assert_eq!(map.object(box_id).unwrap().class(), Some(BOX_CLASS));
    map.notify_moved(box_id, None).unwrap();
    let landed = Isometry3::translation(0.0, -1.0, BOX_CENTRE.z);
    let views = views();
    let mut ids_seen = Vec::new();
    // The same shape, first of another class, then of the box's.
    for class_of_box in [BOX_CLASS + 1, BOX_CLASS] {
        let frame = OwnedFrame::capture(&scene(landed), views[0], k128());
        ids_seen.push(integrate_classed(&mut map, &frame, class_of_box));
        if class_of_box != BOX_CLASS {
            // Gone again, so that the next frame sees a segment no object matches.
            let empty: Vec<Shape> = std::iter::once(floor()).chain(statics()).collect();
            let frame = OwnedFrame::capture(&empty, views[0], k128());
            for _ in 0..=MapConfig::default().settings.max_misses {
                map.integrate(&frame.frame()).unwrap();
            }
        }
    }
    assert_ne!(
        ids_seen[0], box_id,
        "taken for the lost box of another class"
    );
    assert_eq!(ids_seen[1], box_id, "the box of its class is found");
}
