//! Procedural living rooms, seeded: a rectangular room of iTHOR-like size
//! furnished from a [`Catalogue`] with the same statistics as the iTHOR
//! living rooms (which types appear, how many, their sizes and masses) and
//! the same kinds of placement: furniture on the floor (large pieces with
//! their back to a wall), pictures and windows on the walls, small objects
//! dropped onto receptacles by the physics so that they rest on real
//! surfaces. Nothing interpenetrates and the agent always has room to move.

use std::ops::Range;

use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use crate::catalogue::{Catalogue, CatalogueEntry, Placement};
use crate::physics::{deepest_penetration, simulate_drop};
use crate::profile::RobotProfile;
use crate::randomise::{reachable_grid, release_above, MAX_PENETRATION_M};
use crate::scene::{walls_around, OrientedBox, Scene, SceneObject};

/// Room width and depth ranges, metres (iTHOR living rooms: about 4–9 m).
const ROOM_X_M: Range<f32> = 4.5..8.5;
const ROOM_Y_M: Range<f32> = 3.5..6.5;
/// Gap kept between pieces of furniture on the floor, metres.
const FLOOR_GAP_M: f32 = 0.05;
/// Attempts to place one object before giving up on it.
const ATTEMPTS: usize = 20;
/// Least fraction of the floor grid the agent must be able to reach.
const MIN_REACHABLE: f32 = 0.25;
/// Types that stand with their back to a wall.
const AGAINST_WALL: [&str; 7] = [
    "Sofa",
    "Dresser",
    "TVStand",
    "ShelvingUnit",
    "Desk",
    "Cabinet",
    "ArmChair",
];

/// Seed ranges of the generated scene sets (disjoint, like the iTHOR split).
pub const TRAIN_SEEDS: Range<u64> = 0..1_000_000;
/// Validation seeds.
pub const VAL_SEEDS: Range<u64> = 1_000_000..1_000_100;
/// Test seeds.
pub const TEST_SEEDS: Range<u64> = 2_000_000..2_000_100;

/// Materials that give generated objects their appearance, by type.
fn materials(object_type: &str) -> Vec<String> {
    let m: &[&str] = match object_type {
        "Sofa" | "ArmChair" | "Ottoman" | "Pillow" | "DogBed" | "Curtains" => &["Fabric"],
        "Chair" | "CoffeeTable" | "SideTable" | "DiningTable" | "Desk" | "Dresser" | "TVStand"
        | "ShelvingUnit" | "Stool" | "Cabinet" => &["Wood", "Metal"],
        "Vase" | "Bowl" | "Plate" | "Statue" => &["Ceramic"],
        "Laptop" | "Television" | "CellPhone" | "RemoteControl" => &["Plastic", "Metal"],
        "Book" | "Newspaper" | "Box" | "TissueBox" => &["Paper"],
        "HousePlant" => &["Organic", "Ceramic"],
        "Window" | "Mirror" => &["Glass", "Wood"],
        "Candle" => &["Wax"],
        "FloorLamp" | "DeskLamp" | "Safe" | "GarbageCan" | "WateringCan" | "KeyChain" | "Watch" => {
            &["Metal"]
        }
        _ => &[],
    };
    m.iter().map(|s| s.to_string()).collect()
}

/// Generates the room for `seed`. Deterministic: the same catalogue and
/// seed give the same scene.
pub fn generate(catalogue: &Catalogue, seed: u64, profile: &RobotProfile) -> Scene {
    let mut rng = StdRng::seed_from_u64(seed);
    let (w, d) = (rng.random_range(ROOM_X_M), rng.random_range(ROOM_Y_M));
    let (floor_min, floor_max) = (Point2::new(0.0, 0.0), Point2::new(w, d));
    let floor_box = OrientedBox::axis_aligned(Point3::new(0.0, 0.0, -0.1), Point3::new(w, d, 0.0));
    let mut scene = Scene {
        name: format!("Generated{seed}"),
        objects: vec![structural_floor(floor_box)],
        floor_min,
        floor_max,
        floor_top_m: 0.0,
        walls: walls_around(floor_min, floor_max, 0.0, 2.5),
    };

    // Decide what the room holds.
    let mut floor_items = Vec::new();
    let mut wall_items = Vec::new();
    let mut surface_items = Vec::new();
    for entry in &catalogue.entries {
        if !rng.random_bool(f64::from(entry.presence.clamp(0.0, 1.0))) {
            continue;
        }
        let jitter = rng.random_range(0.6..1.4f32);
        let count = (entry.mean_count * jitter).round().max(1.0) as usize;
        for _ in 0..count {
            let size = sample_size(entry, &mut rng);
            let on_floor = match entry.placement {
                Placement::Floor => Some(true),
                Placement::Surface => Some(false),
                Placement::Wall => None,
                Placement::FloorOrSurface { floor_share } => {
                    Some(rng.random_bool(f64::from(floor_share.clamp(0.0, 1.0))))
                }
            };
            match on_floor {
                Some(true) => floor_items.push((entry, size)),
                Some(false) => surface_items.push((entry, size)),
                None => wall_items.push((entry, size)),
            }
        }
    }
    // Largest furniture first, so it finds room.
    floor_items.sort_by(|a, b| (b.1.x * b.1.y).total_cmp(&(a.1.x * a.1.y)));

    let standing = floor_items.into_iter().map(|(e, s)| (e, s, false));
    let hanging = wall_items.into_iter().map(|(e, s)| (e, s, true));
    for (entry, size, on_wall) in standing.chain(hanging) {
        for _ in 0..ATTEMPTS {
            let bounds = if on_wall {
                wall_pose(entry, size, &scene, &mut rng)
            } else {
                floor_pose(entry, size, &scene, &mut rng)
            };
            if fits_on_floor(&scene, &bounds) {
                let object = make_object(&scene, entry, bounds, &mut rng);
                scene.objects.push(object);
                if !on_wall && !leaves_room_to_move(&scene, profile) {
                    scene.objects.pop();
                }
                break;
            }
        }
    }
    for (entry, size) in surface_items {
        place_on_surface(&mut scene, entry, size, &mut rng);
    }
    scene
}

fn structural_floor(bounds: OrientedBox) -> SceneObject {
    let (aabb_min, aabb_max) = bounds.world_aabb();
    SceneObject {
        id: "Floor|0".into(),
        object_type: "Floor".into(),
        position: bounds.center,
        rotation: bounds.rotation,
        bounds,
        aabb_min,
        aabb_max,
        mass_kg: 0.0,
        pickupable: false,
        moveable: false,
        receptacle: true,
        openable: false,
        materials: vec![],
        parent_receptacles: vec![],
    }
}

/// A size within the type's range, around its typical size.
fn sample_size(entry: &CatalogueEntry, rng: &mut StdRng) -> Vector3<f32> {
    let scale = rng.random_range(0.85..1.15f32);
    Vector3::from_fn(|axis, _| {
        let (lo, hi) = (entry.size_min_m[axis], entry.size_max_m[axis]);
        (entry.size_m[axis] * scale).clamp(lo.min(hi), hi.max(lo))
    })
}

/// A box of `size` (width along the box's x, depth along y) standing on the
/// floor: against a wall, facing into the room, for [`AGAINST_WALL`] types;
/// anywhere with a random quarter turn for the rest.
fn floor_pose(
    entry: &CatalogueEntry,
    size: Vector3<f32>,
    scene: &Scene,
    rng: &mut StdRng,
) -> OrientedBox {
    let half = size / 2.0;
    let (lo, hi) = (scene.floor_min, scene.floor_max);
    let (yaw, x, y) = if AGAINST_WALL.contains(&entry.object_type.as_str()) {
        // The box's +y (its back) goes to the wall.
        against_wall(scene, half, 0.02, 0.0, rng)
    } else {
        let yaw = 90.0 * rng.random_range(0..4) as f32 + rng.random_range(-10.0..10.0f32);
        let r = half.x.max(half.y);
        let pick =
            |a: f32, b: f32, rng: &mut StdRng| rng.random_range(a + r..(b - r).max(a + r + 1e-3));
        (yaw, pick(lo.x, hi.x, rng), pick(lo.y, hi.y, rng))
    };
    OrientedBox {
        center: Point3::new(x, y, scene.floor_top_m + half.z + 0.001),
        rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw.to_radians()),
        half_extents: half,
    }
}

/// Yaw (degrees) and floor position of a box with half extents `half`
/// whose +y side faces a random wall `gap` away from it, at a random place
/// along that wall at least `margin` from the corners.
fn against_wall(
    scene: &Scene,
    half: Vector3<f32>,
    gap: f32,
    margin: f32,
    rng: &mut StdRng,
) -> (f32, f32, f32) {
    let (lo, hi) = (scene.floor_min, scene.floor_max);
    let wall = rng.random_range(0..4);
    let mut along = |a: f32, b: f32| {
        let (from, to) = (a + half.x + margin, b - half.x - margin);
        rng.random_range(from..to.max(from + 1e-3))
    };
    match wall {
        0 => (0.0, along(lo.x, hi.x), hi.y - half.y - gap),
        1 => (180.0, along(lo.x, hi.x), lo.y + half.y + gap),
        2 => (90.0, lo.x + half.y + gap, along(lo.y, hi.y)),
        _ => (-90.0, hi.x - half.y - gap, along(lo.y, hi.y)),
    }
}

/// A box of `size` flat against a random wall (its depth along the box's
/// y, out of the wall) at the height the type hangs at.
fn wall_pose(
    entry: &CatalogueEntry,
    size: Vector3<f32>,
    scene: &Scene,
    rng: &mut StdRng,
) -> OrientedBox {
    let half = size / 2.0;
    let centre_height = match entry.object_type.as_str() {
        "LightSwitch" => 1.2,
        "Curtains" => half.z + 0.05,
        "Window" | "Blinds" => (1.45f32).max(half.z + 0.4),
        _ => (1.5f32).max(half.z + 0.9),
    };
    let (yaw, x, y) = against_wall(scene, half, 0.002, 0.1, rng);
    OrientedBox {
        center: Point3::new(x, y, scene.floor_top_m + centre_height),
        rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw.to_radians()),
        half_extents: half,
    }
}

/// True if `bounds` lies inside the room and clear (by [`FLOOR_GAP_M`]) of
/// every object's box but the floor.
fn fits_on_floor(scene: &Scene, bounds: &OrientedBox) -> bool {
    let (lo, hi) = bounds.world_aabb();
    let inside = lo.x >= scene.floor_min.x - 1e-3
        && lo.y >= scene.floor_min.y - 1e-3
        && hi.x <= scene.floor_max.x + 1e-3
        && hi.y <= scene.floor_max.y + 1e-3;
    inside
        && scene.objects.iter().skip(1).all(|o| {
            (0..3)
                .any(|a| o.aabb_max[a] + FLOOR_GAP_M < lo[a] || o.aabb_min[a] - FLOOR_GAP_M > hi[a])
        })
}

/// True if the agent can still reach at least [`MIN_REACHABLE`] of the floor grid.
fn leaves_room_to_move(scene: &Scene, profile: &RobotProfile) -> bool {
    let cells = ((scene.floor_max.x - scene.floor_min.x) / 0.25 + 1.0).floor()
        * ((scene.floor_max.y - scene.floor_min.y) / 0.25 + 1.0).floor();
    reachable_grid(scene, profile).is_ok_and(|r| r.len() as f32 >= MIN_REACHABLE * cells)
}

/// Drops a small object onto a random receptacle (pillows prefer seats);
/// keeps it only if it comes to rest inside the room touching nothing.
fn place_on_surface(
    scene: &mut Scene,
    entry: &CatalogueEntry,
    size: Vector3<f32>,
    rng: &mut StdRng,
) {
    let supports: Vec<usize> = (1..scene.objects.len())
        .filter(|&i| scene.objects[i].receptacle && !scene.objects[i].pickupable)
        .collect();
    let seats: Vec<usize> = supports
        .iter()
        .copied()
        .filter(|&i| matches!(scene.objects[i].object_type.as_str(), "Sofa" | "ArmChair"))
        .collect();
    let pool = if entry.object_type == "Pillow" && !seats.is_empty() {
        seats
    } else {
        supports
    };
    if pool.is_empty() {
        return;
    }
    let template = OrientedBox {
        center: Point3::origin(),
        rotation: UnitQuaternion::identity(),
        half_extents: size / 2.0,
    };
    for _ in 0..ATTEMPTS / 4 {
        let support = pool[rng.random_range(0..pool.len())];
        let Some(release) = release_above(&scene.objects[support].bounds, &template, rng) else {
            continue;
        };
        let mut object = make_object(scene, entry, release, rng);
        object.parent_receptacles = vec![scene.objects[support].id.clone()];
        scene.objects.push(object);
        let index = scene.objects.len() - 1;
        let rest = simulate_drop(scene, index, &release);
        scene.objects[index].move_to(rest);
        let (lo, hi) = rest.world_aabb();
        let footprint = scene.objects[support].bounds;
        let local = footprint.rotation.inverse() * (rest.center - footprint.center);
        let on_support = local.x.abs() <= footprint.half_extents.x
            && local.y.abs() <= footprint.half_extents.y
            && local.z > 0.0;
        let inside = lo.x >= scene.floor_min.x
            && lo.y >= scene.floor_min.y
            && hi.x <= scene.floor_max.x
            && hi.y <= scene.floor_max.y;
        if on_support && inside && deepest_penetration(scene, index) <= MAX_PENETRATION_M {
            return;
        }
        scene.objects.pop();
    }
}

/// A new instance of `entry` with box `bounds`; mixed flags drawn per instance.
fn make_object(
    scene: &Scene,
    entry: &CatalogueEntry,
    bounds: OrientedBox,
    rng: &mut StdRng,
) -> SceneObject {
    let number = scene
        .objects
        .iter()
        .filter(|o| o.object_type == entry.object_type)
        .count();
    let mut draw = |p: f32| rng.random_bool(f64::from(p.clamp(0.0, 1.0)));
    let pickupable = draw(entry.pickupable);
    let moveable = !pickupable && draw(entry.moveable);
    let receptacle = draw(entry.receptacle);
    let mut object = SceneObject {
        id: format!("{}|{}", entry.object_type, number + 1),
        object_type: entry.object_type.clone(),
        position: bounds.center,
        rotation: bounds.rotation,
        bounds,
        aabb_min: bounds.center,
        aabb_max: bounds.center,
        mass_kg: if pickupable || moveable {
            entry.mass_kg * rng.random_range(0.8..1.2f32)
        } else {
            0.0
        },
        pickupable,
        moveable,
        receptacle,
        openable: entry.openable,
        materials: materials(&entry.object_type),
        parent_receptacles: vec![],
    };
    object.move_to(bounds);
    object
}
