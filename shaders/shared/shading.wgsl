// The shading kernels' parameters (host: gpu::layout::ShadeParams), the per-pixel path state
// between waves of secondary rays, and the pixel they write.

// Mirrors gpu::layout::Light. pos.w: 0 directional (xyz: unit direction towards the light),
// 1 point (xyz: position); color: the light's scale (irradiance at unit distance for a point).
struct Light {
    pos: vec4<f32>,
    color: vec4<f32>,
}

// Mirrors gpu::layout::MAX_LIGHTS.
const MAX_LIGHTS: u32 = 4u;

// Mirrors gpu::layout::ShadeParams.
struct ShadeParams {
    sky: vec4<f32>,      // path: constant sky radiance
    sun_dir: vec4<f32>,  // path: unit direction towards the sun
    sun: vec4<f32>,      // path: sun irradiance; w 1 when the sun is on (next-event rays)
    mode: u32,
    fan: u32,            // secondary rays per pixel in one wave
    ao_rays: u32,
    ao_distance: f32,
    max_depth: u32,
    rr_depth: u32,       // Russian roulette from this bounce on
    light_count: u32,
    offset_mode: u32,    // 0: past the hit point's error along the normal, 1: fixed epsilon
    epsilon: f32,
    ambient: f32,        // shadows: ambient term
    any_hit: u32,        // RayState.flags of shadow and occlusion rays (ANY_HIT, or 0)
    pad1: u32,
    lights: array<Light, MAX_LIGHTS>,
}

// The shading parameters of the render (one buffer; the modes' kernels and a wave's first
// traversal round read it).
@group(0) @binding(8) var<storage, read> shading: ShadeParams;

const MODE_CAST: u32 = 0u;
const MODE_SHADOWS: u32 = 1u;
const MODE_AO: u32 = 2u;
const MODE_PATH: u32 = 3u;
// The pipeline's shading mode: each mode compiles only its own code.
override MODE: u32 = 0u;

// Mirrors gpu::layout::Path: the per-pixel state of a sample between waves of secondary rays.
struct Path {
    pos: vec3<f32>,
    alive: u32,
    n: vec3<f32>,      // geometric normal facing the incoming ray
    depth: u32,        // bounces so far
    albedo: vec3<f32>,
    pixel: u32,        // y * width + x: keys the sampler
    tp: vec3<f32>,     // path throughput
    err: f32,          // how far along n a new ray's origin moves (offset_ray)
    l: vec3<f32>,      // radiance gathered so far
    tri: u32,          // the hit triangle (BVH order), which rays leaving it skip
}

// Mirrors gpu::layout::Pixel: what the shade kernel writes for each ray.
struct Pixel {
    r: f32, g: f32, b: f32,
    // Hit distance along the normalized ray as f32 bits; +inf on a miss (written as bits since
    // WGSL has no infinity literal).
    depth_bits: u32,
    id: u32,      // primitive id; NONE on a miss
    nx: f32, ny: f32, nz: f32,
}
