//! Triangle meshes of a layer's zero level set, and PLY export.
//!
//! The cell walk is marching cubes': every cube of eight observed voxel
//! centres is polygonised, vertices are placed on edges by linear
//! interpolation and shared between neighbouring cells. Each cube is split
//! into six tetrahedra around its main diagonal (the Kuhn triangulation),
//! which every neighbour splits the same way on the shared face. That replaces
//! the 256-case marching cubes table and its ambiguous faces (the source of
//! cracks in the classic table) with three cases per tetrahedron, so the mesh
//! is watertight wherever the surface stays in observed space. The price is
//! about twice the triangles, which does not matter for debugging and recording.

use std::io::{self, Write};

use nalgebra::Point3;
use rustc_hash::FxHashMap;

use crate::layer::{Layer, VoxelIndex, BLOCK_VOXELS};
use crate::Pose;

/// An indexed triangle mesh; triangles wind counter-clockwise seen from
/// outside (positive SDF).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<Point3<f32>>,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
}

/// Corner offsets of a cube, bit a of the corner number = +1 along axis a.
const CORNERS: [[i32; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [0, 1, 0],
    [1, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [0, 1, 1],
    [1, 1, 1],
];

/// The six tetrahedra of the Kuhn triangulation: paths from corner 0 to
/// corner 7 adding one axis at a time, one per axis order.
const TETRAHEDRA: [[usize; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];

/// Builds the mesh of one layer, vertices mapped by `t_world_layer`.
pub fn mesh_layer(layer: &Layer, t_world_layer: &Pose) -> Mesh {
    let mut mesh = Mesh::default();
    let mut vertex_of_edge: FxHashMap<(VoxelIndex, VoxelIndex), u32> = FxHashMap::default();
    for b in layer.block_indices() {
        for offset in 0..BLOCK_VOXELS {
            let origin = VoxelIndex::join(b, offset);
            let mut index = [origin; 8];
            let mut sdf = [0.0f32; 8];
            let observed = CORNERS.iter().enumerate().all(|(c, d)| {
                index[c] = VoxelIndex([0, 1, 2].map(|a| origin.0[a] + d[a]));
                match layer.voxel(index[c]) {
                    Some(v) if v.weight > 0.0 => {
                        sdf[c] = v.sdf;
                        true
                    }
                    _ => false,
                }
            });
            if !observed || sdf.iter().all(|&s| s < 0.0) || sdf.iter().all(|&s| s >= 0.0) {
                continue;
            }
            for tet in TETRAHEDRA {
                let corners = tet.map(|c| (index[c], sdf[c]));
                polygonise_tetrahedron(layer, &corners, &mut vertex_of_edge, &mut mesh);
            }
        }
    }
    for v in &mut mesh.vertices {
        *v = t_world_layer * *v;
    }
    mesh
}

fn polygonise_tetrahedron(
    layer: &Layer,
    corners: &[(VoxelIndex, f32); 4],
    vertex_of_edge: &mut FxHashMap<(VoxelIndex, VoxelIndex), u32>,
    mesh: &mut Mesh,
) {
    let inside: Vec<usize> = (0..4).filter(|&i| corners[i].1 < 0.0).collect();
    let outside: Vec<usize> = (0..4).filter(|&i| corners[i].1 >= 0.0).collect();
    if inside.is_empty() || outside.is_empty() {
        return;
    }
    let mut vertex = |a: usize, b: usize| -> u32 {
        let (ia, sa) = corners[a];
        let (ib, sb) = corners[b];
        let key = if ia < ib { (ia, ib) } else { (ib, ia) };
        *vertex_of_edge.entry(key).or_insert_with(|| {
            let (pa, pb) = (layer.voxel_center(ia), layer.voxel_center(ib));
            mesh.vertices.push(pa + (pb - pa) * (sa / (sa - sb)));
            (mesh.vertices.len() - 1) as u32
        })
    };
    let polygon: Vec<u32> = match (inside.len(), outside.len()) {
        (1, 3) => outside.iter().map(|&o| vertex(inside[0], o)).collect(),
        (3, 1) => inside.iter().map(|&i| vertex(i, outside[0])).collect(),
        // Two and two: a quad around the tetrahedron, in cyclic order.
        _ => vec![
            vertex(inside[0], outside[0]),
            vertex(inside[0], outside[1]),
            vertex(inside[1], outside[1]),
            vertex(inside[1], outside[0]),
        ],
    };
    // Orient towards the outside: from the inside corners' centre to the outside ones'.
    let centre = |set: &[usize]| {
        set.iter()
            .map(|&i| layer.voxel_center(corners[i].0).coords)
            .sum::<nalgebra::Vector3<f32>>()
            / set.len() as f32
    };
    let outward = centre(&outside) - centre(&inside);
    for k in 1..polygon.len() - 1 {
        let mut tri = [polygon[0], polygon[k], polygon[k + 1]];
        let [p0, p1, p2] = tri.map(|i| mesh.vertices[i as usize]);
        if (p1 - p0).cross(&(p2 - p0)).dot(&outward) < 0.0 {
            tri.swap(1, 2);
        }
        mesh.triangles.push(tri);
    }
}

impl Mesh {
    /// Writes the mesh as binary little-endian PLY (readable by MeshLab,
    /// Open3D, Blender).
    pub fn write_ply(&self, mut out: impl Write) -> io::Result<()> {
        write!(
            out,
            "ply\nformat binary_little_endian 1.0\ncomment affordance-explorer map object\n\
             element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            self.vertices.len(),
            self.triangles.len()
        )?;
        let mut bytes = Vec::with_capacity(self.vertices.len() * 12 + self.triangles.len() * 13);
        for v in &self.vertices {
            for c in [v.x, v.y, v.z] {
                bytes.extend(c.to_le_bytes());
            }
        }
        for t in &self.triangles {
            bytes.push(3);
            for &i in t {
                bytes.extend((i as i32).to_le_bytes());
            }
        }
        out.write_all(&bytes)?;
        out.flush()
    }

    /// Undirected edges used by other than exactly two triangles (0 for a
    /// closed, watertight surface).
    pub fn open_edges(&self) -> usize {
        let mut uses: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        uses.values().filter(|&&n| n != 2).count()
    }
}
