// Mirror test (tests only): evaluates the shared functions that have CPU twins (src/mirror/,
// dc::cache_line of the input over 4, bvh::Node::child_box, colormap and srgb_color) on the host's inputs, one case per invocation, so the
// tests can compare the twins with the GPU.
#import params
#import tiles
#import sampling
#import offset
#import dc
#import node
#import colormap
#import compensated

// Mirrors gpu::layout::MirrorCase.
struct MirrorCase {
    p: vec4<f32>,      // offset_ray's point (xyz) and distance (w)
    n: vec4<f32>,      // offset_ray's and cosine_dir's normal (xyz)
    u: vec4<f32>,      // cosine_dir's sample (xy)
    words: vec4<u32>,  // hash input, sample2's pixel, dim, index (child_box's slot: index % 4)
    node: array<vec4<u32>, 4>,  // child_box's node
    c: vec4<f32>,      // colormap's s, lo, scale (map: words.z % 4; srgb_color's word: words.x)
}

// Mirrors gpu::layout::MirrorResult.
struct MirrorResult {
    offset: vec4<f32>,   // offset_ray(p, n)
    dir: vec4<f32>,      // cosine_dir(n, u)
    sample: vec4<f32>,   // sample2(pixel, dim, index) in xy, dot_difference(n, p, u) in z
    words: vec4<u32>,    // hash(input), tile_pixel(invocation) in yz, cache_line(input)
    lo: vec4<f32>,       // child_box(node, node_step(node), slot)
    hi: vec4<f32>,
    color: vec4<f32>,    // colormap(c.x, c.y, c.z, words.z % 4)
    rgb: vec4<f32>,      // srgb_color(words.x)
    row: vec4<u32>,      // block_row(invocation) in x
    patched: vec4<f32>,  // sample2_patch(pixel, params.width, dim, index) in xy
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
    r.sample = vec4(sample2(c.words.y, c.words.z, c.words.w),
                    dot_difference(c.n.xyz, c.p.xyz, c.u.xyz), 0.0);
    let t = tile_pixel(i);
    r.words = vec4(hash(c.words.x), t.x, t.y, cache_line(c.words.x >> 2u));
    let n = node_of(c.node[0], c.node[1], c.node[2], c.node[3]);
    let b = child_box(n, node_step(n), c.words.w % 4u);
    r.lo = vec4(b.lo, 0.0);
    r.hi = vec4(b.hi, 0.0);
    r.color = vec4(colormap(c.c.x, c.c.y, c.c.z, c.words.z % 4u), 0.0);
    r.rgb = vec4(srgb_color(c.words.x), 0.0);
    r.row = vec4(block_row(i), 0u, 0u, 0u);
    r.patched = vec4(sample2_patch(c.words.y, params.width, c.words.z, c.words.w), 0.0, 0.0);
    mirror_out[i] = r;
}
