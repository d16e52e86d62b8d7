// After a wave of secondary rays is traced: one invocation per pixel slot reads its `fan` rays.
// A ray that was traced (DONE) and hit nothing means the light, the sun or the sky is visible.
// Shadows and ambient occlusion end here; a path either ends (sky, depth limit, Russian
// roulette) or moves to its new hit for the next wave. An ended path adds its radiance to the
// pixel's sum.
#import params
#import ray
#import scene
#import shading
#import sampling
#import spawn

@group(1) @binding(0) var<storage, read_write> rays: array<RayGroups>;
@group(1) @binding(1) var<storage, read_write> pixels: array<Pixel>;
@group(1) @binding(2) var<storage, read_write> paths: array<Path>;
// Colour by data: the albedo kernel's colour of each bounce ray's hit (see shade.wgsl).
@group(1) @binding(4) var<storage, read> albedos: array<vec4<f32>>;

fn unoccluded(r: RayState) -> bool {
    return r.status == DONE && r.hit == NONE;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.batch_rays {
        return;
    }
    // A dead path's slot is left as it is: its flag alone is loaded (the spawn kernel did not
    // store its rays).
    if paths[i].alive == 0u {
        return;
    }
    var path = paths[i];
    let fan = shading.fan;
    if MODE == MODE_SHADOWS {
        for (var k = 0u; k < fan; k++) {
            let r = ray_state(rays[wave_slot(i, k, fan)]);
            if unoccluded(r) {
                let l = shading.lights[k];
                var e = l.color.xyz;
                if l.pos.w != 0.0 {
                    e /= r.t * r.t;  // r.t is still the distance to the light
                }
                path.l += path.albedo * e * dot(ray_dir(r), path.n);
            }
        }
        path.alive = 0u;
    } else if MODE == MODE_AO {
        var open = 0u;
        for (var k = 0u; k < fan; k++) {
            open += u32(unoccluded(ray_state(rays[wave_slot(i, k, fan)])));
        }
        path.l = vec3(f32(open) / f32(fan));
        path.alive = 0u;
    } else if MODE == MODE_PATH {
        var kb = 0u;
        if shading.sun.w != 0.0 {
            kb = 1u;
            let s = ray_state(rays[wave_slot(i, 0u, fan)]);
            if unoccluded(s) {
                let cos_s = dot(shading.sun_dir.xyz, path.n);
                path.l += path.tp * path.albedo * (1.0 / PI) * shading.sun.xyz * cos_s;
            }
        }
        let r = ray_state(rays[wave_slot(i, kb, fan)]);
        // Cosine-weighted sampling: the Lambertian BRDF times cosine over the pdf is the albedo.
        path.tp *= path.albedo;
        if r.status != DONE {
            path.alive = 0u;
        } else if r.hit == NONE {
            path.l += path.tp * shading.sky.xyz;
            path.alive = 0u;
        } else {
            let n = vec3(r.nx, r.ny, r.nz);
            let d = ray_dir(r);
            path.pos = ray_hit_point(r);
            path.err = r.herr;
            path.tri = r.hit;
            path.n = select(n, -n, dot(n, d) > 0.0);
            let mesh = meshes[mesh_of(r.prim)];
            path.albedo = mesh.color.xyz;
            if COLORED && mesh.look != LOOK_CONSTANT {
                path.albedo = albedos[wave_slot(i, kb, fan)].xyz;
            }
            path.depth += 1u;
            if path.depth >= shading.max_depth {
                path.alive = 0u;
            } else if path.depth >= shading.rr_depth {
                let q = min(1.0, max(path.tp.x, max(path.tp.y, path.tp.z)));
                let u = sample2(path.pixel, 3u + 2u * path.depth, params.sample).x;
                if u >= q {
                    path.alive = 0u;
                } else {
                    path.tp /= q;
                }
            }
        }
    }
    if path.alive == 0u {
        pixels[i].r += path.l.x;
        pixels[i].g += path.l.y;
        pixels[i].b += path.l.z;
    }
    paths[i] = path;
}
