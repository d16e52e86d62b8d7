//! The GPU trace loop (DESIGN.md section 3) for a model whose blocks are all resident.
//!
//! A frame is traced in batches of 8x8 tiles. Per batch: `raygen` writes a state record per ray
//! and the live list; then rounds of `trace` (each live ray runs at most `step_budget` loop
//! iterations, then saves its state) and `args` (turns the count of rays still live into the
//! next round's indirect dispatch), with the live count read back every few rounds; when no ray
//! is live, `shade` writes the pixels.

use super::Gpu;
use super::layout::{
    Counter, FaultHeader, MeshInfo, NONE, Params, Pixel, RayState, ShadeParams, Stats, flags,
    status,
};
use super::shaders::{self, Store};
use crate::blocks::Format;
use crate::dc::source::BlockSource;
use crate::dc::trace::{Fault, FrameTrace, Round};
use crate::dc::{CacheMap, Ranks, cache_line};
use crate::error::{Error, Result};
use crate::reference::Ray;
use crate::scene::CameraBasis;
use crate::shading::{Mode, Shading};
use std::time::{Duration, Instant};
use wgpu::util::DeviceExt;

pub const TILE: u32 = 8;
const TILE_RAYS: u32 = TILE * TILE;
const WORKGROUP: u32 = 64;
/// lavapipe stops any shader loop after 65,535 iterations per invocation; a budget plus the
/// largest leaf (255 triangles) must stay below that.
pub const MAX_STEP_BUDGET: u32 = 60_000;
pub const DEFAULT_STEP_BUDGET: u32 = 4096;
/// Deeper BVHs than this get this many stack entries, and a ray that would overflow is reported
/// as an error rather than traced wrongly. 8 bytes an entry: a stack this deep still leaves room
/// for 4096 rays a batch in a 128 MiB storage buffer.
pub const MAX_STACK: u32 = 4096;
const DEFAULT_MAX_BATCH_RAYS: u32 = 1 << 20;
const RAY_BYTES: u64 = std::mem::size_of::<RayState>() as u64;
/// `Path` in `shaders/common.wgsl` (GPU only).
const PATH_BYTES: u64 = 80;
const SHADE_BYTES: u64 = std::mem::size_of::<ShadeParams>() as u64;

#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Loop iterations a ray may run per trace dispatch.
    pub step_budget: u32,
    /// Upper bound on rays per batch (rounded down to whole tiles); memory limits may lower it.
    pub max_batch_rays: u32,
    /// Where the GPU keeps the blocks.
    pub store: Store,
    /// Shading mode, samples, lights: the pipelines are built for this mode.
    pub shading: Shading,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            step_budget: DEFAULT_STEP_BUDGET,
            max_batch_rays: DEFAULT_MAX_BATCH_RAYS,
            store: Store::Texture,
            shading: Shading::default(),
        }
    }
}

/// Each mesh's first primitive id and colour: all the tracer needs to know of the scene besides
/// its blocks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Meshes {
    pub first_prim: Vec<u32>,
    pub colors: Vec<[f32; 3]>,
}

/// What one frame cost.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FrameStats {
    pub rays: u64,
    pub batches: u32,
    /// Trace dispatches, summed over batches (including empty trailing ones).
    pub rounds: u32,
    /// The most rounds any batch needed before no ray was live.
    pub max_live_rounds: u32,
    pub steps: u64,
    pub tri_tests: u64,
    /// Wall time of the whole frame, and of its parts: ray generation and trace rounds until the
    /// last live count came back; shading and the pixel readback (including the copy into the
    /// frame).
    pub seconds: f64,
    pub trace_seconds: f64,
    pub shade_seconds: f64,
    /// GPU time of the trace rounds by GPU timestamps (0 when the adapter has none); the rest of
    /// `trace_seconds` is submission, readback and the CPU's fault service.
    pub gpu_seconds: f64,
    /// Distributed cache: cache consultations, hits, misses; blocks fetched and their bytes;
    /// time fetching (CPU) and uploading into the cache.
    pub lookups: u64,
    pub hits: u64,
    pub misses: u64,
    pub fetched_blocks: u64,
    pub fetched_bytes: u64,
    pub fetch_seconds: f64,
    pub upload_seconds: f64,
    /// Rounds that had faults.
    pub fault_rounds: u32,
    /// Inner-node visits and node-block entries (a visit in another block than the previous).
    pub node_visits: u64,
    pub block_entries: u64,
    /// Samples per pixel traced; secondary rays spawned; rays that entered traversal (primary
    /// rays culled by the model's box and rays not needed do not).
    pub samples: u32,
    pub secondary_rays: u64,
    pub traced_rays: u64,
}

/// A traced frame: one `Pixel` per image pixel, row-major, y down.
#[derive(Clone, Debug)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Pixel>,
}

struct Kernels {
    raygen: wgpu::ComputePipeline,
    trace: wgpu::ComputePipeline,
    args: wgpu::ComputePipeline,
    shade: wgpu::ComputePipeline,
    probe: wgpu::ComputePipeline,
    /// Secondary-ray waves: built only for modes that have them.
    spawn: Option<wgpu::ComputePipeline>,
    gather: Option<wgpu::ComputePipeline>,
}

/// What starts a batch's trace rounds: primary rays, or a wave of secondary rays.
#[derive(Clone, Copy)]
enum Gen {
    Primary,
    Secondary { fan: u32 },
}

/// Buffers sized for one batch, with the bind groups over them.
struct Batch {
    rays_cap: u32,
    pixels: wgpu::Buffer,
    counters: [wgpu::Buffer; 2],
    stats: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Two GPU timestamps around each submission's trace rounds, and their resolve buffer.
    timestamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
    fault_readback: wgpu::Buffer,
    waiter_readback: wgpu::Buffer,
    pixel_readback: wgpu::Buffer,
    raygen_bg: wgpu::BindGroup,
    trace_bg: [wgpu::BindGroup; 2],
    args_bg: [wgpu::BindGroup; 2],
    shade_bg: wgpu::BindGroup,
    rays: wgpu::Buffer,
    /// The first round's live list, which `trace_rays` fills.
    live0: wgpu::Buffer,
}

/// Pipeline constants fixed for a model (block addressing, DC).
type Constants = Vec<(&'static str, f64)>;

pub struct Tracer<'g> {
    gpu: &'g Gpu,
    kernels: Kernels,
    params: Params,
    params_buf: wgpu::Buffer,
    scene_bg: wgpu::BindGroup,
    batch: Batch,
    settings: Settings,
    layouts: Layouts,
    blocks_store: BlockStore,
    rows_per_layer: u32,
    format: Format,
    dc: Option<Dc>,
    frame_start: Instant,
    /// The BVH depth the model declared (the stack holds `min(depth, MAX_STACK)` entries).
    depth: u32,
    constants: Constants,
    shade_buf: wgpu::Buffer,
}

/// A rectangle of the image in pixels: what one `render_rect` call traces.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

impl Rect {
    pub fn whole(width: u32, height: u32) -> Rect {
        Rect {
            x: 0,
            y: 0,
            w: width,
            h: height,
        }
    }

    pub fn pixels(&self) -> usize {
        self.w as usize * self.h as usize
    }
}

const NONE_TAG: u32 = u32::MAX;

/// The GPU copy of the blocks, kept alive while the tracer's bind group uses it.
enum BlockStore {
    Texture(wgpu::Texture, wgpu::TextureView),
    Buffer(wgpu::Buffer),
}

impl BlockStore {
    /// Replaces the block in `row` (a cache line) between dispatches.
    fn write_row(&self, gpu: &Gpu, format: Format, per_layer: u32, row: u32, words: &[u32]) {
        match self {
            BlockStore::Texture(t, _) => write_texture_rows(gpu, t, format, per_layer, row, words),
            BlockStore::Buffer(b) => gpu.queue.write_buffer(
                b,
                u64::from(row) * u64::from(format.block_bytes),
                bytemuck::cast_slice(words),
            ),
        }
    }

    fn resource(&self) -> wgpu::BindingResource<'_> {
        match self {
            BlockStore::Texture(_, view) => wgpu::BindingResource::TextureView(view),
            BlockStore::Buffer(b) => b.as_entire_binding(),
        }
    }
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn bgl(gpu: &Gpu, label: &str, entries: &[wgpu::BindGroupLayoutEntry]) -> wgpu::BindGroupLayout {
    gpu.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries,
        })
}

fn bind(gpu: &Gpu, layout: &wgpu::BindGroupLayout, buffers: &[&wgpu::Buffer]) -> wgpu::BindGroup {
    let entries: Vec<_> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout,
        entries: &entries,
    })
}

struct Layouts {
    scene: wgpu::BindGroupLayout,
    raygen: wgpu::BindGroupLayout,
    trace: wgpu::BindGroupLayout,
    args: wgpu::BindGroupLayout,
    shade: wgpu::BindGroupLayout,
    probe: wgpu::BindGroupLayout,
}

impl Layouts {
    fn for_kernel(&self, name: &str) -> &wgpu::BindGroupLayout {
        match name {
            "raygen" => &self.raygen,
            "trace" => &self.trace,
            "args" => &self.args,
            "shade" | "spawn" | "gather" => &self.shade,
            _ => &self.probe,
        }
    }
}

fn layouts(gpu: &Gpu, store: Store) -> Layouts {
    let blocks = match store {
        Store::Texture => wgpu::BindGroupLayoutEntry {
            binding: 1,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Uint,
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        },
        Store::Buffer => storage(1, true),
    };
    let scene = bgl(
        gpu,
        "scene",
        &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            blocks,
            storage(2, true),
            storage(3, true),
            storage(4, false),
            storage(5, false),
            storage(6, false),
        ],
    );
    let rw = |n: u32| -> Vec<_> { (0..n).map(|i| storage(i, false)).collect() };
    Layouts {
        raygen: bgl(gpu, "raygen", &rw(3)),
        trace: bgl(
            gpu,
            "trace",
            &[
                storage(0, false),
                storage(1, false),
                storage(2, true),
                storage(3, true),
                storage(4, false),
                storage(5, false),
                storage(6, false),
            ],
        ),
        args: bgl(gpu, "args", &rw(2)),
        shade: bgl(
            gpu,
            "shade",
            &[
                storage(0, false),
                storage(1, false),
                storage(2, false),
                storage(3, true),
                storage(4, false),
                storage(5, false),
            ],
        ),
        probe: bgl(
            gpu,
            "probe",
            &[storage(0, true), storage(1, false), storage(2, true)],
        ),
        scene,
    }
}

fn pipeline(
    gpu: &Gpu,
    store: Store,
    constants: &[(&str, f64)],
    name: &str,
    scene: &wgpu::BindGroupLayout,
    own: &wgpu::BindGroupLayout,
) -> wgpu::ComputePipeline {
    let module = gpu
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(name),
            source: wgpu::ShaderSource::Wgsl(shaders::source(name, store).into()),
        });
    let layout = gpu
        .device
        .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(name),
            bind_group_layouts: &[Some(scene), Some(own)],
            immediate_size: 0,
        });
    gpu.device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(name),
            layout: Some(&layout),
            module: &module,
            entry_point: Some("main"),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants,
                ..Default::default()
            },
            cache: None,
        })
}

/// The pipelines of a shading mode: each carries only its mode's code (`MODE` is a pipeline
/// constant), and modes without secondary rays get no spawn or gather pipeline.
fn build_kernels(
    gpu: &Gpu,
    store: Store,
    constants: &[(&'static str, f64)],
    l: &Layouts,
    mode: Mode,
) -> Kernels {
    let mut c = constants.to_vec();
    c.push(("MODE", f64::from(mode as u32)));
    let k = |name| pipeline(gpu, store, &c, name, &l.scene, l.for_kernel(name));
    let waves = mode != Mode::Cast;
    Kernels {
        raygen: k("raygen"),
        trace: k("trace"),
        args: k("args"),
        shade: k("shade"),
        probe: k("probe"),
        spawn: waves.then(|| k("spawn")),
        gather: waves.then(|| k("gather")),
    }
}

fn buffer(gpu: &Gpu, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage,
        mapped_at_creation: false,
    })
}

/// The rows of blocks a GPU holds: the resident ones it is given, then `lines` cache lines.
struct Rows<'a> {
    format: Format,
    resident: &'a [u32],
    lines: u32,
}

impl Rows<'_> {
    fn resident_rows(&self) -> u32 {
        (self.resident.len() / self.format.words() as usize) as u32
    }
    fn total(&self) -> u32 {
        self.resident_rows() + self.lines
    }
    fn bytes(&self) -> u64 {
        u64::from(self.total()) * u64::from(self.format.block_bytes)
    }
}

/// Uploads resident rows into one `Rgba32Uint` 2D array texture, one block per row, with room
/// for the cache lines after them.
fn upload_texture(gpu: &Gpu, rows: &Rows<'_>) -> Result<(wgpu::Texture, u32)> {
    let format = rows.format;
    let texels = format.texels();
    let max2d = gpu.limits.max_texture_dimension_2d;
    let count = rows.total().max(1);
    if texels > max2d {
        return Err(Error::Gpu(format!(
            "block of {} bytes needs a texture {texels} texels wide; the adapter allows {max2d}",
            format.block_bytes
        )));
    }
    let per_layer = count.min(max2d);
    let layers = count.div_ceil(per_layer);
    if layers > gpu.limits.max_texture_array_layers {
        return Err(Error::Gpu(format!(
            "{count} blocks ({} MiB: resident blocks and cache) need {layers} texture layers of \
             {per_layer} blocks; the adapter allows {} layers",
            rows.bytes() >> 20,
            gpu.limits.max_texture_array_layers
        )));
    }
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let scope_v = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("blocks"),
        size: wgpu::Extent3d {
            width: texels,
            height: per_layer,
            depth_or_array_layers: layers,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Uint,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let resident = rows.resident_rows();
    let mut first = 0;
    while first < resident {
        let n = (resident - first).min(per_layer - first % per_layer);
        write_texture_rows(
            gpu,
            &texture,
            format,
            per_layer,
            first,
            rows_of(rows, first, n),
        );
        first += n;
    }
    let fail = |e: wgpu::Error| {
        Error::Gpu(format!(
            "cannot hold {} MiB of blocks (resident and cache) in one texture: {e}",
            rows.bytes() >> 20
        ))
    };
    if let Some(e) = pollster::block_on(scope_v.pop()) {
        return Err(fail(e));
    }
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(fail(e));
    }
    Ok((texture, per_layer))
}

fn rows_of<'a>(rows: &Rows<'a>, first: u32, n: u32) -> &'a [u32] {
    let bw = rows.format.words() as usize;
    &rows.resident[first as usize * bw..(first + n) as usize * bw]
}

/// Writes `data` (whole blocks) into consecutive rows from `first`, all in one layer.
fn write_texture_rows(
    gpu: &Gpu,
    texture: &wgpu::Texture,
    format: Format,
    per_layer: u32,
    first: u32,
    data: &[u32],
) {
    let n = (data.len() / format.words() as usize) as u32;
    gpu.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: 0,
                y: first % per_layer,
                z: first / per_layer,
            },
            aspect: wgpu::TextureAspect::All,
        },
        bytemuck::cast_slice(data),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(format.block_bytes),
            rows_per_image: Some(n),
        },
        wgpu::Extent3d {
            width: format.texels(),
            height: n,
            depth_or_array_layers: 1,
        },
    );
}

/// Uploads resident rows into one storage buffer with room for the cache lines.
fn upload_buffer(gpu: &Gpu, rows: &Rows<'_>) -> Result<wgpu::Buffer> {
    let limit = gpu
        .limits
        .max_storage_buffer_binding_size
        .min(gpu.limits.max_buffer_size);
    if rows.bytes() > limit {
        return Err(Error::Gpu(format!(
            "{} MiB of blocks (resident and cache) exceed the adapter's {} MiB storage buffer \
             binding; use the texture store",
            rows.bytes() >> 20,
            limit >> 20
        )));
    }
    let buf = buffer(
        gpu,
        "blocks",
        rows.bytes(),
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    );
    gpu.queue
        .write_buffer(&buf, 0, bytemuck::cast_slice(rows.resident));
    Ok(buf)
}

/// The distributed cache of one rank: its place among the ranks, the cache, where borrowed
/// blocks come from, and the trace of the current frame.
pub struct DcSetup {
    pub ranks: Ranks,
    pub lines: u32,
    pub map: CacheMap,
    pub source: Box<dyn BlockSource>,
}

struct Dc {
    ranks: Ranks,
    lines: u32,
    map: CacheMap,
    source: Box<dyn BlockSource>,
    /// Block in each line (`NONE` when empty), as the GPU's tag table holds it.
    tags: Vec<u32>,
    /// Row of every block on this GPU (`NONE` when absent): the GPU's `block_rows`.
    block_rows: Vec<u32>,
    rows_buf: wgpu::Buffer,
    faults: wgpu::Buffer,
    requested: wgpu::Buffer,
    waiters: wgpu::Buffer,
    fault_cap: u32,
    trace: FrameTrace,
}

/// The largest number of distinct faults one round records (more fault again next round).
const FAULT_CAP: u32 = 1 << 16;

/// A model as one GPU holds it: every block (replicated), or its resident rows plus a cache.
pub struct GpuModel<'a> {
    pub format: Format,
    pub node_blocks: u32,
    pub tri_blocks: u32,
    /// Words of the resident rows: all blocks in id order when replicated; with a DC, the
    /// rank's own blocks by slot, then the root block unless the rank owns it.
    pub resident: &'a [u32],
    pub meshes: &'a Meshes,
    /// BVH depth: sizes the traversal stack.
    pub depth: u32,
}

impl<'g> Tracer<'g> {
    /// Uploads a model's blocks; `dc` is `None` for a replicated model.
    pub fn new(
        gpu: &'g Gpu,
        model: &GpuModel<'_>,
        settings: Settings,
        dc: Option<DcSetup>,
    ) -> Result<Tracer<'g>> {
        if !(1..=MAX_STEP_BUDGET).contains(&settings.step_budget) {
            return Err(Error::Invalid(format!(
                "step budget {} is out of range 1..={MAX_STEP_BUDGET}",
                settings.step_budget
            )));
        }
        let format = model.format;
        let blocks = model.node_blocks + model.tri_blocks;
        let lines = dc.as_ref().map_or(0, |d| d.lines);
        let rows = Rows {
            format,
            resident: model.resident,
            lines,
        };
        let st = settings.store;
        let l = layouts(gpu, st);
        let (store, rows_per_layer) = match st {
            Store::Texture => {
                let (texture, per_layer) = upload_texture(gpu, &rows)?;
                let view = texture.create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2Array),
                    ..Default::default()
                });
                (BlockStore::Texture(texture, view), per_layer)
            }
            Store::Buffer => (BlockStore::Buffer(upload_buffer(gpu, &rows)?), 1),
        };
        settings.shading.validate()?;
        let constants: Constants = vec![
            ("DC", if dc.is_some() { 1.0 } else { 0.0 }),
            ("NODES_PER_BLOCK", f64::from(format.nodes_per_block())),
            ("TRIS_PER_BLOCK", f64::from(format.tris_per_block())),
            ("TEXELS_PER_BLOCK", f64::from(format.texels())),
            ("ROWS_PER_LAYER", f64::from(rows_per_layer)),
        ];
        let kernels = build_kernels(gpu, st, &constants, &l, settings.shading.mode);
        let meshes: Vec<MeshInfo> = model
            .meshes
            .colors
            .iter()
            .zip(&model.meshes.first_prim)
            .map(|(c, &f)| MeshInfo {
                color: [c[0], c[1], c[2], 1.0],
                first_prim: f,
                pad: [0; 3],
            })
            .collect();
        let meshes_buf = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("meshes"),
                contents: bytemuck::cast_slice(&meshes),
                usage: wgpu::BufferUsages::STORAGE,
            });
        let stack_size = model.depth.clamp(1, MAX_STACK);
        let mut params = Params {
            step_budget: settings.step_budget,
            stack_size,
            mesh_count: meshes.len() as u32,
            node_blocks: model.node_blocks,
            dc_ranks: 1,
            ..Params::default()
        };
        use wgpu::BufferUsages as U;
        let dc = match dc {
            None => None,
            Some(d) => {
                let resident = rows.resident_rows();
                let expect = d.ranks.owned(blocks) + u32::from(!d.ranks.owns(0));
                if resident != expect {
                    return Err(Error::Invalid(format!(
                        "rank {} of {} should hold {expect} resident blocks, was given {resident}",
                        d.ranks.rank, d.ranks.n
                    )));
                }
                params.dc_ranks = d.ranks.n;
                params.dc_rank = d.ranks.rank;
                params.dc_lines = d.lines;
                params.dc_map = match d.map {
                    CacheMap::Ize => 0,
                    CacheMap::Demarle => 1,
                };
                params.dc_cache_row = resident;
                params.dc_root_row = if d.ranks.owns(0) { 0 } else { resident - 1 };
                params.dc_fault_cap = FAULT_CAP;
                let tags = vec![NONE_TAG; d.lines as usize];
                // Resident blocks at their rows, the root at its row, the rest absent.
                let mut block_rows = vec![NONE_TAG; blocks as usize];
                for (k, row) in block_rows.iter_mut().enumerate() {
                    let k = k as u32;
                    if d.ranks.owns(k) {
                        *row = d.ranks.slot(k);
                    }
                }
                block_rows[0] = params.dc_root_row;
                let rows_buf = gpu
                    .device
                    .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some("block rows"),
                        contents: bytemuck::cast_slice(&block_rows),
                        usage: U::STORAGE | U::COPY_DST,
                    });
                Some(Dc {
                    ranks: d.ranks,
                    lines: d.lines,
                    map: d.map,
                    source: d.source,
                    tags,
                    block_rows,
                    rows_buf,
                    faults: buffer(
                        gpu,
                        "faults",
                        16 + 4 * u64::from(FAULT_CAP),
                        U::STORAGE | U::COPY_SRC | U::COPY_DST,
                    ),
                    requested: buffer(
                        gpu,
                        "requested",
                        4 * u64::from(blocks.div_ceil(32)),
                        U::STORAGE | U::COPY_DST,
                    ),
                    waiters: buffer(
                        gpu,
                        "waiters",
                        4 * u64::from(d.lines),
                        U::STORAGE | U::COPY_SRC | U::COPY_DST,
                    ),
                    fault_cap: FAULT_CAP,
                    trace: FrameTrace::default(),
                })
            }
        };
        // A replicated model binds small placeholders the kernels never read.
        let placeholder = || buffer(gpu, "unused", 32, U::STORAGE);
        let (p3, p4, p5, p6);
        let dc_bufs: [&wgpu::Buffer; 4] = match &dc {
            Some(d) => [&d.rows_buf, &d.faults, &d.requested, &d.waiters],
            None => {
                p3 = placeholder();
                p4 = placeholder();
                p5 = placeholder();
                p6 = placeholder();
                [&p3, &p4, &p5, &p6]
            }
        };
        let params_buf = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        let mut entries = vec![
            wgpu::BindGroupEntry {
                binding: 0,
                resource: params_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: store.resource(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: meshes_buf.as_entire_binding(),
            },
        ];
        for (i, b) in dc_bufs.iter().enumerate() {
            entries.push(wgpu::BindGroupEntry {
                binding: 3 + i as u32,
                resource: b.as_entire_binding(),
            });
        }
        let scene_bg = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &l.scene,
            entries: &entries,
        });
        let shade_buf = buffer(gpu, "shading", SHADE_BYTES, U::STORAGE | U::COPY_DST);
        let batch = Self::make_batch(
            gpu,
            &l,
            stack_size,
            settings.max_batch_rays,
            lines,
            &shade_buf,
        )?;
        Ok(Tracer {
            gpu,
            kernels,
            params,
            params_buf,
            scene_bg,
            batch,
            settings,
            layouts: l,
            blocks_store: store,
            rows_per_layer,
            format,
            dc,
            frame_start: Instant::now(),
            depth: model.depth,
            constants,
            shade_buf,
        })
    }

    /// Changes the shading settings; the pipelines are rebuilt when the mode changes.
    pub fn set_shading(&mut self, shading: Shading) -> Result<()> {
        shading.validate()?;
        if shading.mode != self.settings.shading.mode {
            let st = self.settings.store;
            self.kernels =
                build_kernels(self.gpu, st, &self.constants, &self.layouts, shading.mode);
        }
        self.settings.shading = shading;
        Ok(())
    }

    /// Allocates per-batch buffers as large as the settings and the adapter's limits allow.
    fn make_batch(
        gpu: &Gpu,
        l: &Layouts,
        stack_size: u32,
        max_rays: u32,
        lines: u32,
        shade_buf: &wgpu::Buffer,
    ) -> Result<Batch> {
        let limit = gpu
            .limits
            .max_storage_buffer_binding_size
            .min(gpu.limits.max_buffer_size);
        let per_ray_max = (u64::from(stack_size) * 8).max(RAY_BYTES).max(PATH_BYTES);
        let by_memory = limit / per_ray_max;
        let by_dispatch = u64::from(gpu.limits.max_compute_workgroups_per_dimension) * 64;
        let rays = u64::from(max_rays).min(by_memory).min(by_dispatch);
        let rays_cap = (rays / u64::from(TILE_RAYS) * u64::from(TILE_RAYS)) as u32;
        if rays_cap == 0 {
            return Err(Error::Gpu(format!(
                "a traversal stack of {stack_size} entries per ray leaves no room for a tile of \
                 rays in a {limit}-byte storage buffer"
            )));
        }
        let n = u64::from(rays_cap);
        use wgpu::BufferUsages as U;
        // COPY_DST: `trace_rays` uploads its rays and live list directly.
        let rays_buf = buffer(
            gpu,
            "rays",
            n * RAY_BYTES,
            U::STORAGE | U::COPY_SRC | U::COPY_DST,
        );
        let stacks = buffer(gpu, "stacks", n * u64::from(stack_size) * 8, U::STORAGE);
        let live = [
            buffer(gpu, "live0", n * 4, U::STORAGE | U::COPY_DST),
            buffer(gpu, "live1", n * 4, U::STORAGE),
        ];
        let counter_usage = U::STORAGE | U::INDIRECT | U::COPY_SRC | U::COPY_DST;
        let counters = [
            buffer(gpu, "counter0", 16, counter_usage),
            buffer(gpu, "counter1", 16, counter_usage),
        ];
        let stats = buffer(gpu, "stats", 48, U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let pixels = buffer(gpu, "pixels", n * 32, U::STORAGE | U::COPY_SRC);
        // Counter, stats, GPU timestamps, and the live count a batch's rounds started with.
        let readback = buffer(gpu, "readback", 96, U::MAP_READ | U::COPY_DST);
        let paths = buffer(gpu, "paths", n * PATH_BYTES, U::STORAGE);
        let fault_readback = buffer(
            gpu,
            "fault readback",
            16 + 4 * u64::from(FAULT_CAP),
            U::MAP_READ | U::COPY_DST,
        );
        let waiter_readback = buffer(
            gpu,
            "waiter readback",
            4 * u64::from(lines),
            U::MAP_READ | U::COPY_DST,
        );
        let pixel_readback = buffer(gpu, "pixel readback", n * 32, U::MAP_READ | U::COPY_DST);
        let raygen_bg = bind(gpu, &l.raygen, &[&rays_buf, &live[0], &counters[0]]);
        let trace_bg = [0, 1].map(|i| {
            let o = 1 - i;
            bind(
                gpu,
                &l.trace,
                &[
                    &rays_buf,
                    &stacks,
                    &live[i],
                    &counters[i],
                    &live[o],
                    &counters[o],
                    &stats,
                ],
            )
        });
        // args_bg[i]: counter i was just produced, the other is cleared for the next round.
        let args_bg = [0, 1].map(|i| bind(gpu, &l.args, &[&counters[i], &counters[1 - i]]));
        let shade_bg = bind(
            gpu,
            &l.shade,
            &[
                &rays_buf,
                &pixels,
                &paths,
                shade_buf,
                &live[0],
                &counters[0],
            ],
        );
        let timestamps = gpu
            .features
            .contains(wgpu::Features::TIMESTAMP_QUERY)
            .then(|| {
                let q = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("round timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                });
                let resolve = buffer(gpu, "timestamps", 16, U::QUERY_RESOLVE | U::COPY_SRC);
                (q, resolve)
            });
        Ok(Batch {
            timestamps,
            rays_cap,
            pixels,
            counters,
            stats,
            readback,
            fault_readback,
            waiter_readback,
            pixel_readback,
            raygen_bg,
            trace_bg,
            args_bg,
            shade_bg,
            rays: rays_buf,
            live0: live[0].clone(),
        })
    }

    pub fn stack_size(&self) -> u32 {
        self.params.stack_size
    }

    pub fn batch_rays(&self) -> u32 {
        self.batch.rays_cap
    }

    fn dispatch(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        bg: &wgpu::BindGroup,
        groups: Dispatch<'_>,
    ) {
        self.dispatch_timed(enc, pipeline, bg, groups, (false, false));
    }

    /// `stamp`: write the GPU timestamp at the pass's (beginning, end), when the adapter has
    /// timestamps: the rounds' GPU time is measured from the first trace pass to the last.
    fn dispatch_timed(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        bg: &wgpu::BindGroup,
        groups: Dispatch<'_>,
        stamp: (bool, bool),
    ) {
        let timestamp_writes = self
            .batch
            .timestamps
            .as_ref()
            .filter(|_| stamp.0 || stamp.1)
            .map(|(q, _)| wgpu::ComputePassTimestampWrites {
                query_set: q,
                beginning_of_pass_write_index: stamp.0.then_some(0),
                end_of_pass_write_index: stamp.1.then_some(1),
            });
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: None,
            timestamp_writes,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &self.scene_bg, &[]);
        pass.set_bind_group(1, bg, &[]);
        match groups {
            Dispatch::Direct(n) => pass.dispatch_workgroups(n, 1, 1),
            Dispatch::Indirect(buf) => pass.dispatch_workgroups_indirect(buf, 4),
        }
    }

    /// Traces and shades one whole frame.
    pub fn render(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
    ) -> Result<(Frame, FrameStats)> {
        let (width, height) = (basis.width, basis.height);
        let mut stats = self.begin_frame();
        let rect = Rect::whole(width, height);
        let pixels = self.render_rect(basis, background, rect, &mut stats)?;
        self.end_frame(&mut stats);
        let frame = Frame {
            width,
            height,
            pixels,
        };
        Ok((frame, stats))
    }

    /// Starts a frame made of `render_rect` calls: clears the cache trace; the stats returned
    /// start the frame's clock.
    pub fn begin_frame(&mut self) -> FrameStats {
        if let Some(dc) = self.dc.as_mut() {
            let frame = dc.trace.summary.frame;
            dc.trace = FrameTrace::default();
            dc.trace.summary.frame = frame;
        }
        self.frame_start = Instant::now();
        FrameStats::default()
    }

    /// Traces and shades the pixels of `rect` (row-major within it), adding to `stats`.
    pub fn render_rect(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
        rect: Rect,
        stats: &mut FrameStats,
    ) -> Result<Vec<Pixel>> {
        let (w, h) = (basis.width, basis.height);
        if rect.w == 0 || rect.h == 0 || rect.x + rect.w > w || rect.y + rect.h > h {
            return Err(Error::Invalid(format!(
                "tile {rect:?} is empty or outside the {w}x{h} image"
            )));
        }
        let tiles_x = rect.w.div_ceil(TILE);
        let tiles = tiles_x * rect.h.div_ceil(TILE);
        let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
        self.params.origin = v4(basis.origin, 1.0);
        self.params.forward = v4(basis.forward, 0.0);
        self.params.right = v4(basis.right, 0.0);
        self.params.up = v4(basis.up, 0.0);
        self.params.background = v4(background, 1.0);
        self.params.width = w;
        self.params.height = h;
        self.params.tiles_x = tiles_x;
        (self.params.rect_x, self.params.rect_y) = (rect.x, rect.y);
        (self.params.rect_w, self.params.rect_h) = (rect.w, rect.h);
        let sh = self.settings.shading;
        let fan = sh.fan(basis);
        let waves = sh.waves(basis);
        gpu_write(self.gpu, &self.shade_buf, &sh.gpu_params(basis));
        self.params.seed = sh.seed;
        self.params.spp = sh.spp;
        let mut pixels = vec![Pixel::default(); rect.pixels()];
        // A wave puts `fan` secondary rays per pixel in the ray buffer: fewer pixels per batch.
        let tiles_per_batch = self.batch.rays_cap / fan.max(1) / TILE_RAYS;
        if tiles_per_batch == 0 {
            return Err(Error::Gpu(format!(
                "{fan} secondary rays per pixel do not fit a batch of {} rays",
                self.batch.rays_cap
            )));
        }
        let mut first = 0;
        while first < tiles {
            let n_tiles = tiles_per_batch.min(tiles - first);
            self.params.first_tile = first;
            self.params.batch_rays = n_tiles * TILE_RAYS;
            for s in 0..sh.spp {
                self.params.sample = sh.first_sample + s;
                self.params.flags = if sh.spp > 1 { flags::JITTER } else { 0 }
                    | if sh.cull { flags::CULL } else { 0 }
                    | if s == 0 { flags::FIRST_SAMPLE } else { 0 };
                let t = Instant::now();
                stats.traced_rays += u64::from(self.trace_batch(stats, Gen::Primary)?);
                let t2 = Instant::now();
                stats.trace_seconds += (t2 - t).as_secs_f64();
                self.run(&self.kernels.shade, self.params.batch_rays);
                for _ in 0..waves {
                    let t = Instant::now();
                    let live = self.trace_batch(stats, Gen::Secondary { fan })?;
                    stats.trace_seconds += t.elapsed().as_secs_f64();
                    stats.secondary_rays += u64::from(live);
                    stats.traced_rays += u64::from(live);
                    if let Some(g) = &self.kernels.gather {
                        self.run(g, self.params.batch_rays);
                    }
                    if live == 0 {
                        break;
                    }
                }
                stats.shade_seconds += t2.elapsed().as_secs_f64();
            }
            let t = Instant::now();
            self.read_pixels(first, n_tiles, rect, sh.spp, &mut pixels)?;
            stats.shade_seconds += t.elapsed().as_secs_f64();
            stats.batches += 1;
            first += n_tiles;
        }
        stats.samples = sh.spp;
        stats.rays += rect.pixels() as u64;
        Ok(pixels)
    }

    /// Ends a frame begun with `begin_frame`: its wall time and the cache trace's summary.
    pub fn end_frame(&mut self, stats: &mut FrameStats) {
        stats.seconds = self.frame_start.elapsed().as_secs_f64();
        if let Some(dc) = self.dc.as_mut() {
            let s = &mut dc.trace.summary;
            s.rank = dc.ranks.rank;
            s.role = "render".into();
            s.ranks = dc.ranks.n;
            s.cache_lines = dc.lines;
            s.cache_map = format!("{:?}", dc.map).to_lowercase();
            s.rounds = stats.rounds;
            s.fault_rounds = stats.fault_rounds;
            s.lookups = stats.lookups;
            s.hits = stats.hits;
            s.misses = stats.misses;
            s.hit_rate = if stats.lookups > 0 {
                stats.hits as f64 / stats.lookups as f64
            } else {
                1.0
            };
            s.fetched_blocks = stats.fetched_blocks;
            s.fetched_bytes = stats.fetched_bytes;
            s.frame_ms = stats.seconds * 1e3;
            s.trace_ms = stats.trace_seconds * 1e3;
            s.fetch_ms = stats.fetch_seconds * 1e3;
            s.upload_ms = stats.upload_seconds * 1e3;
            s.shade_ms = stats.shade_seconds * 1e3;
        }
    }

    /// Submits one direct dispatch of `kernel` over `n` invocations (no wait).
    fn run(&self, kernel: &wgpu::ComputePipeline, n: u32) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let groups = Dispatch::Direct(n.div_ceil(WORKGROUP));
        self.dispatch(&mut enc, kernel, &self.batch.shade_bg, groups);
        self.gpu.queue.submit([enc.finish()]);
    }

    /// Generates the batch's rays (primary, or a wave of secondary rays) and runs trace rounds
    /// until none is live: secondary rays fault, suspend and resume exactly as primary rays do.
    /// Returns how many rays entered traversal.
    fn trace_batch(&mut self, stats: &mut FrameStats, gen_: Gen) -> Result<u32> {
        let gpu = self.gpu;
        gpu.queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let b = &self.batch;
            for c in &b.counters {
                enc.clear_buffer(c, 0, None);
            }
            enc.clear_buffer(&b.stats, 0, None);
            self.clear_faults(&mut enc);
            match (gen_, &self.kernels.spawn) {
                (Gen::Secondary { fan }, Some(spawn)) => {
                    let groups =
                        Dispatch::Direct((self.params.batch_rays * fan).div_ceil(WORKGROUP));
                    self.dispatch(&mut enc, spawn, &b.shade_bg, groups);
                }
                _ => {
                    let groups = Dispatch::Direct(self.params.batch_rays.div_ceil(WORKGROUP));
                    self.dispatch(&mut enc, &self.kernels.raygen, &b.raygen_bg, groups);
                }
            }
            let one = Dispatch::Direct(1);
            self.dispatch(&mut enc, &self.kernels.args, &b.args_bg[0], one);
            enc.copy_buffer_to_buffer(&b.counters[0], 0, &b.readback, 80, 4);
        }
        self.run_rounds(enc, stats)
    }

    /// Trace rounds until no ray is live, starting from the live list and counter 0 that `enc`
    /// has already prepared (with the first `args` dispatch recorded). Returns the live count
    /// the first round started with (read from the readback at byte 80, where ray generation
    /// copies it).
    fn run_rounds(&mut self, mut enc: wgpu::CommandEncoder, stats: &mut FrameStats) -> Result<u32> {
        let gpu = self.gpu;
        let mut started = None;
        // `cur` is the counter holding the live rays of the next round. With a cache, faults are
        // served after every round; without, several rounds go in one submission.
        let mut cur = 0usize;
        let mut per_check = if self.dc.is_some() { 1 } else { 2u32 };
        let mut live_rounds = 0u32;
        loop {
            let b = &self.batch;
            for i in 0..per_check {
                let o = 1 - cur;
                let ind = Dispatch::Indirect(&b.counters[cur]);
                let (first, last) = (i == 0, i + 1 == per_check);
                let k = &self.kernels;
                self.dispatch_timed(&mut enc, &k.trace, &b.trace_bg[cur], ind, (first, false));
                let one = Dispatch::Direct(1);
                self.dispatch_timed(&mut enc, &k.args, &b.args_bg[o], one, (false, last));
                cur = o;
            }
            if let Some((q, resolve)) = &b.timestamps {
                enc.resolve_query_set(q, 0..2, resolve, 0);
                enc.copy_buffer_to_buffer(resolve, 0, &b.readback, 64, 16);
            }
            stats.rounds += per_check;
            live_rounds += per_check;
            enc.copy_buffer_to_buffer(&b.counters[cur], 0, &b.readback, 0, 16);
            enc.copy_buffer_to_buffer(&b.stats, 0, &b.readback, 16, 48);
            if let Some(dc) = &self.dc {
                let fault_bytes = 16 + 4 * u64::from(dc.fault_cap);
                enc.copy_buffer_to_buffer(&dc.faults, 0, &b.fault_readback, 0, fault_bytes);
                let wait_bytes = 4 * u64::from(dc.lines);
                enc.copy_buffer_to_buffer(&dc.waiters, 0, &b.waiter_readback, 0, wait_bytes);
            }
            gpu.queue.submit([enc.finish()]);
            let data = gpu.map_read(&b.readback)?;
            // Mapped bytes carry no alignment promise: read them unaligned.
            let counter: Counter = bytemuck::pod_read_unaligned(&data[..16]);
            let s: Stats = bytemuck::pod_read_unaligned(&data[16..64]);
            if started.is_none() {
                started = Some(bytemuck::pod_read_unaligned::<u32>(&data[80..84]));
            }
            if b.timestamps.is_some() {
                let t: [u64; 2] = bytemuck::pod_read_unaligned(&data[64..80]);
                let period = f64::from(gpu.queue.get_timestamp_period());
                stats.gpu_seconds += t[1].saturating_sub(t[0]) as f64 * period * 1e-9;
            }
            if s.overflows > 0 {
                return Err(Error::Gpu(format!(
                    "traversal stack overflow in {} rays: the BVH is deeper than the {}-entry \
                     stack (the model declares depth {}, the stack holds at most {MAX_STACK})",
                    s.overflows, self.params.stack_size, self.depth
                )));
            }
            enc = gpu.device.create_command_encoder(&Default::default());
            if self.dc.is_some() {
                let faults = gpu.map_read(&self.batch.fault_readback)?;
                let waiters = gpu.map_read(&self.batch.waiter_readback)?;
                self.serve_faults(&faults, &waiters, counter.count, live_rounds, stats)?;
                self.clear_faults(&mut enc);
            }
            if counter.count == 0 {
                stats.steps += u64::from(s.steps);
                stats.tri_tests += u64::from(s.tri_tests);
                stats.lookups += u64::from(s.lookups);
                stats.hits += u64::from(s.hits);
                stats.misses += u64::from(s.misses);
                stats.node_visits += u64::from(s.node_visits);
                stats.block_entries += u64::from(s.block_entries);
                stats.max_live_rounds = stats.max_live_rounds.max(live_rounds);
                return Ok(started.unwrap_or(0));
            }
            if self.dc.is_none() {
                per_check = (per_check * 2).min(16);
            }
        }
    }

    fn clear_faults(&self, enc: &mut wgpu::CommandEncoder) {
        if let Some(dc) = &self.dc {
            enc.clear_buffer(&dc.faults, 0, Some(16));
            enc.clear_buffer(&dc.requested, 0, None);
            enc.clear_buffer(&dc.waiters, 0, None);
        }
    }

    /// Fetches the blocks a round faulted on and places them in their cache lines. The first
    /// fault for a line wins it; the others fault again next round, so every round with faults
    /// loads at least one block and even a single-line cache finishes.
    fn serve_faults(
        &mut self,
        faults: &[u8],
        waiters: &[u8],
        live: u32,
        round: u32,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let Some(dc) = self.dc.as_mut() else {
            return Ok(());
        };
        let header: FaultHeader = bytemuck::pod_read_unaligned(&faults[..16]);
        let n = header.count.min(dc.fault_cap) as usize;
        if n == 0 {
            return Ok(());
        }
        let list: Vec<u32> = bytemuck::pod_collect_to_vec(&faults[16..16 + 4 * n]);
        let waiting: Vec<u32> = bytemuck::pod_collect_to_vec(&waiters[..4 * dc.lines as usize]);
        let mut claimed = vec![false; 0];
        claimed.resize(dc.lines.min(1 << 24) as usize, false);
        let mut rec = Round {
            batch: stats.batches,
            round,
            live,
            dropped: header.dropped,
            source: dc.source.name(),
            ..Round::default()
        };
        let mut serve = Vec::new();
        for &k in &list {
            let line = cache_line(dc.map, dc.ranks, dc.lines, k);
            let first = !std::mem::replace(&mut claimed[line as usize], true);
            let old = dc.tags[line as usize];
            rec.faults.push(Fault {
                block: k,
                owner: dc.ranks.owner(k),
                line,
                evicted: (first && old != NONE_TAG).then_some(old),
                waiting: waiting[line as usize],
                served: first,
            });
            if first {
                serve.push((k, line));
            }
        }
        let bw = self.format.words() as usize;
        let blocks: Vec<u32> = serve.iter().map(|&(k, _)| k).collect();
        let mut data = vec![0u32; blocks.len() * bw];
        let t = Instant::now();
        dc.source.fetch(&blocks, &mut data)?;
        let fetch = t.elapsed().as_secs_f64();
        let t = Instant::now();
        for (&(k, line), words) in serve.iter().zip(data.chunks(bw)) {
            let row = self.params.dc_cache_row + line;
            self.blocks_store
                .write_row(self.gpu, self.format, self.rows_per_layer, row, words);
            let old = std::mem::replace(&mut dc.tags[line as usize], k);
            for (b, r) in [(old, NONE_TAG), (k, row)] {
                if b != NONE_TAG {
                    dc.block_rows[b as usize] = r;
                    self.gpu.queue.write_buffer(
                        &dc.rows_buf,
                        u64::from(b) * 4,
                        bytemuck::bytes_of(&r),
                    );
                }
            }
        }
        let upload = t.elapsed().as_secs_f64();
        rec.fetched_blocks = serve.len() as u32;
        rec.fetched_bytes = (serve.len() * bw * 4) as u64;
        rec.fetch_us = fetch * 1e6;
        rec.upload_us = upload * 1e6;
        stats.fetched_blocks += u64::from(rec.fetched_blocks);
        stats.fetched_bytes += rec.fetched_bytes;
        stats.fetch_seconds += fetch;
        stats.upload_seconds += upload;
        stats.fault_rounds += 1;
        dc.trace.rounds.push(rec);
        Ok(())
    }

    /// The trace of the last frame (rounds with faults, and its summary); empty without a cache.
    pub fn take_trace(&mut self) -> FrameTrace {
        self.dc
            .as_mut()
            .map(|d| std::mem::take(&mut d.trace))
            .unwrap_or_default()
    }

    /// Ranks and cache lines, when this tracer has a cache.
    pub fn cache(&self) -> Option<(Ranks, u32, CacheMap)> {
        self.dc.as_ref().map(|d| (d.ranks, d.lines, d.map))
    }

    /// Reads the batch's pixels back; colours are sums over `spp` samples, divided here.
    fn read_pixels(
        &self,
        first_tile: u32,
        n_tiles: u32,
        rect: Rect,
        spp: u32,
        out: &mut [Pixel],
    ) -> Result<()> {
        let gpu = self.gpu;
        let b = &self.batch;
        let n = n_tiles * TILE_RAYS;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        // A multiply by 1/spp: exactly the sum when spp is 1.
        let scale = 1.0 / spp as f32;
        let bytes = u64::from(n) * 32;
        enc.copy_buffer_to_buffer(&b.pixels, 0, &b.pixel_readback, 0, bytes);
        gpu.queue.submit([enc.finish()]);
        let data = gpu.map_read_prefix(&b.pixel_readback, bytes)?;
        {
            let px: Vec<Pixel> = bytemuck::pod_collect_to_vec(&data);
            let tiles_x = self.params.tiles_x;
            for (i, p) in px.iter().enumerate() {
                let i = i as u32;
                let tile = first_tile + i / TILE_RAYS;
                let local = i % TILE_RAYS;
                let x = (tile % tiles_x) * TILE + local % TILE;
                let y = (tile / tiles_x) * TILE + local / TILE;
                if x < rect.w && y < rect.h {
                    let mut p = *p;
                    p.rgb = p.rgb.map(|c| c * scale);
                    out[(y * rect.w + x) as usize] = p;
                }
            }
        }
        Ok(())
    }

    /// Runs the layout probe (tests): `rays` must hold two states; returns the words the probe
    /// wrote. `params` replaces the tracer's own, so the caller controls every member.
    pub fn probe(
        &mut self,
        params: Params,
        rays: &[RayState; 2],
        shading: &ShadeParams,
    ) -> Result<Vec<u32>> {
        let gpu = self.gpu;
        gpu.queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&params));
        let input = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("probe rays"),
                contents: bytemuck::cast_slice(rays),
                usage: wgpu::BufferUsages::STORAGE,
            });
        let shade = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("probe shading"),
                contents: bytemuck::bytes_of(shading),
                usage: wgpu::BufferUsages::STORAGE,
            });
        let words = 48 + 8 * params.pad0 + 10 * params.pad1 + 40 + 8 * params.mesh_count + 56;
        let out = buffer(
            gpu,
            "probe out",
            u64::from(words) * 4,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let bg = bind(gpu, &self.layouts.probe, &[&input, &out, &shade]);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut enc, &self.kernels.probe, &bg, Dispatch::Direct(1));
        gpu.queue.submit([enc.finish()]);
        let data = gpu.read_buffer(&out, 0, u64::from(words) * 4)?;
        gpu.queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        Ok(bytemuck::pod_collect_to_vec(&data))
    }

    pub fn params(&self) -> Params {
        self.params
    }

    pub fn settings(&self) -> Settings {
        self.settings
    }

    /// The per-batch ray states after the last batch (tests inspect them).
    pub fn read_rays(&self, n: u32) -> Result<Vec<RayState>> {
        let data = self
            .gpu
            .read_buffer(&self.batch.rays, 0, u64::from(n) * RAY_BYTES)?;
        Ok(bytemuck::pod_collect_to_vec(&data))
    }

    /// Traces arbitrary rays (tests, tools, secondary rays from the host) through the same trace
    /// kernel and round loop as rendering, in batches of at most `batch_rays()` rays; returns
    /// each ray's closest hit with `t` in `(0, tmax)`, in units of the direction's length.
    ///
    /// A ray with a NaN or infinite origin or direction component, a zero direction, or a `tmax`
    /// that is NaN or not positive is a miss (the trace kernel checks, so rays made on the GPU
    /// get the same treatment). `tmax = +inf` means no limit (the kernel's `FAR`, 3e38).
    pub fn trace_rays(&mut self, rays: &[Ray]) -> Result<Vec<Option<RayHit>>> {
        let mut out = Vec::with_capacity(rays.len());
        let mut stats = FrameStats::default();
        for chunk in rays.chunks(self.batch.rays_cap as usize) {
            let n = chunk.len() as u32;
            let states: Vec<RayState> = chunk
                .iter()
                .map(|r| RayState {
                    origin: r.origin,
                    t: if r.tmax == f32::INFINITY { FAR } else { r.tmax },
                    dir: r.dir,
                    hit: NONE,
                    cur_index: NONE,
                    cur_count: NONE,
                    prim: NONE,
                    wait_block: NONE,
                    ..RayState::default()
                })
                .collect();
            let live: Vec<u32> = (0..n).collect();
            let gpu = self.gpu;
            self.params.batch_rays = n;
            gpu.queue
                .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
            gpu.queue
                .write_buffer(&self.batch.rays, 0, bytemuck::cast_slice(&states));
            gpu.queue
                .write_buffer(&self.batch.live0, 0, bytemuck::cast_slice(&live));
            let counter = Counter {
                count: n,
                dispatch: [0; 3],
            };
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            enc.clear_buffer(&self.batch.counters[1], 0, None);
            enc.clear_buffer(&self.batch.stats, 0, None);
            self.clear_faults(&mut enc);
            gpu.queue
                .write_buffer(&self.batch.counters[0], 0, bytemuck::bytes_of(&counter));
            let b = &self.batch;
            self.dispatch(
                &mut enc,
                &self.kernels.args,
                &b.args_bg[0],
                Dispatch::Direct(1),
            );
            self.run_rounds(enc, &mut stats)?;
            stats.batches += 1;
            out.extend(self.read_rays(n)?.into_iter().map(|r| {
                (r.status == status::DONE && r.hit != NONE).then_some(RayHit {
                    t: r.t,
                    prim: r.prim,
                    normal: r.normal,
                })
            }));
        }
        Ok(out)
    }
}

/// The closest hit of a ray traced by [`Tracer::trace_rays`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    /// Ray parameter of the hit, in units of the direction's length.
    pub t: f32,
    /// Primitive id (input order).
    pub prim: u32,
    /// Unit geometric normal `normalize((v1 - v0) x (v2 - v0))`.
    pub normal: [f32; 3],
}

/// The trace kernel's initial `tmax` (`FAR` in `shaders/common.wgsl`): finite, because WGSL
/// promises nothing for infinities.
pub const FAR: f32 = 3.0e38;

enum Dispatch<'a> {
    Direct(u32),
    Indirect(&'a wgpu::Buffer),
}

/// Rounds a duration to milliseconds for reports.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn gpu_write<T: bytemuck::Pod>(gpu: &Gpu, buf: &wgpu::Buffer, v: &T) {
    gpu.queue.write_buffer(buf, 0, bytemuck::bytes_of(v));
}
