// Reading nodes and triangles out of block rows (the byte layout is documented in
// src/blocks/mod.rs). Which row holds a block is `locate`'s answer (dc.wgsl).
#import params
#import store
#import node

// Fixed for a model: pipeline constants, so that the driver turns the divisions of block
// addressing into multiplies and shifts (CPU drivers otherwise divide lane by lane).
override NODES_PER_BLOCK: u32 = 128u;
override TRIS_PER_BLOCK: u32 = 204u;

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
    return node_of(texel(row, slot * 4u), texel(row, slot * 4u + 1u), texel(row, slot * 4u + 2u),
                   texel(row, slot * 4u + 3u));
}

fn word_at(row: u32, w: u32) -> u32 {
    let t = texel(row, w / 4u);
    let c = w % 4u;
    return select(select(t.w, t.z, c == 2u), select(t.y, t.x, c == 0u), c < 2u);
}

// The first texel of triangle `slot` and the word its 9 words start at within it: they always
// span exactly 3 texels.
fn tri_texel(slot: u32) -> vec2<u32> {
    let w = slot * 9u;
    return vec2(w / 4u, w % 4u);
}

fn tri_at(row: u32, slot: u32) -> Tri {
    let t = tri_texel(slot);
    return tri_of(texel(row, t.x), texel(row, t.x + 1u), texel(row, t.x + 2u), t.y);
}

// The triangle in texels a, b and c from word o of a.
fn tri_of(a: vec4<u32>, b: vec4<u32>, c: vec4<u32>, o: u32) -> Tri {
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
