//! `cargo bench -p mapper`: integrate one 128 × 128 frame with ~40 objects in
//! view into a room-sized map, split into rendering / association /
//! integration. Also writes the frames to `target/mapper-bench-frames/` so
//! `mapper/benches/open3d_tsdf.py` can time Open3D on the very same frames
//! (it is run at the end, side by side, when Python has open3d).

#[path = "../tests/common/mod.rs"]
mod common;

use std::io::Write;

use common::{k128, look_at, OwnedFrame, Shape};
use criterion::{criterion_group, criterion_main, Criterion};
use mapper::{Map, MapConfig};
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

/// A 6 × 6 m room: floor, four walls (background, id 0) and 42 objects.
fn room() -> Vec<Shape> {
    let wall = |x: f32, y: f32, hx: f32, hy: f32| Shape::Box {
        t_world_box: Isometry3::translation(x, y, 1.25),
        half: Vector3::new(hx, hy, 1.25),
        id: 0,
    };
    let mut shapes = vec![
        Shape::Box {
            t_world_box: Isometry3::translation(0.0, 0.0, -0.05),
            half: Vector3::new(3.0, 3.0, 0.05),
            id: 0,
        },
        wall(-3.05, 0.0, 0.05, 3.0),
        wall(3.05, 0.0, 0.05, 3.0),
        wall(0.0, -3.05, 3.0, 0.05),
        wall(0.0, 3.05, 3.0, 0.05),
    ];
    let mut id = 1;
    for i in 0..7 {
        for j in 0..6 {
            let (x, y) = (-2.4 + 0.8 * i as f32, -0.9 + 0.6 * j as f32);
            let size = 0.12 + 0.03 * ((i * 7 + j * 3) % 5) as f32;
            shapes.push(if (i + j) % 3 == 0 {
                Shape::Sphere {
                    center: Point3::new(x, y, size),
                    radius: size,
                    id,
                }
            } else {
                let t = Isometry3::from_parts(
                    nalgebra::Translation3::new(x, y, size),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3 * id as f32),
                );
                Shape::Box {
                    t_world_box: t,
                    half: Vector3::new(size, size * 0.8, size),
                    id,
                }
            });
            id += 1;
        }
    }
    shapes
}

fn frames(shapes: &[Shape]) -> Vec<OwnedFrame> {
    (0..12)
        .map(|i| {
            let x = -0.6 + 0.1 * i as f32;
            look_at(Point3::new(x, -2.7, 1.6), Point3::new(x * 0.5, 0.6, 0.2))
        })
        .map(|pose| OwnedFrame::capture(shapes, pose, k128()))
        .collect()
}

fn export(frames: &[OwnedFrame]) {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/mapper-bench-frames");
    if std::fs::create_dir_all(&dir).is_err() {
        return;
    }
    for (i, f) in frames.iter().enumerate() {
        let m = f.pose.to_homogeneous();
        let mut bytes = Vec::new();
        for r in 0..4 {
            for c in 0..4 {
                bytes.extend(m[(r, c)].to_le_bytes());
            }
        }
        for d in &f.depth {
            bytes.extend(d.to_le_bytes());
        }
        if let Ok(mut file) = std::fs::File::create(dir.join(format!("frame{i:02}.bin"))) {
            let _ = file.write_all(&bytes);
        }
    }
}

fn bench(c: &mut Criterion) {
    let shapes = room();
    let frames = frames(&shapes);
    export(&frames);
    let mut warm = Map::new(MapConfig::default());
    for f in &frames {
        warm.integrate(&f.frame()).expect("valid frame");
    }
    let visible = frames
        .iter()
        .map(|f| {
            f.ids
                .iter()
                .filter(|&&i| i != 0)
                .collect::<std::collections::BTreeSet<_>>()
                .len()
        })
        .max()
        .unwrap_or(0);
    eprintln!(
        "map: {} objects; up to {visible} objects in view per frame",
        warm.objects().len()
    );

    // One core, as the target says.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool");
    let mut map = warm.clone();
    let mut splits = Vec::new();
    let mut totals = Vec::new();
    let mut i = 0;
    c.bench_function(
        "integrate 128x128 frame, ~40 objects in view, 1 thread",
        |b| {
            b.iter(|| {
                let f = &frames[i % frames.len()];
                i += 1;
                let started = std::time::Instant::now();
                let ids = pool.install(|| map.integrate(&f.frame()).expect("valid frame"));
                totals.push(started.elapsed().as_secs_f64());
                splits.push(map.last_timings());
                ids
            })
        },
    );
    if totals.is_empty() {
        // A filter on the command line skipped the timed frames.
        return;
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2] * 1e3
    };
    let ours = median(totals);
    let ours_integration = median(
        splits
            .iter()
            .map(|t| t.integrate_s + t.background_s)
            .collect(),
    );
    eprintln!(
        "ours: median {ours:.3} ms per frame over {} frames; split: render {:.3} ms, association {:.3} ms, tracking {:.3} ms, object integration {:.3} ms, background integration {:.3} ms, book-keeping {:.3} ms",
        splits.len(),
        median(splits.iter().map(|t| t.render_s).collect()),
        median(splits.iter().map(|t| t.associate_s).collect()),
        median(splits.iter().map(|t| t.tracking_s).collect()),
        median(splits.iter().map(|t| t.integrate_s).collect()),
        median(splits.iter().map(|t| t.background_s).collect()),
        median(splits.iter().map(|t| t.book_keeping_s).collect()),
    );
    compare_with_open3d(ours, ours_integration);
    compare_renderers(&warm, &frames);
    time_surface_points(&map);
}

/// The map queries the actor's state makes once per step: gathering the
/// map's surface points (a scan of every voxel of the map), then the
/// state's 14 egocentric projections (occupancy and 3 label kinds per
/// affordance, for 2 affordances, at 10 m and 2 m, 128 cells) rasterised in
/// one pass, side by side with one pass per projection.
fn time_surface_points(map: &Map) {
    use mapper::projection::{GridSpec, ProjectionKind};
    use mapper::Affordance;
    let median_ms = |mut f: Box<dyn FnMut() + '_>| {
        let mut times: Vec<f64> = (0..50)
            .map(|_| {
                let started = std::time::Instant::now();
                f();
                started.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        times[times.len() / 2] * 1e3
    };
    let gather = median_ms(Box::new(|| {
        std::hint::black_box(map.surface_points());
    }));
    let mut requests = Vec::new();
    for extent_m in [10.0, 2.0] {
        let grid = GridSpec {
            center: nalgebra::Point2::new(3.0, 3.0),
            up_heading_rad: 0.3,
            extent_m,
            cells: 128,
        };
        requests.push((
            ProjectionKind::Occupancy {
                min_height_m: 0.05,
                max_height_m: 1.8,
            },
            grid,
        ));
        for a in [Affordance::PickUp, Affordance::Push] {
            for kind in [
                ProjectionKind::InteractedSuccess(a),
                ProjectionKind::InteractedFailure(a),
                ProjectionKind::NotInteracted(a),
            ] {
                requests.push((kind, grid));
            }
        }
    }
    let surface = map.surface_points();
    let fused = median_ms(Box::new(|| {
        std::hint::black_box(surface.project_all(&requests));
    }));
    let one_by_one = median_ms(Box::new(|| {
        for (kind, grid) in &requests {
            std::hint::black_box(surface.project(*kind, grid));
        }
    }));
    eprintln!(
        "surface points of the whole map ({} blocks): median {gather:.3} ms; its {} projections in one pass {fused:.3} ms, one pass each {one_by_one:.3} ms",
        map.objects()
            .values()
            .map(|o| o.volume.len())
            .sum::<usize>()
            + map.background().len(),
        requests.len(),
    );
}

/// Rendering the objects for association: `render_layers` (a quarter of
/// the rays, the rest filled or marched at silhouettes) against a ray
/// through every pixel, at the paper's 128 px and at 64 px, side by side.
fn compare_renderers(map: &Map, frames: &[OwnedFrame]) {
    use mapper::render::{render_layers, Pixels, RenderTarget};
    for size in [128, 64] {
        let k = mapper::Intrinsics::from_fov(size, size, 90.0);
        let (mut quarter, mut every) = (Vec::new(), Vec::new());
        // How far the quarter-ray render strays from a ray per pixel.
        let mut agreement = common::RenderAgreement::default();
        for round in 0..5 {
            for f in frames {
                let layers = map.objects_in_camera(&f.pose);
                let started = std::time::Instant::now();
                let fast = std::hint::black_box(render_layers(&layers, &k, 0.1, 0.04, None));
                quarter.push(started.elapsed().as_secs_f64());
                let started = std::time::Instant::now();
                let mut target = RenderTarget::new(&k);
                for l in &layers {
                    l.raycast(&k, 0.1, &mut target, Pixels::All);
                }
                let exact = std::hint::black_box(target);
                every.push(started.elapsed().as_secs_f64());
                if round == 0 {
                    agreement.add(&fast, &exact);
                }
            }
        }
        let (p99, max) = agreement.depth_p99_and_max();
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2] * 1e3
        };
        let (q, e) = (median(quarter), median(every));
        eprintln!(
            "render objects at {size} px: quarter rays {q:.3} ms, a ray per pixel {e:.3} ms (ratio {:.2}); \
             the quarter-ray render against a ray per pixel: {} of {} pixels with another id, \
             depth error p99 {:.1} mm, max {:.1} mm over {} object pixels",
            q / e,
            agreement.other_id,
            agreement.compared,
            p99 * 1e3,
            max * 1e3,
            agreement.depth_errors.len()
        );
    }
}

/// Runs `open3d_tsdf.py` on the exported frames (one OpenMP thread) and
/// prints our times over Open3D's. Skipped, with the reason, when Python or
/// Open3D is missing.
fn compare_with_open3d(ours_ms: f64, ours_integration_ms: f64) {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/open3d_tsdf.py");
    let output = std::process::Command::new("python3")
        .arg(&script)
        .env("OMP_NUM_THREADS", "1")
        .output();
    let text = match output {
        Ok(o) if o.status.success() => String::from_utf8_lossy(&o.stdout).into_owned(),
        Ok(o) => {
            eprintln!(
                "open3d comparison skipped: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            return;
        }
        Err(e) => {
            eprintln!("open3d comparison skipped: cannot run python3: {e}");
            return;
        }
    };
    eprint!("{text}");
    let theirs = text
        .split("median ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|ms| ms.parse::<f64>().ok());
    match theirs {
        Some(theirs) => eprintln!(
            "same frames, 1 thread each: ours whole frame / open3d = {ours_ms:.3} / {theirs:.3} ms = {:.2}; \
             ours TSDF integration only / open3d = {ours_integration_ms:.3} / {theirs:.3} ms = {:.2}",
            ours_ms / theirs,
            ours_integration_ms / theirs
        ),
        None => eprintln!("open3d comparison: could not read its median"),
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
