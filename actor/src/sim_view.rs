//! `actor sim-view`: a way to look at the simulator. It walks the agent
//! along a short scripted path through one room and writes, per step, the
//! RGB image, the depth image (colour-mapped) and the instance ids as PNGs,
//! plus a top-down map of the room with the path drawn on it.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use nalgebra::{Point3, Vector3};
use sim::agent::{AgentState, NavAction, Simulator};
use sim::catalogue::Catalogue;
use sim::geometry::SceneGeometry;
use sim::ithor::load_scene;
use sim::procgen::generate;
use sim::profile::RobotProfile;
use sim::raycast::Frame;
use sim::renderer::{Renderer, RendererChoice};
use sim::scene::Scene;

/// The walk: look around, cross the room, look down at what is near.
pub const WALK: [NavAction; 12] = [
    NavAction::RotateLeft,
    NavAction::RotateLeft,
    NavAction::RotateLeft,
    NavAction::MoveAhead,
    NavAction::MoveAhead,
    NavAction::LookDown,
    NavAction::RotateRight,
    NavAction::MoveAhead,
    NavAction::MoveAhead,
    NavAction::RotateRight,
    NavAction::LookDown,
    NavAction::LookUp,
];

/// Top-down map resolution, pixels per metre.
const MAP_PX_PER_M: f32 = 60.0;

/// What sim-view looks at and how.
#[derive(Debug, Clone)]
pub struct SimViewSettings {
    /// `FloorPlan2NN` (read from `data_dir/ithor-livingrooms`) or `generated:SEED`.
    pub scene: String,
    /// The shared data directory (iTHOR rooms and the object catalogue).
    pub data_dir: PathBuf,
    /// Robot profile name or TOML path.
    pub profile: String,
    /// Renderer.
    pub renderer: RendererChoice,
    /// Side of the camera's square images, pixels.
    pub image_size: usize,
    /// Output directory (created).
    pub out: PathBuf,
}

/// What sim-view wrote.
#[derive(Debug, Clone)]
pub struct SimViewSummary {
    /// Files written.
    pub files: Vec<PathBuf>,
    /// The renderer used.
    pub renderer: String,
    /// Steps of the walk that succeeded.
    pub moved: usize,
}

/// Loads `FloorPlan2NN` from the data directory or generates `generated:SEED`.
pub(crate) fn load_named_scene(
    name: &str,
    data_dir: &Path,
    profile: &RobotProfile,
) -> anyhow::Result<Scene> {
    if let Some(seed) = name.strip_prefix("generated:") {
        let seed: u64 = seed
            .parse()
            .with_context(|| format!("`{name}`: the seed after `generated:` must be a number"))?;
        let path = data_dir.join("ithor-object-types.tsv");
        let catalogue = Catalogue::load(&path).context("loading the object catalogue (--data)")?;
        return Ok(generate(&catalogue, seed, profile));
    }
    if !name.starts_with("FloorPlan") {
        bail!("unknown scene `{name}`: use FloorPlan201 … FloorPlan230 or generated:SEED");
    }
    let path = data_dir
        .join("ithor-livingrooms")
        .join(format!("{name}.json"));
    load_scene(&path).with_context(|| format!("loading {} (is --data right?)", path.display()))
}

/// Runs the walk and writes the images.
pub fn run(settings: &SimViewSettings) -> anyhow::Result<SimViewSummary> {
    let profile = RobotProfile::load(&settings.profile)?;
    let scene = load_named_scene(&settings.scene, &settings.data_dir, &profile)?;
    let start = central_start(&scene, &profile)?;
    anyhow::ensure!(
        settings.image_size >= 8,
        "--image-size must be at least 8 pixels, got {}",
        settings.image_size
    );
    let mut sim = Simulator::new(scene, profile, start, settings.image_size)?;
    let mut renderer = Renderer::open(settings.renderer)?;
    std::fs::create_dir_all(&settings.out)
        .with_context(|| format!("creating {}", settings.out.display()))?;
    let mut files = Vec::new();
    let mut path = vec![sim.agent()];
    let mut moved = 0;
    for step in 0..=WALK.len() {
        if step > 0 {
            if sim.step(WALK[step - 1]).success {
                moved += 1;
            }
            path.push(sim.agent());
        }
        let frame = sim.render(&mut renderer)?;
        for (kind, rgb) in [
            ("rgb", frame.rgb.clone()),
            ("depth", depth_colours(&frame)),
            ("ids", id_colours(&frame)),
        ] {
            let file = settings.out.join(format!("step{step:02}_{kind}.png"));
            write_png(&file, frame.width, frame.height, &rgb)?;
            files.push(file);
        }
    }
    let (width, height, map) = top_down_map(sim.scene(), &path);
    let file = settings.out.join("map.png");
    write_png(&file, width, height, &map)?;
    files.push(file);
    Ok(SimViewSummary {
        files,
        renderer: renderer.describe(),
        moved,
    })
}

/// The reachable grid position nearest the room's centre, facing +x.
fn central_start(scene: &Scene, profile: &RobotProfile) -> anyhow::Result<AgentState> {
    let centre = scene.floor_min + (scene.floor_max - scene.floor_min) / 2.0;
    let (x, y) = sim::randomise::reachable_nearest(scene, profile, centre.x, centre.y)?;
    Ok(AgentState {
        x,
        y,
        yaw_deg: 0.0,
        horizon_deg: 0.0,
    })
}

/// Depth as colours: near yellow through green and blue to far purple
/// (a viridis-like ramp over 0–6 m); black where nothing was hit.
pub(crate) fn depth_colours(frame: &Frame) -> Vec<u8> {
    const RAMP: [[f32; 3]; 5] = [
        [253.0, 231.0, 37.0],
        [94.0, 201.0, 98.0],
        [33.0, 145.0, 140.0],
        [59.0, 82.0, 139.0],
        [68.0, 1.0, 84.0],
    ];
    frame
        .depth_m
        .iter()
        .flat_map(|&d| {
            if d <= 0.0 {
                return [0, 0, 0];
            }
            let t = (d / 6.0).clamp(0.0, 1.0) * (RAMP.len() - 1) as f32;
            let (i, f) = (
                (t.floor() as usize).min(RAMP.len() - 2),
                t - t.floor().min((RAMP.len() - 2) as f32),
            );
            std::array::from_fn(|c| (RAMP[i][c] + (RAMP[i + 1][c] - RAMP[i][c]) * f) as u8)
        })
        .collect()
}

/// Instance ids as distinct colours (a hash of the id); 0 is black.
pub(crate) fn id_colours(frame: &Frame) -> Vec<u8> {
    frame
        .ids
        .iter()
        .flat_map(|&id| {
            if id == 0 {
                return [0, 0, 0];
            }
            let h = id.wrapping_mul(2_654_435_761);
            [
                64 + (h >> 24) as u8 % 192,
                64 + (h >> 16) as u8 % 192,
                64 + (h >> 8) as u8 % 192,
            ]
        })
        .collect()
}

/// The room seen from straight above (rays cast down from just under the
/// ceiling, shaded by height), with the agent's path in red and its final
/// heading as a short line.
fn top_down_map(scene: &Scene, path: &[AgentState]) -> (usize, usize, Vec<u8>) {
    let geometry = SceneGeometry::new(scene);
    let (lo, hi) = (scene.floor_min, scene.floor_max);
    let width = ((hi.x - lo.x) * MAP_PX_PER_M).ceil() as usize;
    let height = ((hi.y - lo.y) * MAP_PX_PER_M).ceil() as usize;
    let top = scene
        .walls
        .iter()
        .map(|w| w.center.z - w.half_extents.z)
        .fold(scene.floor_top_m + 1.0, f32::max)
        - 0.01;
    let down = Vector3::new(0.0, 0.0, -1.0);
    let mut image = vec![0u8; 3 * width * height];
    for row in 0..height {
        for col in 0..width {
            // North (+y) up.
            let x = lo.x + (col as f32 + 0.5) / MAP_PX_PER_M;
            let y = hi.y - (row as f32 + 0.5) / MAP_PX_PER_M;
            let origin = Point3::new(x, y, top);
            if let Some((t, _, colour, _)) = geometry.cast(&origin, &down, 10.0) {
                let height_above_floor = (top - t - scene.floor_top_m).max(0.0);
                let shade = 0.6 + 0.4 * (height_above_floor / 2.0).min(1.0);
                let px = 3 * (row * width + col);
                for c in 0..3 {
                    image[px + c] = (colour[c] * shade * 255.0).clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
    let mut dot = |x: f32, y: f32, colour: [u8; 3], radius: i32| {
        let col = ((x - lo.x) * MAP_PX_PER_M) as i32;
        let row = ((hi.y - y) * MAP_PX_PER_M) as i32;
        for dr in -radius..=radius {
            for dc in -radius..=radius {
                let (r, c) = (row + dr, col + dc);
                if r >= 0 && c >= 0 && (r as usize) < height && (c as usize) < width {
                    let px = 3 * (r as usize * width + c as usize);
                    image[px..px + 3].copy_from_slice(&colour);
                }
            }
        }
    };
    for pair in path.windows(2) {
        for k in 0..=20 {
            let f = k as f32 / 20.0;
            let x = pair[0].x + (pair[1].x - pair[0].x) * f;
            let y = pair[0].y + (pair[1].y - pair[0].y) * f;
            dot(x, y, [230, 20, 20], 1);
        }
    }
    if let Some(last) = path.last() {
        dot(last.x, last.y, [230, 20, 20], 4);
        let yaw = last.yaw_deg.to_radians();
        for k in 0..=15 {
            let r = 0.02 * k as f32;
            dot(
                last.x + r * yaw.cos(),
                last.y + r * yaw.sin(),
                [255, 255, 255],
                1,
            );
        }
    }
    (width, height, image)
}

/// Writes an 8-bit RGB PNG.
pub(crate) fn write_png(
    path: &Path,
    width: usize,
    height: usize,
    rgb: &[u8],
) -> anyhow::Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder
        .write_header()
        .with_context(|| format!("writing {}", path.display()))?;
    writer
        .write_image_data(rgb)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
