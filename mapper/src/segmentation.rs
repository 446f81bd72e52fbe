//! Where instance masks come from: the simulator's ground truth, or a simple
//! geometric segmentation of the depth image written here, to show that the
//! map's association does not depend on perfect masks.
//!
//! The geometric segmentation grows regions over neighbouring pixels and cuts
//! them at depth discontinuities and at *concave* folds (where a box meets
//! the floor), but not at convex ones (the edges of a box), in the spirit of
//! Tateno et al., "Real-time and scalable incremental segmentation on dense
//! SLAM" (IROS 2015). Regions that are very large, or that lie on the floor,
//! are labelled background (0); tiny regions are dropped.

use std::str::FromStr;

use nalgebra::{Point3, Vector3};

use crate::camera::Intrinsics;
use crate::Pose;

/// Which masks the map integrates with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Segmentation {
    /// The frame's own instance mask (ground truth from the simulator).
    Provided,
    /// [`segment_geometric`] of the depth image; the frame's mask is ignored.
    Geometric(GeometricParams),
}

impl FromStr for Segmentation {
    type Err = String;

    /// `ground-truth` or `geometric` (the values of a `--segmentation` flag).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "ground-truth" => Ok(Self::Provided),
            "geometric" => Ok(Self::Geometric(GeometricParams::default())),
            other => Err(format!(
                "unknown segmentation {other:?}: use `ground-truth` or `geometric`"
            )),
        }
    }
}

/// Settings of the geometric segmentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeometricParams {
    /// Neighbours whose depth departs from the other's tangent plane by more
    /// than `depth_jump_m + depth_jump_per_m · depth` are on different surfaces.
    pub depth_jump_m: f32,
    /// See `depth_jump_m`.
    pub depth_jump_per_m: f32,
    /// A fold sharper than this (degrees between normals) is cut if concave.
    pub concave_angle_deg: f32,
    /// Regions larger than this across (metres) are background (walls, floor).
    pub max_object_extent_m: f32,
    /// Pixels below this world height are floor: never joined to pixels
    /// above it, and regions mostly made of them are background.
    pub floor_height_m: f32,
    /// Regions smaller than this many pixels are dropped (left as 0); pixels
    /// of a 128 × 128 frame, scaled by [`Intrinsics::scaled_px`].
    pub min_region_px: usize,
    /// Depths outside this range are ignored.
    pub min_depth_m: f32,
    /// See `min_depth_m`.
    pub max_depth_m: f32,
}

impl Default for GeometricParams {
    fn default() -> Self {
        Self {
            depth_jump_m: 0.02,
            depth_jump_per_m: 0.015,
            concave_angle_deg: 20.0,
            max_object_extent_m: 1.6,
            floor_height_m: 0.02,
            min_region_px: 20,
            min_depth_m: 0.1,
            max_depth_m: 8.0,
        }
    }
}

/// Union-find over pixels.
struct Regions {
    parent: Vec<u32>,
}

impl Regions {
    fn new(n: usize) -> Self {
        Self {
            parent: (0..n as u32).collect(),
        }
    }

    fn root(&mut self, mut i: u32) -> u32 {
        while self.parent[i as usize] != i {
            let grand = self.parent[self.parent[i as usize] as usize];
            self.parent[i as usize] = grand;
            i = grand;
        }
        i
    }

    fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.root(a), self.root(b));
        // The smaller index wins, so labels do not depend on visiting order.
        if ra < rb {
            self.parent[rb as usize] = ra;
        } else if rb < ra {
            self.parent[ra as usize] = rb;
        }
    }
}

/// One optional value per pixel.
type PerPixel<T> = Vec<Option<T>>;

/// Camera-frame points (None where the depth is unusable) and unit normals
/// facing the camera (None where no smooth neighbourhood exists).
fn points_and_normals(
    k: &Intrinsics,
    depth_m: &[f32],
    params: &GeometricParams,
) -> (PerPixel<Point3<f32>>, PerPixel<Vector3<f32>>) {
    let (w, h) = (k.width, k.height);
    let points: PerPixel<Point3<f32>> = (0..w * h)
        .map(|px| {
            let d = depth_m[px];
            (d.is_finite() && d >= params.min_depth_m && d <= params.max_depth_m)
                .then(|| k.back_project((px % w) as f32, (px / w) as f32, d))
        })
        .collect();
    let jump = |d: f32| 4.0 * (params.depth_jump_m + params.depth_jump_per_m * d);
    let normals = (0..w * h)
        .map(|px| {
            let c = points[px]?;
            let (u, v) = (px % w, px / w);
            // Per axis, the tangent towards the neighbour on the same surface.
            let tangent = |a: Option<usize>, b: Option<usize>| {
                let candidates = [
                    b.and_then(|i| points[i]).map(|p| p - c),
                    a.and_then(|i| points[i]).map(|p| c - p),
                ];
                candidates
                    .into_iter()
                    .flatten()
                    .filter(|t| t.z.abs() < jump(c.z))
                    .min_by(|x, y| x.z.abs().total_cmp(&y.z.abs()))
            };
            let tu = tangent((u > 0).then(|| px - 1), (u + 1 < w).then(|| px + 1))?;
            let tv = tangent((v > 0).then(|| px - w), (v + 1 < h).then(|| px + w))?;
            let n = tu.cross(&tv).try_normalize(1e-12)?;
            Some(if n.dot(&c.coords) > 0.0 { -n } else { n })
        })
        .collect();
    (points, normals)
}

/// Segments a depth image into instance ids: 0 for background and dropped
/// pixels, 1, 2, … for regions in order of their first pixel.
pub fn segment_geometric(
    k: &Intrinsics,
    depth_m: &[f32],
    t_world_camera: &Pose,
    params: &GeometricParams,
) -> Vec<u32> {
    let (w, h) = (k.width, k.height);
    let min_region_px = k.scaled_px(params.min_region_px);
    let (points, normals) = points_and_normals(k, depth_m, params);
    let concave_cos = params.concave_angle_deg.to_radians().cos();
    let on_floor: Vec<bool> = points
        .iter()
        .map(|p| p.is_some_and(|p| (t_world_camera * p).z < params.floor_height_m))
        .collect();
    let same_surface = |a: usize, b: usize| {
        let (Some(p), Some(q)) = (points[a], points[b]) else {
            return false;
        };
        // Objects stand on the floor; the fold where they meet it is where
        // normals from a 128-pixel image are least reliable, so cut by height.
        if on_floor[a] != on_floor[b] {
            return false;
        }
        let tolerance = params.depth_jump_m + params.depth_jump_per_m * p.z.min(q.z);
        let (Some(np), Some(nq)) = (normals[a], normals[b]) else {
            return (p.z - q.z).abs() < tolerance;
        };
        // Distance of each point from the other's tangent plane.
        if (q - p).dot(&np).abs() > tolerance || (p - q).dot(&nq).abs() > tolerance {
            return false;
        }
        // A fold is concave when each point lies in front of the other's
        // tangent plane.
        let concave = (q - p).dot(&np) > 0.0 && (p - q).dot(&nq) > 0.0;
        !(concave && np.dot(&nq) < concave_cos)
    };
    let mut regions = Regions::new(w * h);
    for v in 0..h {
        for u in 0..w {
            let px = v * w + u;
            if u + 1 < w && same_surface(px, px + 1) {
                regions.join(px as u32, px as u32 + 1);
            }
            if v + 1 < h && same_surface(px, px + w) {
                regions.join(px as u32, (px + w) as u32);
            }
        }
    }
    // Region statistics: pixels, world bounds, pixels on the floor.
    let mut stats: rustc_hash::FxHashMap<u32, (usize, Point3<f32>, Point3<f32>, usize)> =
        rustc_hash::FxHashMap::default();
    let mut root_of = vec![u32::MAX; w * h];
    for px in 0..w * h {
        let Some(p) = points[px] else { continue };
        let root = regions.root(px as u32);
        root_of[px] = root;
        let world = t_world_camera * p;
        let entry = stats.entry(root).or_insert((0, world, world, 0));
        entry.0 += 1;
        entry.1 = entry.1.inf(&world);
        entry.2 = entry.2.sup(&world);
        entry.3 += usize::from(world.z < params.floor_height_m);
    }
    let mut label_of: rustc_hash::FxHashMap<u32, u32> = rustc_hash::FxHashMap::default();
    let mut out = vec![0u32; w * h];
    for px in 0..w * h {
        let root = root_of[px];
        if root == u32::MAX {
            continue;
        }
        let (n, lo, hi, on_floor) = stats[&root];
        let extent = (hi - lo).norm();
        if n < min_region_px || extent > params.max_object_extent_m || on_floor * 2 > n {
            continue;
        }
        let next = label_of.len() as u32 + 1;
        out[px] = *label_of.entry(root).or_insert(next);
    }
    out
}
