// A wave of secondary rays whose paths have thinned out (shared/spawn.wgsl): each slot's ray
// stored, and the live ones appended to list 0, compacted for the wave's first indirect round.
// A wave in which nearly every path is alive is made by its first traversal round instead.
#import params
#import ray
#import shading
#import spawn
#import queue

@group(1) @binding(0) var<storage, read_write> rays: array<RayGroups>;
@group(1) @binding(2) var<storage, read_write> paths: array<Path>;

@compute @workgroup_size(WORKGROUP)  // the `args` kernel sizes indirect dispatches by it
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let j = gid.x;
    let fan = shading.fan;
    var live = false;
    if j < params.batch_rays * fan {
        let ik = wave_ray(j, fan);
        // A dead path's slot gets only the group with its status (OUTSIDE: the albedo kernel
        // skips it; gather skips dead paths), which makes a wave of few live paths cheap (a CPU
        // driver loads and stores lane by lane).
        if paths[ik.x].alive != 0u {
            let r = spawn_ray(paths[ik.x], ik.y);
            live = r.status == LIVE;
            rays[j] = ray_groups(r);
        } else {
            rays[j].g[2] = vec4(0u, OUTSIDE, 0u, 0u);
        }
    }
    append_live(live, lid, j);
}
