// Ray generation for one batch of 8x8 tiles: one invocation per ray, pixel centres exactly as
// docs/ARCHITECTURE.md (Cameras and rays) defines them for a perspective or a parallel camera
// (jittered by the sampler when JITTER is set). Valid rays are appended to the live list; with
// CULL, a ray that misses the (padded) root box is done at once and skips traversal: its result,
// a miss, is what traversal would give.
#import params
#import ray
#import tiles
#import queue
#import blocks
#import dc
#import intersect
#import sampling

@group(1) @binding(0) var<storage, read_write> rays: array<RayGroups>;

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

@compute @workgroup_size(WORKGROUP)  // the `args` kernel sizes indirect dispatches by it
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let i = gid.x;
    var live = false;
    if i < params.batch_rays {
        let l = tile_pixel(i);
        let lx = l.x;
        let ly = l.y;
        let px = params.rect_x + lx;
        let py = params.rect_y + ly;
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
        if lx >= params.rect_w || ly >= params.rect_h || !finite3(d) || !finite3(o) {
            r.status = OUTSIDE;
        } else if (params.flags & CULL) != 0u && !hits_root(o, d) {
            r.status = DONE;
        } else {
            live = true;
        }
        rays[i] = ray_groups(r);
    }
    append_live(live, lid, i);
}
