//! Rendering layers into a camera by ray marching their TSDF, with a z-buffer
//! shared between layers: per pixel, the nearest surface's depth and id.
//!
//! The map renders every frame for association, so [`render_layers`] casts
//! about a quarter of the rays: it marches a sparse grid, fills pixels
//! inside one surface from their neighbours, and marches the rest
//! (silhouettes, depth edges) exactly. The map may be rendered by ray marching or
//! projection; this keeps marching's exact silhouettes, which splatting
//! voxels would dilate, at 0.72–0.80 of its cost in `cargo bench -p mapper`'s
//! room (silhouettes' rays, grazing their surfaces, cost more than most).
//!
//! Each ray is marched only near where its layer can show a surface: from
//! a few voxels before the box of possible zero crossings
//! ([`Layer::crossing_bounds`]) to where it leaves that box.

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;

use crate::camera::Intrinsics;
use crate::layer::{BlockIndex, CachedReader, Layer};
use crate::sdf_sample::{sample, Sample};
use crate::Pose;

/// Per-pixel nearest surface: depth (z, metres; +∞ = nothing) and owner id (0 = none).
#[derive(Debug, Clone, PartialEq)]
pub struct RenderTarget {
    /// Z-depth of the nearest rendered surface.
    pub depth_m: Vec<f32>,
    /// Id of the layer that surface belongs to.
    pub ids: Vec<u32>,
}

impl RenderTarget {
    /// An empty target for `k`.
    pub fn new(k: &Intrinsics) -> Self {
        Self {
            depth_m: vec![f32::INFINITY; k.pixels()],
            ids: vec![0; k.pixels()],
        }
    }
}

/// Pixel rectangle covered by the projection of the part of the box
/// `[lo, hi]` (layer frame) at z-depth `near` or more: its corners there,
/// and where its edges cross that depth. Rays march no nearer than `near`,
/// so no pixel outside can see the box; a box reaching behind the camera
/// covers only the side of the image it lies on, not the whole image.
fn projected_rect(
    lo: &Point3<f32>,
    hi: &Point3<f32>,
    t_camera_layer: &Pose,
    k: &Intrinsics,
    near: f32,
) -> Option<(usize, usize, usize, usize)> {
    let corners: [Point3<f32>; 8] = std::array::from_fn(|i| {
        t_camera_layer
            * Point3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
    });
    let (mut umin, mut vmin, mut umax, mut vmax) = (
        f32::INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NEG_INFINITY,
    );
    let mut include = |p: &Point3<f32>| {
        if let Some((u, v, _)) = k.project(p) {
            umin = umin.min(u);
            umax = umax.max(u);
            vmin = vmin.min(v);
            vmax = vmax.max(v);
        }
    };
    for (i, a) in corners.iter().enumerate() {
        if a.z >= near {
            include(a);
        }
        // The edges from this corner along each axis it has not yet taken.
        for axis in (0..3).filter(|axis| i & (1 << axis) == 0) {
            let b = &corners[i | (1 << axis)];
            if (a.z < near) != (b.z < near) {
                let t = (near - a.z) / (b.z - a.z);
                include(&(a + (b - a) * t));
            }
        }
    }
    if !(umin <= umax && vmin <= vmax) {
        return None;
    }
    let clamp = |x: f32, n: usize| x.round().clamp(0.0, (n - 1) as f32) as usize;
    if umax < -0.5 || vmax < -0.5 || umin > k.width as f32 - 0.5 || vmin > k.height as f32 - 0.5 {
        return None;
    }
    Some((
        clamp(umin, k.width),
        clamp(umax, k.width),
        clamp(vmin, k.height),
        clamp(vmax, k.height),
    ))
}

/// Z range `[z0, z1]` where the ray `o + z·d` is inside the box.
fn slab(
    o: &Point3<f32>,
    d: &Vector3<f32>,
    lo: &Point3<f32>,
    hi: &Point3<f32>,
) -> Option<(f32, f32)> {
    let (mut z0, mut z1) = (0.0f32, f32::INFINITY);
    for a in 0..3 {
        if d[a].abs() < 1e-9 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        z0 = z0.max(t0.min(t1));
        z1 = z1.min(t0.max(t1));
    }
    (z0 <= z1).then_some((z0, z1))
}

/// Ray parameter where the ray `o + z·d` leaves block `b`.
fn block_exit(layer: &Layer, b: BlockIndex, o: &Point3<f32>, d: &Vector3<f32>) -> f32 {
    let s = layer.block_size_m();
    (0..3)
        .filter(|&a| d[a].abs() > 1e-9)
        .map(|a| {
            let face = if d[a] > 0.0 { b.0[a] + 1 } else { b.0[a] } as f32 * s;
            (face - o[a]) / d[a]
        })
        .fold(f32::INFINITY, f32::min)
        + 1e-4
}

/// Which pixels of a layer's projected rectangle [`raycast_layer`] marches.
#[derive(Debug, Clone, Copy)]
pub enum Pixels<'a> {
    /// Every pixel.
    All,
    /// Pixels in even rows and even columns: a quarter of the rays.
    EvenGrid,
    /// These pixels only.
    Listed(&'a [usize]),
}

/// Ray-marches `layer` (placed by `t_camera_layer`) into `target` at
/// `pixels`, writing `id` where its zero crossing is nearer than what is
/// there. Returns the number of pixels it won.
pub fn raycast_layer(
    layer: &Layer,
    t_camera_layer: &Pose,
    k: &Intrinsics,
    id: u32,
    min_depth_m: f32,
    target: &mut RenderTarget,
    pixels: Pixels<'_>,
) -> usize {
    let (Some((lo, hi)), Some(crossings)) = (layer.block_bounds(), layer.crossing_bounds()) else {
        return 0;
    };
    // Only pixels whose rays meet the box of possible crossings can win.
    let Some((u0, u1, v0, v1)) = projected_rect(
        &crossings.0,
        &crossings.1,
        t_camera_layer,
        k,
        min_depth_m.max(1e-4),
    ) else {
        return 0;
    };
    let t_layer_camera = t_camera_layer.inverse();
    let marcher = Marcher {
        layer,
        origin: t_layer_camera * Point3::origin(),
        lo,
        hi,
        crossings,
        lead_in_voxels: LEAD_IN_VOXELS,
        min_depth_m,
    };
    let mut reader = CachedReader::new(layer);
    let mut won = 0;
    let mut shade = |u: usize, v: usize| {
        let px = v * k.width + u;
        let dir = t_layer_camera.rotation * k.ray(u as f32, v as f32);
        if let Some(hit) = marcher.march(&mut reader, &dir, target.depth_m[px]) {
            target.depth_m[px] = hit;
            target.ids[px] = id;
            won += 1;
        }
    };
    match pixels {
        Pixels::All => (v0..=v1).for_each(|v| (u0..=u1).for_each(|u| shade(u, v))),
        Pixels::EvenGrid => (v0.next_multiple_of(2)..=v1).step_by(2).for_each(|v| {
            (u0.next_multiple_of(2)..=u1)
                .step_by(2)
                .for_each(|u| shade(u, v))
        }),
        Pixels::Listed(list) => list
            .iter()
            .map(|&px| (px % k.width, px / k.width))
            .filter(|&(u, v)| (u0..=u1).contains(&u) && (v0..=v1).contains(&v))
            .for_each(|(u, v)| shade(u, v)),
    }
    won
}

/// How far before the box of possible crossings ([`Layer::crossing_bounds`])
/// a ray starts marching, in voxels along the ray. Samples before the box
/// find no crossing; they only give the first sample in it a predecessor,
/// the known distance in front of the surface that a crossing is detected
/// against, and the free space in front of a surface is observed over the
/// truncation band (three voxels at the default settings). Marching the
/// whole ray from the camera instead finds the same surfaces (the
/// samples fall elsewhere along the ray, which moves a hit by a fraction
/// of the step) at twice the samples.
const LEAD_IN_VOXELS: f32 = 3.0;

/// Ray marching into one layer: what all its rays share.
struct Marcher<'a> {
    layer: &'a Layer,
    /// Camera centre in the layer's frame.
    origin: Point3<f32>,
    /// The layer's allocated bounds.
    lo: Point3<f32>,
    hi: Point3<f32>,
    /// Where zero crossings can lie ([`Layer::crossing_bounds`]).
    crossings: (Point3<f32>, Point3<f32>),
    /// Voxels marched before the box of crossings ([`LEAD_IN_VOXELS`]).
    lead_in_voxels: f32,
    min_depth_m: f32,
}

impl Marcher<'_> {
    /// Z-depth of the first zero crossing along direction `dir` (layer
    /// frame, unit z in the camera) nearer than `z_limit`, if any.
    fn march(
        &self,
        reader: &mut CachedReader<'_>,
        dir: &Vector3<f32>,
        z_limit: f32,
    ) -> Option<f32> {
        let (origin, layer) = (self.origin, self.layer);
        let voxel = layer.voxel_size_m;
        // Marching covers the ray's part in the box of possible crossings
        // and a lead-in before it, within the allocated blocks.
        let (crossings_start, crossings_end) =
            slab(&origin, dir, &self.crossings.0, &self.crossings.1)?;
        let (z0, z1) = slab(&origin, dir, &self.lo, &self.hi)?;
        let z_end = z1.min(crossings_end).min(z_limit);
        let metres_per_z = dir.norm();
        // Steps along the ray in z: a voxel, half a voxel, per metre.
        let (voxel_z, half_voxel_z) = (voxel / metres_per_z, 0.5 * voxel / metres_per_z);
        let z_per_metre = 1.0 / metres_per_z;
        let mut z = z0
            .max(self.min_depth_m)
            .max(crossings_start - self.lead_in_voxels * voxel_z);
        let mut previous: Option<(f32, f32)> = None;
        while z <= z_end {
            let p = origin + dir * z;
            let here = sample(reader, &p);
            if let (Some((zp, sp)), Sample::Known(s)) = (previous, here) {
                if sp > 0.0 && s <= 0.0 {
                    let hit = zp + (z - zp) * sp / (sp - s);
                    return (hit < z_limit).then_some(hit);
                }
            }
            // Sphere-trace through known free space; half voxels near the
            // surface; unobserved space holds no crossing, so leap it: to
            // the exit of an unallocated block, else a whole voxel.
            let next = z + voxel_z;
            (previous, z) = match here {
                Sample::Known(s) if s > voxel => (Some((z, s)), z + 0.8 * s * z_per_metre),
                Sample::Known(s) => (Some((z, s)), z + half_voxel_z),
                Sample::Unobserved => (None, next),
                Sample::Unallocated(block) => {
                    (None, block_exit(layer, block, &origin, dir).max(next))
                }
            };
        }
        None
    }
}

/// How far (a share of [`render_layers`]' `max_spread_m`) the depth a
/// pixel between two marched ones gets from them may stray from what each
/// side's two nearest marched pixels, continued, say it is: a surface whose
/// depth changes fast (seen at a slant) is still filled from its
/// neighbours, a step within one layer's surface (one of its parts in
/// front of another) is not.
const SMOOTH_TOLERANCE: f32 = 0.25;

/// Whether the surface of layer `id` runs on without a step across pixel
/// `at` along `step` (one pixel along a row, a column or a diagonal): the
/// marched pixels one and three steps away on either side show that layer,
/// and the depths each side's two continue to at `at` (inverse depths
/// continued linearly, exact on a plane) lie within `tolerance` of the
/// depth from the nearest two. False where the stencil leaves the image.
fn smooth_across(
    target: &RenderTarget,
    k: &Intrinsics,
    at: (usize, usize),
    step: (isize, isize),
    id: u32,
    tolerance: f32,
) -> bool {
    let inverse_depth = |steps: isize| {
        let u =
            at.0.checked_add_signed(steps * step.0)
                .filter(|&u| u < k.width)?;
        let v =
            at.1.checked_add_signed(steps * step.1)
                .filter(|&v| v < k.height)?;
        let px = v * k.width + u;
        (target.ids[px] == id).then(|| target.depth_m[px].recip())
    };
    let (Some(far_before), Some(before), Some(after), Some(far_after)) = (
        inverse_depth(-3),
        inverse_depth(-1),
        inverse_depth(1),
        inverse_depth(3),
    ) else {
        return false;
    };
    let between = 2.0 / (before + after);
    // Each side's two continued to `at` (half their spacing further on).
    [
        before + 0.5 * (before - far_before),
        after + 0.5 * (after - far_after),
    ]
    .iter()
    .all(|&w| w > 0.0 && (w.recip() - between).abs() <= tolerance)
}

/// One layer placed in a camera, for [`render_layers`].
#[derive(Debug, Clone, Copy)]
pub struct PlacedLayer<'a> {
    /// The volume.
    pub layer: &'a Layer,
    /// Its pose in the camera.
    pub t_camera_layer: Pose,
    /// The id its pixels get.
    pub id: u32,
}

impl PlacedLayer<'_> {
    /// [`raycast_layer`] of this layer at `pixels`; the number of pixels it won.
    pub fn raycast(
        &self,
        k: &Intrinsics,
        min_depth_m: f32,
        target: &mut RenderTarget,
        pixels: Pixels<'_>,
    ) -> usize {
        raycast_layer(
            self.layer,
            &self.t_camera_layer,
            k,
            self.id,
            min_depth_m,
            target,
            pixels,
        )
    }
}

/// Renders `layers` (best front to back: the z-buffer then cuts the rays of
/// occluded layers short) with fewer rays than a full render.
///
/// Rays go through every other pixel of every other row first. A pixel in
/// between whose sampled neighbours all show nothing, or all show the same
/// layer at depths within `max_spread_m` or on a surface that runs on
/// smoothly across it (continued from either side, it meets the middle
/// within a quarter of `max_spread_m`: a surface seen at a slant, where
/// depth changes by more than `max_spread_m` between sampled pixels), is
/// filled from them (the mean of their inverse depths, exact on a plane).
/// The others (silhouettes, depth edges) get rays of their own, into the
/// layers their neighbours show only, so ids and depths there are exact;
/// pixels of the last row and column, which lack neighbours on one side,
/// get rays into every layer. What this can miss: a layer narrower than two
/// pixels, which association ignores anyway.
///
/// With `far_m` (a z-depth per pixel), a pixel shows only surfaces nearer
/// than its `far_m`: rays stop there, and layers wholly beyond it are not
/// marched at all. Pixels showing nothing get +∞ depth either way.
///
/// # Panics
/// If `far_m` does not hold one depth per pixel of `k` (the map passes its
/// frame's depth image, whose size it has checked).
pub fn render_layers(
    layers: &[PlacedLayer<'_>],
    k: &Intrinsics,
    min_depth_m: f32,
    max_spread_m: f32,
    far_m: Option<&[f32]>,
) -> RenderTarget {
    let mut target = RenderTarget::new(k);
    if let Some(far_m) = far_m {
        assert_eq!(
            far_m.len(),
            k.pixels(),
            "render_layers: one far depth per pixel"
        );
        target.depth_m.copy_from_slice(far_m);
    }
    for placed in layers {
        placed.raycast(k, min_depth_m, &mut target, Pixels::EvenGrid);
    }
    // Pixels needing their own ray, per layer id a neighbour showed; and
    // pixels needing rays into every layer.
    let mut own_rays: FxHashMap<u32, Vec<usize>> = FxHashMap::default();
    let mut border = Vec::new();
    for v in 0..k.height {
        for u in 0..k.width {
            if u % 2 == 0 && v % 2 == 0 {
                continue;
            }
            let px = v * k.width + u;
            let us = if u % 2 == 0 { [u, u] } else { [u - 1, u + 1] };
            let vs = if v % 2 == 0 { [v, v] } else { [v - 1, v + 1] };
            if us[1] >= k.width || vs[1] >= k.height {
                border.push(px);
                continue;
            }
            let neighbours = [
                vs[0] * k.width + us[0],
                vs[0] * k.width + us[1],
                vs[1] * k.width + us[0],
                vs[1] * k.width + us[1],
            ];
            let ids = neighbours.map(|n| target.ids[n]);
            let depths = neighbours.map(|n| target.depth_m[n]);
            let (lo, hi) = depths
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &d| {
                    (lo.min(d), hi.max(d))
                });
            let one_layer = ids.iter().all(|&i| i == ids[0]);
            if one_layer && ids[0] == 0 {
                continue; // nothing around, nothing here
            }
            if one_layer {
                // Inverse depth is affine in the pixel coordinates on a
                // plane, so its mean over the neighbours (symmetric about
                // this pixel) is exact there.
                let depth = 4.0 / depths.iter().map(|d| d.recip()).sum::<f32>();
                let smooth = || {
                    hi - lo <= max_spread_m || {
                        let tolerance = SMOOTH_TOLERANCE * max_spread_m;
                        let along = |du: isize, dv: isize| {
                            smooth_across(&target, k, (u, v), (du, dv), ids[0], tolerance)
                        };
                        match (u % 2 == 1, v % 2 == 1) {
                            (true, false) => along(1, 0),
                            (false, true) => along(0, 1),
                            _ => along(1, 1) && along(1, -1),
                        }
                    }
                };
                if depth < target.depth_m[px] && smooth() {
                    target.depth_m[px] = depth;
                    target.ids[px] = ids[0];
                    continue;
                }
            }
            for (i, &id) in ids.iter().enumerate() {
                if id != 0 && !ids[..i].contains(&id) {
                    own_rays.entry(id).or_default().push(px);
                }
            }
        }
    }
    for placed in layers {
        let own = own_rays.get(&placed.id).map_or(&[][..], |p| &p[..]);
        for pixels in [own, &border] {
            placed.raycast(k, min_depth_m, &mut target, Pixels::Listed(pixels));
        }
    }
    if far_m.is_some() {
        for (depth, &id) in target.depth_m.iter_mut().zip(&target.ids) {
            if id == 0 {
                *depth = f32::INFINITY;
            }
        }
    }
    target
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf_sample::tests::{ball_layer, sampled_layer};

    /// The camera the ball tests look through, and where it sits in the
    /// ball's layer.
    fn ball_camera() -> (Intrinsics, Pose) {
        let k = Intrinsics::from_fov(64, 48, 60.0);
        let t_camera_layer = Pose::new(
            Vector3::new(0.02, 0.03, 0.1),
            Vector3::new(0.05, -0.1, 0.02),
        );
        (k, t_camera_layer)
    }

    /// A ray's hit per pixel of `k` by `marcher`.
    fn march_every_pixel(
        marcher: &Marcher<'_>,
        k: &Intrinsics,
        t_layer_camera: &Pose,
    ) -> Vec<Option<f32>> {
        let mut reader = CachedReader::new(marcher.layer);
        (0..k.pixels())
            .map(|px| {
                let ray = k.ray((px % k.width) as f32, (px / k.width) as f32);
                marcher.march(&mut reader, &(t_layer_camera.rotation * ray), f32::INFINITY)
            })
            .collect()
    }

    #[test]
    fn rays_cut_at_the_box_of_possible_crossings_find_what_whole_rays_find() {
        let layer = ball_layer(Point3::new(0.13, -0.05, 0.9), 0.22, true);
        let (lo, hi) = layer.block_bounds().unwrap();
        let crossings = layer.crossing_bounds().unwrap();
        assert!(
            (0..3).all(|a| crossings.0[a] > lo[a] + 0.1 && crossings.1[a] < hi[a] - 0.1),
            "the crossing box {crossings:?} should be well inside the blocks {lo} – {hi}"
        );
        let (k, t_camera_layer) = ball_camera();
        let t_layer_camera = t_camera_layer.inverse();
        // Both march from where the rays enter the blocks; one stops where
        // they leave the box of crossings, the other where they leave the
        // blocks.
        let marcher = |crossings| Marcher {
            layer: &layer,
            origin: t_layer_camera * Point3::origin(),
            lo,
            hi,
            crossings,
            lead_in_voxels: f32::INFINITY,
            min_depth_m: 0.1,
        };
        let cut = march_every_pixel(&marcher(crossings), &k, &t_layer_camera);
        let whole = march_every_pixel(&marcher((lo, hi)), &k, &t_layer_camera);
        assert_eq!(cut, whole);
        let hits = whole.iter().flatten().count();
        assert!(hits > 300, "only {hits} pixels see the ball");
    }

    #[test]
    fn rays_marched_from_near_the_box_of_possible_crossings_find_what_whole_rays_find() {
        let s = 0.04;
        let layer = ball_layer(Point3::new(0.13, -0.05, 0.9), 0.22, false);
        let (k, t_camera_layer) = ball_camera();
        let mut near_box = RenderTarget::new(&k);
        raycast_layer(
            &layer,
            &t_camera_layer,
            &k,
            7,
            0.1,
            &mut near_box,
            Pixels::All,
        );
        // The same rays marched from the camera.
        let t_layer_camera = t_camera_layer.inverse();
        let (lo, hi) = layer.block_bounds().unwrap();
        let whole = Marcher {
            layer: &layer,
            origin: t_layer_camera * Point3::origin(),
            lo,
            hi,
            crossings: (lo, hi),
            lead_in_voxels: f32::INFINITY,
            min_depth_m: 0.1,
        };
        let whole_hits = march_every_pixel(&whole, &k, &t_layer_camera);
        let (mut hits, mut disagreements, mut largest_gap) = (0, 0, 0.0f32);
        for (px, expected) in whole_hits.iter().enumerate() {
            let got = (near_box.ids[px] == 7).then_some(near_box.depth_m[px]);
            let (u, v) = (px % k.width, px / k.width);
            match (got, expected) {
                (Some(a), Some(b)) => largest_gap = largest_gap.max((a - b).abs()),
                (None, None) => {}
                _ => {
                    // Samples elsewhere along a ray grazing the ball may
                    // touch it or not: only at its silhouette.
                    let silhouette = [(0, 1), (2, 1), (1, 0), (1, 2)].iter().any(|&(du, dv)| {
                        let (nu, nv) = ((u + du).wrapping_sub(1), (v + dv).wrapping_sub(1));
                        nu < k.width && nv < k.height && whole_hits[nv * k.width + nu].is_none()
                    });
                    assert!(
                        silhouette,
                        "pixel ({u}, {v}): {got:?} near the box, {expected:?} whole"
                    );
                    disagreements += 1;
                }
            }
            hits += usize::from(expected.is_some());
        }
        assert!(hits > 400, "only {hits} pixels see the ball");
        assert!(
            disagreements * 100 < hits,
            "{disagreements} of {hits} silhouette pixels differ"
        );
        assert!(largest_gap < 0.3 * s, "hits {largest_gap} m apart");
    }

    #[test]
    fn a_box_reaching_behind_the_camera_covers_only_the_pixels_that_can_see_it() {
        let k = Intrinsics::from_fov(64, 48, 90.0);
        let near = 0.1;
        // Boxes around the camera: beside it reaching behind, straddling
        // the image's edge, wholly in front, and behind.
        let boxes = [
            (Point3::new(-1.5, -0.5, -1.0), Point3::new(-0.4, 0.5, 0.6)),
            (Point3::new(0.3, -0.2, -0.5), Point3::new(0.9, 0.4, 2.0)),
            (Point3::new(-0.2, -0.3, 1.0), Point3::new(0.4, 0.1, 1.6)),
            (Point3::new(-1.0, -1.0, 0.2), Point3::new(1.0, 1.0, 0.5)),
            (Point3::new(-0.5, -0.5, -2.0), Point3::new(0.5, 0.5, -0.5)),
        ];
        let poses = [
            Pose::identity(),
            Pose::new(Vector3::new(0.1, -0.2, 0.05), Vector3::new(0.3, -0.5, 0.2)),
        ];
        let mut narrower_than_the_image = 0;
        for (lo, hi) in &boxes {
            for pose in &poses {
                let rect = projected_rect(lo, hi, pose, &k, near);
                // Every pixel whose ray meets the box at z ≥ near lies inside.
                let inverse = pose.inverse();
                let origin = inverse * Point3::origin();
                let mut seen = 0;
                for v in 0..k.height {
                    for u in 0..k.width {
                        let dir = inverse.rotation * k.ray(u as f32, v as f32);
                        let Some((z0, z1)) = slab(&origin, &dir, lo, hi) else {
                            continue;
                        };
                        if z1 < near || z0 > 100.0 {
                            continue;
                        }
                        seen += 1;
                        let (u0, u1, v0, v1) = rect.unwrap_or_else(|| {
                            panic!("box {lo} – {hi} seen at ({u}, {v}), no rect")
                        });
                        assert!(
                            (u0..=u1).contains(&u) && (v0..=v1).contains(&v),
                            "box {lo} – {hi}: pixel ({u}, {v}) outside {:?}",
                            rect
                        );
                    }
                }
                if seen == 0 {
                    assert_eq!(rect, None, "box {lo} – {hi} unseen");
                }
                if let Some((u0, u1, v0, v1)) = rect {
                    if (u1 - u0 + 1) * (v1 - v0 + 1) < k.pixels() / 2 {
                        narrower_than_the_image += 1;
                    }
                }
            }
        }
        // Before clipping at `near`, the first box (beside the camera,
        // reaching behind it) covered the whole image.
        let beside = projected_rect(&boxes[0].0, &boxes[0].1, &Pose::identity(), &k, near);
        let (u0, u1, _, _) = beside.unwrap();
        assert_eq!(u0, 0);
        assert!(
            u1 < k.width / 2,
            "the box left of the camera reaches column {u1}"
        );
        assert!(narrower_than_the_image >= 4);
    }

    /// A target whose pixel `(u, v)` shows layer 7 at the depth `depth`
    /// gives it (`None`: nothing).
    fn target_of(k: &Intrinsics, depth: impl Fn(f32, f32) -> Option<f32>) -> RenderTarget {
        let mut target = RenderTarget::new(k);
        for px in 0..k.pixels() {
            if let Some(d) = depth((px % k.width) as f32, (px / k.width) as f32) {
                target.depth_m[px] = d;
                target.ids[px] = 7;
            }
        }
        target
    }

    #[test]
    fn a_slanted_plane_runs_on_smoothly_and_a_step_does_not() {
        let k = Intrinsics::from_fov(32, 32, 90.0);
        let tolerance = 0.01;
        let across =
            |target: &RenderTarget, at, step| smooth_across(target, &k, at, step, 7, tolerance);
        // A plane seen at a slant: inverse depth affine in the pixel, the
        // depth 1.2 m to 4 m across the image (far more than a voxel
        // between marched neighbours).
        let plane = target_of(&k, |u, v| Some(1.0 / (0.8 - 0.02 * u - 0.003 * v)));
        for (at, step) in [
            ((9, 10), (1, 0)),
            ((10, 9), (0, 1)),
            ((9, 9), (1, 1)),
            ((9, 9), (1, -1)),
        ] {
            assert!(across(&plane, at, step), "plane at {at:?} along {step:?}");
        }
        // The same plane with a 10 cm step between columns 9 and 11 (one
        // part of the object in front of another): not smooth across it,
        // along the row or either diagonal, but smooth along the column.
        let stepped = target_of(&k, |u, v| {
            let d = 1.0 / (0.8 - 0.02 * u - 0.003 * v);
            Some(if u > 9.5 { d + 0.1 } else { d })
        });
        assert!(!across(&stepped, (9, 10), (1, 0)));
        assert!(!across(&stepped, (9, 9), (1, 1)));
        assert!(!across(&stepped, (9, 9), (1, -1)));
        assert!(across(&stepped, (12, 9), (0, 1)));
        // A step of 3 cm, over three times the tolerance, shows too.
        let small_step = target_of(&k, |u, v| {
            let d = 1.0 / (0.8 - 0.02 * u - 0.003 * v);
            Some(if u > 9.5 { d + 0.03 } else { d })
        });
        assert!(!across(&small_step, (9, 10), (1, 0)));
        // Another layer, or nothing, in the stencil; the stencil leaving the image.
        let mut other = plane.clone();
        other.ids[10 * k.width + 12] = 8;
        assert!(!across(&other, (9, 10), (1, 0)));
        let holed = target_of(&k, |u, v| {
            (u > 6.5).then(|| 1.0 / (0.8 - 0.02 * u - 0.003 * v))
        });
        assert!(!across(&holed, (9, 10), (1, 0)));
        assert!(!across(&plane, (1, 10), (1, 0)));
        assert!(!across(&plane, (30, 10), (1, 0)));
    }

    #[test]
    fn a_quarter_of_the_rays_render_a_slanted_surface_and_a_step_in_it_as_a_ray_per_pixel_does() {
        // One object: a slab seen at a slant (its top rises away from the
        // camera), and a block standing on it nearer the camera, whose
        // front is a step in the object's depth.
        let tilt = Vector3::new(0.0, -0.8, -0.6).normalize(); // the slab's up, in the camera frame
        let slab = move |p: Point3<f32>| {
            let height = tilt.dot(&(p - Point3::new(0.0, 0.4, 2.0)));
            let inside_box = (p.x.abs() - 1.2).max((p.z - 2.0).abs() - 1.4);
            (height - 0.0).max(-height - 0.2).max(inside_box)
        };
        let block = |p: Point3<f32>| {
            let q =
                (p - Point3::new(0.25, 0.05, 1.45)).map(f32::abs) - Vector3::new(0.25, 0.3, 0.15);
            q.map(|c| c.max(0.0)).norm() + q.max().min(0.0)
        };
        let layer = sampled_layer(
            Point3::new(-1.5, -0.8, 0.4),
            Point3::new(1.5, 1.4, 3.6),
            |_, p| Some(slab(p).min(block(p))),
        );
        let k = Intrinsics::from_fov(128, 128, 90.0);
        let placed = [PlacedLayer {
            layer: &layer,
            t_camera_layer: Pose::identity(),
            id: 3,
        }];
        let (max_spread_m, min_depth_m) = (0.04, 0.1);
        let fast = render_layers(&placed, &k, min_depth_m, max_spread_m, None);
        let mut exact = RenderTarget::new(&k);
        placed[0].raycast(&k, min_depth_m, &mut exact, Pixels::All);
        // The scene holds what the fill must tell apart: pixels between
        // marched ones on the object whose depths spread over more than a
        // voxel, on the slant and at the step.
        let shows = |u: usize, v: usize| {
            (exact.ids[v * k.width + u] == 3).then(|| exact.depth_m[v * k.width + u])
        };
        let spread = (1..k.height - 1)
            .step_by(2)
            .flat_map(|v| (0..k.width).step_by(2).map(move |u| (u, v)))
            .filter_map(|(u, v)| Some((shows(u, v - 1)? - shows(u, v + 1)?).abs()))
            .filter(|&d| d > max_spread_m)
            .count();
        assert!(
            spread > 100,
            "only {spread} pixels of a steep slant or a step"
        );
        let (mut other_id, mut worst) = (0, 0.0f32);
        for px in 0..k.pixels() {
            if fast.ids[px] != exact.ids[px] {
                other_id += 1;
            } else if exact.ids[px] != 0 {
                worst = worst.max((fast.depth_m[px] - exact.depth_m[px]).abs());
            }
        }
        // Filled pixels within the fill's tolerance (a quarter of a
        // voxel) and the marching's own error of the rays it is filled
        // from; no pixel at the step takes the mean of its two sides.
        assert!(other_id <= 4, "{other_id} pixels with another id");
        assert!(worst < 0.02, "a depth {worst} m off");
    }
}
