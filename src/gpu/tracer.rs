//! The GPU trace loop (DESIGN.md section 3) for a model whose blocks are all resident.
//!
//! A frame is traced in batches of 8x8 tiles. Per batch: `raygen` writes a state record per ray
//! and the live list; then rounds of `trace` (each live ray runs at most `step_budget` loop
//! iterations, then saves its state) and `args` (turns the count of rays still live into the
//! next round's indirect dispatch), with the live count read back every few rounds; when no ray
//! is live, `shade` writes the pixels.

use super::Gpu;
use super::layout::{Counter, MeshInfo, Params, Pixel, RayState, Stats};
use super::shaders::{self, Store};
use crate::blocks::Blocks;
use crate::error::{Error, Result};
use crate::scene::CameraBasis;
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
/// as an error rather than traced wrongly.
pub const MAX_STACK: u32 = 256;
const DEFAULT_MAX_BATCH_RAYS: u32 = 1 << 20;
const RAY_BYTES: u64 = std::mem::size_of::<RayState>() as u64;

#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Loop iterations a ray may run per trace dispatch.
    pub step_budget: u32,
    /// Upper bound on rays per batch (rounded down to whole tiles); memory limits may lower it.
    pub max_batch_rays: u32,
    /// Where the GPU keeps the blocks.
    pub store: Store,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            step_budget: DEFAULT_STEP_BUDGET,
            max_batch_rays: DEFAULT_MAX_BATCH_RAYS,
            store: Store::Texture,
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
}

/// Buffers sized for one batch, with the bind groups over them.
struct Batch {
    rays_cap: u32,
    pixels: wgpu::Buffer,
    counters: [wgpu::Buffer; 2],
    stats: wgpu::Buffer,
    readback: wgpu::Buffer,
    pixel_readback: wgpu::Buffer,
    raygen_bg: wgpu::BindGroup,
    trace_bg: [wgpu::BindGroup; 2],
    args_bg: [wgpu::BindGroup; 2],
    shade_bg: wgpu::BindGroup,
    rays: wgpu::Buffer,
}

pub struct Tracer<'g> {
    gpu: &'g Gpu,
    kernels: Kernels,
    params: Params,
    params_buf: wgpu::Buffer,
    scene_bg: wgpu::BindGroup,
    batch: Batch,
    settings: Settings,
    layouts: Layouts,
    _blocks: BlockStore,
}

/// The GPU copy of the blocks, kept alive while the tracer's bind group uses it.
enum BlockStore {
    Texture(wgpu::TextureView),
    Buffer(wgpu::Buffer),
}

impl BlockStore {
    fn resource(&self) -> wgpu::BindingResource<'_> {
        match self {
            BlockStore::Texture(view) => wgpu::BindingResource::TextureView(view),
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
        shade: bgl(gpu, "shade", &[storage(0, true), storage(1, false)]),
        probe: bgl(gpu, "probe", &[storage(0, true), storage(1, false)]),
        scene,
    }
}

fn pipeline(
    gpu: &Gpu,
    store: Store,
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
            compilation_options: Default::default(),
            cache: None,
        })
}

fn buffer(gpu: &Gpu, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage,
        mapped_at_creation: false,
    })
}

/// Uploads all blocks into one `Rgba32Uint` 2D array texture, one block per row.
fn upload_blocks(gpu: &Gpu, blocks: &Blocks) -> Result<(wgpu::Texture, u32)> {
    let texels = blocks.format.texels();
    let max2d = gpu.limits.max_texture_dimension_2d;
    let count = blocks.count().max(1);
    if texels > max2d {
        return Err(Error::Gpu(format!(
            "block of {} bytes needs a texture {texels} texels wide; the adapter allows {max2d}",
            blocks.format.block_bytes
        )));
    }
    let rows = count.min(max2d);
    let layers = count.div_ceil(rows);
    if layers > gpu.limits.max_texture_array_layers {
        return Err(Error::Gpu(format!(
            "the model's {count} blocks ({} MiB) need {layers} texture layers of {rows} blocks; \
             the adapter allows {} layers",
            blocks.bytes() >> 20,
            gpu.limits.max_texture_array_layers
        )));
    }
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let scope_v = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("blocks"),
        size: wgpu::Extent3d {
            width: texels,
            height: rows,
            depth_or_array_layers: layers,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Uint,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let bytes: &[u8] = bytemuck::cast_slice(&blocks.words);
    let per_block = blocks.format.block_bytes as usize;
    for layer in 0..layers {
        let first = (layer * rows) as usize;
        let n = (blocks.count() as usize)
            .saturating_sub(first)
            .min(rows as usize);
        if n == 0 {
            continue;
        }
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d {
                    x: 0,
                    y: 0,
                    z: layer,
                },
                aspect: wgpu::TextureAspect::All,
            },
            &bytes[first * per_block..(first + n) * per_block],
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(blocks.format.block_bytes),
                rows_per_image: Some(n as u32),
            },
            wgpu::Extent3d {
                width: texels,
                height: n as u32,
                depth_or_array_layers: 1,
            },
        );
    }
    let fail = |e: wgpu::Error| {
        Error::Gpu(format!(
            "cannot hold the model's {} MiB of blocks in one texture: {e}",
            blocks.bytes() >> 20
        ))
    };
    if let Some(e) = pollster::block_on(scope_v.pop()) {
        return Err(fail(e));
    }
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(fail(e));
    }
    Ok((texture, rows))
}

/// Uploads all blocks into one storage buffer.
fn upload_buffer(gpu: &Gpu, blocks: &Blocks) -> Result<wgpu::Buffer> {
    let limit = gpu
        .limits
        .max_storage_buffer_binding_size
        .min(gpu.limits.max_buffer_size);
    if blocks.bytes() > limit {
        return Err(Error::Gpu(format!(
            "the model's {} MiB of blocks exceed the adapter's {} MiB storage buffer binding; \
             use the texture store",
            blocks.bytes() >> 20,
            limit >> 20
        )));
    }
    Ok(gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("blocks"),
            contents: bytemuck::cast_slice(&blocks.words),
            usage: wgpu::BufferUsages::STORAGE,
        }))
}

impl<'g> Tracer<'g> {
    /// Uploads a model's blocks. `depth` is the BVH depth (it sizes the traversal stack).
    pub fn new(
        gpu: &'g Gpu,
        blocks: &Blocks,
        meshes: &Meshes,
        depth: u32,
        settings: Settings,
    ) -> Result<Tracer<'g>> {
        if !(1..=MAX_STEP_BUDGET).contains(&settings.step_budget) {
            return Err(Error::Invalid(format!(
                "step budget {} is out of range 1..={MAX_STEP_BUDGET}",
                settings.step_budget
            )));
        }
        let st = settings.store;
        let l = layouts(gpu, st);
        let kernels = Kernels {
            raygen: pipeline(gpu, st, "raygen", &l.scene, &l.raygen),
            trace: pipeline(gpu, st, "trace", &l.scene, &l.trace),
            args: pipeline(gpu, st, "args", &l.scene, &l.args),
            shade: pipeline(gpu, st, "shade", &l.scene, &l.shade),
            probe: pipeline(gpu, st, "probe", &l.scene, &l.probe),
        };
        let (store, rows_per_layer) = match st {
            Store::Texture => {
                let (texture, rows) = upload_blocks(gpu, blocks)?;
                let view = texture.create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2Array),
                    ..Default::default()
                });
                (BlockStore::Texture(view), rows)
            }
            Store::Buffer => (BlockStore::Buffer(upload_buffer(gpu, blocks)?), 0),
        };
        let meshes: Vec<MeshInfo> = meshes
            .colors
            .iter()
            .zip(&meshes.first_prim)
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
        let stack_size = depth.clamp(1, MAX_STACK);
        let params = Params {
            step_budget: settings.step_budget,
            stack_size,
            mesh_count: meshes.len() as u32,
            node_blocks: blocks.node_blocks,
            rows_per_layer,
            nodes_per_block: blocks.format.nodes_per_block(),
            tris_per_block: blocks.format.tris_per_block(),
            id_word: blocks.format.id_word(),
            texels_per_block: blocks.format.texels(),
            ..Params::default()
        };
        let params_buf = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        let scene_bg = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &l.scene,
            entries: &[
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
            ],
        });
        let batch = Self::make_batch(gpu, &l, stack_size, settings.max_batch_rays)?;
        Ok(Tracer {
            gpu,
            kernels,
            params,
            params_buf,
            scene_bg,
            batch,
            settings,
            layouts: l,
            _blocks: store,
        })
    }

    /// Allocates per-batch buffers as large as the settings and the adapter's limits allow.
    fn make_batch(gpu: &Gpu, l: &Layouts, stack_size: u32, max_rays: u32) -> Result<Batch> {
        let limit = gpu
            .limits
            .max_storage_buffer_binding_size
            .min(gpu.limits.max_buffer_size);
        let per_ray_max = (u64::from(stack_size) * 8).max(RAY_BYTES);
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
        let rays_buf = buffer(gpu, "rays", n * RAY_BYTES, U::STORAGE | U::COPY_SRC);
        let stacks = buffer(gpu, "stacks", n * u64::from(stack_size) * 8, U::STORAGE);
        let live = [
            buffer(gpu, "live0", n * 4, U::STORAGE),
            buffer(gpu, "live1", n * 4, U::STORAGE),
        ];
        let counter_usage = U::STORAGE | U::INDIRECT | U::COPY_SRC | U::COPY_DST;
        let counters = [
            buffer(gpu, "counter0", 16, counter_usage),
            buffer(gpu, "counter1", 16, counter_usage),
        ];
        let stats = buffer(gpu, "stats", 16, U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let pixels = buffer(gpu, "pixels", n * 32, U::STORAGE | U::COPY_SRC);
        let readback = buffer(gpu, "readback", 32, U::MAP_READ | U::COPY_DST);
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
        let shade_bg = bind(gpu, &l.shade, &[&rays_buf, &pixels]);
        Ok(Batch {
            rays_cap,
            pixels,
            counters,
            stats,
            readback,
            pixel_readback,
            raygen_bg,
            trace_bg,
            args_bg,
            shade_bg,
            rays: rays_buf,
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
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: None,
            timestamp_writes: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &self.scene_bg, &[]);
        pass.set_bind_group(1, bg, &[]);
        match groups {
            Dispatch::Direct(n) => pass.dispatch_workgroups(n, 1, 1),
            Dispatch::Indirect(buf) => pass.dispatch_workgroups_indirect(buf, 4),
        }
    }

    /// Traces and shades one frame.
    pub fn render(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
    ) -> Result<(Frame, FrameStats)> {
        let start = Instant::now();
        let (w, h) = (basis.width, basis.height);
        let tiles_x = w.div_ceil(TILE);
        let tiles = tiles_x * h.div_ceil(TILE);
        let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
        self.params.origin = v4(basis.origin, 1.0);
        self.params.forward = v4(basis.forward, 0.0);
        self.params.right = v4(basis.right, 0.0);
        self.params.up = v4(basis.up, 0.0);
        self.params.background = v4(background, 1.0);
        self.params.width = w;
        self.params.height = h;
        self.params.tiles_x = tiles_x;
        let mut frame = Frame {
            width: w,
            height: h,
            pixels: vec![Pixel::default(); (w as usize) * (h as usize)],
        };
        let mut stats = FrameStats::default();
        let tiles_per_batch = self.batch.rays_cap / TILE_RAYS;
        let mut first = 0;
        while first < tiles {
            let n_tiles = tiles_per_batch.min(tiles - first);
            self.params.first_tile = first;
            self.params.batch_rays = n_tiles * TILE_RAYS;
            let t = Instant::now();
            self.trace_batch(&mut stats)?;
            let t2 = Instant::now();
            stats.trace_seconds += (t2 - t).as_secs_f64();
            self.read_pixels(first, n_tiles, &mut frame)?;
            stats.shade_seconds += t2.elapsed().as_secs_f64();
            stats.batches += 1;
            first += n_tiles;
        }
        stats.rays = u64::from(w) * u64::from(h);
        stats.seconds = start.elapsed().as_secs_f64();
        Ok((frame, stats))
    }

    /// Generates the batch's rays and runs trace rounds until none is live.
    fn trace_batch(&mut self, stats: &mut FrameStats) -> Result<()> {
        let gpu = self.gpu;
        gpu.queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let b = &self.batch;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for c in &b.counters {
            enc.clear_buffer(c, 0, None);
        }
        enc.clear_buffer(&b.stats, 0, None);
        let groups = self.params.batch_rays.div_ceil(WORKGROUP);
        self.dispatch(
            &mut enc,
            &self.kernels.raygen,
            &b.raygen_bg,
            Dispatch::Direct(groups),
        );
        self.dispatch(
            &mut enc,
            &self.kernels.args,
            &b.args_bg[0],
            Dispatch::Direct(1),
        );
        // `cur` is the counter holding the live rays of the next round.
        let mut cur = 0usize;
        let mut per_check = 2u32;
        let mut live_rounds = 0u32;
        loop {
            for _ in 0..per_check {
                let o = 1 - cur;
                let ind = Dispatch::Indirect(&b.counters[cur]);
                self.dispatch(&mut enc, &self.kernels.trace, &b.trace_bg[cur], ind);
                self.dispatch(
                    &mut enc,
                    &self.kernels.args,
                    &b.args_bg[o],
                    Dispatch::Direct(1),
                );
                cur = o;
            }
            stats.rounds += per_check;
            enc.copy_buffer_to_buffer(&b.counters[cur], 0, &b.readback, 0, 16);
            enc.copy_buffer_to_buffer(&b.stats, 0, &b.readback, 16, 16);
            gpu.queue.submit([enc.finish()]);
            let data = gpu.map_read(&b.readback)?;
            let counter: Counter = *bytemuck::from_bytes(&data[..16]);
            let s: Stats = *bytemuck::from_bytes(&data[16..32]);
            if s.overflows > 0 {
                return Err(Error::Gpu(format!(
                    "traversal stack overflow in {} rays: the BVH is deeper than the {}-entry \
                     stack",
                    s.overflows, self.params.stack_size
                )));
            }
            if counter.count == 0 {
                stats.steps += u64::from(s.steps);
                stats.tri_tests += u64::from(s.tri_tests);
                // Rounds after the last ray finished cost an empty indirect dispatch each.
                live_rounds += per_check;
                stats.max_live_rounds = stats.max_live_rounds.max(live_rounds);
                return Ok(());
            }
            live_rounds += per_check;
            per_check = (per_check * 2).min(16);
            enc = gpu.device.create_command_encoder(&Default::default());
        }
    }

    fn read_pixels(&self, first_tile: u32, n_tiles: u32, frame: &mut Frame) -> Result<()> {
        let gpu = self.gpu;
        let b = &self.batch;
        let n = n_tiles * TILE_RAYS;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.dispatch(
            &mut enc,
            &self.kernels.shade,
            &b.shade_bg,
            Dispatch::Direct(n.div_ceil(WORKGROUP)),
        );
        let bytes = u64::from(n) * 32;
        enc.copy_buffer_to_buffer(&b.pixels, 0, &b.pixel_readback, 0, bytes);
        gpu.queue.submit([enc.finish()]);
        let slice = b.pixel_readback.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        gpu.wait()?;
        rx.recv()
            .map_err(|_| Error::Gpu("pixel map callback never ran".into()))?
            .map_err(|e| Error::Gpu(format!("pixel map failed: {e}")))?;
        {
            let view = slice
                .get_mapped_range()
                .map_err(|e| Error::Gpu(format!("pixel map failed: {e}")))?;
            let px: &[Pixel] = bytemuck::cast_slice(&view);
            let tiles_x = self.params.tiles_x;
            for (i, p) in px.iter().enumerate() {
                let i = i as u32;
                let tile = first_tile + i / TILE_RAYS;
                let local = i % TILE_RAYS;
                let x = (tile % tiles_x) * TILE + local % TILE;
                let y = (tile / tiles_x) * TILE + local / TILE;
                if x < frame.width && y < frame.height {
                    frame.pixels[(y * frame.width + x) as usize] = *p;
                }
            }
        }
        b.pixel_readback.unmap();
        Ok(())
    }

    /// Runs the layout probe (tests): `rays` must hold two states; returns the words the probe
    /// wrote. `params` replaces the tracer's own, so the caller controls every member.
    pub fn probe(&mut self, params: Params, rays: &[RayState; 2]) -> Result<Vec<u32>> {
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
        let words = 36 + 8 * params.pad0 + 10 * params.pad1 + 36 + 8 * params.mesh_count;
        let out = buffer(
            gpu,
            "probe out",
            u64::from(words) * 4,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let bg = bind(gpu, &self.layouts.probe, &[&input, &out]);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut enc, &self.kernels.probe, &bg, Dispatch::Direct(1));
        gpu.queue.submit([enc.finish()]);
        let data = gpu.read_buffer(&out, 0, u64::from(words) * 4)?;
        gpu.queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        Ok(bytemuck::cast_slice(&data).to_vec())
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
            .read_buffer(&self.batch.rays, 0, u64::from(n) * 48)?;
        Ok(bytemuck::cast_slice(&data).to_vec())
    }
}

enum Dispatch<'a> {
    Direct(u32),
    Indirect(&'a wgpu::Buffer),
}

/// Rounds a duration to milliseconds for reports.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
