//! Pushes and drops decided by the physics: a chair moves under the default
//! push and a sofa does not; a dropped pillow comes to rest on a surface.

use nalgebra::Vector3;
use sim::ithor::{load_set, SceneSet};
use sim::physics::{simulate_drop, simulate_push};
use sim::profile::RobotProfile;
use sim::scene::Scene;

fn scenes() -> Vec<Scene> {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    load_set(&dir, SceneSet::Test).unwrap()
}

/// Pushes object `index` horizontally along +x.
fn push_distance(scene: &Scene, index: usize, force_n: f32) -> f32 {
    let b = scene.objects[index].bounds;
    let after = simulate_push(scene, index, Vector3::new(force_n, 0.0, 0.0));
    (after.center - b.center).xy().norm()
}

#[test]
fn the_default_push_moves_a_chair_but_not_a_sofa() {
    let force = RobotProfile::load("default").unwrap().push_force_n;
    let mut chairs = 0;
    let mut sofas = 0;
    for scene in scenes() {
        for (i, o) in scene.objects.iter().enumerate() {
            match o.object_type.as_str() {
                "Chair" if chairs < 2 => {
                    let d = push_distance(&scene, i, force);
                    eprintln!(
                        "{}: {} ({:.1} kg) moved {d:.3} m",
                        scene.name, o.id, o.mass_kg
                    );
                    assert!(d >= 0.02, "a pushed chair must move: {d}");
                    chairs += 1;
                }
                "Sofa" if sofas < 2 => {
                    let d = push_distance(&scene, i, force);
                    eprintln!(
                        "{}: {} ({:.1} kg) moved {d:.3} m",
                        scene.name, o.id, o.mass_kg
                    );
                    assert!(d < 0.02, "a pushed sofa must not move: {d}");
                    sofas += 1;
                }
                _ => {}
            }
        }
    }
    assert!(
        chairs > 0 && sofas > 0,
        "the test scenes have chairs and sofas"
    );
}

#[test]
fn a_dropped_pillow_comes_to_rest_on_a_surface() {
    let scene = scenes()
        .into_iter()
        .find(|s| s.objects.iter().any(|o| o.object_type == "Pillow"))
        .unwrap();
    let index = scene
        .objects
        .iter()
        .position(|o| o.object_type == "Pillow")
        .unwrap();
    let mut release = scene.objects[index].bounds;
    release.center.z += 0.6;
    let rest = simulate_drop(&scene, index, &release);
    let bottom = rest
        .corners()
        .iter()
        .map(|c| c.z)
        .fold(f32::INFINITY, f32::min);
    eprintln!(
        "pillow released at z {:.3}, rests with its bottom at z {bottom:.3}",
        release.center.z
    );
    assert!(rest.center.z < release.center.z - 0.3, "it fell");
    // Its bottom touches the floor or the top of something below it.
    let below: Vec<f32> = std::iter::once(scene.floor_top_m)
        .chain(
            scene
                .objects
                .iter()
                .enumerate()
                .filter(|(i, o)| {
                    *i != index
                        && o.aabb_min.x <= rest.center.x
                        && rest.center.x <= o.aabb_max.x
                        && o.aabb_min.y <= rest.center.y
                        && rest.center.y <= o.aabb_max.y
                })
                .map(|(_, o)| o.aabb_max.z),
        )
        .collect();
    let gap = below
        .iter()
        .map(|&z| (bottom - z).abs())
        .fold(f32::INFINITY, f32::min);
    assert!(
        gap < 0.05 || bottom >= scene.floor_top_m - 0.01,
        "resting on nothing: gap {gap}"
    );
    assert!(bottom > scene.floor_top_m - 0.02, "fell through the floor");
}

#[test]
fn ground_truth_affordances_follow_the_profiles_and_the_physics() {
    use sim::affordances::ground_truth;
    let scene = scenes().remove(1);
    let default = ground_truth(&scene, &RobotProfile::load("default").unwrap());
    let weak = ground_truth(&scene, &RobotProfile::load("weak-arm").unwrap());
    let of = |list: &[sim::affordances::ObjectAffordances], t: &str| -> Vec<(bool, bool)> {
        list.iter()
            .filter(|a| a.id.starts_with(&format!("{t}|")))
            .map(|a| (a.pick_up, a.push))
            .collect()
    };
    assert!(
        of(&default, "Sofa").iter().all(|&(p, s)| !p && !s),
        "sofas: {:?}",
        of(&default, "Sofa")
    );
    assert!(
        of(&default, "Chair").iter().all(|&(p, s)| !p && s),
        "chairs: {:?}",
        of(&default, "Chair")
    );
    assert!(
        of(&weak, "Chair").iter().all(|&(_, s)| !s),
        "the weak arm cannot push a chair"
    );
    let picks =
        |list: &[sim::affordances::ObjectAffordances]| list.iter().filter(|a| a.pick_up).count();
    eprintln!(
        "{}: default picks {} and pushes {}; weak arm picks {} and pushes {} of {} objects",
        scene.name,
        picks(&default),
        default.iter().filter(|a| a.push).count(),
        picks(&weak),
        weak.iter().filter(|a| a.push).count(),
        default.len()
    );
    assert!(picks(&weak) < picks(&default));
}

#[test]
fn randomised_episodes_interpenetrate_nothing_and_are_deterministic() {
    use rand::SeedableRng;
    use sim::physics::deepest_penetration;
    use sim::randomise::{randomise, MAX_PENETRATION_M};
    let scene = scenes().remove(2);
    let profile = RobotProfile::load("default").unwrap();
    let run = |seed: u64| {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        randomise(&scene, &profile, 128, &mut rng).unwrap()
    };
    let (sim, report) = run(7);
    eprintln!("{}: {report:?}, agent {:?}", scene.name, sim.agent());
    assert!(report.moved > report.kept, "{report:?}");
    for (i, o) in sim.scene().objects.iter().enumerate() {
        if o.pickupable && o.bounds != scene.objects[i].bounds {
            let depth = deepest_penetration(sim.scene(), i);
            assert!(depth <= MAX_PENETRATION_M, "{} overlaps by {depth} m", o.id);
        }
    }
    assert_eq!(sim.agent().yaw_deg % 30.0, 0.0);
    let (again, _) = run(7);
    assert_eq!(again.scene(), sim.scene(), "same seed, same room");
    assert_eq!(again.agent(), sim.agent());
    assert_eq!(
        again.render_cpu(),
        sim.render_cpu(),
        "same seed, same frame"
    );
    let (other, _) = run(8);
    assert_ne!(other.scene(), sim.scene(), "another seed, another room");
}
