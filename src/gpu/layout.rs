//! Host mirrors of the structs the GPU reads and writes. Each is `#[repr(C)]` + `Pod` and must
//! match the WGSL struct of the same name (in the `shaders/` file named) member by member: the
//! layout tests (`tests/all/layout.rs`) compare every member's offset with naga's layout of the
//! composed kernels, and the layout probe reads every member back through a shader.

use super::shaders::wgsl;
use bytemuck::{Pod, Zeroable};

/// `Params` in `shaders/shared/params.wgsl`: the uniform of every kernel that reads the scene.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Params {
    pub origin: [f32; 4],
    pub forward: [f32; 4],
    pub right: [f32; 4],
    pub up: [f32; 4],
    pub background: [f32; 4],
    pub width: u32,
    pub height: u32,
    pub tiles_x: u32,
    pub first_tile: u32,
    pub batch_rays: u32,
    pub step_budget: u32,
    pub stack_size: u32,
    pub mesh_count: u32,
    pub node_blocks: u32,
    pub dc_ranks: u32,
    pub dc_rank: u32,
    pub dc_lines: u32,
    /// 0 Ize, 1 DeMarle.
    pub dc_map: u32,
    pub dc_cache_row: u32,
    pub dc_root_row: u32,
    pub dc_fault_cap: u32,
    /// The image rectangle this render covers (the whole image, or one tile of the cluster's
    /// load balancer); `tiles_x` counts 8x8 tiles across it.
    pub rect_x: u32,
    pub rect_y: u32,
    pub rect_w: u32,
    pub rect_h: u32,
    pub pad0: u32,
    pub pad1: u32,
    /// Set-aside slots a ray may use this frame (`Tracer::end_frame` decides).
    pub dc_defer: u32,
    /// 0: a value the shader compiler cannot know, which hides the compensated sums of
    /// `shared/compensated.wgsl` from its algebra.
    pub opaque_zero: u32,
    /// The sampler's sample index of this pass, its seed, `flags::*` and the render's samples
    /// per pixel.
    pub sample: u32,
    pub seed: u32,
    pub flags: u32,
    pub spp: u32,
    /// Colour by data: the first attribute block, and the ray slots the `albedo` kernel reads,
    /// `wave_slot(i, albedo_stride - 1, albedo_stride)` in `shaders/shared/tiles.wgsl` (1: every
    /// primary ray; a wave's fan: its bounce rays).
    pub attr_block0: u32,
    pub albedo_stride: u32,
    /// Tiles across a band of the batch order (`mirror::tiles::Tiling::band`); 0: one band.
    pub band_tiles: u32,
    /// The lane of the batch a dispatch serves: the high bits of a fault's requester
    /// (`requester` in shaders/shared/dc.wgsl, `gpu::faults::requester_lane`).
    pub lane: u32,
}
const _: () = assert!(std::mem::size_of::<Params>() == 208);

/// `Params.flags` and `RayState.flags` values, as the WGSL declares them.
pub mod flags {
    use crate::gpu::shaders::wgsl;
    /// Params: jitter primary rays in the pixel.
    pub const JITTER: u32 = wgsl::JITTER;
    /// Params: primary rays that miss the root box skip traversal.
    pub const CULL: u32 = wgsl::CULL;
    /// Params: the first pass of a render (the shade kernel resets the pixels).
    pub const FIRST_SAMPLE: u32 = wgsl::FIRST_SAMPLE;
    /// Params: `sample2` hashes independent uniform numbers (default: Owen-scrambled Sobol').
    pub const SAMPLER_INDEPENDENT: u32 = wgsl::SAMPLER_INDEPENDENT;
    /// Params: a parallel projection (rays along `forward` from the image plane).
    pub const PARALLEL: u32 = wgsl::PARALLEL;
    /// RayState: stop at the first hit found.
    pub const ANY_HIT: u32 = wgsl::ANY_HIT;
    /// RayState: the ray starts at the camera, on no surface (no proof of a positive hit
    /// distance beyond rounding is needed).
    pub const FROM_CAMERA: u32 = wgsl::FROM_CAMERA;
}

/// `RayState` in `shaders/shared/ray.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RayState {
    pub origin: [f32; 3],
    pub t: f32,
    pub dir: [f32; 3],
    pub hit: u32,
    pub sp: u32,
    pub status: u32,
    pub steps: u32,
    /// What the ray visits next: node `cur_index` when `cur_count` is 0, else `cur_count`
    /// triangles from `cur_index`; `cur_count` `NONE` to pop the stack (a new ray: 0 and 0).
    pub cur_index: u32,
    pub cur_count: u32,
    /// The block the ray suspended on, or `NONE`.
    pub wait_block: u32,
    /// `flags::ANY_HIT` for shadow and occlusion rays, `flags::FROM_CAMERA` for primary rays.
    pub flags: u32,
    /// The triangle (BVH order) a secondary ray leaves and skips, or `NONE`.
    pub skip: u32,
    /// Primitive id and unit geometric normal of the closest hit. This and what follows is only
    /// written by traversal (when it finds a closer hit): the first 64 bytes are all it reads.
    pub prim: u32,
    pub normal: [f32; 3],
    /// The closest hit's point from its barycentrics, and the distance along the normal that
    /// moves a new ray's origin past its rounding error.
    pub hit_point: [f32; 3],
    pub hit_error: f32,
    /// The closest hit's barycentrics of v1 and v2 (point data is interpolated with them).
    pub b1: f32,
    pub b2: f32,
    pub pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<RayState>() == 112);

/// `RayState.status` values, as the WGSL declares them.
pub mod status {
    use crate::gpu::shaders::wgsl;
    pub const LIVE: u32 = wgsl::LIVE;
    pub const DONE: u32 = wgsl::DONE;
    pub const OUTSIDE: u32 = wgsl::OUTSIDE;
    pub const OVERFLOW: u32 = wgsl::OVERFLOW;
    /// Ended in a batch's first round, which wrote its pixel (cast mode without colour by data):
    /// of its state only `sp`, `status`, `steps` and `cur_index` are stored.
    pub const SHADED: u32 = wgsl::SHADED;
}

/// `MeshInfo` in `shaders/shared/scene.wgsl`: a mesh-table entry's first primitive, colour and
/// look.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MeshInfo {
    pub color: [f32; 4],
    pub first_prim: u32,
    /// `look::*`.
    pub look: u32,
    /// 1: attributes per corner (point data), 0: per triangle.
    pub point: u32,
    /// Colormap index (`colormap::Colormap::index`).
    pub map: u32,
    /// The range's start and `colormap::scale` of it.
    pub lo: f32,
    pub scale: f32,
    pub pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<MeshInfo>() == 48);

/// `MeshInfo.look` values, as the WGSL declares them.
pub mod look {
    use crate::gpu::shaders::wgsl;
    pub const CONSTANT: u32 = wgsl::LOOK_CONSTANT;
    pub const SCALARS: u32 = wgsl::LOOK_SCALARS;
    pub const COLORS: u32 = wgsl::LOOK_COLORS;
}

/// `Pixel` in `shaders/shared/shading.wgsl`: the shade kernel's output for one ray.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Pixel {
    pub rgb: [f32; 3],
    /// Distance along the normalized ray; +inf on a miss.
    pub depth: f32,
    /// Primitive id; `u32::MAX` on a miss.
    pub id: u32,
    pub normal: [f32; 3],
}
const _: () = assert!(std::mem::size_of::<Pixel>() == 32);

impl Pixel {
    /// `n` zeroed pixels (`Pixel::default()`), allocated zeroed: the allocator hands out pages
    /// the system has zeroed, where `vec![Pixel::default(); n]` writes each pixel (17 ms of a
    /// 150 ms frame at 1024x1024).
    pub fn zeroed_vec(n: usize) -> Vec<Pixel> {
        bytemuck::zeroed_vec(n)
    }
}

/// `Counter` in `shaders/shared/counter.wgsl`: a live-ray count and the indirect dispatch arguments of
/// the round that consumes it (at byte offset 4).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Counter {
    pub count: u32,
    pub dispatch: [u32; 3],
}

/// `Stats` in `shaders/traverse.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Stats {
    pub steps: u32,
    pub tri_tests: u32,
    pub overflows: u32,
    /// Rays that stopped on a fault this round.
    pub suspended: u32,
    /// Rays that entered traversal: counted by a first round that makes its rays, copied from
    /// the count of a spawned wave.
    pub started: u32,
    /// Cache consultations (blocks neither owned nor the root): how they went.
    pub hits: u32,
    pub misses: u32,
    /// Inner-node visits, and how many of them moved to another node block than the previous.
    pub node_visits: u32,
    pub block_entries: u32,
    /// Triangle reads from another triangle block than the ray's previous one.
    pub tri_block_entries: u32,
    /// Summed over subgroups, the most loop iterations one of its invocations ran; and the
    /// subgroup size (`FrameStats::lane_steps`).
    pub subgroup_steps: u32,
    pub subgroup_size: u32,
    /// Rays that do not stop at any hit and found one, counted in modes with secondary rays:
    /// when a batch's rays found none, no path goes on (`rounds::Traced::closest_hits`).
    pub closest_hits: u32,
    pub pad: u32,
}
const _: () = assert!(std::mem::size_of::<Stats>() == 56);

/// `Faults` in `shaders/shared/dc.wgsl`, before its list of faulted blocks.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FaultHeader {
    /// Distinct blocks faulted this round (may exceed the list's capacity).
    pub count: u32,
    /// Faults that did not fit in the list; they fault again next round.
    pub dropped: u32,
    pub pad: [u32; 2],
}

/// `Light` in `shaders/shared/shading.wgsl`. `pos[3]`: 0 directional (`pos` the unit direction towards
/// the light), 1 point (`pos` its position).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Light {
    pub pos: [f32; 4],
    pub color: [f32; 4],
}

/// Lights a pipeline can take (`MAX_LIGHTS` in `shaders/shared/shading.wgsl`).
pub const MAX_LIGHTS: usize = crate::shading::MAX_LIGHTS;
const _: () = assert!(MAX_LIGHTS == wgsl::MAX_LIGHTS as usize);

/// `ShadeParams` in `shaders/shared/shading.wgsl`: what the shade, spawn and gather kernels read.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ShadeParams {
    pub sky: [f32; 4],
    pub sun_dir: [f32; 4],
    /// Sun irradiance; `[3]` is 1 when the sun is on.
    pub sun: [f32; 4],
    pub mode: u32,
    /// Secondary rays per pixel in one wave.
    pub fan: u32,
    pub ao_rays: u32,
    pub ao_distance: f32,
    pub max_depth: u32,
    pub rr_depth: u32,
    pub light_count: u32,
    /// 0: past the hit point's error bound along the normal; 1: fixed epsilon.
    pub offset_mode: u32,
    pub epsilon: f32,
    pub ambient: f32,
    /// `flags::ANY_HIT` when shadow and occlusion rays stop at any hit, else 0.
    pub any_hit: u32,
    pub pad: u32,
    pub lights: [Light; MAX_LIGHTS],
}
const _: () = assert!(std::mem::size_of::<ShadeParams>() == 224);

/// No block, no row, no hit (WGSL's `NONE`): the distributed cache's empty entry.
pub const NONE: u32 = crate::dc::NONE;
const _: () = assert!(NONE == wgsl::NONE);
// The host's values that the kernels declare again, checked by the build: the tile edge, and
// the shading modes (`MODE_*` in shaders/shared/shading.wgsl, the `MODE` override's values).
const _: () = assert!(crate::mirror::tiles::TILE == wgsl::TILE);
// The sRGB decode table follows the colormaps in the palette (`colormap::palette`).
const _: () = assert!(
    crate::colormap::ENTRIES * crate::colormap::Colormap::ALL.len() == wgsl::SRGB_LEVELS as usize
);
const _: () = assert!(
    crate::shading::Mode::Cast as u32 == wgsl::MODE_CAST
        && crate::shading::Mode::Shadows as u32 == wgsl::MODE_SHADOWS
        && crate::shading::Mode::Ao as u32 == wgsl::MODE_AO
        && crate::shading::Mode::Path as u32 == wgsl::MODE_PATH
);
/// The kernels' finite stand-in for an unbounded ray (`FAR` in `shaders/shared/ray.wgsl`):
/// finite, because WGSL promises nothing for infinities.
pub const FAR: f32 = 3.0e38;

/// `Path` in `shaders/shared/shading.wgsl`: a pixel's sample between waves of secondary rays.
/// Only the GPU reads and writes it; the host sizes its buffer and the probe tests read it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Path {
    pub pos: [f32; 3],
    pub alive: u32,
    /// Geometric normal facing the incoming ray.
    pub n: [f32; 3],
    pub depth: u32,
    pub albedo: [f32; 3],
    /// `y * width + x`: keys the sampler.
    pub pixel: u32,
    /// Throughput.
    pub tp: [f32; 3],
    /// How far along `n` a new ray's origin moves.
    pub err: f32,
    /// Radiance gathered so far.
    pub l: [f32; 3],
    /// The hit triangle (BVH order), which rays leaving it skip.
    pub tri: u32,
}
const _: () = assert!(std::mem::size_of::<Path>() == 80);

/// What the host reads back after each batch of traversal rounds, copied together into one
/// buffer: the live counter, the trace statistics, the rounds' two GPU timestamps and, after a
/// batch's first round of primary rays, the rays it left live.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RoundReadback {
    pub counter: Counter,
    pub stats: Stats,
    pub timestamps: [u64; 2],
    /// Rays left live by the batch's first round of primary rays (copied by that round only).
    pub opened: u32,
    pub pad: [u32; 3],
}

/// `MirrorCase` in `shaders/mirror.wgsl` (tests): inputs of the shared functions with CPU twins.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MirrorCase {
    pub p: [f32; 4],
    pub n: [f32; 4],
    pub u: [f32; 4],
    /// `hash` input, then `sample2`'s pixel, dimension and index (`child_box`'s slot: index % 4).
    pub words: [u32; 4],
    /// `child_box`'s node (`bvh::Node`'s words).
    pub node: [u32; 16],
    /// `colormap`'s value, range start and scale (its map: `words[2] % 4`; `srgb_color`'s
    /// word: `words[0]`).
    pub c: [f32; 4],
}

/// `MirrorResult` in `shaders/mirror.wgsl` (tests): what the GPU computed for one case.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MirrorResult {
    pub offset: [f32; 4],
    pub dir: [f32; 4],
    pub sample: [f32; 4],
    /// `hash`, then `tile_pixel` of the case's index (x, y), then `cache_line` of the hash input over 4.
    pub words: [u32; 4],
    /// `child_box` of the case's node and slot.
    pub lo: [f32; 4],
    pub hi: [f32; 4],
    /// `colormap` and `srgb_color` of the case.
    pub color: [f32; 4],
    pub rgb: [f32; 4],
    /// `block_row` of the case's index (x) in the table `run_mirror` was given.
    pub row: [u32; 4],
    /// `sample2_patch` of the case's pixel, dimension and index, at `Params::width`.
    pub patched: [f32; 4],
}
