//! The scene geometry as triangles for the GPU renderer: every convex part
//! tessellated finely enough that depth stays within a millimetre or two of
//! the exact shape the CPU reference renderer ray-casts.

use nalgebra::{Point3, Vector3};

use crate::geometry::{Convex, SceneGeometry};

/// Segments around a cylinder or a sphere's equator (48: an inscribed
/// polygon lies within 0.22 % of the radius).
const AROUND: usize = 48;
/// Rings from pole to pole of a sphere.
const RINGS: usize = 24;

/// One vertex as the GPU sees it.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MeshVertex {
    /// World position, metres.
    pub position: [f32; 3],
    /// World normal (unit).
    pub normal: [f32; 3],
    /// Linear RGB, 0..1.
    pub colour: [f32; 3],
    /// Instance id (object index + 1; 0 for floor and walls).
    pub id: u32,
}

/// Triangle list (three vertices per triangle) of everything in `geometry`.
pub fn scene_triangles(geometry: &SceneGeometry) -> Vec<MeshVertex> {
    let mut out = Vec::new();
    for instance in &geometry.instances {
        for part in &instance.parts {
            let t_world_part = part.t_part_world.inverse();
            let emit = &mut |p: Point3<f32>, n: Vector3<f32>| {
                out.push(MeshVertex {
                    position: (t_world_part * p).coords.into(),
                    normal: (t_world_part.rotation * n).into(),
                    colour: part.colour,
                    id: instance.id,
                });
            };
            match part.shape {
                Convex::Cuboid(c) => cuboid(c.half_extents.into(), emit),
                Convex::Cylinder(c) => cylinder(c.half_height, c.radius, emit),
                Convex::Ball(b) => ball(b.radius, emit),
            }
        }
    }
    out
}

type Emit<'a> = dyn FnMut(Point3<f32>, Vector3<f32>) + 'a;

fn cuboid(h: [f32; 3], emit: &mut Emit) {
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut normal = Vector3::zeros();
            normal[axis] = sign;
            let corner = |sa: f32, sb: f32| {
                let mut p = Point3::origin();
                p[axis] = sign * h[axis];
                p[a] = sa * h[a];
                p[b] = sb * h[b];
                p
            };
            let quad = [
                corner(-1.0, -1.0),
                corner(1.0, -1.0),
                corner(1.0, 1.0),
                corner(-1.0, 1.0),
            ];
            for i in [0, 1, 2, 0, 2, 3] {
                emit(quad[i], normal);
            }
        }
    }
}

/// A cylinder along y (parry's convention).
fn cylinder(half_height: f32, radius: f32, emit: &mut Emit) {
    let ring = |k: usize| {
        let a = std::f32::consts::TAU * k as f32 / AROUND as f32;
        (a.cos(), a.sin())
    };
    for k in 0..AROUND {
        let ((c0, s0), (c1, s1)) = (ring(k), ring(k + 1));
        let p = |c: f32, s: f32, y: f32| Point3::new(radius * c, y, radius * s);
        let n = |c: f32, s: f32| Vector3::new(c, 0.0, s);
        let (lo, hi) = (-half_height, half_height);
        for (c, s, y) in [
            (c0, s0, lo),
            (c1, s1, lo),
            (c1, s1, hi),
            (c0, s0, lo),
            (c1, s1, hi),
            (c0, s0, hi),
        ] {
            emit(p(c, s, y), n(c, s));
        }
        for (y, ny) in [(hi, 1.0), (lo, -1.0)] {
            let up = Vector3::new(0.0, ny, 0.0);
            emit(Point3::new(0.0, y, 0.0), up);
            emit(p(c0, s0, y), up);
            emit(p(c1, s1, y), up);
        }
    }
}

fn ball(radius: f32, emit: &mut Emit) {
    let point = |ring: usize, k: usize| {
        let polar = std::f32::consts::PI * ring as f32 / RINGS as f32;
        let a = std::f32::consts::TAU * k as f32 / AROUND as f32;
        Vector3::new(polar.sin() * a.cos(), polar.cos(), polar.sin() * a.sin())
    };
    for ring in 0..RINGS {
        for k in 0..AROUND {
            let quad = [
                point(ring, k),
                point(ring + 1, k),
                point(ring + 1, k + 1),
                point(ring, k + 1),
            ];
            for i in [0, 1, 2, 0, 2, 3] {
                emit(Point3::from(quad[i] * radius), quad[i]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tessellated_vertices_lie_on_the_exact_surfaces() {
        let mut points = Vec::new();
        cylinder(0.4, 0.3, &mut |p, n| points.push((p, n, "cylinder")));
        ball(0.2, &mut |p, n| points.push((p, n, "ball")));
        cuboid([0.1, 0.2, 0.3], &mut |p, n| points.push((p, n, "cuboid")));
        assert_eq!(points.len() % 3, 0);
        for (p, n, what) in points {
            assert!((n.norm() - 1.0).abs() < 1e-5, "{what}");
            match what {
                "cylinder" => {
                    let r = (p.x * p.x + p.z * p.z).sqrt();
                    assert!(p.y.abs() <= 0.4 + 1e-6);
                    assert!(
                        r <= 0.3 + 1e-6
                            && (r < 1e-6 || (r - 0.3).abs() < 1e-5 || p.y.abs() > 0.4 - 1e-6)
                    );
                }
                "ball" => assert!((p.coords.norm() - 0.2).abs() < 1e-5),
                _ => assert!(
                    p.x.abs() <= 0.1 + 1e-6 && p.y.abs() <= 0.2 + 1e-6 && p.z.abs() <= 0.3 + 1e-6
                ),
            }
        }
    }
}
