// A primary ray's pixel: the AOVs of the EXR contract, which the first sample of a render writes
// (depth along the normalized ray, primitive id, unit geometric normal), and cast mode's colour,
// headlight Lambert times the mesh colour. Colours are summed over samples; the host divides by
// the sample count.
#import params
#import ray
#import scene
#import shading

const AMBIENT: f32 = 0.15;
const POS_INF: u32 = 0x7f800000u;

// Whether a traced ray ends on a surface.
fn ray_hit(r: RayState) -> bool {
    return r.hit != NONE && r.status == DONE;
}

// The pixel a render's first sample starts from: its AOVs, no colour.
fn first_pixel(r: RayState) -> Pixel {
    if ray_hit(r) {
        return Pixel(0.0, 0.0, 0.0, bitcast<u32>(r.t), r.prim, r.nx, r.ny, r.nz);
    }
    return Pixel(0.0, 0.0, 0.0, POS_INF, NONE, 0.0, 0.0, 0.0);
}

// Cast mode's colour of a hit with geometric normal n along direction d.
fn headlight(albedo: vec3<f32>, n: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    return albedo * (AMBIENT + (1.0 - AMBIENT) * abs(dot(n, d)));
}

// Whether the first traversal round of a batch writes the pixels of the rays that end in it
// (shaders/traverse.wgsl): in cast mode, when no mesh is coloured by data (whose albedos are
// resolved after the trace), a ray's pixel needs nothing the round does not hold.
fn first_round_shades() -> bool {
    return MODE == MODE_CAST && !COLORED;
}

// The pixel of cast ray r with this sample added; `before` is the sum of the samples before it
// (ignored in the first sample). Meshes coloured by data are shaded by the shade kernel.
fn cast_pixel(r: RayState, before: Pixel) -> Pixel {
    var p = before;
    if (params.flags & FIRST_SAMPLE) != 0u {
        p = first_pixel(r);
    }
    var c = params.background.xyz;
    if ray_hit(r) {
        c = headlight(meshes[mesh_of(r.prim)].color.xyz, vec3(r.nx, r.ny, r.nz), ray_dir(r));
    }
    p.r += c.x;
    p.g += c.y;
    p.b += c.z;
    return p;
}
