// Camera rays: the primary ray of a batch slot, its pixel centre exactly as docs/ARCHITECTURE.md
// (Cameras and rays) defines it for a perspective or a parallel camera (jittered by the sampler
// when JITTER is set). The first traversal round makes them in registers (shaders/traverse.wgsl):
// a kernel of its own would store every ray's seven groups for the first round to load back.
#import params
#import ray
#import tiles
#import blocks
#import dc
#import intersect
#import sampling

fn finite3(v: vec3<f32>) -> bool {
    // Exponent bits all set means inf or NaN; checked on the bits, not with IEEE comparisons.
    let e = (bitcast<vec3<u32>>(v) >> vec3(23u)) & vec3(0xffu);
    return all(e != vec3(0xffu));
}

// The root node's box, padded far beyond rounding: every child box a traversal could enter lies
// inside it. The root block is resident on every rank, so this never faults.
fn hits_root(o: vec3<f32>, d: vec3<f32>) -> bool {
    let root = node_bounds(node_at(locate(0u), 0u));
    let pad = (root.hi - root.lo) * 1e-3 + max(abs(root.lo), abs(root.hi)) * 1e-5;
    return box_entry(root.lo - pad, root.hi + pad, o, safe_inverse(d), FAR) >= 0.0;
}

// The primary ray of batch slot i: LIVE; OUTSIDE for a slot past the rectangle or a ray that is
// not finite; with CULL, DONE for a miss of the (padded) root box, which is what traversal would
// give it.
fn camera_ray(i: u32) -> RayState {
    let l = tile_pixel(i);
    let px = params.rect_x + l.x;
    let py = params.rect_y + l.y;
    var j = vec2(0.5, 0.5);
    if (params.flags & JITTER) != 0u {
        j = sample2(py * params.width + px, 0u, params.sample);
    }
    let sx = 2.0 * (f32(px) + j.x) / f32(params.width) - 1.0;
    let sy = 1.0 - 2.0 * (f32(py) + j.y) / f32(params.height);
    var d = normalize(params.forward.xyz + sx * params.right.xyz + sy * params.up.xyz);
    var o = params.origin.xyz;
    // A parallel projection: every ray along the view, from its place on the image plane.
    if (params.flags & PARALLEL) != 0u {
        d = normalize(params.forward.xyz);
        o = params.origin.xyz + sx * params.right.xyz + sy * params.up.xyz;
    }
    var r = new_ray(o, d, FAR, LIVE, FROM_CAMERA, NONE);
    if l.x >= params.rect_w || l.y >= params.rect_h || !finite3(d) || !finite3(o) {
        r.status = OUTSIDE;
    } else if (params.flags & CULL) != 0u && !hits_root(o, d) {
        r.status = DONE;
    }
    return r;
}
