// Shading of one batch: headlight Lambert times the mesh colour, plus the AOVs of the EXR
// contract (depth along the normalized ray, primitive id, unit geometric normal).

@group(1) @binding(0) var<storage, read> rays: array<RayState>;
@group(1) @binding(1) var<storage, read_write> pixels: array<Pixel>;

const AMBIENT: f32 = 0.15;
const POS_INF: u32 = 0x7f800000u;

fn mesh_of(prim: u32) -> u32 {
    // Last mesh whose first primitive is <= prim.
    var lo = 0u;
    var hi = params.mesh_count;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if meshes[mid].first_prim <= prim {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.batch_rays {
        return;
    }
    let r = rays[i];
    var p = Pixel(params.background.x, params.background.y, params.background.z,
                  POS_INF, NONE, 0.0, 0.0, 0.0);
    if r.hit != NONE && r.status == DONE {
        let n = vec3(r.nx, r.ny, r.nz);
        let prim = r.prim;
        let c = meshes[mesh_of(prim)].color.xyz * (AMBIENT + (1.0 - AMBIENT) * abs(dot(n, ray_dir(r))));
        p = Pixel(c.x, c.y, c.z, bitcast<u32>(r.t), prim, n.x, n.y, n.z);
    }
    pixels[i] = p;
}
