//! What a scene is to the simulator: objects with their boxes and physical
//! facts, the floor's extent and the walls that close the room.
//!
//! World frame: metres, right-handed, z up (the mapper's convention).
//! AI2-THOR's Unity frame (left-handed, y up) maps to it by `(x, y, z) ↦ (x, z, y)`.

use nalgebra::{Matrix3, Point2, Point3, Rotation3, UnitQuaternion, Vector3};

/// A box with a pose: centre, orientation (columns = box axes in the world),
/// and half extents along those axes. The third axis is the one closest to
/// world up, pointing up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    /// Centre, world frame.
    pub center: Point3<f32>,
    /// Orientation of the box axes.
    pub rotation: UnitQuaternion<f32>,
    /// Half extents along the box axes, metres.
    pub half_extents: Vector3<f32>,
}

/// The axis-aligned box around `points`: (lower, upper) corner; infinite
/// bounds for no points.
pub fn points_aabb(points: &[Point3<f32>]) -> (Point3<f32>, Point3<f32>) {
    points.iter().fold(
        (
            Point3::from([f32::INFINITY; 3]),
            Point3::from([f32::NEG_INFINITY; 3]),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    )
}

/// The 8 corners of the axis-aligned box between `lo` and `hi`.
pub fn aabb_corners(lo: &Point3<f32>, hi: &Point3<f32>) -> [Point3<f32>; 8] {
    std::array::from_fn(|i| {
        Point3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

/// Smallest half extent kept for flat objects (paintings, rugs), metres.
pub const MIN_HALF_EXTENT_M: f32 = 0.005;

impl OrientedBox {
    /// An axis-aligned box between two corners.
    pub fn axis_aligned(min: Point3<f32>, max: Point3<f32>) -> Self {
        Self {
            center: nalgebra::center(&min, &max),
            rotation: UnitQuaternion::identity(),
            half_extents: ((max - min) / 2.0).map(|h| h.max(MIN_HALF_EXTENT_M)),
        }
    }

    /// The box spanned by 8 corner points (any order), or `None` if they do
    /// not form a box (within `tolerance_m`).
    pub fn from_corners(corners: &[Point3<f32>; 8], tolerance_m: f32) -> Option<Self> {
        let center = Point3::from(corners.iter().map(|c| c.coords).sum::<Vector3<f32>>() / 8.0);
        // The three shortest non-zero edges from corner 0 are the box's edges.
        let mut edges: Vec<Vector3<f32>> = corners[1..].iter().map(|c| c - corners[0]).collect();
        edges.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
        let mut axes: Vec<Vector3<f32>> = Vec::with_capacity(3);
        let mut lengths = Vec::with_capacity(3);
        for e in edges {
            if axes.len() == 3 {
                break;
            }
            // Skip diagonals: they are not orthogonal to the edges already found.
            if axes
                .iter()
                .any(|a: &Vector3<f32>| a.dot(&e).abs() > 0.05 * e.norm().max(1e-6))
            {
                continue;
            }
            lengths.push(e.norm());
            axes.push(e.try_normalize(1e-9).unwrap_or(Vector3::zeros()));
        }
        // Degenerate (flat) boxes: complete the frame from the known axes.
        while axes.len() < 3 {
            let fill = match axes.len() {
                0 => Vector3::x(),
                1 => axes[0]
                    .cross(&Vector3::z())
                    .try_normalize(1e-6)
                    .unwrap_or(Vector3::y()),
                _ => axes[0].cross(&axes[1]),
            };
            axes.push(fill.normalize());
            lengths.push(0.0);
        }
        for i in 0..3 {
            if axes[i] == Vector3::zeros() {
                let (a, b) = (axes[(i + 1) % 3], axes[(i + 2) % 3]);
                axes[i] = a.cross(&b).try_normalize(1e-9)?;
            }
        }
        // Up-most axis third, pointing up; then right-handed.
        let up = (0..3)
            .max_by(|&a, &b| axes[a].z.abs().total_cmp(&axes[b].z.abs()))
            .expect("three axes");
        axes.swap(up, 2);
        lengths.swap(up, 2);
        if axes[2].z < 0.0 {
            axes[2] = -axes[2];
        }
        if axes[0].cross(&axes[1]).dot(&axes[2]) < 0.0 {
            axes[1] = -axes[1];
        }
        let half_extents = Vector3::new(lengths[0], lengths[1], lengths[2]) / 2.0;
        let rotation = Rotation3::from_matrix(&Matrix3::from_columns(&axes));
        let candidate = Self {
            center,
            rotation: UnitQuaternion::from_rotation_matrix(&rotation),
            half_extents: half_extents.map(|h| h.max(MIN_HALF_EXTENT_M)),
        };
        // Every corner must be a corner of the candidate.
        let fits = corners.iter().all(|c| {
            let local = candidate.rotation.inverse() * (c - candidate.center);
            (0..3).all(|a| (local[a].abs() - half_extents[a]).abs() <= tolerance_m)
        });
        fits.then_some(candidate)
    }

    /// The 8 corners, world frame.
    /// The axis-aligned world box around this box: (lower, upper) corner.
    pub fn world_aabb(&self) -> (Point3<f32>, Point3<f32>) {
        points_aabb(&self.corners())
    }

    pub fn corners(&self) -> [Point3<f32>; 8] {
        std::array::from_fn(|i| {
            let s = Vector3::new(
                if i & 1 == 0 { -1.0 } else { 1.0 },
                if i & 2 == 0 { -1.0 } else { 1.0 },
                if i & 4 == 0 { -1.0 } else { 1.0 },
            );
            self.center + self.rotation * s.component_mul(&self.half_extents)
        })
    }
}

/// One object of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneObject {
    /// Unique id (AI2-THOR's `objectId` for imported scenes).
    pub id: String,
    /// Object type (`Sofa`, `Pillow`, …).
    pub object_type: String,
    /// The object's pivot, world frame.
    pub position: Point3<f32>,
    /// The pivot's orientation (from AI2-THOR's Euler angles).
    pub rotation: UnitQuaternion<f32>,
    /// The object's box: its oriented box when the source has one, else its axis-aligned box.
    pub bounds: OrientedBox,
    /// World axis-aligned bounds as the source reports them: minimum corner.
    pub aabb_min: Point3<f32>,
    /// World axis-aligned bounds: maximum corner.
    pub aabb_max: Point3<f32>,
    /// Mass, kg (0 for static objects).
    pub mass_kg: f32,
    /// Can be picked up (AI2-THOR's flag).
    pub pickupable: bool,
    /// Can be moved without being picked up (AI2-THOR's flag).
    pub moveable: bool,
    /// Other objects can rest on or in it.
    pub receptacle: bool,
    /// Has a door or lid.
    pub openable: bool,
    /// Dominant materials, e.g. `Fabric`, `Wood`.
    pub materials: Vec<String>,
    /// Ids of the receptacles it rests on.
    pub parent_receptacles: Vec<String>,
}

impl SceneObject {
    /// Whether this is the room's floor: structure, not an object anyone
    /// interacts with (it supports, collides and renders as background).
    pub fn is_floor(&self) -> bool {
        self.object_type == "Floor"
    }

    /// AI2-THOR's rule: anything pickupable or moveable can be pushed.
    pub fn pushable(&self) -> bool {
        self.pickupable || self.moveable
    }

    /// Moves the object so that its box becomes `to`; the pivot and
    /// rotation follow rigidly and the world box is recomputed.
    pub fn move_to(&mut self, to: OrientedBox) {
        let pose =
            |b: &OrientedBox| nalgebra::Isometry3::from_parts(b.center.coords.into(), b.rotation);
        let motion = pose(&to) * pose(&self.bounds).inverse();
        self.position = motion * self.position;
        self.rotation = motion.rotation * self.rotation;
        self.bounds = to;
        (self.aabb_min, self.aabb_max) = to.world_aabb();
    }
}

/// A room: objects, the floor's extent, and the walls closing it.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Scene name, e.g. `FloorPlan227`.
    pub name: String,
    /// Objects, sorted by id (the floor included, as AI2-THOR lists it).
    pub objects: Vec<SceneObject>,
    /// Floor extent: minimum corner (x, y).
    pub floor_min: Point2<f32>,
    /// Floor extent: maximum corner (x, y).
    pub floor_max: Point2<f32>,
    /// Height of the floor's top surface, metres.
    pub floor_top_m: f32,
    /// Walls along the floor's edges, then the ceiling.
    pub walls: Vec<OrientedBox>,
}

/// Wall thickness, metres.
pub const WALL_THICKNESS_M: f32 = 0.1;
/// Lowest wall height, metres (raised to clear the tallest object).
pub const MIN_WALL_HEIGHT_M: f32 = 2.5;

/// Four walls standing outside the floor's rectangle, tall enough for every
/// object, and a ceiling on them (the room is closed: every ray hits something).
pub fn walls_around(
    floor_min: Point2<f32>,
    floor_max: Point2<f32>,
    floor_top_m: f32,
    tallest_m: f32,
) -> Vec<OrientedBox> {
    let height = MIN_WALL_HEIGHT_M.max(tallest_m - floor_top_m + 0.2);
    let (z0, z1) = (floor_top_m, floor_top_m + height);
    let t = WALL_THICKNESS_M;
    let (x0, y0, x1, y1) = (floor_min.x, floor_min.y, floor_max.x, floor_max.y);
    [
        (Point3::new(x0 - t, y0 - t, z0), Point3::new(x0, y1 + t, z1)),
        (Point3::new(x1, y0 - t, z0), Point3::new(x1 + t, y1 + t, z1)),
        (Point3::new(x0, y0 - t, z0), Point3::new(x1, y0, z1)),
        (Point3::new(x0, y1, z0), Point3::new(x1, y1 + t, z1)),
        (
            Point3::new(x0 - t, y0 - t, z1),
            Point3::new(x1 + t, y1 + t, z1 + t),
        ),
    ]
    .into_iter()
    .map(|(min, max)| OrientedBox::axis_aligned(min, max))
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_survives_corners_and_back_in_any_order() {
        let b = OrientedBox {
            center: Point3::new(1.0, -2.0, 0.5),
            rotation: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7),
            half_extents: Vector3::new(0.4, 0.2, 0.3),
        };
        let mut corners = b.corners();
        corners.reverse();
        corners.swap(1, 5);
        let back = OrientedBox::from_corners(&corners, 1e-4).unwrap();
        assert!((back.center - b.center).norm() < 1e-5);
        let mut got: Vec<f32> = back.half_extents.iter().copied().collect();
        got.sort_by(f32::total_cmp);
        assert!(
            (got[0] - 0.2).abs() < 1e-5
                && (got[1] - 0.3).abs() < 1e-5
                && (got[2] - 0.4).abs() < 1e-5
        );
        assert!(
            (back.half_extents.z - 0.3).abs() < 1e-5,
            "height stays the third axis"
        );
        for c in back.corners() {
            assert!(b.corners().iter().any(|d| (c - d).norm() < 1e-4));
        }
        let mut broken = b.corners();
        broken[3].x += 0.1;
        assert!(OrientedBox::from_corners(&broken, 1e-3).is_none());
    }
}
