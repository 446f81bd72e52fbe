//! What the robot can reach, pixel by pixel: each pixel's horizontal
//! distance from the agent's vertical axis, worked out once a step and
//! shared by selection within reach ([`beyond_reach_hidden`]) and the
//! state's distance image ([`crate::env::state`]).

use mapper::{Intrinsics, Pose};

/// Each pixel's horizontal distance (metres) from the agent's vertical axis
/// at `agent_xy`: the pixel's depth back-projected through `intrinsics` and
/// `t_world_camera`, the same point by which the simulator judges reach.
/// Infinite where the depth is missing (not finite or not positive).
///
/// A pixel's world point is `t + z · R · ray(u, v)`, and `R · ray(u, v)` is
/// linear in `u`, so a row costs two multiply-adds a pixel rather than a
/// back-projection and a rotation each.
pub fn horizontal_distances(
    depth_m: &[f32],
    intrinsics: &Intrinsics,
    t_world_camera: &Pose,
    agent_xy: (f32, f32),
) -> Vec<f32> {
    let width = intrinsics.width.max(1);
    let rotation = t_world_camera.rotation;
    let origin = t_world_camera.translation.vector;
    // The camera's offset from the agent's axis, and how a world ray's
    // horizontal part moves per pixel along a row.
    let (ox, oy) = (origin.x - agent_xy.0, origin.y - agent_xy.1);
    let per_u = rotation * intrinsics.ray(1.0, 0.0) - rotation * intrinsics.ray(0.0, 0.0);
    let mut out = Vec::with_capacity(depth_m.len());
    for (v, row) in depth_m.chunks(width).enumerate() {
        let start = rotation * intrinsics.ray(0.0, v as f32);
        out.extend(row.iter().enumerate().map(|(u, &z)| {
            if !(z.is_finite() && z > 0.0) {
                return f32::INFINITY;
            }
            let u = u as f32;
            let dx = ox + z * (start.x + u * per_u.x);
            let dy = oy + z * (start.y + u * per_u.y);
            (dx * dx + dy * dy).sqrt()
        }));
    }
    out
}

/// The object-id image `ids` with every pixel farther than `reach_m` from
/// the agent's axis ([`horizontal_distances`]) set to 0 (no object), as is
/// every pixel without a valid depth: what selection may choose from when
/// it offers only objects within reach.
pub(crate) fn beyond_reach_hidden(ids: &[u32], horizontal_m: &[f32], reach_m: f32) -> Vec<u32> {
    ids.iter()
        .zip(horizontal_m)
        .map(|(&id, &h)| if h <= reach_m { id } else { 0 })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances_match_a_back_projection_per_pixel() {
        let k = Intrinsics::from_fov(16, 12, 90.0);
        let t_world_camera = Pose::new(
            nalgebra::Vector3::new(1.0, -2.0, 1.5),
            nalgebra::Vector3::new(0.4, -0.3, 1.2),
        );
        let mut depth_m: Vec<f32> = (0..k.pixels()).map(|p| 0.5 + 0.01 * p as f32).collect();
        depth_m[3] = f32::NAN;
        depth_m[7] = 0.0;
        let agent = (0.7, -1.6);
        let got = horizontal_distances(&depth_m, &k, &t_world_camera, agent);
        for (p, &z) in depth_m.iter().enumerate() {
            if z.is_nan() || z <= 0.0 {
                assert_eq!(got[p], f32::INFINITY, "pixel {p}");
                continue;
            }
            let world =
                t_world_camera * k.back_project((p % k.width) as f32, (p / k.width) as f32, z);
            let want = (world.x - agent.0).hypot(world.y - agent.1);
            assert!(
                (got[p] - want).abs() < 1e-5 * (1.0 + want),
                "pixel {p}: {} vs {want}",
                got[p]
            );
        }
        let ids: Vec<u32> = (1..=k.pixels() as u32).collect();
        let reach = got[40];
        let shown = beyond_reach_hidden(&ids, &got, reach);
        for p in 0..ids.len() {
            assert_eq!(shown[p] != 0, got[p] <= reach, "pixel {p}");
        }
    }

    #[test]
    fn selection_within_reach_hides_what_the_simulator_calls_out_of_reach() {
        use sim::agent::{AgentState, Failure, Simulator};
        let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/ithor-livingrooms");
        let scene = sim::ithor::load_scene(&dir.join("FloorPlan221.json")).unwrap();
        let profile = sim::profile::RobotProfile::load("default").unwrap();
        let centre = scene.floor_min + (scene.floor_max - scene.floor_min) / 2.0;
        let (x, y) =
            sim::randomise::reachable_nearest(&scene, &profile, centre.x, centre.y).unwrap();
        let (mut near, mut far) = (0, 0);
        for (yaw_deg, horizon_deg) in [(0.0, 30.0), (90.0, 0.0), (180.0, 30.0), (270.0, 60.0)] {
            let agent = AgentState {
                x,
                y,
                yaw_deg,
                horizon_deg,
            };
            let sim = Simulator::new(scene.clone(), profile.clone(), agent, 32).unwrap();
            let camera = sim.camera();
            let frame = sim.render_cpu();
            let horizontal_m = horizontal_distances(
                &frame.depth_m,
                &crate::mapping::intrinsics(&camera),
                &camera.t_world_camera,
                (x, y),
            );
            let shown = |reach_m: f32| beyond_reach_hidden(&frame.ids, &horizontal_m, reach_m);
            let (inner, outer) = (shown(profile.reach_m - 0.05), shown(profile.reach_m + 0.05));
            let shown = shown(profile.reach_m);
            // The simulator's own judgement, pixel by pixel, away from the
            // reach's edge (where a pixel's ray and its depth's
            // back-projection may fall either side).
            for p in (0..frame.ids.len()).filter(|&p| frame.ids[p] != 0 && inner[p] == outer[p]) {
                let (u, v) = (p % frame.width, p / frame.width);
                let outcome = sim.clone().push(u, v);
                let out_of_reach = matches!(outcome.failure, Some(Failure::OutOfReach { .. }));
                assert_eq!(
                    shown[p] == 0,
                    out_of_reach,
                    "pixel ({u}, {v}) at yaw {yaw_deg}, horizon {horizon_deg}: {outcome:?}"
                );
                if out_of_reach {
                    far += 1;
                } else {
                    near += 1;
                }
            }
        }
        assert!(
            near > 50 && far > 50,
            "{near} pixels within reach, {far} beyond"
        );
    }
}
