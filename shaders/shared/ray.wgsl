// The state of one ray between traversal rounds (host: gpu::layout::RayState) and what every kernel
// asks of a ray.
#import params

// The initial tmax: finite, because WGSL gives no guarantees for infinities.
const FAR: f32 = 3.0e38;

// RayState.status
const LIVE: u32 = 0u;
const DONE: u32 = 1u;
const OUTSIDE: u32 = 2u;   // pixel outside the image (partial edge tile) or an invalid ray
const OVERFLOW: u32 = 3u;  // traversal stack overflow: reported to the host as an error
// A primary ray the first traversal round ended and wrote the pixel of (shared/pixel.wgsl,
// first_round_shades): only this status is stored, and the shade kernel skips the slot.
const SHADED: u32 = 4u;

// Mirrors gpu::layout::RayState: one per ray of a batch, kept between trace dispatches.
struct RayState {
    ox: f32, oy: f32, oz: f32,
    t: f32,       // closest hit so far (the ray's tmax)
    dx: f32, dy: f32, dz: f32,
    hit: u32,     // triangle index (BVH order) of the closest hit, or NONE
    sp: u32,      // stack entries in use
    status: u32,
    steps: u32,   // loop iterations taken so far
    // What the ray visits next, as a stack entry holds it: node `cur_index` when `cur_count` is
    // 0, else `cur_count` triangles from `cur_index`; `cur_count` NONE to pop the stack.
    cur_index: u32,
    cur_count: u32,
    // The block this ray suspended on, or NONE: until it arrives the ray only renews its request.
    wait_block: u32,
    flags: u32,   // ANY_HIT, FROM_CAMERA
    // The triangle (BVH order) a secondary ray leaves, which it cannot hit again (a ray meets a
    // plane once), or NONE: skipping it saves proving, in extended precision, that its hit lies
    // behind the origin.
    skip: u32,
    // Recorded when the closest hit is found, while its block is at hand: shading then needs no
    // block. Traversal reads none of what follows (the first four groups of RayGroups hold the
    // rest) and writes it only with a closer hit.
    prim: u32,
    nx: f32, ny: f32, nz: f32,
    // The closest hit's point, from its barycentrics, and how far along the normal a new ray's
    // origin must move to be past its rounding error (hit_point_error, offset_distance).
    hx: f32, hy: f32, hz: f32,
    herr: f32,
    // The closest hit's barycentrics of v1 and v2: point data is interpolated with them.
    b1: f32, b2: f32,
    pad0: u32,
    pad1: u32,
}

// A RayState as the rays buffer holds it: seven 16-byte groups of its words in member order
// (the host's gpu::layout::RayState). Kernels bind `array<RayGroups>` and load and store whole
// groups: a CPU driver moves every member of a buffer load or store in a loop over the lanes of
// its own, so a group moves four members in one loop where members would take four.
struct RayGroups {
    g: array<vec4<u32>, 7>,
}

fn ray_state(w: RayGroups) -> RayState {
    let a = w.g[0];
    let b = w.g[1];
    let c = w.g[2];
    let d = w.g[3];
    let e = w.g[4];
    let f = bitcast<vec4<f32>>(w.g[5]);
    let g = w.g[6];
    let af = bitcast<vec4<f32>>(a);
    let bf = bitcast<vec4<f32>>(b);
    let ef = bitcast<vec4<f32>>(e);
    let gf = bitcast<vec4<f32>>(g);
    return RayState(af.x, af.y, af.z, af.w, bf.x, bf.y, bf.z, b.w, c.x, c.y, c.z, c.w, d.x, d.y,
                    d.z, d.w, e.x, ef.y, ef.z, ef.w, f.x, f.y, f.z, f.w, gf.x, gf.y, g.z, g.w);
}

fn ray_groups(r: RayState) -> RayGroups {
    return RayGroups(array(
        bitcast<vec4<u32>>(vec4(r.ox, r.oy, r.oz, r.t)),
        vec4(bitcast<vec3<u32>>(vec3(r.dx, r.dy, r.dz)), r.hit),
        vec4(r.sp, r.status, r.steps, r.cur_index),
        vec4(r.cur_count, r.wait_block, r.flags, r.skip),
        vec4(r.prim, bitcast<vec3<u32>>(vec3(r.nx, r.ny, r.nz))),
        bitcast<vec4<u32>>(vec4(r.hx, r.hy, r.hz, r.herr)),
        vec4(bitcast<vec2<u32>>(vec2(r.b1, r.b2)), r.pad0, r.pad1)));
}

// RayState.flags: stop at the first hit found (shadow and ambient-occlusion rays).
const ANY_HIT: u32 = 1u;
// RayState.flags: the ray starts at the camera, on no surface: it cannot hit the surface it
// leaves, so a hit needs no proof that it lies in front of the origin beyond rounding.
const FROM_CAMERA: u32 = 2u;

// A ray that has not started traversal: no hit, the root next.
fn new_ray(o: vec3<f32>, d: vec3<f32>, tmax: f32, status: u32, flags: u32, skip: u32)
    -> RayState {
    return RayState(o.x, o.y, o.z, tmax, d.x, d.y, d.z, NONE, 0u, status, 0u, 0u, 0u, NONE,
                    flags, skip, NONE, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0u, 0u);
}

fn ray_origin(r: RayState) -> vec3<f32> {
    return vec3(r.ox, r.oy, r.oz);
}

fn ray_dir(r: RayState) -> vec3<f32> {
    return vec3(r.dx, r.dy, r.dz);
}

fn ray_hit_point(r: RayState) -> vec3<f32> {
    return vec3(r.hx, r.hy, r.hz);
}

// Whether a ray can be traced: finite origin, direction and tmax (checked on the bits: WGSL
// implementations may assume no NaN or infinity, so IEEE comparisons cannot be trusted to find
// them), a nonzero direction and a positive tmax. Other rays are misses.
fn ray_valid(r: RayState) -> bool {
    let e = (bitcast<vec3<u32>>(ray_origin(r)) >> vec3(23u)) & vec3(0xffu);
    let f = (bitcast<vec3<u32>>(ray_dir(r)) >> vec3(23u)) & vec3(0xffu);
    let g = (bitcast<u32>(r.t) >> 23u) & 0xffu;
    let finite = all(e != vec3(0xffu)) && all(f != vec3(0xffu)) && g != 0xffu;
    // Sign bits masked off: -0.0 is zero too.
    let nonzero = any((bitcast<vec3<u32>>(ray_dir(r)) & vec3(0x7fffffffu)) != vec3(0u));
    return finite && nonzero && r.t > 0.0;
}
