//! The floor-plane projections the actor's egocentric maps are made of:
//! rasterising many projections in one pass gives, plane for plane, what a
//! plain scan of the map's surface voxels gives, and the planes show what
//! they are meant to (labelled objects where they are, heights respected).

mod common;

use common::{k128, look_at, OwnedFrame, Shape};
use mapper::{Affordance, GridSpec, Map, MapConfig, Outcome, ProjectionKind};
use nalgebra::{Isometry3, Point2, Point3, Vector3};

const PICKED: u32 = 11;
const FAILED: u32 = 12;

/// A floor and a wall (the background), two labelled objects and one
/// never tried.
fn scene() -> Vec<Shape> {
    vec![
        Shape::Box {
            t_world_box: Isometry3::translation(0.0, 0.0, -0.1),
            half: Vector3::new(3.0, 3.0, 0.1),
            id: 0,
        },
        // 2.6 m high: occupancy's heights end inside its blocks' columns.
        Shape::Box {
            t_world_box: Isometry3::translation(-2.5, 0.4, 1.3),
            half: Vector3::new(0.1, 1.2, 1.3),
            id: 0,
        },
        Shape::Box {
            t_world_box: Isometry3::translation(0.0, 0.0, 0.3),
            half: Vector3::new(0.3, 0.25, 0.3),
            id: PICKED,
        },
        Shape::Sphere {
            center: Point3::new(1.0, 0.8, 0.25),
            radius: 0.25,
            id: FAILED,
        },
        Shape::Box {
            t_world_box: Isometry3::translation(-1.0, 0.9, 0.15),
            half: Vector3::new(0.15, 0.15, 0.15),
            id: 13,
        },
    ]
}

/// The map of [`scene`] seen from eight viewpoints, with the object under
/// `PICKED` labelled a pick-up success and the one under `FAILED` a failure.
fn labelled_map() -> Map {
    labelled_map_watched(|_| {})
}

/// [`labelled_map`], calling `after_each_view` on the map after each view.
fn labelled_map_watched(mut after_each_view: impl FnMut(&Map)) -> Map {
    let shapes = scene();
    let mut map = Map::new(MapConfig::default());
    let target = Point3::new(0.0, 0.4, 0.2);
    for i in 0..8 {
        let a = i as f32 / 8.0 * std::f32::consts::TAU;
        let pose = look_at(Point3::new(2.5 * a.cos(), 0.4 + 2.5 * a.sin(), 1.5), target);
        let frame = OwnedFrame::capture(&shapes, pose, k128());
        let ids = map.integrate(&frame.frame()).unwrap();
        for (instance, outcome) in [(PICKED, Outcome::Success), (FAILED, Outcome::Failure)] {
            if let Some(p) = frame.ids.iter().position(|&id| id == instance) {
                if ids[p] != 0 {
                    let id = mapper::ObjectId(ids[p]);
                    if !map.objects()[&id].labels.interacted(Affordance::PickUp) {
                        map.record_interaction(id, Affordance::PickUp, outcome)
                            .unwrap();
                    }
                }
            }
        }
        after_each_view(&map);
    }
    assert_eq!(map.objects().len(), 3, "the scene's three objects");
    map
}

/// Occupancy at two bands of heights and the three label kinds of pick-up,
/// on a world-aligned 10 m grid and on an egocentric 2 m one turned 40°.
fn requests() -> Vec<(ProjectionKind, GridSpec)> {
    let global = GridSpec {
        center: Point2::new(0.0, 0.0),
        up_heading_rad: std::f32::consts::FRAC_PI_2,
        extent_m: 10.0,
        cells: 64,
    };
    let local = GridSpec {
        center: Point2::new(0.0, 0.6),
        up_heading_rad: 40f32.to_radians(),
        extent_m: 2.0,
        cells: 48,
    };
    let kinds = [
        ProjectionKind::Occupancy {
            min_height_m: 0.05,
            max_height_m: 1.8,
        },
        ProjectionKind::Occupancy {
            min_height_m: 0.5,
            max_height_m: 1.3,
        },
        ProjectionKind::InteractedSuccess(Affordance::PickUp),
        ProjectionKind::InteractedFailure(Affordance::PickUp),
        ProjectionKind::NotInteracted(Affordance::PickUp),
    ];
    [global, local]
        .into_iter()
        .flat_map(|g| kinds.map(|k| (k, g)))
        .collect()
}

/// The plain reference: every surface voxel of the map, one request at a time.
fn reference(map: &Map, kind: ProjectionKind, grid: &GridSpec) -> Vec<f32> {
    let mut out = vec![0.0; grid.cells * grid.cells];
    let mut mark = |p: Point3<f32>| {
        if let ProjectionKind::Occupancy {
            min_height_m,
            max_height_m,
        } = kind
        {
            if p.z < min_height_m || p.z > max_height_m {
                return;
            }
        }
        if let Some(c) = grid.cell_of(p.x, p.y) {
            out[c] = 1.0;
        }
    };
    if matches!(kind, ProjectionKind::Occupancy { .. }) {
        let background = map.background();
        for (p, _) in background.near_surface_voxels(background.voxel_size_m) {
            mark(p);
        }
    }
    for object in map.objects().values().filter(|o| o.is_placed()) {
        let labels = &object.labels;
        let shown = match kind {
            ProjectionKind::Occupancy { .. } => true,
            ProjectionKind::InteractedSuccess(a) => {
                labels.interacted(a) && labels.label(a) == Some(true)
            }
            ProjectionKind::InteractedFailure(a) => {
                labels.interacted(a) && labels.label(a) == Some(false)
            }
            ProjectionKind::NotInteracted(a) => !labels.interacted(a),
        };
        if shown {
            for (p, _) in object
                .volume
                .near_surface_voxels(object.volume.voxel_size_m)
            {
                mark(object.t_world_object * p);
            }
        }
    }
    out
}

fn marked(plane: &[f32]) -> usize {
    plane.iter().filter(|&&v| v == 1.0).count()
}

#[test]
fn one_pass_over_many_projections_gives_what_a_plain_scan_gives() {
    let map = labelled_map();
    let requests = requests();
    let surface = map.surface_points();
    let planes = surface.project_all(&requests);
    assert_eq!(planes.len(), requests.len());
    for ((kind, grid), plane) in requests.iter().zip(&planes) {
        let expected = reference(&map, *kind, grid);
        assert!(marked(&expected) > 0, "{kind:?} on {grid:?} shows nothing");
        assert_eq!(plane, &expected, "{kind:?} on {grid:?}");
        assert_eq!(plane, &surface.project(*kind, grid), "{kind:?} alone");
    }
}

#[test]
fn surface_points_follow_the_map_as_it_changes() {
    // Blocks keep their surface points until their voxels change: asking
    // after every view fills those caches while later views still change
    // the blocks, so stale points would show in the final planes.
    let mut gathered = Vec::new();
    let map =
        labelled_map_watched(|map| gathered.push(map.surface_points().project_all(&requests())));
    assert_ne!(gathered[0], gathered[7], "later views changed the planes");
    let requests = requests();
    let planes = map.surface_points().project_all(&requests);
    for ((kind, grid), plane) in requests.iter().zip(&planes) {
        assert_eq!(plane, &reference(&map, *kind, grid), "{kind:?} on {grid:?}");
    }
}

#[test]
fn occupancy_follows_its_heights_from_one_call_to_the_next() {
    // Each object keeps its surface in the world for the heights it was
    // last asked with (the actor's floor is one per episode): asked with
    // other heights, it must not answer with the kept ones.
    let map = labelled_map();
    let grid = requests()[0].1;
    let mut planes = Vec::new();
    for (min_height_m, max_height_m) in [(0.05, 1.8), (0.4, 0.45), (0.05, 1.8)] {
        let kind = ProjectionKind::Occupancy {
            min_height_m,
            max_height_m,
        };
        let plane = map.surface_points().project(kind, &grid);
        assert_eq!(plane, reference(&map, kind, &grid), "{kind:?}");
        planes.push(plane);
    }
    assert_ne!(planes[0], planes[1], "the heights change the plane");
}

#[test]
fn surface_points_follow_an_object_moved_held_and_put_back() {
    // Ask once (filling the blocks' kept points), then move one object,
    // hold another (no longer placed, so not shown), release it elsewhere,
    // and compare each time with the plain scan.
    let mut map = labelled_map();
    let requests = requests();
    let check = |map: &Map, when: &str| {
        let planes = map.surface_points().project_all(&requests);
        for ((kind, grid), plane) in requests.iter().zip(&planes) {
            assert_eq!(
                plane,
                &reference(map, *kind, grid),
                "{when}: {kind:?} on {grid:?}"
            );
        }
        planes
    };
    let before = check(&map, "as mapped");
    let ids: Vec<mapper::ObjectId> = map.objects().keys().copied().collect();
    let (moved, held) = (ids[0], ids[1]);
    let pose = map.objects()[&moved].t_world_object;
    map.set_object_pose(moved, Isometry3::translation(0.6, -0.4, 0.0) * pose)
        .unwrap();
    let after_move = check(&map, "one object moved");
    assert_ne!(after_move, before, "the move shows in the planes");
    // Turned about z and lifted (a voxel column's points share a cell, and
    // their heights are their own plus the lift), then tilted (neither).
    let turned = Isometry3::new(Vector3::new(0.1, 0.2, 0.03), Vector3::z() * 0.7);
    map.set_object_pose(moved, turned * pose).unwrap();
    check(&map, "turned about z");
    map.hold(held).unwrap();
    check(&map, "another held");
    let tilted = Isometry3::new(Vector3::new(-0.5, 0.0, 0.1), Vector3::new(0.3, -0.2, 0.5));
    map.release(held, tilted).unwrap();
    check(&map, "released elsewhere, tilted");
}

#[test]
fn label_planes_show_each_object_where_it_stands_and_occupancy_respects_heights() {
    let map = labelled_map();
    let grid = GridSpec {
        center: Point2::new(0.0, 0.0),
        up_heading_rad: std::f32::consts::FRAC_PI_2,
        extent_m: 4.0,
        cells: 40,
    };
    let planes = map.surface_points().project_all(&[
        (ProjectionKind::InteractedSuccess(Affordance::PickUp), grid),
        (ProjectionKind::InteractedFailure(Affordance::PickUp), grid),
        (ProjectionKind::NotInteracted(Affordance::PickUp), grid),
        (
            ProjectionKind::Occupancy {
                min_height_m: 0.05,
                max_height_m: 1.8,
            },
            grid,
        ),
        (
            ProjectionKind::Occupancy {
                min_height_m: 2.0,
                max_height_m: 3.0,
            },
            grid,
        ),
    ]);
    // Cells 0.1 m wide, row 0 towards +y: the cell of (x, y).
    let cell = |x: f32, y: f32| grid.cell_of(x, y).unwrap();
    let [success, failure, untried, occupancy, above] = &planes[..] else {
        unreachable!()
    };
    assert_eq!(success[cell(0.0, 0.0)], 1.0, "the picked box's centre");
    assert_eq!(failure[cell(0.0, 0.0)], 0.0);
    assert_eq!(failure[cell(1.0, 0.8)], 1.0, "the failed sphere's centre");
    assert_eq!(untried[cell(-1.0, 0.9)], 1.0, "the untried box's centre");
    assert_eq!(untried[cell(0.0, 0.0)], 0.0);
    for (x, y) in [(0.0, 0.0), (1.0, 0.8), (-1.0, 0.9)] {
        assert_eq!(occupancy[cell(x, y)], 1.0, "occupancy at ({x}, {y})");
    }
    assert_eq!(
        occupancy[cell(1.8, -1.8)],
        0.0,
        "bare floor lies below 5 cm"
    );
    assert_eq!(marked(above), 0, "nothing stands 2 to 3 m high");
    // Each label plane holds one object only: nothing far from it.
    let far = |plane: &[f32], x: f32, y: f32| {
        (0..plane.len()).filter(|&c| plane[c] == 1.0).all(|c| {
            let (row, col) = (c / grid.cells, c % grid.cells);
            let (cx, cy) = (col as f32 * 0.1 - 2.0 + 0.05, 2.0 - row as f32 * 0.1 - 0.05);
            (cx - x).hypot(cy - y) < 0.6
        })
    };
    assert!(
        far(success, 0.0, 0.0),
        "success cells away from the picked box"
    );
    assert!(far(failure, 1.0, 0.8), "failure cells away from the sphere");
}
