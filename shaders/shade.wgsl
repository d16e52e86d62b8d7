// The primary hits of one pass over a batch (one invocation per pixel slot). In `cast` mode:
// headlight Lambert times the mesh colour (shared/pixel.wgsl); the pixels of rays the first
// traversal round shaded (`SHADED`) are left as it wrote them. In the other modes: the sample's
// path starts here (spawn and gather follow). The first pass of a render also writes the AOVs of
// the EXR contract. Colours are summed over passes; the host divides by the sample count.
#import params
#import ray
#import scene
#import shading
#import pixel
#import tiles

@group(1) @binding(0) var<storage, read_write> rays: array<RayGroups>;
@group(1) @binding(1) var<storage, read_write> pixels: array<Pixel>;
@group(1) @binding(2) var<storage, read_write> paths: array<Path>;
// Colour by data: the albedo kernel's colour of each hit on a mesh coloured by data.
@group(1) @binding(4) var<storage, read> albedos: array<vec4<f32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.batch_rays {
        return;
    }
    // Only the status is read first: most rays of a cast frame end in the first round.
    if first_round_shades() && rays[i].g[2].y == SHADED {
        return;
    }
    let r = ray_state(rays[i]);
    if first_round_shades() {
        pixels[i] = cast_pixel(r, pixels[i]);
        return;
    }
    let hit = ray_hit(r);
    var p = pixels[i];
    if (params.flags & FIRST_SAMPLE) != 0u {
        p = first_pixel(r);
    }
    var c = params.background.xyz;
    if MODE == MODE_PATH {
        c = shading.sky.xyz;
    }
    if hit {
        let n = vec3(r.nx, r.ny, r.nz);
        let d = ray_dir(r);
        let mesh = meshes[mesh_of(r.prim)];
        var albedo = mesh.color.xyz;
        if COLORED && mesh.look != LOOK_CONSTANT {
            albedo = albedos[i].xyz;
        }
        if MODE == MODE_CAST {
            c = headlight(albedo, n, d);
        } else {
            var path: Path;
            path.pos = ray_hit_point(r);
            path.err = r.herr;
            path.tri = r.hit;
            path.n = select(n, -n, dot(n, d) > 0.0);
            path.alive = 1u;
            path.depth = 0u;
            path.albedo = albedo;
            let l = tile_pixel(i);
            let px = params.rect_x + l.x;
            let py = params.rect_y + l.y;
            path.pixel = py * params.width + px;
            path.tp = vec3(1.0);
            path.l = vec3(0.0);
            if MODE == MODE_SHADOWS {
                path.l = albedo * shading.ambient;
                // Without lights there is no shadow ray to wait for.
                path.alive = u32(shading.light_count > 0u);
            }
            c = select(path.l, vec3(0.0), path.alive != 0u);
            paths[i] = path;
        }
    } else if MODE != MODE_CAST {
        paths[i].alive = 0u;
    }
    p.r += c.x;
    p.g += c.y;
    p.b += c.z;
    pixels[i] = p;
}
