//! Recognisable parametric shapes per object type, scaled to the object's
//! box: a sofa is a seat, a back and two arms; a table is a top on four legs;
//! a lamp is a base, a pole and a shade. Every part is convex (box, cylinder
//! or ball), so the same parts serve as physics colliders (a compound of
//! convex parts), for ray casting and for rendering.
//!
//! Part poses are in the object's box frame: origin at the box centre, axes
//! along the box axes (x width, y depth, z up), so a part list depends only
//! on the type and the half extents.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A convex primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive {
    /// Box with half extents.
    Cuboid(Vector3<f32>),
    /// Cylinder along the part's z axis.
    Cylinder {
        /// Half of its height.
        half_height: f32,
        /// Radius.
        radius: f32,
    },
    /// Sphere.
    Ball(f32),
}

/// One convex part of an object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Part {
    /// Pose in the object's box frame.
    pub pose: Isometry3<f32>,
    /// Its shape.
    pub primitive: Primitive,
    /// Which of the object's colours it takes: 0 main, 1 accent.
    pub tone: u8,
}

/// Smallest size of any part dimension, metres (keeps thin objects solid).
const MIN_HALF: f32 = 0.004;

fn cuboid(center: Vector3<f32>, half: Vector3<f32>, tone: u8) -> Part {
    Part {
        pose: Isometry3::from_parts(Translation3::from(center), UnitQuaternion::identity()),
        primitive: Primitive::Cuboid(half.map(|h| h.max(MIN_HALF))),
        tone,
    }
}

fn cylinder(center: Vector3<f32>, half_height: f32, radius: f32, tone: u8) -> Part {
    Part {
        pose: Isometry3::from_parts(Translation3::from(center), UnitQuaternion::identity()),
        primitive: Primitive::Cylinder {
            half_height: half_height.max(MIN_HALF),
            radius: radius.max(MIN_HALF),
        },
        tone,
    }
}

fn ball(center: Vector3<f32>, radius: f32, tone: u8) -> Part {
    Part {
        pose: Isometry3::from_parts(Translation3::from(center), UnitQuaternion::identity()),
        primitive: Primitive::Ball(radius.max(MIN_HALF)),
        tone,
    }
}

/// A top slab over four legs (tables, desks, stools).
fn table(h: Vector3<f32>, top_fraction: f32) -> Vec<Part> {
    let top = (h.z * 2.0 * top_fraction).max(0.02) / 2.0;
    let leg = (h.x.min(h.y) * 0.08).clamp(0.015, 0.05);
    let leg_half_height = h.z - top;
    let mut parts = vec![cuboid(
        Vector3::new(0.0, 0.0, h.z - top),
        Vector3::new(h.x, h.y, top),
        0,
    )];
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        parts.push(cuboid(
            Vector3::new(sx * (h.x - leg), sy * (h.y - leg), -h.z + leg_half_height),
            Vector3::new(leg, leg, leg_half_height),
            1,
        ));
    }
    parts
}

/// A seat with a back and optional arms (chairs, armchairs, sofas). The
/// back is along −y (the box's back side).
fn seat(h: Vector3<f32>, arms: bool) -> Vec<Part> {
    let seat_top = -h.z + 2.0 * h.z * 0.45;
    let back = (h.y * 0.2).max(0.03);
    let arm = if arms {
        (h.x * 0.12).clamp(0.05, 0.15)
    } else {
        0.0
    };
    let mut parts = vec![
        // Seat block from the floor to the seat height.
        cuboid(
            Vector3::new(0.0, back / 2.0, (-h.z + seat_top) / 2.0),
            Vector3::new(h.x - arm, h.y - back / 2.0, (seat_top + h.z) / 2.0),
            0,
        ),
        // Back, full width and height.
        cuboid(
            Vector3::new(0.0, -h.y + back, 0.0),
            Vector3::new(h.x, back, h.z),
            0,
        ),
    ];
    if arms {
        let arm_top = -h.z + 2.0 * h.z * 0.65;
        for s in [-1.0, 1.0] {
            parts.push(cuboid(
                Vector3::new(s * (h.x - arm), 0.0, (-h.z + arm_top) / 2.0),
                Vector3::new(arm, h.y, (arm_top + h.z) / 2.0),
                1,
            ));
        }
    }
    parts
}

/// A lamp: round base, thin pole, shade on top.
fn lamp(h: Vector3<f32>) -> Vec<Part> {
    let r = h.x.min(h.y);
    let base = (h.z * 0.04).max(0.01);
    let shade = h.z * 0.2;
    vec![
        cylinder(Vector3::new(0.0, 0.0, -h.z + base), base, r * 0.6, 1),
        cylinder(
            Vector3::new(0.0, 0.0, -h.z + 2.0 * base + (h.z - base - shade)),
            h.z - base - shade,
            (r * 0.06).max(0.01),
            1,
        ),
        cylinder(Vector3::new(0.0, 0.0, h.z - shade), shade, r, 0),
    ]
}

/// A cabinet-like block with a plinth (dressers, TV stands, safes, boxes).
fn block(h: Vector3<f32>, plinth: bool) -> Vec<Part> {
    if !plinth {
        return vec![cuboid(Vector3::zeros(), h, 0)];
    }
    let p = (h.z * 0.06).max(0.01);
    vec![
        cuboid(
            Vector3::new(0.0, 0.0, p),
            Vector3::new(h.x, h.y, h.z - p),
            0,
        ),
        cuboid(
            Vector3::new(0.0, 0.0, -h.z + p),
            Vector3::new(h.x * 0.95, h.y * 0.9, p),
            1,
        ),
    ]
}

/// Open shelves: two sides, a back and evenly spaced boards.
fn shelves(h: Vector3<f32>, boards: usize) -> Vec<Part> {
    let t = (h.x.min(h.y) * 0.05).clamp(0.01, 0.03);
    let mut parts = vec![
        cuboid(
            Vector3::new(-h.x + t, 0.0, 0.0),
            Vector3::new(t, h.y, h.z),
            0,
        ),
        cuboid(
            Vector3::new(h.x - t, 0.0, 0.0),
            Vector3::new(t, h.y, h.z),
            0,
        ),
        cuboid(
            Vector3::new(0.0, -h.y + t, 0.0),
            Vector3::new(h.x, t, h.z),
            0,
        ),
    ];
    for i in 0..boards {
        let z = -h.z + t + (2.0 * h.z - 2.0 * t) * i as f32 / (boards - 1).max(1) as f32;
        parts.push(cuboid(
            Vector3::new(0.0, 0.0, z),
            Vector3::new(h.x, h.y, t),
            1,
        ));
    }
    parts
}

/// A vessel: cylinder body, optionally with a ball on top (plants, statues).
fn vessel(h: Vector3<f32>, crown: bool) -> Vec<Part> {
    let r = h.x.min(h.y);
    if !crown {
        return vec![cylinder(Vector3::zeros(), h.z, r, 0)];
    }
    let body = h.z * 0.45;
    let crown_r = r.min(h.z - body);
    vec![
        cylinder(Vector3::new(0.0, 0.0, -h.z + body), body, r * 0.8, 1),
        ball(Vector3::new(0.0, 0.0, h.z - crown_r), crown_r, 0),
    ]
}

/// A screen on a small stand (televisions) or a hinged lid (laptops).
fn screen(h: Vector3<f32>, laptop: bool) -> Vec<Part> {
    if laptop {
        let base = (h.z * 0.08).max(0.008);
        return vec![
            cuboid(
                Vector3::new(0.0, 0.0, -h.z + base),
                Vector3::new(h.x, h.y, base),
                1,
            ),
            cuboid(
                Vector3::new(0.0, -h.y + base, 0.0),
                Vector3::new(h.x, base, h.z),
                0,
            ),
        ];
    }
    let stand = h.z * 0.12;
    vec![
        cuboid(
            Vector3::new(0.0, 0.0, stand),
            Vector3::new(h.x, (h.y * 0.25).max(0.02), h.z - stand),
            0,
        ),
        cuboid(
            Vector3::new(0.0, 0.0, -h.z + stand / 2.0),
            Vector3::new(h.x * 0.3, h.y, stand / 2.0),
            1,
        ),
    ]
}

/// The parts of an object of `object_type` whose box has half extents `h`.
/// Unknown types get their box.
pub fn parts_for(object_type: &str, h: Vector3<f32>) -> Vec<Part> {
    match object_type {
        "Sofa" | "ArmChair" => seat(h, true),
        "Chair" => seat(h, false),
        "CoffeeTable" | "DiningTable" | "SideTable" | "Desk" => table(h, 0.1),
        "Stool" => table(h, 0.08),
        "FloorLamp" | "DeskLamp" => lamp(h),
        "Dresser" | "TVStand" | "Safe" | "Ottoman" => block(h, true),
        "ShelvingUnit" => shelves(h, 5),
        "Shelf" => shelves(h, 2),
        "HousePlant" | "Statue" => vessel(h, true),
        "Vase" | "Candle" | "GarbageCan" | "Bowl" | "Plate" | "Watch" | "WateringCan" => {
            vessel(h, false)
        }
        "Television" => screen(h, false),
        "Laptop" => screen(h, true),
        _ => block(h, false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Axis-aligned bounds of a part in the box frame.
    fn bounds(p: &Part) -> (Vector3<f32>, Vector3<f32>) {
        let half = match p.primitive {
            Primitive::Cuboid(h) => h,
            Primitive::Cylinder {
                half_height,
                radius,
            } => Vector3::new(radius, radius, half_height),
            Primitive::Ball(r) => Vector3::repeat(r),
        };
        let c = p.pose.translation.vector;
        (c - half, c + half)
    }

    #[test]
    fn every_type_fits_its_box_and_reaches_its_top_and_bottom() {
        let types = [
            "Sofa",
            "ArmChair",
            "Chair",
            "CoffeeTable",
            "DiningTable",
            "SideTable",
            "Desk",
            "Stool",
            "FloorLamp",
            "DeskLamp",
            "Dresser",
            "TVStand",
            "Safe",
            "Ottoman",
            "ShelvingUnit",
            "Shelf",
            "HousePlant",
            "Statue",
            "Vase",
            "Candle",
            "GarbageCan",
            "Bowl",
            "Plate",
            "Watch",
            "WateringCan",
            "Television",
            "Laptop",
            "Pillow",
            "Book",
        ];
        for t in types {
            for h in [Vector3::new(1.2, 0.45, 0.5), Vector3::new(0.1, 0.1, 0.12)] {
                let parts = parts_for(t, h);
                assert!(!parts.is_empty());
                let (mut lo, mut hi) = (
                    Vector3::repeat(f32::INFINITY),
                    Vector3::repeat(f32::NEG_INFINITY),
                );
                for p in &parts {
                    let (a, b) = bounds(p);
                    lo = lo.inf(&a);
                    hi = hi.sup(&b);
                }
                for a in 0..3 {
                    assert!(
                        lo[a] >= -h[a] - 1e-4 && hi[a] <= h[a] + 1e-4,
                        "{t}: part outside the box on axis {a}"
                    );
                }
                assert!(
                    (lo.z + h.z).abs() < 0.02 * h.z.max(0.1),
                    "{t}: does not reach the floor of its box"
                );
                assert!(
                    (hi.z - h.z).abs() < 0.02 * h.z.max(0.1),
                    "{t}: does not reach the top of its box"
                );
            }
        }
    }
}
