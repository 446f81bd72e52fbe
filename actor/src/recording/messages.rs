//! Our frames, poses, maps and meshes as Foxglove's typed messages
//! (`foxglove::messages`, protobuf), each placed in the frames Foxglove's
//! 3-D panel joins: `world` (the room, z up) and `camera` (x right, y down,
//! z forward, the optical frame Foxglove's camera model expects).

use foxglove::messages::{
    packed_element_field::NumericType, CameraCalibration, Color, FrameTransform, Grid,
    KeyValuePair, PackedElementField, Point3, Pose as FoxglovePose, Quaternion, RawImage,
    SceneEntity, Timestamp, TriangleListPrimitive, Vector2, Vector3,
};
use mapper::{Intrinsics, Mesh, Pose};

/// The room's frame.
pub(crate) const WORLD_FRAME: &str = "world";
/// The camera's optical frame.
pub(crate) const CAMERA_FRAME: &str = "camera";

/// A wall-clock time, nanoseconds since the Unix epoch, as Foxglove's.
pub(crate) fn timestamp(ns: u64) -> Timestamp {
    let sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (ns % 1_000_000_000) as u32)
}

/// An image in the camera's frame; `data` holds `height` rows of `width`
/// pixels of `bytes_per_pixel` bytes.
pub(crate) fn camera_image(
    ns: u64,
    (width, height): (usize, usize),
    encoding: &str,
    bytes_per_pixel: usize,
    data: Vec<u8>,
) -> RawImage {
    RawImage {
        timestamp: Some(timestamp(ns)),
        frame_id: CAMERA_FRAME.into(),
        width: width as u32,
        height: height as u32,
        encoding: encoding.into(),
        step: (width * bytes_per_pixel) as u32,
        data: data.into(),
    }
}

/// The pinhole intrinsics as a calibration without distortion, so that
/// Foxglove projects the images into the 3-D view.
pub fn calibration(ns: u64, k: &Intrinsics) -> CameraCalibration {
    let (fx, fy, cx, cy) = (
        f64::from(k.fx),
        f64::from(k.fy),
        f64::from(k.cx),
        f64::from(k.cy),
    );
    CameraCalibration {
        timestamp: Some(timestamp(ns)),
        frame_id: CAMERA_FRAME.into(),
        width: k.width as u32,
        height: k.height as u32,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }
}

/// The camera's pose in the world as the `world` → `camera` transform.
pub(crate) fn world_to_camera(ns: u64, t_world_camera: &Pose) -> FrameTransform {
    let t = t_world_camera.translation.vector;
    let q = t_world_camera.rotation;
    FrameTransform {
        timestamp: Some(timestamp(ns)),
        parent_frame_id: WORLD_FRAME.into(),
        child_frame_id: CAMERA_FRAME.into(),
        translation: Some(Vector3 {
            x: f64::from(t.x),
            y: f64::from(t.y),
            z: f64::from(t.z),
        }),
        rotation: Some(Quaternion {
            x: f64::from(q.i),
            y: f64::from(q.j),
            z: f64::from(q.k),
            w: f64::from(q.w),
        }),
    }
}

/// Where an egocentric map lies: centred on the agent, its top row ahead
/// of it (`mapper::GridSpec` with the agent's heading).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GridPlacement {
    /// The agent: world x and y (metres) and heading (radians from +x,
    /// counter-clockwise).
    pub agent: (f32, f32, f32),
    /// Height of the floor, metres: the grid is drawn on it.
    pub floor_z: f32,
    /// Edge length, metres.
    pub extent_m: f32,
    /// Cells per edge.
    pub cells: usize,
}

/// Planes of `cells × cells` values (row 0 ahead of the agent, column 0 on
/// its left, as the policy sees them) as one grid with a float field per
/// plane, placed on the floor of the world.
///
/// Foxglove lays a grid's rows along its frame's +y; the planes' rows run
/// backwards from the agent, so rows are written last first and the grid's
/// +x is the agent's right, +y its front (a right-handed frame, z up).
pub(crate) fn agent_grid(
    ns: u64,
    placement: &GridPlacement,
    names: &[String],
    planes: &[f32],
) -> Grid {
    let n = placement.cells;
    let fields = names.len();
    let (x, y, heading) = placement.agent;
    let (sin, cos) = heading.sin_cos();
    let half = placement.extent_m / 2.0;
    // The corner behind the agent on its left: centre − half·right − half·forward.
    let (right, forward) = ((sin, -cos), (cos, sin));
    let corner = (
        x - half * right.0 - half * forward.0,
        y - half * right.1 - half * forward.1,
    );
    let yaw = f64::from(heading) - std::f64::consts::FRAC_PI_2;
    let mut data = Vec::with_capacity(n * n * fields * 4);
    for row in (0..n).rev() {
        for col in 0..n {
            for plane in 0..fields {
                let value = planes.get(plane * n * n + row * n + col).copied();
                data.extend(value.unwrap_or(0.0).to_le_bytes());
            }
        }
    }
    Grid {
        timestamp: Some(timestamp(ns)),
        frame_id: WORLD_FRAME.into(),
        pose: Some(FoxglovePose {
            position: Some(Vector3 {
                x: f64::from(corner.0),
                y: f64::from(corner.1),
                z: f64::from(placement.floor_z),
            }),
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: (yaw / 2.0).sin(),
                w: (yaw / 2.0).cos(),
            }),
        }),
        column_count: n as u32,
        cell_size: Some(Vector2 {
            x: f64::from(placement.extent_m) / n as f64,
            y: f64::from(placement.extent_m) / n as f64,
        }),
        row_stride: (n * fields * 4) as u32,
        cell_stride: (fields * 4) as u32,
        fields: names
            .iter()
            .enumerate()
            .map(|(i, name)| PackedElementField {
                name: name.clone(),
                offset: (i * 4) as u32,
                r#type: NumericType::Float32 as i32,
            })
            .collect(),
        data: data.into(),
    }
}

/// One map object: its mesh (world frame) in `rgb`, with `metadata`
/// (labels, class) shown when it is selected.
pub(crate) fn object_entity(
    ns: u64,
    id: u32,
    mesh: &Mesh,
    rgb: [u8; 3],
    metadata: &[(String, String)],
) -> SceneEntity {
    let channel = |c: u8| f64::from(c) / 255.0;
    SceneEntity {
        timestamp: Some(timestamp(ns)),
        frame_id: WORLD_FRAME.into(),
        id: format!("object {id}"),
        metadata: metadata
            .iter()
            .map(|(key, value)| KeyValuePair {
                key: key.clone(),
                value: value.clone(),
            })
            .collect(),
        triangles: vec![TriangleListPrimitive {
            pose: Some(FoxglovePose {
                position: Some(Vector3::default()),
                orientation: Some(Quaternion {
                    w: 1.0,
                    ..Quaternion::default()
                }),
            }),
            points: mesh
                .vertices
                .iter()
                .map(|p| Point3 {
                    x: f64::from(p.x),
                    y: f64::from(p.y),
                    z: f64::from(p.z),
                })
                .collect(),
            color: Some(Color {
                r: channel(rgb[0]),
                g: channel(rgb[1]),
                b: channel(rgb[2]),
                a: 1.0,
            }),
            colors: Vec::new(),
            indices: mesh.triangles.iter().flatten().copied().collect(),
        }],
        ..SceneEntity::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::GridSpec;
    use nalgebra::Point2;

    /// The world point at the centre of a grid cell, from the message's pose
    /// and cell size alone.
    fn cell_centre(grid: &Grid, col: usize, row: usize) -> (f32, f32) {
        let pose = grid.pose.as_ref().unwrap();
        let p = pose.position.as_ref().unwrap();
        let q = pose.orientation.as_ref().unwrap();
        let yaw = 2.0 * q.z.atan2(q.w);
        let size = grid.cell_size.as_ref().unwrap();
        let (u, v) = ((col as f64 + 0.5) * size.x, (row as f64 + 0.5) * size.y);
        (
            (p.x + u * yaw.cos() - v * yaw.sin()) as f32,
            (p.y + u * yaw.sin() + v * yaw.cos()) as f32,
        )
    }

    #[test]
    fn every_grid_cell_lies_where_the_policy_s_plane_has_it() {
        let cells = 8;
        for heading in [0.0f32, 0.7, 2.0, -2.5] {
            let placement = GridPlacement {
                agent: (1.5, -0.5, heading),
                floor_z: 0.1,
                extent_m: 4.0,
                cells,
            };
            let spec = GridSpec {
                center: Point2::new(1.5, -0.5),
                up_heading_rad: heading,
                extent_m: 4.0,
                cells,
            };
            // Plane value = the cell's index in the policy's layout.
            let plane: Vec<f32> = (0..cells * cells).map(|i| i as f32).collect();
            let grid = agent_grid(0, &placement, &["index".into()], &plane);
            for row in 0..cells {
                for col in 0..cells {
                    let (x, y) = cell_centre(&grid, col, row);
                    let offset = row * grid.row_stride as usize + col * grid.cell_stride as usize;
                    let bytes: [u8; 4] = grid.data[offset..offset + 4].try_into().unwrap();
                    let value = f32::from_le_bytes(bytes) as usize;
                    assert_eq!(
                        spec.cell_of(x, y),
                        Some(value),
                        "heading {heading}, grid cell ({col}, {row}) at ({x}, {y})"
                    );
                }
            }
        }
    }

    #[test]
    fn the_calibration_projects_like_the_intrinsics() {
        let k = Intrinsics {
            width: 64,
            height: 48,
            fx: 50.0,
            fy: 51.0,
            cx: 31.5,
            cy: 23.5,
        };
        let c = calibration(0, &k);
        let point = nalgebra::Point3::new(0.3f32, -0.2, 2.0);
        let (u, v, _) = k.project(&point).unwrap();
        let p = &c.p;
        let (x, y, z) = (f64::from(point.x), f64::from(point.y), f64::from(point.z));
        let w = p[8] * x + p[9] * y + p[10] * z + p[11];
        let pu = (p[0] * x + p[1] * y + p[2] * z + p[3]) / w;
        let pv = (p[4] * x + p[5] * y + p[6] * z + p[7]) / w;
        assert!((pu - f64::from(u)).abs() < 1e-4, "{pu} vs {u}");
        assert!((pv - f64::from(v)).abs() < 1e-4, "{pv} vs {v}");
    }
}
