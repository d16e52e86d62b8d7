// What the kernels know of the scene besides its blocks: each mesh-table entry's first
// primitive, colour and look (coloured by data or not).
#import params

// Mirrors gpu::layout::MeshInfo.
struct MeshInfo {
    color: vec4<f32>,
    first_prim: u32,
    look: u32,    // LOOK_*
    point: u32,   // 1: attributes per corner (point data), 0: per triangle
    map: u32,     // colormap index
    lo: f32,      // the range's start
    scale: f32,   // 256 / (hi - lo)
    pad0: u32,
    pad1: u32,
}

// MeshInfo.look, mirrors gpu::layout::look.
const LOOK_CONSTANT: u32 = 0u;
const LOOK_SCALARS: u32 = 1u;
const LOOK_COLORS: u32 = 2u;
// Whether the model has colour data (attribute blocks): without it no kernel reads an albedo
// slot, which costs a CPU driver a loop over the lanes per read even where a select drops it.
override COLORED: bool = true;

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
