// Reading nodes and triangles out of block rows (the byte layout is documented in
// src/blocks/mod.rs). Which row holds a block is `locate`'s answer (dc.wgsl).
#import params
#import store

// Fixed for a model: pipeline constants, so that the driver turns the divisions of block
// addressing into multiplies and shifts (CPU drivers otherwise divide lane by lane).
override NODES_PER_BLOCK: u32 = 128u;
override TRIS_PER_BLOCK: u32 = 204u;

// Mirrors bvh::Node: a 4-wide node, its children's boxes quantized on a per-node grid.
struct Node {
    origin: vec3<f32>,
    exponents: u32,   // per axis (byte) the biased f32 exponent of the grid step
    child_base: u32,  // the first inner child; inner children are adjacent in slot order
    tri_base: u32,    // the first triangle of the leaf children, adjacent in slot order
    counts: u32,      // per slot (byte): EMPTY, INNER or the leaf's triangle count
    lo: vec3<u32>,    // per axis, byte i: slot i's lower bound in grid steps
    hi: vec3<u32>,
}

// Node.counts bytes.
const EMPTY: u32 = 0u;
const INNER: u32 = 255u;

struct Box {
    lo: vec3<f32>,
    hi: vec3<f32>,
}

struct Tri {
    v0: vec3<f32>,
    v1: vec3<f32>,
    v2: vec3<f32>,
}

// (block id, slot in the block) of node i and of triangle t.
fn node_loc(i: u32) -> vec2<u32> {
    let b = i / NODES_PER_BLOCK;
    return vec2(b, i - b * NODES_PER_BLOCK);
}

fn tri_loc(t: u32) -> vec2<u32> {
    let b = t / TRIS_PER_BLOCK;
    return vec2(params.node_blocks + b, t - b * TRIS_PER_BLOCK);
}

fn node_at(row: u32, slot: u32) -> Node {
    let a = texel(row, slot * 4u);
    let b = texel(row, slot * 4u + 1u);
    let c = texel(row, slot * 4u + 2u);
    let d = texel(row, slot * 4u + 3u);
    return Node(bitcast<vec3<f32>>(a.xyz), a.w, b.x, b.y, b.z, c.xyz, vec3(c.w, d.x, d.y));
}

// The grid step per axis, a power of two (0 on an axis where every child is flat).
fn node_step(n: Node) -> vec3<f32> {
    return bitcast<vec3<f32>>(((vec3(n.exponents) >> vec3(0u, 8u, 16u)) & vec3(0xffu)) << vec3(23u));
}

// Slot i's box (mirror: bvh::Node::child_box): `q * step` is exact, and the host chose each q so
// that the one rounding of the sum falls outside the exact box.
fn child_box(n: Node, step: vec3<f32>, i: u32) -> Box {
    let s = vec3(8u * i);
    let lo = vec3<f32>((n.lo >> s) & vec3(0xffu));
    let hi = vec3<f32>((n.hi >> s) & vec3(0xffu));
    return Box(n.origin + lo * step, n.origin + hi * step);
}

// The union of the used slots' boxes (mirror: bvh::Node::bounds): the root's holds the scene.
fn node_bounds(n: Node) -> Box {
    let step = node_step(n);
    var b = Box(vec3(3.0e38), vec3(-3.0e38));
    for (var i = 0u; i < 4u; i++) {
        if ((n.counts >> (8u * i)) & 0xffu) != EMPTY {
            let c = child_box(n, step, i);
            b = Box(min(b.lo, c.lo), max(b.hi, c.hi));
        }
    }
    return b;
}

fn word_at(row: u32, w: u32) -> u32 {
    let t = texel(row, w / 4u);
    let c = w % 4u;
    return select(select(t.w, t.z, c == 2u), select(t.y, t.x, c == 0u), c < 2u);
}

fn tri_at(row: u32, slot: u32) -> Tri {
    // The 9 words of a triangle always span exactly 3 texels, starting at word offset o.
    let w = slot * 9u;
    let t0 = w / 4u;
    let o = w % 4u;
    let a = texel(row, t0);
    let b = texel(row, t0 + 1u);
    let c = texel(row, t0 + 2u);
    var v: vec3<f32>;
    var e: vec3<f32>;
    var f: vec3<f32>;
    // Select the 9 words by offset without a dynamically indexed local array (slow on CPUs).
    if o == 0u {
        v = bitcast<vec3<f32>>(a.xyz);
        e = bitcast<vec3<f32>>(vec3(a.w, b.x, b.y));
        f = bitcast<vec3<f32>>(vec3(b.z, b.w, c.x));
    } else if o == 1u {
        v = bitcast<vec3<f32>>(a.yzw);
        e = bitcast<vec3<f32>>(b.xyz);
        f = bitcast<vec3<f32>>(vec3(b.w, c.x, c.y));
    } else if o == 2u {
        v = bitcast<vec3<f32>>(vec3(a.z, a.w, b.x));
        e = bitcast<vec3<f32>>(vec3(b.y, b.z, b.w));
        f = bitcast<vec3<f32>>(c.xyz);
    } else {
        v = bitcast<vec3<f32>>(vec3(a.w, b.x, b.y));
        e = bitcast<vec3<f32>>(vec3(b.z, b.w, c.x));
        f = bitcast<vec3<f32>>(c.yzw);
    }
    return Tri(v, e, f);
}

fn prim_id_at(row: u32, slot: u32) -> u32 {
    return word_at(row, 9u * TRIS_PER_BLOCK + slot);
}
