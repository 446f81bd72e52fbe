// The simulator's one render pass: shaded colour, metric z-depth and the
// instance id, to three colour targets. Shading matches the CPU reference
// renderer (src/raycast.rs): ambient 0.35 plus 0.65 Lambert from a fixed
// light, with normals turned towards the camera.

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
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) colour: vec3<f32>,
    @location(3) @interpolate(flat) id: u32,
    @location(4) depth: f32,
};

@vertex
fn vs(v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = u.view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.normal = v.normal;
    out.colour = v.colour;
    out.id = v.id;
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
    out.colour = vec4<f32>(f.colour * shade, 1.0);
    out.depth = f.depth;
    out.id = f.id;
    return out;
}
