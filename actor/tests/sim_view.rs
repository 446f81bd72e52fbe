//! `actor sim-view` writes what it promises: per walk step an RGB, a depth
//! and an id PNG of the profile's image size, and a top-down map with the
//! path drawn on it; bad scene names are explained.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use actor::sim_view::{run, SimViewSettings, WALK};
use sim::renderer::RendererChoice;

fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn colours(rgb: &[u8]) -> HashSet<[u8; 3]> {
    rgb.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn settings(scene: &str, out: &Path) -> SimViewSettings {
    SimViewSettings {
        scene: scene.into(),
        data_dir: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"),
        profile: "default".into(),
        renderer: RendererChoice::Cpu,
        image_size: 128,
        out: out.to_owned(),
    }
}

#[test]
fn sim_view_writes_frames_and_a_map() {
    let out = std::env::temp_dir().join(format!("sim-view-test-{}", std::process::id()));
    let summary = run(&settings("FloorPlan227", &out)).unwrap();
    assert_eq!(summary.files.len(), 3 * (WALK.len() + 1) + 1);
    assert!(summary.moved >= WALK.len() / 2, "the walk went nowhere");
    for step in [0, WALK.len()] {
        let (w, h, rgb) = read_png(&out.join(format!("step{step:02}_rgb.png")));
        assert_eq!((w, h), (128, 128));
        assert!(colours(&rgb).len() > 50, "the RGB image is flat");
        let (_, _, depth) = read_png(&out.join(format!("step{step:02}_depth.png")));
        assert!(colours(&depth).len() > 20, "the depth image is flat");
        let (_, _, ids) = read_png(&out.join(format!("step{step:02}_ids.png")));
        assert!(colours(&ids).len() >= 4, "too few instances in view");
    }
    let (w, h, map) = read_png(&out.join("map.png"));
    assert!(w > 200 && h > 150, "map is {w}×{h}");
    let red = map.chunks(3).filter(|c| c == &[230, 20, 20]).count();
    assert!(red > 20, "the path is not drawn");
    std::fs::remove_dir_all(&out).unwrap();

    let generated = std::env::temp_dir().join(format!("sim-view-gen-{}", std::process::id()));
    assert!(run(&settings("generated:4", &generated)).is_ok());
    std::fs::remove_dir_all(&generated).unwrap();

    let error = run(&settings("Kitchen1", &out)).unwrap_err().to_string();
    assert!(error.contains("FloorPlan201"), "{error}");
}
