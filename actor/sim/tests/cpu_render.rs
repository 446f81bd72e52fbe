//! The CPU ray caster against closed-form ray–box intersections, the camera
//! conventions, and a look at an imported room.

use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};
use sim::geometry::SceneGeometry;
use sim::ithor::load_scene;
use sim::raycast::{agent_camera_pose, render, Camera};
use sim::scene::{walls_around, OrientedBox, Scene, SceneObject};

fn object(id: &str, object_type: &str, bounds: OrientedBox) -> SceneObject {
    let (lo, hi) = bounds.world_aabb();
    SceneObject {
        id: id.into(),
        object_type: object_type.into(),
        position: bounds.center,
        rotation: bounds.rotation,
        bounds,
        aabb_min: lo,
        aabb_max: hi,
        mass_kg: 1.0,
        pickupable: false,
        moveable: true,
        receptacle: false,
        openable: false,
        materials: vec!["Wood".into()],
        parent_receptacles: vec![],
    }
}

/// A 4 × 4 m room with one rotated box standing on the floor.
fn room() -> (Scene, OrientedBox) {
    let floor =
        OrientedBox::axis_aligned(Point3::new(-2.0, -2.0, -0.1), Point3::new(2.0, 2.0, 0.0));
    let the_box = OrientedBox {
        center: Point3::new(0.8, 0.3, 0.25),
        rotation: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
        half_extents: Vector3::new(0.3, 0.2, 0.25),
    };
    let scene = Scene {
        name: "test".into(),
        objects: vec![
            object("Box|1", "Box", the_box),
            object("Floor|0", "Floor", floor),
        ],
        floor_min: Point2::new(-2.0, -2.0),
        floor_max: Point2::new(2.0, 2.0),
        floor_top_m: 0.0,
        walls: walls_around(Point2::new(-2.0, -2.0), Point2::new(2.0, 2.0), 0.0, 0.5),
    };
    (scene, the_box)
}

/// Entry parameter of a ray into an oriented box.
fn hit_box(o: &Point3<f32>, d: &Vector3<f32>, b: &OrientedBox) -> Option<f32> {
    let inv = b.rotation.inverse();
    let (ol, dl) = (inv * (o - b.center), inv * d);
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for a in 0..3 {
        let (ta, tb) = (
            (-b.half_extents[a] - ol[a]) / dl[a],
            (b.half_extents[a] - ol[a]) / dl[a],
        );
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 <= t1 && t0 > 0.0).then_some(t0)
}

#[test]
fn depth_and_ids_match_closed_form_intersections() {
    let (scene, the_box) = room();
    let geometry = SceneGeometry::new(&scene);
    let mut boxes: Vec<(u32, OrientedBox)> = vec![(1, the_box), (0, scene.objects[1].bounds)];
    boxes.extend(scene.walls.iter().map(|w| (0, *w)));
    let mut checked = 0;
    for (x, y, yaw, horizon) in [
        (-1.2, -0.5, 20.0, 20.0),
        (-0.5, 1.5, -50.0, 30.0),
        (1.5, -1.5, 120.0, 10.0),
    ] {
        let camera = Camera {
            t_world_camera: agent_camera_pose(x, y, 0.0, 1.5, yaw, horizon),
            width: 64,
            height: 64,
            fov_deg: 90.0,
        };
        let frame = render(&geometry, &camera, 10.0);
        let origin = camera.t_world_camera * Point3::origin();
        let mut box_pixels = 0;
        for v in 0..64 {
            for u in 0..64 {
                let r = camera.ray(u as f32, v as f32);
                let dir = camera.t_world_camera.rotation * r;
                let (t, id) = boxes
                    .iter()
                    .filter_map(|(id, b)| hit_box(&origin, &dir, b).map(|t| (t, *id)))
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .expect("the room is closed");
                let px = v * 64 + u;
                // `dir` has camera-z 1, so t is the z-depth.
                assert!(
                    (frame.depth_m[px] - t).abs() < 1e-3,
                    "depth {} vs {t} at ({u}, {v})",
                    frame.depth_m[px]
                );
                assert_eq!(frame.ids[px], id, "id at ({u}, {v})");
                box_pixels += usize::from(id == 1);
                checked += 1;
            }
        }
        assert!(box_pixels > 20, "the box should be in view");
    }
    assert_eq!(checked, 3 * 64 * 64);
}

#[test]
fn the_agent_camera_looks_where_it_says() {
    let pose = agent_camera_pose(1.0, 2.0, 0.0, 1.5, 90.0, 30.0);
    let forward = pose.rotation * Vector3::z();
    assert!(
        (forward - Vector3::new(0.0, 30f32.to_radians().cos(), -30f32.to_radians().sin())).norm()
            < 1e-5
    );
    let right = pose.rotation * Vector3::x();
    assert!(
        (right - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-5,
        "heading +y, right is +x"
    );
    assert!((pose.translation.vector - Vector3::new(1.0, 2.0, 1.5)).norm() < 1e-6);
}

#[test]
fn an_imported_room_renders_with_many_objects_in_view() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms/FloorPlan227.json");
    let scene = load_scene(&path).unwrap();
    let geometry = SceneGeometry::new(&scene);
    let centre = nalgebra::center(
        &Point3::new(scene.floor_min.x, scene.floor_min.y, 0.0),
        &Point3::new(scene.floor_max.x, scene.floor_max.y, 0.0),
    );
    let mut seen = std::collections::BTreeSet::new();
    for yaw in (0..360).step_by(30) {
        let camera = Camera {
            t_world_camera: agent_camera_pose(
                centre.x,
                centre.y,
                scene.floor_top_m,
                1.58,
                yaw as f32,
                15.0,
            ),
            width: 128,
            height: 128,
            fov_deg: 90.0,
        };
        let frame = render(&geometry, &camera, 20.0);
        assert!(
            frame.depth_m.iter().all(|&d| d > 0.0),
            "the room is closed: every ray hits something"
        );
        seen.extend(frame.ids.iter().copied().filter(|&i| i != 0));
    }
    eprintln!(
        "FloorPlan227: {} of {} objects seen from the room's centre",
        seen.len(),
        scene.objects.len()
    );
    assert!(
        seen.len() * 2 > scene.objects.len(),
        "only {} objects seen",
        seen.len()
    );
}

#[test]
fn tiles_and_nearest_first_candidates_change_no_pixel() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    let scene = load_scene(&dir.join("FloorPlan229.json")).unwrap();
    let geometry = SceneGeometry::new(&scene);
    let centre = scene.floor_min + (scene.floor_max - scene.floor_min) / 2.0;
    for (yaw, horizon) in [(0.0, 0.0), (75.0, 30.0), (200.0, -30.0), (300.0, 60.0)] {
        let camera = Camera {
            t_world_camera: agent_camera_pose(centre.x, centre.y, 0.0, 1.5, yaw, horizon),
            width: 96,
            height: 64,
            fov_deg: 90.0,
        };
        let frame = render(&geometry, &camera, 20.0);
        let origin = camera.t_world_camera * Point3::origin();
        for v in 0..camera.height {
            for u in 0..camera.width {
                let ray = camera.ray(u as f32, v as f32);
                let z_per_metre = 1.0 / ray.norm();
                let dir = camera.t_world_camera.rotation * ray.normalize();
                // Every instance in scene order, no tiles, no nearest-first.
                let expected = geometry.cast(&origin, &dir, 20.0 / z_per_metre);
                let px = v * camera.width + u;
                assert_eq!(
                    (frame.ids[px], frame.depth_m[px]),
                    expected.map_or((0, 0.0), |h| (h.1, h.0 * z_per_metre)),
                    "pixel ({u}, {v})"
                );
            }
        }
    }
}
