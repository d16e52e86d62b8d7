// Ray generation for one batch of 8x8 tiles: one invocation per ray, pixel centres exactly as
// DESIGN.md section 7 defines them. Valid rays are appended to the live list.

@group(1) @binding(0) var<storage, read_write> rays: array<RayState>;
@group(1) @binding(1) var<storage, read_write> live_out: array<u32>;
@group(1) @binding(2) var<storage, read_write> counter_out: Counter;

var<workgroup> wg_count: atomic<u32>;
var<workgroup> wg_base: u32;

fn finite3(v: vec3<f32>) -> bool {
    // Exponent bits all set means inf or NaN; checked on the bits, not with IEEE comparisons.
    let e = (bitcast<vec3<u32>>(v) >> vec3(23u)) & vec3(0xffu);
    return all(e != vec3(0xffu));
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let i = gid.x;
    var live = false;
    var slot = 0u;
    if i < params.batch_rays {
        let tile = params.first_tile + i / (TILE * TILE);
        let local = i % (TILE * TILE);
        let lx = (tile % params.tiles_x) * TILE + local % TILE;
        let ly = (tile / params.tiles_x) * TILE + local / TILE;
        let px = params.rect_x + lx;
        let py = params.rect_y + ly;
        let sx = 2.0 * (f32(px) + 0.5) / f32(params.width) - 1.0;
        let sy = 1.0 - 2.0 * (f32(py) + 0.5) / f32(params.height);
        let d = normalize(params.forward.xyz + sx * params.right.xyz + sy * params.up.xyz);
        let o = params.origin.xyz;
        var r = RayState(o.x, o.y, o.z, FAR, d.x, d.y, d.z, NONE, 0u, 0u, LIVE, 0u, 0u, NONE, NONE,
                         0.0, 0.0, 0.0, NONE, 0u);
        if lx >= params.rect_w || ly >= params.rect_h || !finite3(d) || !finite3(o) {
            r.status = OUTSIDE;
        } else {
            live = true;
        }
        rays[i] = r;
        if live {
            slot = atomicAdd(&wg_count, 1u);
        }
    }
    // One global atomic per workgroup instead of one per ray.
    workgroupBarrier();
    if lid == 0u {
        wg_base = atomicAdd(&counter_out.count, atomicLoad(&wg_count));
    }
    let base = workgroupUniformLoad(&wg_base);
    if live {
        live_out[base + slot] = i;
    }
}
