// Shared by every kernel: the structs the host writes (mirrored in src/gpu/layout.rs, checked by
// the layout probe test), the scene bindings (group 0), block accessors and the robust
// ray/box and ray/triangle tests. The host prepends this file to each kernel.

const NONE: u32 = 0xffffffffu;
// The initial tmax: finite, because WGSL gives no guarantees for infinities.
const FAR: f32 = 3.0e38;
const TILE: u32 = 8u;
const WORKGROUP: u32 = 64u;

// RayState.status
const LIVE: u32 = 0u;
const DONE: u32 = 1u;
const OUTSIDE: u32 = 2u;   // pixel outside the image (partial edge tile) or an invalid ray
const OVERFLOW: u32 = 3u;  // traversal stack overflow: reported to the host as an error

// Mirrors gpu::layout::Params.
struct Params {
    origin: vec4<f32>,
    forward: vec4<f32>,
    right: vec4<f32>,       // camera right * tan(view_angle / 2) * aspect
    up: vec4<f32>,          // camera up * tan(view_angle / 2)
    background: vec4<f32>,
    width: u32,
    height: u32,
    tiles_x: u32,
    first_tile: u32,
    batch_rays: u32,
    step_budget: u32,
    stack_size: u32,
    mesh_count: u32,
    node_blocks: u32,
    // Distributed cache (DESIGN.md sections 2, 3): ranks N, this rank, cache lines, mapping
    // (0 Ize, 1 DeMarle), first cache row, the replicated root block's row, fault list capacity.
    dc_ranks: u32,
    dc_rank: u32,
    dc_lines: u32,
    dc_map: u32,
    dc_cache_row: u32,
    dc_root_row: u32,
    dc_fault_cap: u32,
    // The rectangle of the image this render covers; tiles_x counts 8x8 tiles across it.
    rect_x: u32,
    rect_y: u32,
    rect_w: u32,
    rect_h: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    pad3: u32,
    // Sampling: the sample index of this pass (the sampler's index), the seed, flags (JITTER,
    // CULL, FIRST_SAMPLE) and the samples per pixel of the render.
    sample: u32,
    seed: u32,
    flags: u32,
    spp: u32,
}

// Params.flags
const JITTER: u32 = 1u;        // jitter primary rays in the pixel (spp > 1)
const CULL: u32 = 2u;          // primary rays that miss the root box skip traversal
const FIRST_SAMPLE: u32 = 4u;  // the first pass of a render: the shade kernel resets pixels

// Fixed for a model: pipeline constants, so that the driver turns the divisions of block
// addressing into multiplies and shifts (CPU drivers otherwise divide lane by lane).
override NODES_PER_BLOCK: u32 = 256u;
override TRIS_PER_BLOCK: u32 = 204u;
override TEXELS_PER_BLOCK: u32 = 512u;
override ROWS_PER_LAYER: u32 = 16384u;

// Mirrors gpu::layout::RayState: one per ray of a batch, kept between trace dispatches.
struct RayState {
    ox: f32, oy: f32, oz: f32,
    t: f32,       // closest hit so far (the ray's tmax)
    dx: f32, dy: f32, dz: f32,
    hit: u32,     // triangle index (BVH order) of the closest hit, or NONE
    node: u32,    // node to visit next, or NONE to pop the stack
    sp: u32,      // stack entries in use
    status: u32,
    steps: u32,   // loop iterations taken so far
    // The content of `node` when already read (`cur_count` NONE when not): a resumed ray need
    // not read its parent's block again.
    cur_index: u32,
    cur_count: u32,
    // Recorded when the closest hit is found, while its block is at hand: shading then needs no
    // block.
    prim: u32,
    nx: f32, ny: f32, nz: f32,
    // The block this ray suspended on, or NONE: until it arrives the ray only renews its request.
    wait_block: u32,
    flags: u32,   // ANY_HIT
}

// RayState.flags: stop at the first hit found (shadow and ambient-occlusion rays).
const ANY_HIT: u32 = 1u;

// Mirrors gpu::layout::MeshInfo.
struct MeshInfo {
    color: vec4<f32>,
    first_prim: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
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

// Mirrors gpu::layout::Counter: a live-ray count followed by indirect dispatch arguments.
struct Counter {
    count: atomic<u32>,
    x: u32,
    y: u32,
    z: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Block storage (binding 1 and `fn texel(block, t) -> vec4<u32>`) comes from store_*.wgsl.
@group(0) @binding(2) var<storage, read> meshes: array<MeshInfo>;

struct Node {
    lo: vec3<f32>,
    hi: vec3<f32>,
    index: u32,
    count: u32,
}

// --- Block access. `locate` maps a block id to the row that holds it, or NONE after recording a
// fault; the accessors below read from a row.

// Pipelines built for the distributed cache set DC; replicated ones leave it false and pay for
// no cache check at all.
override DC: bool = false;

// Mirrors gpu::layout::FaultHeader, followed by the deduplicated list of faulted blocks.
struct Faults {
    count: atomic<u32>,
    dropped: atomic<u32>,
    pad0: u32,
    pad1: u32,
    blocks: array<u32>,
}
// The row of every block on this GPU (resident or cached), NONE when absent: one load replaces
// the ownership and tag arithmetic. The host updates it between rounds.
@group(0) @binding(3) var<storage, read> block_rows: array<u32>;
@group(0) @binding(4) var<storage, read_write> faults: Faults;
@group(0) @binding(5) var<storage, read_write> requested: array<atomic<u32>>;  // bit per block
@group(0) @binding(6) var<storage, read_write> waiters: array<atomic<u32>>;    // per cache line

// Per invocation, summed into Stats by the trace kernel.
var<private> dc_lookups: u32 = 0u;
var<private> dc_hits: u32 = 0u;
var<private> dc_misses: u32 = 0u;

fn cache_line(k: u32) -> u32 {
    if params.dc_map == 0u {
        // Ize: count only the blocks this rank does not own, so no line is wasted.
        let n = params.dc_ranks;
        return (k - (k + (n - params.dc_rank)) / n) % params.dc_lines;
    }
    return k % params.dc_lines;
}

fn locate(k: u32) -> u32 {
    if !DC {
        return k;
    }
    let row = block_rows[k];
    if row < params.dc_cache_row {
        return row;  // owned, or the replicated root
    }
    dc_lookups += 1u;
    if row != NONE {
        dc_hits += 1u;
        return row;
    }
    dc_misses += 1u;
    request(k);
    return NONE;
}

// Records a fault on block k, once per round however many rays ask.
fn request(k: u32) {
    atomicAdd(&waiters[cache_line(k)], 1u);
    let bit = 1u << (k % 32u);
    if (atomicOr(&requested[k / 32u], bit) & bit) == 0u {
        let i = atomicAdd(&faults.count, 1u);
        if i < params.dc_fault_cap {
            faults.blocks[i] = k;
        } else {
            atomicAdd(&faults.dropped, 1u);
        }
    }
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
    let a = texel(row, slot * 2u);
    let b = texel(row, slot * 2u + 1u);
    return Node(bitcast<vec3<f32>>(a.xyz), vec3<f32>(bitcast<f32>(a.w), bitcast<vec2<f32>>(b.xy)), b.z, b.w);
}

fn word_at(row: u32, w: u32) -> u32 {
    let t = texel(row, w / 4u);
    let c = w % 4u;
    return select(select(t.w, t.z, c == 2u), select(t.y, t.x, c == 0u), c < 2u);
}

struct Tri {
    v0: vec3<f32>,
    v1: vec3<f32>,
    v2: vec3<f32>,
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

// Reciprocal of a direction, clamped so that no component is infinite: WGSL does not promise
// IEEE behaviour for 1/0, and a huge finite value gives the same slab answer without NaNs.
// A clamped component is exactly +-PARALLEL_INV, which box_entry recognizes.
const PARALLEL_INV: f32 = 1e20;
fn safe_inverse(d: vec3<f32>) -> vec3<f32> {
    let tiny = 1e-20;
    let s = select(vec3(-PARALLEL_INV), vec3(PARALLEL_INV), d >= vec3(0.0));
    return select(1.0 / d, s, abs(d) < vec3(tiny));
}

// Conservative slab test (Ize, JCGT 2013): the exit distance is widened to cover the rounding of
// the subtraction, the 2.5-ulp WGSL division and the product. Returns the entry distance, or -1.
const EXIT_WIDEN: f32 = 1.0000024;
fn box_entry(lo: vec3<f32>, hi: vec3<f32>, org: vec3<f32>, inv: vec3<f32>, tmax: f32) -> f32 {
    let t0 = (lo - org) * inv;
    let t1 = (hi - org) * inv;
    // A ray parallel to a slab and lying in one of its planes stays in the slab for every t, but
    // 0 * inv gives 0 for that plane and would cut the interval at t = 0: such a ray would slip
    // past a mesh edge or face it runs along. Inside the closed slab, the interval is unbounded.
    let along = abs(inv) == vec3(PARALLEL_INV) & org >= lo & org <= hi;
    let tn = select(min(t0, t1), vec3(-FAR), along);
    let tf = select(max(t0, t1), vec3(FAR), along);
    let enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    let exit = min(min(tf.x, tf.y), tf.z) * EXIT_WIDEN;
    return select(-1.0, enter, enter <= min(exit, tmax));
}

// Per-ray constants of the watertight test (Woop, Benthin & Wald, JCGT 2013).
struct Shear {
    k: vec3<u32>,  // kx, ky, kz
    s: vec3<f32>,  // Sx, Sy, Sz
}

fn max_axis(v: vec3<f32>) -> u32 {
    let a = abs(v);
    return select(select(2u, 1u, a.y >= a.z), select(2u, 0u, a.x >= a.z), a.x >= a.y);
}

fn make_shear(d: vec3<f32>) -> Shear {
    let kz = max_axis(d);
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let t = kx;
        kx = ky;
        ky = t;
    }
    let sz = 1.0 / d[kz];
    return Shear(vec3(kx, ky, kz), vec3(d[kx] * sz, d[ky] * sz, sz));
}

// 2D edge function of the sheared vertices a, b. Evaluated in a canonical vertex order so that two
// triangles sharing an edge compute exactly the negated value even when the compiler contracts
// to fused multiply-adds: that keeps the test watertight.
fn edge(a: vec2<f32>, b: vec2<f32>) -> f32 {
    let swap = a.x > b.x || (a.x == b.x && a.y > b.y);
    let p = select(a, b, swap);
    let q = select(b, a, swap);
    let e = p.x * q.y - p.y * q.x;
    return select(e, -e, swap);
}

// Returns the hit distance in (0, tmax), or -1. Degenerate triangles (det == 0) never hit.
fn intersect(tri: Tri, org: vec3<f32>, sh: Shear, tmax: f32) -> f32 {
    let a = tri.v0 - org;
    let b = tri.v1 - org;
    let c = tri.v2 - org;
    let a2 = vec2(a[sh.k.x] - sh.s.x * a[sh.k.z], a[sh.k.y] - sh.s.y * a[sh.k.z]);
    let b2 = vec2(b[sh.k.x] - sh.s.x * b[sh.k.z], b[sh.k.y] - sh.s.y * b[sh.k.z]);
    let c2 = vec2(c[sh.k.x] - sh.s.x * c[sh.k.z], c[sh.k.y] - sh.s.y * c[sh.k.z]);
    let u = edge(c2, b2);
    let v = edge(a2, c2);
    let w = edge(b2, a2);
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return -1.0;
    }
    let det = u + v + w;
    if det == 0.0 {
        return -1.0;
    }
    let z = sh.s.z * vec3(a[sh.k.z], b[sh.k.z], c[sh.k.z]);
    let tt = u * z.x + v * z.y + w * z.z;
    // Sign-aware: the hit is in front when tt and det agree in sign.
    let stt = select(tt, -tt, det < 0.0);
    if stt <= 0.0 {
        return -1.0;
    }
    let t = stt / abs(det);
    if t <= 0.0 || t >= tmax {
        return -1.0;
    }
    // A hit closer than the rounding error of t may be behind the origin: a ray leaving a
    // surface would hit it again (pbrt-v4's conservative t; a needle's error grows with its
    // length over its width, beyond any origin offset).
    let max_z = max(max(abs(z.x), abs(z.y)), abs(z.z));
    let max_x = max(max(abs(a2.x), abs(b2.x)), abs(c2.x));
    let max_y = max(max(abs(a2.y), abs(b2.y)), abs(c2.y));
    let max_e = max(max(abs(u), abs(v)), abs(w));
    let delta_x = gamma(5.0) * (max_x + max_z);
    let delta_y = gamma(5.0) * (max_y + max_z);
    let delta_z = gamma(3.0) * max_z;
    let delta_e = 2.0 * (gamma(2.0) * max_x * max_y + delta_y * max_x + delta_x * max_y);
    let delta_t = 3.0 * (gamma(3.0) * max_e * max_z + delta_e * max_z + delta_z * max_e) / abs(det);
    if t <= delta_t {
        return -1.0;
    }
    return t;
}

// Bound on the relative rounding error of n correctly rounded f32 operations (pbrt's gamma).
fn gamma(n: f32) -> f32 {
    let u = 5.9604645e-8;  // 2^-24
    return n * u / (1.0 - n * u);
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

fn max3(v: vec3<f32>) -> f32 {
    return max(max(v.x, v.y), v.z);
}

// Unit geometric normal, normalize((v1 - v0) x (v2 - v0)), scaled before squaring: a plain
// normalize loses the squares to denormals below ~1e-10 across (a normal that is not unit, or
// NaN) and overflows above ~1e10 (a zero normal). A hit triangle has nonzero edges; if its
// edges are parallel in f32 (a needle), any unit vector perpendicular to the first edge is
// returned.
fn unit_normal(tri: Tri) -> vec3<f32> {
    let e1 = tri.v1 - tri.v0;
    let e2 = tri.v2 - tri.v0;
    let c = cross(e1 / max3(abs(e1)), e2 / max3(abs(e2)));
    let m = max3(abs(c));
    let p = select(vec3(0.0, -e1.z, e1.y), vec3(-e1.y, e1.x, 0.0), abs(e1.x) > abs(e1.z));
    let n = select(p / max3(abs(p)), c / m, m > 0.0);
    return normalize(n);
}

fn ray_origin(r: RayState) -> vec3<f32> {
    return vec3(r.ox, r.oy, r.oz);
}

fn ray_dir(r: RayState) -> vec3<f32> {
    return vec3(r.dx, r.dy, r.dz);
}

// --- Shading (shade, spawn and gather kernels).

// Mirrors gpu::layout::Light. pos.w: 0 directional (xyz: unit direction towards the light),
// 1 point (xyz: position); color: the light's scale (irradiance at unit distance for a point).
struct Light {
    pos: vec4<f32>,
    color: vec4<f32>,
}

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
    offset_mode: u32,    // 0: integer-ulp offset along the normal, 1: fixed epsilon
    epsilon: f32,
    ambient: f32,        // shadows: ambient term
    any_hit: u32,        // RayState.flags of shadow and occlusion rays (ANY_HIT, or 0)
    pad1: u32,
    lights: array<Light, 4>,
}

const MODE_CAST: u32 = 0u;
const MODE_SHADOWS: u32 = 1u;
const MODE_AO: u32 = 2u;
const MODE_PATH: u32 = 3u;
// The pipeline's shading mode: each mode compiles only its own code.
override MODE: u32 = 0u;

const PI: f32 = 3.14159265358979;

// Per-pixel state of a sample between waves of secondary rays (GPU only).
struct Path {
    pos: vec3<f32>,
    alive: u32,
    n: vec3<f32>,      // geometric normal facing the incoming ray
    depth: u32,        // bounces so far
    albedo: vec3<f32>,
    pixel: u32,        // y * width + x: keys the sampler
    tp: vec3<f32>,     // path throughput
    pad0: u32,
    l: vec3<f32>,      // radiance gathered so far
    pad1: u32,
}

// lowbias32 (C. Wellons): mirrored by shading::hash on the CPU.
fn hash(x: u32) -> u32 {
    var v = x;
    v ^= v >> 16u;
    v *= 0x7feb352du;
    v ^= v >> 15u;
    v *= 0x846ca68bu;
    v ^= v >> 16u;
    return v;
}

// The sampler: the R2 sequence (Roberts 2018) in 32-bit fixed point, rotated per pixel and
// dimension pair by a hash (Cranley-Patterson). Integer arithmetic only, so the CPU computes the
// same bits (shading::sample2).
fn sample2(pixel: u32, dim: u32, index: u32) -> vec2<f32> {
    let h = hash(pixel ^ hash(dim * 0x9e3779b9u + params.seed));
    let x = hash(h) + index * 3242174889u;
    let y = hash(h ^ 0x68bc21ebu) + index * 2447445414u;
    return vec2(f32(x >> 8u), f32(y >> 8u)) * (1.0 / 16777216.0);
}

// Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection" (Ray Tracing Gems,
// ch. 6): move p along n by a number of ulps per component (a relative offset), and by a fixed
// amount near the origin where ulps are tiny. Mirrored by shading::offset_ray.
const OFFSET_ORIGIN: f32 = 0.03125;
const OFFSET_FLOAT_SCALE: f32 = 1.52587890625e-05;  // 1 / 65536
const OFFSET_INT_SCALE: f32 = 256.0;
fn offset_ray(p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let of_i = vec3<i32>(OFFSET_INT_SCALE * n);
    let p_i = bitcast<vec3<f32>>(bitcast<vec3<i32>>(p) + select(of_i, -of_i, p < vec3(0.0)));
    return select(p_i, p + OFFSET_FLOAT_SCALE * n, abs(p) < vec3(OFFSET_ORIGIN));
}

// Cosine-weighted direction about unit n from u in [0,1)^2, with the branchless orthonormal
// basis of Duff et al. (JCGT 2017).
fn cosine_dir(n: vec3<f32>, u: vec2<f32>) -> vec3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    let t = vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    let bt = vec3(b, s + n.y * n.y * a, -n.y);
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    return normalize(r * cos(phi) * t + r * sin(phi) * bt + sqrt(max(0.0, 1.0 - u.x)) * n);
}

fn mesh_of(prim: u32) -> u32 {
    // Last mesh whose first primitive is <= prim.
    var lo = 0u;
    var hi = params.mesh_count;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if meshes[mid].first_prim <= prim {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}
