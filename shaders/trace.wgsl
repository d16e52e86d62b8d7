// One trace round: every live ray runs at most `step_budget` loop iterations of closest-hit BVH
// traversal (lavapipe silently stops a loop after 65,535 iterations, so no invocation may ever
// come near that), then saves its state. A ray that needs a block its GPU lacks records a fault
// and suspends where it stands; it repeats that step once the block is in the cache. Rays not
// done are appended to the next live list.
#import params
#import ray
#import blocks
#import dc
#import intersect
#import queue
#import offset

@group(1) @binding(0) var<storage, read_write> rays: array<RayState>;
// Per ray `stack_size` entries of (index, count, entry distance bits, node): the content of the
// node pushed, read with its sibling, so that a pop needs no block read.
@group(1) @binding(1) var<storage, read_write> stacks: array<vec4<u32>>;
@group(1) @binding(2) var<storage, read> live_in: array<u32>;
@group(1) @binding(3) var<storage, read> counter_in: array<u32, 4>;
// Mirrors gpu::layout::Stats.
struct Stats {
    steps: atomic<u32>,
    tri_tests: atomic<u32>,
    overflows: atomic<u32>,
    suspended: atomic<u32>,
    lookups: atomic<u32>,
    hits: atomic<u32>,
    misses: atomic<u32>,
    // Node visits, and how often a visit's node block differs from the previous visit's: the
    // chapter's "traversal steps per block".
    node_visits: atomic<u32>,
    block_entries: atomic<u32>,
    // Triangle reads from another triangle block than the ray's previous one.
    tri_block_entries: atomic<u32>,
    unused1: u32,
    unused2: u32,
}
@group(1) @binding(6) var<storage, read_write> stats: Stats;

// Stack entries held in registers (s0..s3 in main).
const SHORT_STACK: u32 = 4u;

var<workgroup> wg_steps: atomic<u32>;
var<workgroup> wg_tris: atomic<u32>;
var<workgroup> wg_suspended: atomic<u32>;
var<workgroup> wg_lookups: atomic<u32>;
var<workgroup> wg_hits: atomic<u32>;
var<workgroup> wg_misses: atomic<u32>;
var<workgroup> wg_visits: atomic<u32>;
var<workgroup> wg_entries: atomic<u32>;
var<workgroup> wg_tri_entries: atomic<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    var again = false;
    var ray_index = 0u;
    var parked = false;
    if gid.x < counter_in[0] {
        ray_index = live_in[gid.x];
        // A ray whose block has not arrived only renews its request: no state is read or
        // written, which makes a round with many waiting rays cheap.
        if DC {
            let wb = rays[ray_index].wait_block;
            if wb != NONE && block_rows[wb] == NONE {
                request(wb);
                parked = true;
                again = true;
            }
        }
    }
    if gid.x < counter_in[0] && !parked {
        var r = rays[ray_index];
        r.wait_block = NONE;
        // A ray with NaN, infinite or zero inputs ends at once as a miss, whoever made it.
        let valid = ray_valid(r);
        if !valid {
            r.node = NONE;
            r.sp = 0u;
            r.hit = NONE;
        }
        let org = ray_origin(r);
        let dir = ray_dir(r);
        let inv = safe_inverse(dir);
        let sh = make_shear(dir);
        let camera = (r.flags & FROM_CAMERA) != 0u;
        let base = ray_index * params.stack_size;
        var iters = 0u;
        var tests = 0u;
        var suspended = false;
        var visits = 0u;
        var entries = 0u;
        var last_block = NONE;
        var tri_entries = 0u;
        // The closest hit found in this round: where its triangle is and its barycentrics. Its
        // normal, point and error are computed once, after the loop: block rows do not change
        // during a dispatch, and a CPU driver runs a branch's code in every iteration however
        // few lanes take it.
        var found = false;
        var hit_row = 0u;
        var hit_slot = 0u;
        var hit_b = vec3(0.0);
        var last_tri_block = NONE;
        // The node being visited, already read when `have`: a child chosen at its parent is not
        // read twice, and a resumed ray needs only the block it faulted on.
        var cur: Node;
        // The top of the stack in four named registers, s0 the top: on a CPU driver a
        // dynamically indexed buffer is a per-lane gather or scatter loop, a select is not. The
        // global stack takes an entry only when a fifth is pushed, and the registers at the end
        // of the round; a round starts with them empty and pops from the global stack.
        var nreg = 0u;
        var s0 = vec4(0u);
        var s1 = vec4(0u);
        var s2 = vec4(0u);
        var s3 = vec4(0u);
        var have = r.cur_count != NONE;
        cur.index = r.cur_index;
        cur.count = r.cur_count;
        loop {
            if r.node == NONE {
                if r.sp == 0u {
                    r.status = DONE;
                    break;
                }
                if iters >= params.step_budget {
                    break;
                }
                iters += 1u;
                r.sp -= 1u;
                var e = s0;
                if nreg == 0u {
                    e = stacks[base + r.sp];
                } else {
                    nreg -= 1u;
                    s0 = s1;
                    s1 = s2;
                    s2 = s3;
                }
                // Entries farther than the closest hit found since they were pushed are culled.
                if !(bitcast<f32>(e.z) <= r.t) {
                    continue;
                }
                // The entry holds the node's content: it is visited in this same iteration.
                r.node = e.w;
                cur.index = e.x;
                cur.count = e.y;
                have = true;
            }
            if iters >= params.step_budget {
                break;
            }
            if !have {
                let l = node_loc(r.node);
                let row = locate(l.x);
                if row == NONE {
                    r.wait_block = l.x;
                    suspended = true;
                    break;
                }
                cur = node_at(row, l.y);
                have = true;
            }
            if cur.count == 0u {
                // Both children share a block: pairs never straddle one.
                let l = node_loc(cur.index);
                let row = locate(l.x);
                if row == NONE {
                    r.wait_block = l.x;
                    suspended = true;
                    break;
                }
                iters += 1u;
                visits += 1u;
                entries += u32(l.x != last_block);
                last_block = l.x;
                let a = node_at(row, l.y);
                let b = node_at(row, l.y + 1u);
                let ta = box_entry(a.lo, a.hi, org, inv, r.t);
                let tb = box_entry(b.lo, b.hi, org, inv, r.t);
                if ta >= 0.0 && tb >= 0.0 {
                    let a_first = ta <= tb;
                    if r.sp >= params.stack_size {
                        r.status = OVERFLOW;
                        break;
                    }
                    let far = select(vec2(a.index, a.count), vec2(b.index, b.count), a_first);
                    let far_node = select(cur.index, cur.index + 1u, a_first);
                    if nreg == SHORT_STACK {
                        stacks[base + r.sp - SHORT_STACK] = s3;
                    } else {
                        nreg += 1u;
                    }
                    s3 = s2;
                    s2 = s1;
                    s1 = s0;
                    s0 = vec4(far, bitcast<u32>(select(ta, tb, a_first)), far_node);
                    r.sp += 1u;
                    if a_first {
                        r.node = cur.index;
                        cur = a;
                    } else {
                        r.node = cur.index + 1u;
                        cur = b;
                    }
                } else if ta >= 0.0 {
                    r.node = cur.index;
                    cur = a;
                } else if tb >= 0.0 {
                    r.node = cur.index + 1u;
                    cur = b;
                } else {
                    r.node = NONE;
                    have = false;
                }
            } else {
                // Leaf. Its triangles may span two blocks: a fault part-way keeps the untested
                // rest as the current node, so a resumed ray never needs the first block again
                // (with one cache line it would evict the second).
                iters += 1u + cur.count;
                var rest = 0u;
                var stop = false;
                for (var k = 0u; k < cur.count; k++) {
                    let l = tri_loc(cur.index + k);
                    let row = locate(l.x);
                    if row == NONE {
                        r.wait_block = l.x;
                        rest = cur.count - k;
                        break;
                    }
                    tests += 1u;
                    tri_entries += u32(l.x != last_tri_block);
                    last_tri_block = l.x;
                    let tri = tri_at(row, l.y);
                    let th = intersect(tri, org, sh, r.t, camera);
                    if th.t > 0.0 {
                        r.t = th.t;
                        r.hit = cur.index + k;
                        found = true;
                        hit_row = row;
                        hit_slot = l.y;
                        hit_b = th.b;
                        // Shadow and occlusion rays need any hit, not the closest.
                        if (r.flags & ANY_HIT) != 0u {
                            stop = true;
                            break;
                        }
                    }
                }
                if stop {
                    r.status = DONE;
                    r.node = NONE;
                    r.sp = 0u;
                    nreg = 0u;
                    have = false;
                    break;
                }
                if rest > 0u {
                    cur.index += cur.count - rest;
                    cur.count = rest;
                    suspended = true;
                    break;
                }
                r.node = NONE;
                have = false;
            }
        }
        if found {
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
        }
        // The registers go back to their places in the global stack for the next round.
        if nreg > 0u {
            stacks[base + r.sp - 1u] = s0;
        }
        if nreg > 1u {
            stacks[base + r.sp - 2u] = s1;
        }
        if nreg > 2u {
            stacks[base + r.sp - 3u] = s2;
        }
        if nreg > 3u {
            stacks[base + r.sp - 4u] = s3;
        }
        if !valid {
            r.status = OUTSIDE;
        }
        r.cur_index = cur.index;
        r.cur_count = select(NONE, cur.count, have && r.node != NONE);
        r.steps += iters;
        rays[ray_index] = r;
        again = r.status == LIVE;
        if r.status == OVERFLOW {
            atomicAdd(&stats.overflows, 1u);
        }
        atomicAdd(&wg_steps, iters);
        atomicAdd(&wg_visits, visits);
        atomicAdd(&wg_entries, entries);
        atomicAdd(&wg_tri_entries, tri_entries);
        atomicAdd(&wg_tris, tests);
        if suspended {
            atomicAdd(&wg_suspended, 1u);
        }
        if DC {
            atomicAdd(&wg_lookups, dc_lookups);
            atomicAdd(&wg_hits, dc_hits);
            atomicAdd(&wg_misses, dc_misses);
        }
    }
    // The barrier in append_live also orders the workgroup's sums before they are read.
    append_live(again, lid, ray_index);
    if lid == 0u {
        atomicAdd(&stats.steps, atomicLoad(&wg_steps));
        atomicAdd(&stats.tri_tests, atomicLoad(&wg_tris));
        atomicAdd(&stats.suspended, atomicLoad(&wg_suspended));
        atomicAdd(&stats.node_visits, atomicLoad(&wg_visits));
        atomicAdd(&stats.block_entries, atomicLoad(&wg_entries));
        atomicAdd(&stats.tri_block_entries, atomicLoad(&wg_tri_entries));
        if DC {
            atomicAdd(&stats.lookups, atomicLoad(&wg_lookups));
            atomicAdd(&stats.hits, atomicLoad(&wg_hits));
            atomicAdd(&stats.misses, atomicLoad(&wg_misses));
        }
    }
}
