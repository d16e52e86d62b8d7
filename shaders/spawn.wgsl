// One wave of secondary rays: `shading.fan` ray slots per pixel slot (slot i * fan + k). Shadows:
// ray k goes to light k; ambient occlusion: ray k is the sample's k-th cosine-weighted direction;
// path: ray 0 goes to the sun (when on), the last is the cosine-weighted bounce. Shadow and
// occlusion rays stop at any hit. Rays not needed (dead path, light behind the surface) are
// OUTSIDE; the rest are appended to the live list and traced by the same rounds as primary rays.
#import params
#import ray
#import shading
#import sampling
#import offset
#import queue

@group(1) @binding(0) var<storage, read_write> rays: array<RayGroups>;
@group(1) @binding(1) var<storage, read_write> pixels: array<Pixel>;
@group(1) @binding(2) var<storage, read_write> paths: array<Path>;
@group(1) @binding(3) var<storage, read> shading: ShadeParams;

fn spawn_origin(p: vec3<f32>, n: vec3<f32>, err: f32) -> vec3<f32> {
    if shading.offset_mode == 0u {
        return offset_ray(p, n, err);
    }
    return p + shading.epsilon * n;
}

@compute @workgroup_size(WORKGROUP)  // the `args` kernel sizes indirect dispatches by it
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let j = gid.x;
    let fan = shading.fan;
    var live = false;
    if j < params.batch_rays * fan {
        let i = j / fan;
        let k = j - i * fan;
        let path = paths[i];
        var r = new_ray(vec3(0.0), vec3(0.0, 0.0, 1.0), FAR, OUTSIDE, 0u, NONE);
        if path.alive != 0u {
            let n = path.n;
            var dir = n;
            var tmax = FAR;
            var flags = shading.any_hit;
            var go = true;
            if MODE == MODE_SHADOWS {
                let l = shading.lights[k];
                if l.pos.w == 0.0 {
                    dir = l.pos.xyz;
                } else {
                    let v = l.pos.xyz - path.pos;
                    tmax = length(v);
                    dir = v / tmax;
                }
                go = dot(dir, n) > 0.0;
            } else if MODE == MODE_AO {
                let u = sample2(path.pixel, 1u, params.sample * shading.ao_rays + k);
                dir = cosine_dir(n, u);
                tmax = shading.ao_distance;
            } else if MODE == MODE_PATH {
                if shading.sun.w != 0.0 && k == 0u {
                    dir = shading.sun_dir.xyz;
                    go = dot(dir, n) > 0.0;
                } else {
                    dir = cosine_dir(n, sample2(path.pixel, 2u + 2u * path.depth, params.sample));
                    flags = 0u;
                }
            }
            if go {
                let o = spawn_origin(path.pos, n, path.err);
                r = new_ray(o, dir, tmax, LIVE, flags, path.tri);
                live = true;
            }
        }
        rays[j] = ray_groups(r);
    }
    append_live(live, lid, j);
}
