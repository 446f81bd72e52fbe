//! The scene geometry as triangles for the GPU renderer: every convex part
//! tessellated finely enough that depth stays within a millimetre or two of
//! the exact shape the CPU reference renderer ray-casts.

use nalgebra::{Point3, Vector3};

use crate::geometry::{Convex, SceneGeometry};

/// Largest distance between a curved surface and its tessellation, metres.
const CHORD_ERROR_M: f32 = 0.0015;
/// Fewest and most segments around a cylinder or a sphere's equator.
const SEGMENTS: (usize, usize) = (8, 64);

/// Segments around a circle of `radius` so that chords stay within
/// [`CHORD_ERROR_M`] of it.
fn segments(radius: f32) -> usize {
    let ratio = (1.0 - CHORD_ERROR_M / radius.max(1e-4)).clamp(-1.0, 1.0);
    let n = (std::f32::consts::PI / ratio.acos()).ceil() as usize;
    n.clamp(SEGMENTS.0, SEGMENTS.1)
}

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
    /// Position in the part's own frame, for the procedural texture.
    pub local: [f32; 3],
    /// Procedural texture ([`crate::texture`]).
    pub pattern: u32,
}

/// The scene as one triangle list with each instance's share of it.
#[derive(Debug, Clone, Default)]
pub struct SceneMesh {
    /// Three vertices per triangle.
    pub vertices: Vec<MeshVertex>,
    /// Per instance: its world box and its range in `vertices`.
    pub instances: Vec<InstanceRange>,
}

/// One instance's vertices and world box, for culling.
#[derive(Debug, Clone, PartialEq)]
pub struct InstanceRange {
    /// World box, lower corner.
    pub aabb_min: Point3<f32>,
    /// World box, upper corner.
    pub aabb_max: Point3<f32>,
    /// Range in [`SceneMesh::vertices`].
    pub vertices: std::ops::Range<u32>,
}

/// Everything in `geometry` as triangles.
pub fn scene_mesh(geometry: &SceneGeometry) -> SceneMesh {
    let mut out = Vec::new();
    let mut instances = Vec::with_capacity(geometry.instances.len());
    for instance in &geometry.instances {
        let first = out.len() as u32;
        for part in &instance.parts {
            let t_world_part = part.t_part_world.inverse();
            let emit = &mut |p: Point3<f32>, n: Vector3<f32>| {
                out.push(MeshVertex {
                    position: (t_world_part * p).coords.into(),
                    normal: (t_world_part.rotation * n).into(),
                    colour: part.colour,
                    id: instance.id,
                    local: p.coords.into(),
                    pattern: part.pattern,
                });
            };
            match part.shape {
                Convex::Cuboid(c) => cuboid(c.half_extents.into(), emit),
                Convex::Cylinder(c) => cylinder(c.half_height, c.radius, emit),
                Convex::Ball(b) => ball(b.radius, emit),
            }
        }
        let (aabb_min, aabb_max) = instance.world_box();
        instances.push(InstanceRange {
            aabb_min,
            aabb_max,
            vertices: first..out.len() as u32,
        });
    }
    SceneMesh {
        vertices: out,
        instances,
    }
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
    let around = segments(radius);
    let ring = |k: usize| {
        let a = std::f32::consts::TAU * k as f32 / around as f32;
        (a.cos(), a.sin())
    };
    for k in 0..around {
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
    let around = segments(radius);
    let rings = around.div_ceil(2);
    let point = |ring: usize, k: usize| {
        let polar = std::f32::consts::PI * ring as f32 / rings as f32;
        let a = std::f32::consts::TAU * k as f32 / around as f32;
        Vector3::new(polar.sin() * a.cos(), polar.cos(), polar.sin() * a.sin())
    };
    for ring in 0..rings {
        for k in 0..around {
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
