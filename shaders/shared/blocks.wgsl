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
