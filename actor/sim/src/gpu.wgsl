// The simulator's one render pass: shaded colour, metric z-depth and the
// instance id, to three colour targets. Shading matches the CPU reference
// renderer (src/raycast.rs): ambient 0.35 plus 0.65 Lambert from a fixed
// light, with normals turned towards the camera, times the procedural
// texture of src/texture.rs.

struct Uniforms {
    view_proj: mat4x4<f32>,
    eye: vec4<f32>,
    light: vec4<f32>,
    // x: largest depth drawn, metres.
    params: vec4<f32>,
};

@group(0) @binding(0) var<uniform> u: Uniforms;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) colour: vec3<f32>,
    @location(3) id: u32,
    @location(4) local: vec3<f32>,
    @location(5) pattern: u32,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) colour: vec3<f32>,
    @location(3) @interpolate(flat) id: u32,
    @location(4) depth: f32,
    @location(5) local: vec3<f32>,
    @location(6) @interpolate(flat) pattern: u32,
};

// Same as texture::shade.
fn texture(pattern: u32, p: vec3<f32>) -> f32 {
    if (pattern == 1u) {
        return 0.86 + 0.14 * (0.5 + 0.5 * sin(p.x * 45.0 + 3.0 * sin(p.y * 9.0 + p.z * 5.0)));
    }
    if (pattern == 2u) {
        let a = floor(p.x * 80.0) + floor(p.y * 80.0) + floor(p.z * 80.0);
        return 0.9 + 0.1 * (a - 2.0 * floor(a / 2.0));
    }
    if (pattern == 3u) {
        let c = floor(p * 60.0);
        let h = abs(fract(sin(c.x * 12.9898 + c.y * 78.233 + c.z * 37.719) * 43758.547));
        return 0.82 + 0.18 * h;
    }
    return 1.0;
}

@vertex
fn vs(v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = u.view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.normal = v.normal;
    out.colour = v.colour;
    out.id = v.id;
    out.local = v.local;
    out.pattern = v.pattern;
    // The projection puts camera-frame z into w.
    out.depth = out.clip.w;
    return out;
}

struct FragmentOut {
    @location(0) colour: vec4<f32>,
    @location(1) depth: f32,
    @location(2) id: u32,
};

@fragment
fn fs(f: VertexOut) -> FragmentOut {
    if (f.depth > u.params.x) {
        discard;
    }
    var n = normalize(f.normal);
    if (dot(n, f.world - u.eye.xyz) > 0.0) {
        n = -n;
    }
    let shade = 0.35 + 0.65 * max(dot(n, u.light.xyz), 0.0);
    var out: FragmentOut;
    out.colour = vec4<f32>(f.colour * shade * texture(f.pattern, f.local), 1.0);
    out.depth = f.depth;
    out.id = f.id;
    return out;
}
