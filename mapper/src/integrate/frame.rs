//! One depth frame prepared for integration: what every layer's voxels read
//! of a pixel, computed once per frame instead of once per layer.

use nalgebra::Point3;

use super::IntegrationParams;
use crate::camera::Intrinsics;

/// What integration reads of one pixel, gathered once per frame into one
/// record, so each voxel reads one record instead of four images. Three
/// 32-bit words without padding (`repr(C)`), so that vector code can gather
/// each word by index.
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub(super) struct PixelRecord {
    /// Z-depth in metres; NaN where unusable (and for the off-image sentinel).
    pub(super) depth: f32,
    /// The factor from [`write_normal_cosines`].
    pub(super) cos: f32,
    /// Bits [`MAY_CARVE`], [`MAY_CARVE_NEAR`] and [`SMOOTH_QUAD`].
    pub(super) flags: u32,
}

/// [`PixelRecord::flags`] bit: the pixel may carve other surfaces
/// ([`mark_carving_pixels`]).
pub(super) const MAY_CARVE: u32 = 1;
/// [`PixelRecord::flags`] bit: the pixel may also contradict voxels within
/// the truncation band of its surface: no neighbour is nearer by more than
/// [`IntegrationParams::free_space_margin_m`] ([`mark_carving_pixels`]).
pub(super) const MAY_CARVE_NEAR: u32 = 2;
/// [`PixelRecord::flags`] bit: depth may be interpolated between this pixel
/// and its right, lower and lower-right neighbours: all four usable and on
/// one smooth surface (within one truncation distance).
pub(super) const SMOOTH_QUAD: u32 = 4;

impl PixelRecord {
    /// A record with depth `depth`, head-on, and no flag set.
    fn new(depth: f32) -> Self {
        Self {
            depth,
            cos: 1.0,
            flags: 0,
        }
    }

    /// True if flag bit `bit` is set.
    #[inline]
    pub(super) fn has(&self, bit: u32) -> bool {
        self.flags & bit != 0
    }

    /// Sets flag bit `bit` to `on` (without branches: set for every pixel).
    #[inline]
    fn set(&mut self, bit: u32, on: bool) {
        self.flags = (self.flags & !bit) | (u32::from(on) * bit);
    }
}

/// One depth frame prepared for integration into any number of layers: per
/// pixel its usable depth, normal cosine, carving permission and whether
/// bilinear interpolation may start there, plus an off-image sentinel.
/// Kept by the map and refilled each frame: fresh buffers of this size cost
/// page faults every frame.
#[derive(Debug, Clone, Default)]
pub struct FramePixels {
    width: usize,
    /// `width × height` records, then the sentinel (depth NaN) that voxels
    /// landing outside the image read.
    pub(super) records: Vec<PixelRecord>,
    /// Each pixel's camera-frame point, where its depth is usable.
    /// NaN where unusable; plain words, so that vector code can gather them.
    pub(super) points: Vec<[f32; 3]>,
    /// Scratch for [`mark_carving_pixels`] and [`mark_smooth_quads`].
    scratch: DepthScratch,
}

impl FramePixels {
    /// Prepares `depth_m` (z-depth per pixel) for integration, reusing this
    /// value's buffers.
    pub fn prepare(&mut self, k: &Intrinsics, depth_m: &[f32], params: &IntegrationParams) {
        self.width = k.width;
        fill_camera_points(k, depth_m, params, &mut self.points);
        self.records.clear();
        self.records.extend(
            depth_m
                .iter()
                .map(|&d| PixelRecord::new(if params.valid_depth(d) { d } else { f32::NAN })),
        );
        write_normal_cosines(k, &self.points, params, &mut self.records);
        mark_carving_pixels(k, params, &mut self.records, &mut self.scratch);
        mark_smooth_quads(k, params, &self.scratch.near, &mut self.records);
        self.records.push(PixelRecord::new(f32::NAN));
    }

    /// True if these pixels were prepared for a camera of `k`'s size.
    pub(super) fn prepared_for(&self, k: &Intrinsics) -> bool {
        self.width == k.width && self.records.len() == k.pixels() + 1
    }

    /// The index voxels landing outside the image read.
    pub(super) fn off_image(&self) -> u32 {
        (self.records.len() - 1) as u32
    }

    /// Depth at continuous pixel coordinates `(u, v)`, whose nearest pixel
    /// has depth `nearest`: bilinear between the four surrounding pixels
    /// where they form a smooth quad, else `nearest`. At 128 × 128 a pixel
    /// spans about a voxel at 2 m, so nearest-pixel lookup alone leaves
    /// errors of half a voxel on slanted surfaces.
    #[inline]
    pub(super) fn depth_at(&self, u: f32, v: f32, nearest: f32) -> f32 {
        if !(u >= 0.0 && v >= 0.0) {
            return nearest;
        }
        let (u0, v0) = ((u as usize) as f32, (v as usize) as f32);
        let i = v0 as usize * self.width + u0 as usize;
        if !self.records[i].has(SMOOTH_QUAD) {
            return nearest;
        }
        let w = self.width;
        let q = [i, i + 1, i + w, i + w + 1].map(|j| self.records[j].depth);
        let (fu, fv) = (u - u0, v - v0);
        (q[0] * (1.0 - fu) + q[1] * fu) * (1.0 - fv) + (q[2] * (1.0 - fu) + q[3] * fu) * fv
    }
}

/// A pixel's camera-frame point from [`FramePixels::points`], if usable.
#[inline]
pub(super) fn usable_point(point: [f32; 3]) -> Option<Point3<f32>> {
    (!point[2].is_nan()).then(|| Point3::from(point))
}

/// Each pixel's camera-frame point where its depth is usable, back-projected
/// once per frame (a pixel is the neighbour of four others, and the point of
/// every layer's search for blocks).
fn fill_camera_points(
    k: &Intrinsics,
    depth_m: &[f32],
    params: &IntegrationParams,
    points: &mut Vec<[f32; 3]>,
) {
    // The rays' x and y per column and row: the same values as
    // `Intrinsics::back_project`, without two divisions per pixel.
    let column_x: Vec<f32> = (0..k.width).map(|u| k.ray(u as f32, 0.0).x).collect();
    let row_y: Vec<f32> = (0..k.height).map(|v| k.ray(0.0, v as f32).y).collect();
    points.clear();
    for (v, &y) in row_y.iter().enumerate() {
        for (u, &x) in column_x.iter().enumerate() {
            let d = depth_m[v * k.width + u];
            points.push(if params.valid_depth(d) {
                [x * d, y * d, d]
            } else {
                [f32::NAN; 3]
            });
        }
    }
}

/// Per pixel, `|cos|` of the angle between the viewing ray and the surface
/// normal estimated from neighbouring depths: central differences inside a
/// surface, one-sided at its edges (left at 1 for isolated pixels).
///
/// Projective TSDF measures distance along the ray, which overestimates the
/// distance to the surface by `1 / cos θ` off the normal; multiplying by this
/// factor turns it into point-to-plane distance (and it down-weights grazing
/// views). This is a departure from TSDF++/voxblox, which leave the bias in.
fn write_normal_cosines(
    k: &Intrinsics,
    points: &[[f32; 3]],
    params: &IntegrationParams,
    records: &mut [PixelRecord],
) {
    let (w, h) = (k.width, k.height);
    let max_jump = 4.0 * params.truncation_m;
    for v in 0..h {
        for u in 0..w {
            let Some(c) = usable_point(points[v * w + u]) else {
                continue;
            };
            let neighbour = |du: isize, dv: isize| {
                let (x, y) = (u.checked_add_signed(du)?, v.checked_add_signed(dv)?);
                if x >= w || y >= h {
                    return None;
                }
                usable_point(points[y * w + x]).filter(|p| (p.z - c.z).abs() < max_jump)
            };
            // Central differences where both neighbours lie on this surface,
            // one-sided at its edges: silhouettes are where views graze the
            // surface, so "unknown" must not mean "head-on" there.
            let tangent =
                |before: Option<Point3<f32>>, after: Option<Point3<f32>>| match (before, after) {
                    (Some(a), Some(b)) => Some(b - a),
                    (None, Some(b)) => Some(b - c),
                    (Some(a), None) => Some(c - a),
                    (None, None) => None,
                };
            let (Some(along_u), Some(along_v)) = (
                tangent(neighbour(-1, 0), neighbour(1, 0)),
                tangent(neighbour(0, -1), neighbour(0, 1)),
            ) else {
                continue;
            };
            let n = along_u.cross(&along_v);
            let n_squared = n.norm_squared();
            if n_squared < 1e-24 {
                continue;
            }
            // |cos| = |n · c| / (|n| |c|), with one root and one division.
            let lengths = (n_squared * c.coords.norm_squared()).sqrt();
            records[v * w + u].cos = (n.dot(&c.coords).abs() / lengths).max(0.2);
        }
    }
}

/// Marks the pixels that may carve other surfaces: those with no neighbour
/// nearer by more than the truncation distance (and, to contradict voxels
/// within the band, by more than the free-space margin). A pixel just outside an
/// object's silhouette sees the far background through the object's edge
/// voxels; carving from it would erode every object by up to a pixel per
/// view.
fn mark_carving_pixels(
    k: &Intrinsics,
    params: &IntegrationParams,
    records: &mut [PixelRecord],
    scratch: &mut DepthScratch,
) {
    let (w, h) = (k.width, k.height);
    let DepthScratch { near, row_min } = scratch;
    // Plain arrays, so that the minima below vectorise: each pixel's depth
    // (+∞ where unusable), then the nearest in each pixel's 3 × 3
    // neighbourhood, as a minimum along rows and then along columns.
    near.clear();
    near.extend(records[..w * h].iter().map(|r| {
        if r.depth.is_nan() {
            f32::INFINITY
        } else {
            r.depth
        }
    }));
    row_min.clear();
    for row in near.chunks_exact(w) {
        row_min.push(row[0].min(row[1.min(w - 1)]));
        row_min.extend(row.windows(3).map(|t| t[0].min(t[1]).min(t[2])));
        if w > 1 {
            row_min.push(row[w - 2].min(row[w - 1]));
        }
    }
    for v in 0..h {
        let above = &row_min[v.saturating_sub(1) * w..][..w];
        let here = &row_min[v * w..][..w];
        let below = &row_min[(v + 1).min(h - 1) * w..][..w];
        let records = &mut records[v * w..][..w];
        for u in 0..w {
            let d = records[u].depth;
            let nearest = here[u].min(above[u]).min(below[u]);
            let usable = !d.is_nan();
            let far = usable && nearest >= d - params.truncation_m;
            let far_near = usable && nearest >= d - params.free_space_margin_m;
            records[u].set(MAY_CARVE, far);
            records[u].set(MAY_CARVE_NEAR, far_near);
        }
    }
}

/// Scratch arrays for [`mark_carving_pixels`] and [`mark_smooth_quads`],
/// kept between frames.
#[derive(Debug, Clone, Default)]
struct DepthScratch {
    /// Per pixel its usable depth, +∞ where there is none (read by
    /// [`mark_smooth_quads`] too).
    near: Vec<f32>,
    /// Per pixel the nearest of `near` in its row's three pixels around it.
    row_min: Vec<f32>,
}

/// Marks the pixels where bilinear depth interpolation may start
/// ([`SMOOTH_QUAD`]).
fn mark_smooth_quads(
    k: &Intrinsics,
    params: &IntegrationParams,
    near: &[f32],
    records: &mut [PixelRecord],
) {
    let (w, h) = (k.width, k.height);
    for v in 0..h.saturating_sub(1) {
        let (top, bottom) = (&near[v * w..][..w], &near[(v + 1) * w..][..w]);
        let records = &mut records[v * w..][..w];
        for u in 0..w.saturating_sub(1) {
            let lo = top[u].min(top[u + 1]).min(bottom[u]).min(bottom[u + 1]);
            let hi = top[u].max(top[u + 1]).max(bottom[u]).max(bottom[u + 1]);
            // An unusable corner (+∞) makes the spread +∞ or NaN: not smooth.
            let smooth = hi - lo <= params.truncation_m;
            records[u].flags =
                (records[u].flags & !SMOOTH_QUAD) | (u32::from(smooth) * SMOOTH_QUAD);
        }
    }
}
