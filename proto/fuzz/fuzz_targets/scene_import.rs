//! Fuzzes the iTHOR scene importer (`sim::ithor::parse_scene`, what
//! `load_scene` does with a room file's text): any text must become a scene
//! or an `ImportError`, never a panic; a scene it accepts has a floor of
//! finite, ordered bounds and finite object boxes.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(scene) = sim::ithor::parse_scene(std::path::Path::new("FloorPlanFuzz.json"), text)
    else {
        return;
    };
    assert!(scene.floor_min.x <= scene.floor_max.x && scene.floor_min.y <= scene.floor_max.y);
    assert!(scene.floor_top_m.is_finite());
    for object in &scene.objects {
        assert!(object
            .bounds
            .corners()
            .iter()
            .all(|c| c.iter().all(|v| v.is_finite())));
    }
});
