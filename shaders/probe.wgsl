// Layout probe (tests only): one invocation reads every member of every host-written struct
// through the same accessors the kernels use and writes it out as raw words, in declaration
// order, so the host can compare each member with what it wrote. `params.pad0` nodes,
// `params.pad1` triangles, two ray states, `params.mesh_count` meshes and the shading parameters
// are probed.
#import params
#import ray
#import blocks
#import dc
#import scene
#import shading

@group(1) @binding(0) var<storage, read> probe_rays: array<RayGroups>;
@group(1) @binding(1) var<storage, read_write> out: array<u32>;
@group(1) @binding(2) var<storage, read> probe_shading: ShadeParams;

var<private> at: u32 = 0u;

fn put(w: u32) {
    out[at] = w;
    at += 1u;
}

fn putf(v: f32) {
    put(bitcast<u32>(v));
}

fn put4(v: vec4<f32>) {
    putf(v.x);
    putf(v.y);
    putf(v.z);
    putf(v.w);
}

@compute @workgroup_size(1)
fn main() {
    let p = params;
    put4(p.origin);
    put4(p.forward);
    put4(p.right);
    put4(p.up);
    put4(p.background);
    put(p.width); put(p.height); put(p.tiles_x); put(p.first_tile);
    put(p.batch_rays); put(p.step_budget); put(p.stack_size); put(p.mesh_count);
    put(p.node_blocks);
    put(p.dc_ranks); put(p.dc_rank); put(p.dc_lines); put(p.dc_map);
    put(p.dc_cache_row); put(p.dc_root_row); put(p.dc_fault_cap);
    put(p.rect_x); put(p.rect_y); put(p.rect_w); put(p.rect_h);
    put(p.pad0); put(p.pad1); put(p.dc_defer); put(p.opaque_zero);
    put(p.sample); put(p.seed); put(p.flags); put(p.spp);
    put(p.attr_block0); put(p.albedo_stride); put(p.band_tiles); put(p.lane);
    for (var i = 0u; i < p.pad0; i++) {
        let l = node_loc(i);
        let n = node_at(locate(l.x), l.y);
        putf(n.origin.x); putf(n.origin.y); putf(n.origin.z); put(n.exponents);
        put(n.child_base); put(n.tri_base); put(n.counts); put(0u);
        put(n.lo.x); put(n.lo.y); put(n.lo.z);
        put(n.hi.x); put(n.hi.y); put(n.hi.z); put(0u); put(0u);
    }
    for (var i = 0u; i < p.pad1; i++) {
        let l = tri_loc(i);
        let t = tri_at(locate(l.x), l.y);
        putf(t.v0.x); putf(t.v0.y); putf(t.v0.z);
        putf(t.v1.x); putf(t.v1.y); putf(t.v1.z);
        putf(t.v2.x); putf(t.v2.y); putf(t.v2.z);
        put(prim_id_at(locate(l.x), l.y));
    }
    for (var i = 0u; i < 2u; i++) {
        let r = ray_state(probe_rays[i]);
        putf(r.ox); putf(r.oy); putf(r.oz); putf(r.t);
        putf(r.dx); putf(r.dy); putf(r.dz); put(r.hit);
        put(r.sp); put(r.status); put(r.steps);
        put(r.cur_index); put(r.cur_count);
        put(r.wait_block); put(r.flags); put(r.skip); put(r.prim);
        putf(r.nx); putf(r.ny); putf(r.nz);
        putf(r.hx); putf(r.hy); putf(r.hz); putf(r.herr);
        putf(r.b1); putf(r.b2); put(r.pad0); put(r.pad1);
    }
    for (var i = 0u; i < p.mesh_count; i++) {
        let m = meshes[i];
        put4(m.color);
        put(m.first_prim); put(m.look); put(m.point); put(m.map);
        putf(m.lo); putf(m.scale); put(m.pad0); put(m.pad1);
    }
    let s = probe_shading;
    put4(s.sky); put4(s.sun_dir); put4(s.sun);
    put(s.mode); put(s.fan); put(s.ao_rays); putf(s.ao_distance);
    put(s.max_depth); put(s.rr_depth); put(s.light_count); put(s.offset_mode);
    putf(s.epsilon); putf(s.ambient); put(s.any_hit); put(s.pad1);
    for (var i = 0u; i < MAX_LIGHTS; i++) {
        put4(s.lights[i].pos);
        put4(s.lights[i].color);
    }
}
