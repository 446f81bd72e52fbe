//! Procedural textures from an object's salient materials: wood grain,
//! fabric weave, stone speckle, or plain. A texture scales the material's
//! colour by a factor computed from the part-local surface point, the same
//! formula here (CPU ray caster) and in `gpu.wgsl`.

/// No pattern.
pub const PLAIN: u32 = 0;
/// Wood grain: wavy stripes.
pub const WOOD: u32 = 1;
/// Fabric: a fine checker weave.
pub const FABRIC: u32 = 2;
/// Stone: speckles.
pub const STONE: u32 = 3;

/// The texture of an AI2-THOR salient material.
pub fn material_pattern(material: &str) -> u32 {
    match material {
        "Wood" => WOOD,
        "Fabric" | "Leather" | "Sponge" => FABRIC,
        "Stone" => STONE,
        _ => PLAIN,
    }
}

/// The brightness factor (0.82–1.0) of `pattern` at part-local point `p`, metres.
pub fn shade(pattern: u32, p: [f32; 3]) -> f32 {
    match pattern {
        WOOD => {
            0.86 + 0.14 * (0.5 + 0.5 * (p[0] * 45.0 + 3.0 * (p[1] * 9.0 + p[2] * 5.0).sin()).sin())
        }
        FABRIC => {
            let a = (p[0] * 80.0).floor() + (p[1] * 80.0).floor() + (p[2] * 80.0).floor();
            0.9 + 0.1 * (a - 2.0 * (a / 2.0).floor())
        }
        STONE => {
            let c = p.map(|x| (x * 60.0).floor());
            let h = ((c[0] * 12.9898 + c[1] * 78.233 + c[2] * 37.719).sin() * 43758.547)
                .fract()
                .abs();
            0.82 + 0.18 * h
        }
        _ => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_vary_within_their_range_and_plain_does_not() {
        for pattern in [WOOD, FABRIC, STONE] {
            let values: Vec<f32> = (0..200)
                .map(|i| shade(pattern, [i as f32 * 0.0037, i as f32 * 0.0021, 0.1]))
                .collect();
            assert!(values.iter().all(|v| (0.8..=1.0).contains(v)), "{pattern}");
            let spread = values.iter().cloned().fold(0.0, f32::max)
                - values.iter().cloned().fold(1.0, f32::min);
            assert!(spread > 0.05, "pattern {pattern} is flat");
        }
        assert_eq!(shade(PLAIN, [0.3, 0.2, 0.1]), 1.0);
    }
}
