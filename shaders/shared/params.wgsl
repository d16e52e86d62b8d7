// The uniform every kernel that reads the scene gets (host: gpu::layout::Params), and the
// "nothing" value of every index the host and the GPU exchange.

const NONE: u32 = 0xffffffffu;

// Mirrors gpu::layout::Params.
struct Params {
    origin: vec4<f32>,
    forward: vec4<f32>,
    right: vec4<f32>,       // camera right * tan(view_angle / 2) * aspect
    up: vec4<f32>,          // camera up * tan(view_angle / 2)
    background: vec4<f32>,
    width: u32,
    height: u32,
    tiles_x: u32,
    first_tile: u32,
    batch_rays: u32,
    step_budget: u32,
    stack_size: u32,
    mesh_count: u32,
    node_blocks: u32,
    // Distributed cache (docs/ARCHITECTURE.md, The distributed cache): ranks N, this rank, cache
    // lines, mapping (0 Ize, 1 DeMarle), first cache row, the replicated root block's row, fault
    // list capacity.
    dc_ranks: u32,
    dc_rank: u32,
    dc_lines: u32,
    dc_map: u32,
    dc_cache_row: u32,
    dc_root_row: u32,
    dc_fault_cap: u32,
    // The rectangle of the image this render covers; tiles_x counts 8x8 tiles across it.
    rect_x: u32,
    rect_y: u32,
    rect_w: u32,
    rect_h: u32,
    pad0: u32,
    pad1: u32,
    // Entries a ray may set aside for absent blocks this frame (shaders/traverse.wgsl); 0: it
    // suspends at every fault.
    dc_defer: u32,
    // 0, unknown to the compiler (shared/compensated.wgsl).
    opaque_zero: u32,
    // Sampling: the sample index of this pass (the sampler's index), the seed, flags (JITTER,
    // CULL, FIRST_SAMPLE, SAMPLER_INDEPENDENT) and the samples per pixel of the render.
    sample: u32,
    seed: u32,
    flags: u32,
    spp: u32,
    // Colour by data: the first attribute block; the albedo kernel reads ray slots
    // wave_slot(i, albedo_stride - 1, albedo_stride) (1: primary rays; a wave's fan: its bounce rays).
    attr_block0: u32,
    albedo_stride: u32,
    // Tiles across a band of the batch order (shared/tiles.wgsl); 0: one band.
    band_tiles: u32,
    // The lane of the batch this dispatch serves (0 when batches do not overlap): the high bits
    // of a fault's requester (shared/dc.wgsl, request).
    lane: u32,
}

// Params.flags
const JITTER: u32 = 1u;        // jitter primary rays in the pixel (spp > 1)
const CULL: u32 = 2u;          // primary rays that miss the root box skip traversal
const FIRST_SAMPLE: u32 = 4u;  // the first pass of a render: the shade kernel resets pixels
const SAMPLER_INDEPENDENT: u32 = 8u;  // sample2 hashes independent uniforms (default: Sobol')
const PARALLEL: u32 = 16u;     // a parallel projection: rays along forward from the image plane

@group(0) @binding(0) var<uniform> params: Params;
