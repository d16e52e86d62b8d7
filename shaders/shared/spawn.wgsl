// A wave of secondary rays: `shading.fan` ray slots per pixel slot (tiles.wgsl, wave_slot). Shadows:
// ray k goes to light k; ambient occlusion: ray k is the sample's k-th cosine-weighted direction;
// path: ray 0 goes to the sun (when on), the last is the cosine-weighted bounce. Shadow and
// occlusion rays stop at any hit. Rays not needed (dead path, light behind the surface) are
// OUTSIDE. A wave's rays are made by its first traversal round (shaders/traverse.wgsl, FIRST)
// when nearly every path is alive, else by the spawn kernel, which compacts the live ones.
#import params
#import ray
#import shading
#import sampling
#import offset
#import tiles

fn spawn_origin(p: vec3<f32>, n: vec3<f32>, err: f32) -> vec3<f32> {
    if shading.offset_mode == 0u {
        return offset_ray(p, n, err);
    }
    return p + shading.epsilon * n;
}

// Ray k of the wave from `path`: LIVE, or OUTSIDE when not needed.
fn spawn_ray(path: Path, k: u32) -> RayState {
    var r = new_ray(vec3(0.0), vec3(0.0, 0.0, 1.0), FAR, OUTSIDE, 0u, NONE);
    if path.alive == 0u {
        return r;
    }
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
        let u = sample2_patch(path.pixel, params.width, 1u, params.sample * shading.ao_rays + k);
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
        r = new_ray(spawn_origin(path.pos, n, path.err), dir, tmax, LIVE, flags, path.tri);
    }
    return r;
}
