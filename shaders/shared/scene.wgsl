// What the kernels know of the scene besides its blocks: each mesh's first primitive and colour.
#import params

// Mirrors gpu::layout::MeshInfo.
struct MeshInfo {
    color: vec4<f32>,
    first_prim: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(2) var<storage, read> meshes: array<MeshInfo>;

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
