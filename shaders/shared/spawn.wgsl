// A wave of secondary rays: `shading.fan` ray slots per pixel slot (mode_wave_slot). Shadows:
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

// The ray slot of ray k of batch slot i in this mode's waves: `wave_slot` (by kind), except
// ambient occlusion, whose rays of a pixel share their origin and differ only in direction: one
// pixel's rays a subgroup (slot i * fan + k) measured as fast as or faster than ray k of
// neighbouring pixels (docs/ARCHITECTURE.md, Shading modes).
fn mode_wave_slot(i: u32, k: u32, fan: u32) -> u32 {
    if MODE == MODE_AO {
        return i * fan + k;
    }
    return wave_slot(i, k, fan);
}

// The batch slot and k of ray slot j of this mode's waves: mode_wave_slot's inverse.
fn mode_wave_ray(j: u32, fan: u32) -> vec2<u32> {
    if MODE == MODE_AO {
        return vec2(j / fan, j % fan);
    }
    return wave_ray(j, fan);
}

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
        r = new_ray(spawn_origin(path.pos, n, path.err), dir, tmax, LIVE, flags, path.tri);
    }
    return r;
}
