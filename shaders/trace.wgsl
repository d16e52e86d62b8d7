// One trace round: every live ray runs at most `step_budget` loop iterations of closest-hit BVH
// traversal (lavapipe silently stops a loop after 65,535 iterations, so no invocation may ever
// come near that), then saves its state. Rays not done are appended to the next live list.

@group(1) @binding(0) var<storage, read_write> rays: array<RayState>;
// Per ray `stack_size` entries of (node, entry distance bits).
@group(1) @binding(1) var<storage, read_write> stacks: array<vec2<u32>>;
@group(1) @binding(2) var<storage, read> live_in: array<u32>;
@group(1) @binding(3) var<storage, read> counter_in: array<u32, 4>;
@group(1) @binding(4) var<storage, read_write> live_out: array<u32>;
@group(1) @binding(5) var<storage, read_write> counter_out: Counter;
// Mirrors gpu::layout::Stats.
struct Stats {
    steps: atomic<u32>,
    tri_tests: atomic<u32>,
    overflows: atomic<u32>,
    unused: u32,
}
@group(1) @binding(6) var<storage, read_write> stats: Stats;

var<workgroup> wg_count: atomic<u32>;
var<workgroup> wg_base: u32;
var<workgroup> wg_steps: atomic<u32>;
var<workgroup> wg_tris: atomic<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    var again = false;
    var ray_index = 0u;
    if gid.x < counter_in[0] {
        ray_index = live_in[gid.x];
        var r = rays[ray_index];
        let org = ray_origin(r);
        let dir = ray_dir(r);
        let inv = safe_inverse(dir);
        let sh = make_shear(dir);
        let base = ray_index * params.stack_size;
        var iters = 0u;
        var tests = 0u;
        // The node being visited, already read when `have`: a child chosen at its parent is not
        // read twice.
        var cur: Node;
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
                let e = stacks[base + r.sp];
                // Entries farther than the closest hit found since they were pushed are culled.
                if bitcast<f32>(e.y) <= r.t {
                    r.node = e.x;
                    have = false;
                }
                continue;
            }
            if iters >= params.step_budget {
                break;
            }
            iters += 1u;
            if !have {
                cur = load_node(r.node);
            }
            if cur.count == 0u {
                let a = load_node(cur.index);
                let b = load_node(cur.index + 1u);
                let ta = box_entry(a.lo, a.hi, org, inv, r.t);
                let tb = box_entry(b.lo, b.hi, org, inv, r.t);
                if ta >= 0.0 && tb >= 0.0 {
                    let a_first = ta <= tb;
                    if r.sp >= params.stack_size {
                        r.status = OVERFLOW;
                        break;
                    }
                    let far = select(cur.index, cur.index + 1u, a_first);
                    stacks[base + r.sp] = vec2(far, bitcast<u32>(select(ta, tb, a_first)));
                    r.sp += 1u;
                    if a_first {
                        r.node = cur.index;
                        cur = a;
                    } else {
                        r.node = cur.index + 1u;
                        cur = b;
                    }
                    have = true;
                } else if ta >= 0.0 {
                    r.node = cur.index;
                    cur = a;
                    have = true;
                } else if tb >= 0.0 {
                    r.node = cur.index + 1u;
                    cur = b;
                    have = true;
                } else {
                    r.node = NONE;
                    have = false;
                }
            } else {
                // Leaf: the triangle loop's iterations count against the same budget.
                iters += cur.count;
                tests += cur.count;
                for (var k = 0u; k < cur.count; k++) {
                    let t = intersect(load_tri(cur.index + k), org, sh, r.t);
                    if t > 0.0 {
                        r.t = t;
                        r.hit = cur.index + k;
                        let tri = load_tri(r.hit);
                        let n = normalize(cross(tri.v1 - tri.v0, tri.v2 - tri.v0));
                        r.nx = n.x;
                        r.ny = n.y;
                        r.nz = n.z;
                        r.prim = load_prim_id(r.hit);
                    }
                }
                r.node = NONE;
                have = false;
            }
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
        atomicAdd(&wg_tris, tests);
    }
    var slot = 0u;
    if again {
        slot = atomicAdd(&wg_count, 1u);
    }
    workgroupBarrier();
    if lid == 0u {
        let n = atomicLoad(&wg_count);
        wg_base = atomicAdd(&counter_out.count, n);
        atomicAdd(&stats.steps, atomicLoad(&wg_steps));
        atomicAdd(&stats.tri_tests, atomicLoad(&wg_tris));
    }
    let base = workgroupUniformLoad(&wg_base);
    if again {
        live_out[base + slot] = ray_index;
    }
}
