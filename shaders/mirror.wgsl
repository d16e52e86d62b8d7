// Mirror test (tests only): evaluates the shared functions that have CPU twins (src/mirror/, and
// dc::cache_line of the input over 4) on the host's inputs, one case per invocation, so the
// tests can compare the twins with the GPU.
#import params
#import tiles
#import sampling
#import offset
#import dc

// Mirrors gpu::layout::MirrorCase.
struct MirrorCase {
    p: vec4<f32>,      // offset_ray's point (xyz) and distance (w)
    n: vec4<f32>,      // offset_ray's and cosine_dir's normal (xyz)
    u: vec4<f32>,      // cosine_dir's sample (xy)
    words: vec4<u32>,  // hash input, sample2's pixel, dim, index
}

// Mirrors gpu::layout::MirrorResult.
struct MirrorResult {
    offset: vec4<f32>,   // offset_ray(p, n)
    dir: vec4<f32>,      // cosine_dir(n, u)
    sample: vec4<f32>,   // sample2(pixel, dim, index) in xy
    words: vec4<u32>,    // hash(input), tile_pixel(invocation) in yz, cache_line(input)
}

@group(1) @binding(0) var<storage, read> mirror_in: array<MirrorCase>;
@group(1) @binding(1) var<storage, read_write> mirror_out: array<MirrorResult>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= arrayLength(&mirror_in) {
        return;
    }
    let c = mirror_in[i];
    var r: MirrorResult;
    r.offset = vec4(offset_ray(c.p.xyz, c.n.xyz, c.p.w), 0.0);
    r.dir = vec4(cosine_dir(c.n.xyz, c.u.xy), 0.0);
    r.sample = vec4(sample2(c.words.y, c.words.z, c.words.w), 0.0, 0.0);
    let t = tile_pixel(i);
    r.words = vec4(hash(c.words.x), t.x, t.y, cache_line(c.words.x >> 2u));
    mirror_out[i] = r;
}
