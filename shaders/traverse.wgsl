// One traversal round: every live ray runs at most `step_budget` loop iterations of closest-hit BVH
// traversal (lavapipe silently stops a loop after 65,535 iterations, so no invocation may ever
// come near that), then saves its state. A ray that needs a block its GPU lacks records a fault,
// sets the entry aside in one of DEFER_SLOTS slots after its stack and goes on with what the GPU
// holds (fault and continue); when nothing else is left, or the slots are full, it suspends
// until one of those blocks is in the cache. Rays not done are appended to the next live list.
// The closest hit is the nearest, and of equally near ones the lowest triangle index, so the
// order in which faults let a ray visit its subtrees never changes the image.
//
// A batch of primary rays, and each wave of secondary rays, starts with a round built with
// FIRST: it makes each ray in registers (camera_ray, spawn_ray) instead of loading what a kernel
// of its own would have stored, and in cast mode without colour by data it writes the pixel of
// every camera ray that ends in it. A wave whose paths have thinned out (FIRST_LISTED) makes
// only the rays the spawn kernel listed as live.
#import params
#import ray
#import blocks
#import dc
#import intersect
#import queue
#import offset
#import camera
#import pixel
#import spawn


@group(1) @binding(0) var<storage, read_write> rays: array<RayGroups>;
// Per ray `stack_size` entries, each a child as its parent's slot gives it (node `index` when
// `count` is 0, else `count` triangles from `index`) and its entry distance, packed in 8 bytes
// (pack_entry): half the memory of a plain (index, count, distance) entry lets a batch hold
// twice the rays, and a CPU driver moves one word less per push and pop.
@group(1) @binding(1) var<storage, read_write> stacks: array<vec2<u32>>;
@group(1) @binding(2) var<storage, read> live_in: array<u32>;
@group(1) @binding(3) var<storage, read> counter_in: array<u32, 4>;
// Mirrors gpu::layout::Stats.
struct Stats {
    steps: atomic<u32>,
    tri_tests: atomic<u32>,
    overflows: atomic<u32>,
    suspended: atomic<u32>,
    // Rays that entered traversal in the first round (FIRST_CAMERA, FIRST_SPAWN; a wave the
    // spawn kernel listed copies its list's count here).
    started: atomic<u32>,
    hits: atomic<u32>,
    misses: atomic<u32>,
    // Node visits, and how often a visit's node block differs from the previous visit's: the
    // chapter's "traversal steps per block".
    node_visits: atomic<u32>,
    block_entries: atomic<u32>,
    // Triangle reads from another triangle block than the ray's previous one.
    tri_block_entries: atomic<u32>,
    // Per subgroup the most loop iterations any of its invocations ran (the iterations its
    // lanes ran together), and the subgroup size: steps over their product is the share of
    // lanes that did work.
    subgroup_steps: atomic<u32>,
    subgroup_size: atomic<u32>,
    // Rays that do not stop at any hit and found one (counted in modes with secondary rays):
    // without any, no path goes on and the next wave is not traced.
    closest_hits: atomic<u32>,
    pad: u32,
}
@group(1) @binding(6) var<storage, read_write> stats: Stats;
// FIRST_CAMERA with first_round_shades(): the pixels of the rays that end in the round.
@group(1) @binding(7) var<storage, read_write> pixels: array<Pixel>;
// FIRST_SPAWN, FIRST_LISTED: the paths their rays leave.
@group(1) @binding(8) var<storage, read> paths: array<Path>;

// The kernel of a first round (see the top of this file). FIRST_CAMERA and FIRST_SPAWN run one
// invocation per ray slot (not per live ray), each making and tracing the ray of its slot: a
// batch's primary rays, or a wave's secondary rays (`shading.fan` slots a pixel slot).
// FIRST_LISTED runs one per live ray of the list the spawn kernel made, and makes its ray
// from its path as FIRST_SPAWN does: no kernel stores a wave's rays for this round to load.
const FIRST_CAMERA: u32 = 1u;
const FIRST_SPAWN: u32 = 2u;
const FIRST_LISTED: u32 = 3u;
override FIRST: u32 = 0u;

// Whether the kernel runs an invocation per ray slot (FIRST_CAMERA, FIRST_SPAWN).
fn per_slot() -> bool {
    return FIRST == FIRST_CAMERA || FIRST == FIRST_SPAWN;
}

// How many strands of the batch's tiles the first round's workgroups interleave (spread_slot).
const SPREAD: u32 = 16u;

// The batch slot first-round invocation i traces: workgroup w (a tile's 64 rays) takes tile
// (w % SPREAD) of SPREAD equal strands of the batch's tiles, its (w / SPREAD)th. lavapipe hands
// each of its threads one contiguous range of a dispatch's workgroups: in tile order, one thread
// would get the top of the image and another the bottom, however unequal their work (the rays
// of later rounds come from live lists the threads fill together, interleaved).
fn spread_slot(i: u32, slots: u32) -> u32 {
    let groups = slots / WORKGROUP;
    let w = i / WORKGROUP;
    let q = groups / SPREAD;
    let rest = groups % SPREAD;
    var k = w % SPREAD;
    var j = w / SPREAD;
    if w >= SPREAD * q {
        k = w - SPREAD * q;
        j = q;
    }
    return (k * q + min(k, rest) + j) * WORKGROUP + i % WORKGROUP;
}

// Stack entries set aside for absent blocks, in the last DEFER_SLOTS entries of a ray's stack
// region (the host sizes stacks for them); 0 when replicated. Their count is in RayState.flags.
override DEFER_SLOTS: u32 = 0u;
const DEFER_SHIFT: u32 = 4u;

fn deferred(r: RayState) -> u32 {
    if DEFER_SLOTS == 0u {
        return 0u;
    }
    return (r.flags >> DEFER_SHIFT) & 0xfu;
}

// Entry e = (index, count, entry distance bits, 0) as the stack holds it: the index, and the
// distance's bits with their low 8 replaced by the count (a leaf holds at most 254 triangles).
// The truncated distance is never above the exact one, so culling on it only ever visits more.
fn pack_entry(e: vec4<u32>) -> vec2<u32> {
    return vec2(e.x, (e.z & 0xffffff00u) | e.y);
}

fn unpack_entry(p: vec2<u32>) -> vec4<u32> {
    return vec4(p.x, p.y & 0xffu, p.y & 0xffffff00u, 0u);
}

// The block an entry's node or first triangle is in.
fn entry_block(e: vec4<u32>) -> u32 {
    return select(tri_loc(e.x).x, node_loc(e.x).x, e.y == 0u);
}

// Node visits, node-block entries and triangle-block entries (Stats) are counted only in
// kernels built with BLOCK_COUNTS (Settings::block_counts, for the benchmarks' block figures):
// in the loop they cost lavapipe 4% of a 1/8-cache frame's trace time.
override BLOCK_COUNTS: bool = false;

// Each subgroup's counts for Stats are summed over its invocations by subgroupAdd and added by
// its first invocation: an atomic add per invocation is a locked operation per lane on a CPU
// driver (nine of them cost lavapipe about 13% of a replicated frame). A CPU driver runs every
// atomic site as a loop over the lanes in every subgroup, taken or not, so there are few: the
// block counts only in kernels that count them, the cache's only with a cache, and `lookups` is
// not counted (the host adds hits and misses). Summing the subgroups' counts in workgroup memory first cost
// more than it saved (each load a loop over the lanes, in every subgroup): 3% of a 1/8-cache
// frame's instructions.

// An entry's distance bits for a child the ray misses: above every hit's (a non-negative f32's
// bits order as the f32 does).
const MISS: u32 = 0xffffffffu;

// Slot i of node n as a stack entry (index, count, entry distance bits or MISS, 0).
fn child_entry(n: Node, step: vec3<f32>, i: u32, index: u32, org: vec3<f32>, inv: vec3<f32>,
               tmax: f32) -> vec4<u32> {
    let c = (n.counts >> (8u * i)) & 0xffu;
    let b = child_box(n, step, i);
    let t = box_entry(b.lo, b.hi, org, inv, tmax);
    let key = select(MISS, bitcast<u32>(t), t >= 0.0 && c != EMPTY);
    return vec4(index, select(c, 0u, c == INNER), key, 0u);
}

// How far past the closest hit a box may begin and still hold a triangle as near: a box's
// entry distance is within a few ulps of the exact one, a resolved hit's t within 2^-13 of it
// (intersect), so a box entered up to 2^-12 beyond the hit is visited. Culling at the hit itself
// would drop a subtree whose equally near triangle has a lower index when a ray meets the
// subtrees in another order (set-aside blocks): the tie rule needs every one of them tested.
fn reach(t: f32) -> f32 {
    return t * (1.0 + 1.0 / 4096.0);
}

// The row holding block k, which the loop found there (rows do not change during a dispatch):
// `lookup` without its counts and marks.
fn row_of(k: u32) -> u32 {
    if !DC {
        return k;
    }
    return block_row(k);
}

// Takes hit th on triangle `index` as the ray's closest, its barycentrics into `b`; true when
// the ray is done with it (shadow and occlusion rays need any hit, not the closest).
fn take_hit(r: ptr<function, RayState>, b: ptr<function, vec3<f32>>, th: TriHit,
            index: u32) -> bool {
    // intersect returns hits up to t inclusive: an equally near one wins by the lower index.
    if !(th.t < (*r).t || ((*r).hit != NONE && index < (*r).hit)) {
        return false;
    }
    (*r).t = th.t;
    (*r).hit = index;
    *b = th.b;
    if ((*r).flags & ANY_HIT) != 0u {
        (*r).status = DONE;
        (*r).sp = 0u;
        return true;
    }
    return false;
}

// Sets entry e (its block absent, its fault recorded) aside in a free slot; false when none is.
fn set_aside(r: ptr<function, RayState>, slots: u32, e: vec4<u32>) -> bool {
    let nd = deferred(*r);
    if nd >= min(params.dc_defer, DEFER_SLOTS) {
        return false;
    }
    stacks[slots + nd] = pack_entry(e);
    (*r).flags += 1u << DEFER_SHIFT;
    return true;
}

// The nearer of two entries first (a compare-exchange of a sorting network).
fn near_first(a: ptr<function, vec4<u32>>, b: ptr<function, vec4<u32>>) {
    let x = *a;
    let y = *b;
    let swap = y.z < x.z;
    *a = select(x, y, swap);
    *b = select(y, x, swap);
}

// Stack entries held in registers (main's `top`): four, as pack_entry makes them, top first. A
// struct of separate members, not an array: a CPU driver indexes a private array with a gather.
const TOP: u32 = 4u;
struct Top {
    e0: vec2<u32>,
    e1: vec2<u32>,
    e2: vec2<u32>,
    e3: vec2<u32>,
}

// Held entry i (0 the top).
fn top_at(t: Top, i: u32) -> vec2<u32> {
    return select(select(t.e3, t.e2, i == 2u), select(t.e1, t.e0, i == 0u), i < 2u);
}

@compute @workgroup_size(WORKGROUP)  // the `args` kernel sizes indirect dispatches by it
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32,
        @builtin(subgroup_invocation_id) sgi: u32, @builtin(subgroup_size) sg_size: u32) {
    var again = false;
    var ray_index = 0u;
    var parked = false;
    var counts = vec4(0u);
    var more_counts = vec4(0u);
    // The block this invocation's ray waits for, requested at the kernel's end: one request site
    // (its atomics are a loop over the lanes on a CPU driver, taken or not).
    var ask = NONE;
    // The ray this invocation traces, if `go`.
    var r = new_ray(vec3(0.0), vec3(0.0), 0.0, OUTSIDE, 0u, NONE);
    var go = false;
    // A first round: a ray slot, and whether its ray entered traversal.
    var slots = params.batch_rays;
    if FIRST == FIRST_SPAWN {
        slots *= shading.fan;
    }
    let slot = per_slot() && gid.x < slots;
    // Whether the first round stores its slot's whole state: a dead path's slots (FIRST_SPAWN)
    // get only the group with their status, OUTSIDE (as the spawn kernel's).
    var whole = slot;
    var entered = 0u;
    // FIRST_LISTED: a listed ray, which the round stores whole.
    var listed = false;
    if per_slot() {
        if slot {
            ray_index = spread_slot(gid.x, slots);
            if FIRST == FIRST_SPAWN {
                let ik = wave_ray(ray_index, shading.fan);
                whole = paths[ik.x].alive != 0u;
                if whole {
                    r = spawn_ray(paths[ik.x], ik.y);
                }
            } else {
                r = camera_ray(ray_index);
            }
            go = r.status == LIVE;
            entered = u32(go);
        }
    } else if FIRST == FIRST_LISTED {
        if gid.x < counter_in[0] {
            ray_index = live_in[gid.x];
            let ik = wave_ray(ray_index, shading.fan);
            // Listed because spawn_ray made it LIVE (`Stats::started` is the list's count).
            r = spawn_ray(paths[ik.x], ik.y);
            go = true;
            listed = true;
        }
    } else if gid.x < counter_in[0] {
        ray_index = live_in[gid.x];
        // A ray whose block has not arrived only renews its request: no state is read or
        // written, which makes a round with many waiting rays cheap.
        if DC {
            let wb = rays[ray_index].g[3].y;
            if wb != NONE && block_row(wb) == NONE {
                ask = wb;
                parked = true;
                again = true;
            }
        }
        if !parked {
            // The four groups traversal reads: those of the closest hit are written whole when
            // one is found (a CPU driver loads a buffer's words lane by lane, stalling on each).
            let z = vec4(0u);
            r = ray_state(RayGroups(array(rays[ray_index].g[0], rays[ray_index].g[1],
                                          rays[ray_index].g[2], rays[ray_index].g[3], z, z, z)));
            go = true;
        }
    }
    if go {
        r.wait_block = NONE;
        // A ray with NaN, infinite or zero inputs ends at once as a miss, whoever made it.
        let valid = ray_valid(r);
        if !valid {
            r.cur_count = NONE;
            r.sp = 0u;
            r.hit = NONE;
        }
        let org = ray_origin(r);
        let dir = ray_dir(r);
        let inv = safe_inverse(dir);
        let sh = make_shear(dir);
        let camera = (r.flags & FROM_CAMERA) != 0u;
        let base = ray_index * params.stack_size;
        // The stack proper, then the deferred entries.
        let cap = params.stack_size - DEFER_SLOTS;
        let slots = base + cap;
        var iters = 0u;
        var tests = 0u;
        var suspended = false;
        // Suspended at a fault (not on an entry set aside earlier, which is requested anyway).
        var wait_fault = false;
        var visits = 0u;
        var entries = 0u;
        var last_block = NONE;
        var tri_entries = 0u;
        // The barycentrics of the closest hit found in this round. The triangle is r.hit (its
        // block and slot follow from the index), and a hit was found when r.hit moved: fewer
        // values live across the loop leave a CPU driver fewer registers to spill. Its normal,
        // point and error are computed once, after the loop: block rows do not change during a
        // dispatch, and a CPU driver runs a branch's code in every iteration however few lanes
        // take it.
        var closest_b = vec3(0.0);
        let hit_before = r.hit;
        var last_tri_block = NONE;
        // What is visited next, as a stack entry holds it (RayState.cur_index, cur_count), and
        // its entry distance's bits (0, never culled, for an entry resumed from RayState).
        var cur = vec2(r.cur_index, r.cur_count);
        var cur_t = 0u;
        // A triangle whose hit distance f32 cannot resolve (intersect's UNRESOLVED_T) ends the
        // traversal loop and is decided by resolve_hit outside it, in the order traversal met it,
        // before the loop resumes: code in the loop costs a CPU driver in every iteration.
        var pending = false;
        // Set-aside entries to put back on the stack, or the block of a fault, when the loop
        // stops for them.
        var restore = false;
        var fault_block = NONE;
        // Which set-aside slots this round filled: their blocks are requested after the loop.
        var set_aside_now = 0u;
        // The row of the last triangle block the ray used (keep_line).
        var tri_row = NONE;
        var pending_index = 0u;
        // The top of the stack in registers: top[0] the top entry, `held` of them in use, the
        // rest in `stacks` below r.sp. A CPU driver runs a buffer access as a loop over the lanes
        // that stalls on every lane taking it; a push or pop here costs a few selects, and the
        // buffer is reached only by a ray whose stack is deeper than TOP.
        var top = Top(vec2(0u), vec2(0u), vec2(0u), vec2(0u));
        var held = 0u;
        // A resumed ray takes its top entries back into registers at once: its stack was
        // stored a dispatch ago and is cold, and a CPU driver loads a buffer lane by lane, so
        // loads issued together overlap their misses where pops one at a time in the loop
        // waited for each (docs/ARCHITECTURE.md, The round loop). Slots below the stack's
        // bottom are read (they are the ray's own) but not held; a wave's new rays have none.
        if FIRST == 0u && r.sp > 0u {
            let sp = r.sp;
            top = Top(stacks[base + max(sp, 1u) - 1u], stacks[base + max(sp, 2u) - 2u],
                      stacks[base + max(sp, 3u) - 3u], stacks[base + max(sp, 4u) - 4u]);
            held = min(sp, TOP);
            r.sp = sp - held;
        }
        loop {
            loop {
                if cur.y == NONE && r.sp == 0u && held == 0u {
                    if deferred(r) == 0u {
                        r.status = DONE;
                    } else {
                        restore = true;
                    }
                    break;
                }
                if iters >= params.step_budget {
                    break;
                }
                iters += 1u;
                if cur.y == NONE {
                    var p = top.e0;
                    if held == 0u {
                        r.sp -= 1u;
                        p = stacks[base + r.sp];
                    } else {
                        top = Top(top.e1, top.e2, top.e3, top.e3);
                        held -= 1u;
                    }
                    let e = unpack_entry(p);
                    // Entries farther than the closest hit found since they were pushed are culled.
                    if !(bitcast<f32>(e.z) <= reach(r.t)) {
                        continue;
                    }
                    // Visited in this same iteration.
                    cur = e.xy;
                    cur_t = e.z;
                }
                // One block lookup and four texel fetches an iteration, for a node (four texels)
                // or a triangle (three): a CPU driver runs both parts of the loop in every
                // iteration whichever its lanes take, so the node and the triangle share them.
                let node = cur.y == 0u;
                let nl = node_loc(cur.x);
                let tl = tri_loc(cur.x);
                let k = select(tl.x, nl.x, node);
                let row = lookup(k);
                if DC {
                    if row == NONE {
                        fault_block = k;
                        break;
                    }
                    tri_row = select(row, tri_row, node);
                }
                let tt = tri_texel(tl.y);
                let t0 = select(tt.x, nl.y * 4u, node);
                let ta = texel(row, t0);
                let tb = texel(row, t0 + 1u);
                let tc = texel(row, t0 + 2u);
                let td = texel(row, t0 + 3u);
                if node {
                    if BLOCK_COUNTS {
                        visits += 1u;
                        entries += u32(k != last_block);
                        last_block = k;
                    }
                    let n = node_of(ta, tb, tc, td);
                    let step = node_step(n);
                    // Inner children are adjacent from child_base, leaves' triangles from tri_base,
                    // both in slot order.
                    var ci = n.child_base;
                    var ti = n.tri_base;
                    let c = (vec4(n.counts) >> vec4(0u, 8u, 16u, 24u)) & vec4(0xffu);
                    let inner = c == vec4(INNER);
                    var e0 = child_entry(n, step, 0u, select(ti, ci, inner.x), org, inv, reach(r.t));
                    ci += u32(inner.x);
                    ti += select(c.x, 0u, inner.x);
                    var e1 = child_entry(n, step, 1u, select(ti, ci, inner.y), org, inv, reach(r.t));
                    ci += u32(inner.y);
                    ti += select(c.y, 0u, inner.y);
                    var e2 = child_entry(n, step, 2u, select(ti, ci, inner.z), org, inv, reach(r.t));
                    ci += u32(inner.z);
                    ti += select(c.z, 0u, inner.z);
                    var e3 = child_entry(n, step, 3u, select(ti, ci, inner.w), org, inv, reach(r.t));
                    near_first(&e0, &e1);
                    near_first(&e2, &e3);
                    near_first(&e0, &e2);
                    near_first(&e1, &e3);
                    near_first(&e1, &e2);
                    // The nearest is visited next, the others pushed farthest first.
                    let pushes = u32(e1.z != MISS) + u32(e2.z != MISS) + u32(e3.z != MISS);
                    if r.sp + held + pushes > cap {
                        r.status = OVERFLOW;
                        break;
                    }
                    // Room for the pushes: the deepest held entries go to the buffer.
                    let spill = held + pushes - min(held + pushes, TOP);
                    for (var j = 0u; j < spill; j++) {
                        stacks[base + r.sp] = top_at(top, held - 1u);
                        r.sp += 1u;
                        held -= 1u;
                    }
                    // e1 on top, then e2 and e3 (sorted, so the pushed ones come first).
                    let p1 = pack_entry(e1);
                    let p2 = pack_entry(e2);
                    let p3 = pack_entry(e3);
                    if pushes == 1u {
                        top = Top(p1, top.e0, top.e1, top.e2);
                    } else if pushes == 2u {
                        top = Top(p1, p2, top.e0, top.e1);
                    } else if pushes == 3u {
                        top = Top(p1, p2, p3, top.e0);
                    }
                    held += pushes;
                    cur = select(vec2(0u, NONE), e0.xy, e0.z != MISS);
                    cur_t = e0.z;
                } else {
                    // One triangle of a leaf per iteration, the rest kept as the current entry: a
                    // loop over the leaf would run, in every lane, as often as the longest leaf
                    // among them. A fault on a leaf that spans two blocks keeps the untested rest, so
                    // a resumed ray never needs the first block again (with one cache line it would
                    // evict the second).
                    tests += 1u;
                    if BLOCK_COUNTS {
                        tri_entries += u32(k != last_tri_block);
                        last_tri_block = k;
                    }
                    let tri = tri_of(ta, tb, tc, tt.y);
                    var th = NO_HIT;
                    if cur.x != r.skip {
                        th = intersect(tri, org, sh, r.t);
                    }
                    let index = cur.x;
                    cur = select(vec2(cur.x + 1u, cur.y - 1u), vec2(0u, NONE), cur.y == 1u);
                    if th.t == UNRESOLVED_T {
                        pending = true;
                        pending_index = index;
                        break;
                    }
                    if th.t > 0.0 && take_hit(&r, &closest_b, th, index) {
                        cur.y = NONE;
                        held = 0u;
                        break;
                    }
                }
            }
            // Faults and set-aside entries are handled here, between runs of the loop: code in
            // the loop costs a CPU driver in every iteration.
            if restore {
                restore = false;
                // Only set-aside entries are left: back on the stack once one of their blocks is
                // here (the first one's on top), else suspend until it comes.
                let nd = deferred(r);
                var here = false;
                for (var i = 0u; i < nd; i++) {
                    here = here || block_row(entry_block(unpack_entry(stacks[slots + i]))) != NONE;
                }
                if !here {
                    r.wait_block = entry_block(unpack_entry(stacks[slots]));
                    suspended = true;
                    break;
                }
                for (var i = 0u; i < nd; i++) {
                    stacks[base + i] = stacks[slots + nd - 1u - i];
                }
                r.sp = nd;
                r.flags &= ~(0xfu << DEFER_SHIFT);
                set_aside_now = 0u;
                continue;
            }
            if DC && fault_block != NONE {
                let k = fault_block;
                fault_block = NONE;
                // The current entry's block is absent: set it aside and go on, or suspend.
                if set_aside(&r, slots, vec4(cur, cur_t, 0u)) {
                    set_aside_now |= 1u << (deferred(r) - 1u);
                    cur = vec2(0u, NONE);
                    continue;
                }
                r.wait_block = k;
                suspended = true;
                wait_fault = true;
                break;
            }
            if !pending {
                break;
            }
            pending = false;
            let pl = tri_loc(pending_index);
            let th = resolve_hit(tri_at(row_of(pl.x), pl.y), org, sh, r.t, camera);
            if th.t > 0.0 && take_hit(&r, &closest_b, th, pending_index) {
                cur.y = NONE;
                held = 0u;
                break;
            }
        }
        // The held entries back into the buffer, deepest first: the stack a resumed ray reads.
        for (var j = 0u; j < held; j++) {
            stacks[base + r.sp] = top_at(top, held - 1u - j);
            r.sp += 1u;
        }
        // The round's faults, requested here rather than in the loop: the blocks of the entries
        // set aside in this round and the one the ray suspended at, as a lookup inside the loop
        // would have requested them. A ray done (an any-hit ray that found one) needs none.
        if DC && r.status == LIVE {
            for (var i = 0u; i < deferred(r); i++) {
                if ((set_aside_now >> i) & 1u) != 0u {
                    request(entry_block(unpack_entry(stacks[slots + i])), requester(ray_index));
                }
            }
            if wait_fault {
                ask = r.wait_block;
            }
            keep_line(tri_row);
        }
        let found = r.hit != hit_before;
        if found {
            let hl = tri_loc(r.hit);
            let hit_row = row_of(hl.x);
            let hit_slot = hl.y;
            let hit_b = closest_b;
            let tri = tri_at(hit_row, hit_slot);
            let n = unit_normal(tri);
            r.nx = n.x;
            r.ny = n.y;
            r.nz = n.z;
            let p = hit_point(tri, hit_b);
            r.hx = p.x;
            r.hy = p.y;
            r.hz = p.z;
            // Past the point's error along the normal, and along any normal the exact one may
            // be (a sliver's computed normal is off by up to a radian).
            let e = hit_point_error(tri, hit_b);
            r.herr = offset_distance(n, e) + normal_error(tri) * (e.x + e.y + e.z);
            r.prim = prim_id_at(hit_row, hit_slot);
            r.b1 = hit_b.y;
            r.b2 = hit_b.z;
        }
        if !valid {
            r.status = OUTSIDE;
        }
        // Only the groups traversal changes are stored: the origin and direction never change,
        // and a CPU driver stores each group lane by lane.
        r.steps += iters;
        r.cur_index = cur.x;
        r.cur_count = cur.y;
        if FIRST == 0u {
            let w = ray_groups(r);
            rays[ray_index].g[0].w = w.g[0].w;
            rays[ray_index].g[1].w = w.g[1].w;
            rays[ray_index].g[2] = w.g[2];
            rays[ray_index].g[3] = w.g[3];
            if found {
                rays[ray_index].g[4] = w.g[4];
                rays[ray_index].g[5] = w.g[5];
                rays[ray_index].g[6] = w.g[6];
            }
        }
        again = r.status == LIVE;
        counts = vec4(iters, tests, visits, entries);
        // Suspended in bits 0-9, overflowed in 10-19, closest hits in 20-29 (a subgroup sums at
        // most 128 of each): one sum instead of three.
        let closest_hit = found && (r.flags & ANY_HIT) == 0u;
        let ended = u32(suspended) | (u32(r.status == OVERFLOW) << 10u) | (u32(closest_hit) << 20u);
        more_counts = vec4(tri_entries, ended, dc_hits, dc_misses);
    }
    // The first round's slot, traced or not: its pixel when the ray has ended and the round
    // shades, else its whole state (no earlier kernel stored any); a listed ray's whole state.
    if listed {
        rays[ray_index] = ray_groups(r);
    } else if slot {
        if !whole {
            rays[ray_index].g[2] = ray_groups(r).g[2];
        } else if FIRST == FIRST_CAMERA && first_round_shades() && r.status != LIVE {
            var before = Pixel();
            if (params.flags & FIRST_SAMPLE) == 0u {
                before = pixels[ray_index];
            }
            pixels[ray_index] = cast_pixel(r, before);
            r.status = SHADED;
            rays[ray_index].g[2] = ray_groups(r).g[2];
        } else {
            rays[ray_index] = ray_groups(r);
        }
    }
    if DC && ask != NONE {
        request(ask, requester(ray_index));
    }
    // Every invocation gets here: the subgroup is whole.
    let sub_counts = subgroupAdd(counts);
    let sub_more = subgroupAdd(more_counts);
    var sub_steps = 0u;
    if BLOCK_COUNTS {
        sub_steps = subgroupMax(counts.x);
    }
    var sub_started = 0u;
    if per_slot() {
        sub_started = subgroupAdd(entered);
    }
    if sgi == 0u {
        if per_slot() {
            atomicAdd(&stats.started, sub_started);
        }
        atomicAdd(&stats.steps, sub_counts.x);
        atomicAdd(&stats.tri_tests, sub_counts.y);
        atomicAdd(&stats.overflows, (sub_more.y >> 10u) & 0x3ffu);
        if MODE != MODE_CAST {
            atomicAdd(&stats.closest_hits, sub_more.y >> 20u);
        }
        if BLOCK_COUNTS {
            atomicAdd(&stats.node_visits, sub_counts.z);
            atomicAdd(&stats.block_entries, sub_counts.w);
            atomicAdd(&stats.tri_block_entries, sub_more.x);
            atomicAdd(&stats.subgroup_steps, sub_steps);
            atomicMax(&stats.subgroup_size, sg_size);
        }
        if DC {
            atomicAdd(&stats.suspended, sub_more.y & 0x3ffu);
            atomicAdd(&stats.hits, sub_more.z);
            atomicAdd(&stats.misses, sub_more.w);
        }
    }
    append_live(again, lid, ray_index);
}
