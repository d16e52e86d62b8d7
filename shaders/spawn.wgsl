// A wave of secondary rays whose paths have thinned out (shared/spawn.wgsl): the slots of the
// live rays listed in list 0, compacted for the wave's first round (traverse, FIRST_LISTED),
// which makes those rays from their paths. A wave in which nearly every path is alive is made by
// its first round over every slot instead (FIRST_SPAWN).
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
        // Only a slot's status is stored here, and only when its ray is not traced (OUTSIDE: the
        // albedo kernel and gather skip it): the listed rays' state is the first round's to store,
        // so a CPU driver, which stores lane by lane, moves one group a dead slot and none a live
        // one. Of spawn_ray only the status is used: the compiler drops the rest.
        live = spawn_ray(paths[ik.x], ik.y).status == LIVE;
        if !live {
            rays[j].g[2] = vec4(0u, OUTSIDE, 0u, 0u);
        }
    }
    append_live(live, lid, j);
}
