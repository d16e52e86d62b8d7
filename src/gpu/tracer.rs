//! The tracer (docs/ARCHITECTURE.md, The GPU side): a model's blocks on one GPU, the kernels of a
//! shading mode, and the calls that trace frames, image rectangles or arbitrary rays with them.
//!
//! A frame is traced in batches of 8x8 tiles. Per batch: `raygen` writes a state record per ray
//! and the live list; then trace rounds (`gpu::rounds`) until no ray is live, serving the
//! distributed cache's faults between rounds; then `shade`, and for modes with secondary rays,
//! waves of `spawn`, trace rounds and `gather`.

use super::Gpu;
use super::batch::{Batch, Lists, TILE_RAYS, fault_bytes};
use super::kernels::{Bound, Dispatch, Kernels};
use super::layout::{
    Counter, MeshInfo, NONE, Params, Pixel, RayState, ShadeParams, flags, look, status,
};
use super::shaders::Store;
use super::store::{BlockStore, Rows};
use crate::blocks::ranks::Ranks;
use crate::blocks::{AttrLayout, Format};
use crate::dc::CacheMap;
use crate::dc::policy::CachePolicy;
use crate::dc::source::BlockSource;
use crate::dc::trace::FrameTrace;
use crate::error::{Error, Result};
use crate::mirror::tiles::{Tiling, tile_corner, z_x};
use crate::scene::CameraBasis;
use crate::scene::ray::Ray;
use crate::shading::{Sampler, Shading};
use std::mem::size_of;
use std::time::Instant;

pub use super::frame::{Frame, FrameStats, Rect, ms};
pub use super::layout::FAR;

pub const TILE: u32 = crate::mirror::tiles::TILE;
/// lavapipe stops any shader loop after 65,535 iterations per invocation; a budget plus the
/// largest leaf (255 triangles) must stay below that.
pub const MAX_STEP_BUDGET: u32 = 60_000;
pub const DEFAULT_STEP_BUDGET: u32 = 4096;
/// Deeper BVHs than this get this many stack entries, and a ray that would overflow is reported
/// as an error rather than traced wrongly. 16 bytes an entry: a stack this deep still leaves room
/// for 2048 rays a batch in a 128 MiB storage buffer.
pub const MAX_STACK: u32 = 4096;
const DEFAULT_MAX_BATCH_RAYS: u32 = 1 << 20;
/// Stack entries a ray with a distributed cache may set aside for absent blocks while it goes on
/// with what the GPU holds (`DEFER_SLOTS` in shaders/trace.wgsl); its faults go out together.
pub const DEFER_SLOTS: u32 = 4;
/// The fewest pixels a batch is cut to so that its blocks fit the cache: the top of the tree is
/// fetched again for every batch, and a smaller batch's rays share too little of the rest.
pub(super) const MIN_FIT_PIXELS: u32 = 4096;
const WORKGROUP: u32 = 64;
/// The most distinct faults one round records (more fault again next round), and the default
/// (`Settings::fault_cap`).
pub const FAULT_CAP: u32 = 1 << 16;

#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Loop iterations a ray may run per trace dispatch.
    pub step_budget: u32,
    /// Upper bound on rays per batch (rounded down to whole tiles); memory limits may lower it.
    pub max_batch_rays: u32,
    /// Where the GPU keeps the blocks.
    pub store: Store,
    /// Bytes one block texture may hold; `None`: the adapter's largest allocation. Tests set it
    /// small so that small models span several textures.
    pub max_texture_bytes: Option<u64>,
    /// With a cache: when a ray sets absent blocks' entries aside and goes on with what the GPU
    /// holds instead of suspending at the fault.
    pub faults: FaultMode,
    /// With a cache: when the next batch starts in another set of batch buffers while the last
    /// rays of the current one still wait for blocks, so that their fault rounds are shared.
    pub overlap_batches: OverlapMode,
    /// Shading mode, samples, lights: the pipelines are built for this mode.
    pub shading: Shading,
    /// With a cache: the distinct faults a round records, 1..=`FAULT_CAP` (the rest fault again
    /// next round). Tests set it small so that rounds drop faults.
    pub fault_cap: u32,
    /// Count node visits and node- and triangle-block entries in every trace round
    /// (`FrameStats::node_visits` and the two after it; 0 without). Off by default: the counts
    /// cost the trace loop time (`BLOCK_COUNTS` in shaders/trace.wgsl), and the benchmarks take
    /// them from a frame of their own (`Tracer::set_block_counts`).
    pub block_counts: bool,
}

impl Settings {
    /// These settings with batches of at most the rays a `width`x`height` frame has at once (a
    /// ray per pixel, or a wave's fan of secondary rays per pixel): a lane's memory follows its
    /// batch, and the default batch is far larger than a small image.
    pub fn for_image(self, width: u32, height: u32) -> Settings {
        let tiles = u64::from(width.div_ceil(TILE)) * u64::from(height.div_ceil(TILE));
        let fan = u64::from(self.shading.fan().max(1));
        let rays = (tiles * u64::from(TILE_RAYS) * fan).min(u64::from(self.max_batch_rays));
        Settings {
            max_batch_rays: rays as u32,
            ..self
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            step_budget: DEFAULT_STEP_BUDGET,
            max_batch_rays: DEFAULT_MAX_BATCH_RAYS,
            store: Store::Texture,
            max_texture_bytes: None,
            faults: FaultMode::Fit,
            overlap_batches: OverlapMode::Auto,
            shading: Shading::default(),
            fault_cap: FAULT_CAP,
            block_counts: false,
        }
    }
}

/// Each mesh-table entry's first primitive id, colour and look: all the tracer needs to know of
/// the scene besides its blocks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Meshes {
    pub first_prim: Vec<u32>,
    pub colors: Vec<[f32; 3]>,
    /// One per entry, or empty: all by their colour.
    pub looks: Vec<crate::scene::color::Look>,
}

impl Meshes {
    /// The GPU's mesh table.
    pub fn infos(&self) -> Vec<MeshInfo> {
        use crate::scene::color::Look;
        self.colors
            .iter()
            .zip(&self.first_prim)
            .enumerate()
            .map(|(i, (c, &f))| {
                let mut m = MeshInfo {
                    color: [c[0], c[1], c[2], 1.0],
                    first_prim: f,
                    ..MeshInfo::default()
                };
                match self.looks.get(i) {
                    None | Some(Look::Constant) => {}
                    Some(Look::Scalars {
                        colormap,
                        range,
                        cell,
                        ..
                    }) => {
                        m.look = look::SCALARS;
                        m.point = u32::from(!cell);
                        m.map = colormap.index();
                        m.lo = range[0];
                        m.scale = crate::colormap::scale(range[0], range[1]);
                    }
                    Some(Look::Colors { cell, .. }) => {
                        m.look = look::COLORS;
                        m.point = u32::from(!cell);
                    }
                }
                m
            })
            .collect()
    }
}

/// A model as one GPU holds it: every block (replicated), or its resident rows plus a cache.
pub struct GpuModel<'a> {
    pub format: Format,
    pub node_blocks: u32,
    pub tri_blocks: u32,
    /// The attribute blocks after the triangle blocks (none without colour by data).
    pub attrs: AttrLayout,
    /// Words of the resident rows: all blocks in id order when replicated; with a DC, the
    /// rank's own blocks by slot, then the replicated blocks the rank does not own
    /// (`dc::Ranks::resident_row`).
    pub resident: &'a [u32],
    pub meshes: &'a Meshes,
    /// BVH depth: sizes the traversal stack.
    pub depth: u32,
}

/// The distributed cache of one rank: its place among the ranks, the cache, and where borrowed
/// blocks come from.
pub struct DcSetup {
    pub ranks: Ranks,
    pub lines: u32,
    pub map: CacheMap,
    pub source: Box<dyn BlockSource>,
}

/// A rank's cache while it traces: the policy, the block source and this frame's trace.
pub(super) struct Dc {
    pub policy: CachePolicy,
    pub source: Box<dyn BlockSource>,
    pub trace: FrameTrace,
    /// The borrowed blocks the frame has looked up so far: the blocks of the lines its rounds
    /// used and the blocks they faulted on (`serve_faults`).
    pub looked_up: Vec<bool>,
}

/// The distributed cache's GPU buffers (small placeholders, never read, when replicated).
pub(super) struct DcBuffers {
    pub rows: super::row_table::RowTable,
    pub faults: wgpu::Buffer,
    /// Per block, the complement of its least requester this round (`request` in
    /// shaders/shared/dc.wgsl); the `requesters` kernel moves the listed blocks' words into the
    /// fault list and clears them.
    pub requested: wgpu::Buffer,
    /// Whether `requested` may hold words the `requesters` kernel did not clear (blocks requested
    /// past the fault list's capacity): the next round then starts by clearing it whole.
    pub requested_dirty: std::cell::Cell<bool>,
    pub waiters: wgpu::Buffer,
    pub line_used: wgpu::Buffer,
}

/// What starts a batch's trace rounds: primary rays, or a wave of secondary rays.
#[derive(Clone, Copy)]
pub(super) enum Gen {
    Primary,
    Secondary { fan: u32 },
}

/// The kernels' bind groups over this tracer's buffers.
pub(super) struct BoundKernels {
    pub raygen: Bound,
    /// Indexed by the live list the round reads.
    pub trace: [Bound; 2],
    pub trace_suspending: Option<[Bound; 2]>,
    pub args: [Bound; 2],
    pub requesters: Bound,
    pub shade: Bound,
    pub spawn: Option<Bound>,
    pub gather: Option<Bound>,
    pub albedo: Option<Bound>,
}

/// A set of batch buffers with the parameters and bind groups of the batch it holds. With a
/// cache a tracer has a second, spare lane: the next batch starts there while the current one's
/// last rays still wait for blocks (docs/ARCHITECTURE.md, Overlapping batches).
pub(super) struct Lane {
    pub batch: Batch,
    pub params_buf: wgpu::Buffer,
    pub bound: BoundKernels,
}

/// Spare lanes as large as the current one (`spare_lanes`): a batch's last rays may climb chains
/// of absent blocks for many rounds, so two batches' tails can be in flight when the next starts.
const SPARE_LANES: usize = 2;

/// At most this many spare lanes sized to the cache's batches (`spare_lanes`).
const MAX_FITTED_SPARES: usize = 8;

/// A spare lane sized to the cache's batches holds this many times the fitted batch's pixels
/// (`Tracer::fit_pixels`): a batch over a sparse part of the image takes more than its even share
/// (`rounds::FaultDensity`), up to the lane's size. Two rather than four: twice the lanes in the
/// same memory let a batch start every round (`rounds::fill_share`; rm 3M at 1/32, rank 0 of 8:
/// 33.5-33.8 fault rounds a warm frame against 35.3-35.7 with four).
const SPARE_FIT_SHARE: u32 = 2;

/// The rays a spare lane holds and how many spare lanes there are, for a current lane of
/// `rays_cap` rays and batches fitted to `fit_pixels`. Without a fit (the cache holds every
/// borrowed block), `SPARE_LANES` lanes as large as the current one. With one, lanes of
/// `SPARE_FIT_SHARE` fitted batches, as many as fit in the memory of `SPARE_LANES` full lanes, at
/// least `SPARE_LANES` and at most `MAX_FITTED_SPARES`: while three lanes hold tails, no batch
/// can start (rm 3M at 1/32, rank 0 of 8: about 10 of 40 fault rounds a frame), and a lane's
/// buffers (216 MB of host memory on lavapipe for 1M rays) dwarf a short cache.
fn spare_lanes(rays_cap: u32, fit_pixels: Option<u32>) -> (u32, usize) {
    let Some(fit) = fit_pixels else {
        return (rays_cap, SPARE_LANES);
    };
    let fit = u64::from(fit.max(MIN_FIT_PIXELS)) * u64::from(SPARE_FIT_SHARE);
    let tiles = fit.div_ceil(u64::from(TILE_RAYS)).max(1);
    let rays = (tiles * u64::from(TILE_RAYS)).min(u64::from(rays_cap)) as u32;
    let budget = SPARE_LANES as u64 * u64::from(rays_cap) / u64::from(rays.max(1));
    let count = (budget as usize).clamp(SPARE_LANES, MAX_FITTED_SPARES);
    (rays, count)
}

/// Pipeline constants fixed for a model (block addressing, DC).
type Constants = Vec<(&'static str, f64)>;

pub struct Tracer<'g> {
    pub(super) gpu: &'g Gpu,
    pub(super) kernels: Kernels,
    pub(super) bound: BoundKernels,
    pub(super) params: Params,
    pub(super) params_buf: wgpu::Buffer,
    meshes_buf: wgpu::Buffer,
    /// The colormaps and the sRGB decode table (`colormap::palette`).
    palette_buf: wgpu::Buffer,
    pub(super) shade_buf: wgpu::Buffer,
    pub(super) batch: Batch,
    settings: Settings,
    pub(super) store: BlockStore,
    pub(super) format: Format,
    pub(super) dc: Option<Dc>,
    pub(super) dc_bufs: DcBuffers,
    /// With a cache, more lanes of batch buffers (`Settings::overlap_batches`).
    pub(super) spares: Vec<Lane>,
    frame_start: Instant,
    /// The BVH depth the model declared (the stack holds `min(3 depth, MAX_STACK)` entries).
    pub(super) depth: u32,
    constants: Constants,
    /// Called after each sample pass of a batch with (passes done, passes in the rectangle).
    pub(super) progress: Option<PassProgress>,
    /// With a cache, the pixels a batch may hold so that its blocks fit the cache, from the last
    /// frame's distinct blocks (`None`: they fit, or no frame has ended yet).
    fit_pixels: Option<u32>,
    /// With a cache, whether a batch's blocks are known to fit it: the cache holds every
    /// borrowed block, or a frame has ended and sized `fit_pixels`. Only then do batches overlap:
    /// two batches too big for the cache evict each other's blocks.
    batches_fit: bool,
    /// With a short cache, last frame's first-round faults per tile, and this frame's so far
    /// (`Tracer::batch_tiles`).
    pub(super) density: Option<super::rounds::FaultDensity>,
    pub(super) next_density: Option<super::rounds::FaultDensity>,
    /// Whether a `render_rect` call of the frame took more than one batch: spare lanes are
    /// worth their memory (`add_spare_lanes`).
    pub(super) several_batches: bool,
}

/// The trace kernel's `BLOCK_COUNTS` constant.
fn block_counts_constant(on: bool) -> f64 {
    if on { 1.0 } else { 0.0 }
}

/// Set-aside slots a ray may use in a frame (`Params::dc_defer`). Only when the frame's blocks fit
/// the cache: a ray that goes on past an absent block also faults on blocks a nearer hit would
/// have culled, and where the cache is short those extra fetches evict blocks other rays need
/// (measured: at a 1/8 cache, 8-25% more fetches and no fewer rounds; at 1/1, 45% fewer rounds).
fn defer_slots(settings: Settings, fits: bool) -> u32 {
    let on = match settings.faults {
        FaultMode::Fit => fits,
        FaultMode::Never => false,
        FaultMode::Always => true,
    };
    if on { DEFER_SLOTS } else { 0 }
}

/// `Params::flags` for sample `s` (counted from the rectangle's first) of a shading setup.
fn sample_flags(sh: Shading, basis: &CameraBasis, s: u32) -> u32 {
    (if sh.spp > 1 { flags::JITTER } else { 0 })
        | if sh.cull { flags::CULL } else { 0 }
        | if s == 0 { flags::FIRST_SAMPLE } else { 0 }
        | match sh.sampler {
            Sampler::Sobol => 0,
            Sampler::Independent => flags::SAMPLER_INDEPENDENT,
        }
        | if basis.parallel { flags::PARALLEL } else { 0 }
}

/// Where `Tracer::render_rects` takes rectangles from and gives their pixels to.
pub trait RectSource {
    /// The next rectangle to trace. `busy`: rectangles are in flight, so answer `Next::Later`
    /// rather than wait when none is at hand; when not busy, wait for one.
    fn next(&mut self, busy: bool) -> Result<Next>;
    /// A rectangle's pixels, row-major within it, once all its rays are done.
    fn done(&mut self, rect: Rect, pixels: Vec<Pixel>) -> Result<()>;
}

/// What a `RectSource` has next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Next {
    Rect(Rect),
    /// None at hand yet.
    Later,
    /// None left this frame.
    End,
}

/// `render_rect`'s one rectangle as a source.
struct OneRect {
    rect: Option<Rect>,
    pixels: Option<Vec<Pixel>>,
}

impl RectSource for OneRect {
    fn next(&mut self, _busy: bool) -> Result<Next> {
        Ok(self.rect.take().map_or(Next::End, Next::Rect))
    }

    fn done(&mut self, _rect: Rect, pixels: Vec<Pixel>) -> Result<()> {
        self.pixels = Some(pixels);
        Ok(())
    }
}

/// How `begin_rect` cuts a rectangle: its 8x8 tiles, tiles a row, tiles a batch.
#[derive(Clone, Copy, Debug)]
pub(super) struct RectPlan {
    pub tiles: u32,
    pub tiling: Tiling,
    pub per_batch: u32,
}

/// When a ray with a distributed cache goes on past a fault (docs/ARCHITECTURE.md, The round
/// loop).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FaultMode {
    /// In frames whose blocks fit the cache.
    #[default]
    Fit,
    /// Never: a ray suspends at every fault.
    Never,
    /// In every frame (where the cache is short it fetches more; for measurements).
    Always,
}

/// When batches overlap with a distributed cache (docs/ARCHITECTURE.md, Overlapping batches).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OverlapMode {
    /// With an associative cache (`lru`): a new batch's blocks take the lines least recently
    /// used. In a direct-mapped cache they evict, by their place, blocks the last batch's rays
    /// wait for (measured: up to 14% more fetches).
    #[default]
    Auto,
    /// With any cache (for measurements).
    Always,
    /// Never: one batch at a time.
    Never,
}

/// What `Tracer::set_progress` installs.
pub type PassProgress = Box<dyn FnMut(u64, u64)>;

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
        if !(1..=FAULT_CAP).contains(&settings.fault_cap) {
            return Err(Error::Invalid(format!(
                "fault cap {} is out of range 1..={FAULT_CAP}",
                settings.fault_cap
            )));
        }
        let format = model.format;
        let attrs = model.attrs;
        let blocks = model.node_blocks + model.tri_blocks + attrs.blocks;
        let lines = dc.as_ref().map_or(0, |d| d.lines);
        let rows = Rows {
            format,
            resident: model.resident,
            lines,
        };
        let store = BlockStore::new(gpu, settings.store, &rows, settings.max_texture_bytes)?;
        settings.shading.validate()?;
        let mut constants: Constants = vec![
            ("DC", if dc.is_some() { 1.0 } else { 0.0 }),
            ("NODES_PER_BLOCK", f64::from(format.nodes_per_block())),
            ("TRIS_PER_BLOCK", f64::from(format.tris_per_block())),
            ("TEXELS_PER_BLOCK", f64::from(format.texels())),
            (
                "ATTRS_PER_BLOCK",
                f64::from(format.attrs_per_block(attrs.words)),
            ),
            ("ATTR_WORDS", f64::from(attrs.words.max(1))),
        ];
        constants.extend(store.constants());
        let slots = if dc.is_some() { DEFER_SLOTS } else { 0 };
        constants.push(("DEFER_SLOTS", f64::from(slots)));
        // The mapping's code alone in the kernels (`cache_line` in shaders/shared/dc.wgsl).
        let map = dc.as_ref().map_or(1.0, |d| match d.map {
            CacheMap::Ize => 0.0,
            CacheMap::Demarle | CacheMap::Lru => 1.0,
        });
        constants.push(("DC_MAP", map));
        constants.push(("ROW_TABLE_WIDTH", f64::from(super::row_table::WIDTH)));
        let colored = attrs.words > 0;
        constants.push(("COLORED", if colored { 1.0 } else { 0.0 }));
        constants.push(("BLOCK_COUNTS", block_counts_constant(settings.block_counts)));
        let mode = settings.shading.mode;
        let kernels = Kernels::new(gpu, store.module(), &constants, mode, colored);
        let meshes = model.meshes.infos();
        let init = |label, contents: &[u8], usage| gpu.buffer_init(label, contents, usage);
        use wgpu::BufferUsages as U;
        let meshes_buf = init("meshes", bytemuck::cast_slice(&meshes), U::STORAGE);
        let palette = crate::colormap::palette();
        let palette_buf = init("palette", bytemuck::cast_slice(&palette), U::STORAGE);
        // A visit pushes at most WIDTH - 1 entries per level; set-aside entries follow.
        let stack_size = model
            .depth
            .saturating_mul(crate::bvh::WIDTH as u32 - 1)
            .clamp(1, MAX_STACK)
            + slots;
        let mut params = Params {
            step_budget: settings.step_budget,
            stack_size,
            mesh_count: meshes.len() as u32,
            node_blocks: model.node_blocks,
            dc_ranks: 1,
            attr_block0: model.node_blocks + model.tri_blocks,
            albedo_stride: 1,
            ..Params::default()
        };
        let (dc, dc_bufs, fits) = match dc {
            None => {
                // A replicated model binds small placeholders the kernels never read.
                let p = || gpu.buffer("unused", 32, U::STORAGE);
                let bufs = DcBuffers {
                    rows: super::row_table::RowTable::placeholder(gpu),
                    faults: p(),
                    requested: p(),
                    requested_dirty: false.into(),
                    waiters: p(),
                    line_used: p(),
                };
                (None, bufs, true)
            }
            Some(d) => {
                let resident = rows.resident_rows();
                let expect = d.ranks.resident_rows(blocks);
                if resident != expect {
                    return Err(Error::Invalid(format!(
                        "rank {} of {} should hold {expect} resident blocks, was given {resident}",
                        d.ranks.rank, d.ranks.n
                    )));
                }
                let policy = CachePolicy::new(d.ranks, d.map, d.lines, blocks, model.node_blocks);
                params.dc_ranks = d.ranks.n;
                params.dc_rank = d.ranks.rank;
                params.dc_lines = d.lines;
                params.dc_map = match d.map {
                    CacheMap::Ize => 0,
                    CacheMap::Demarle | CacheMap::Lru => 1,
                };
                params.dc_cache_row = policy.cache_row();
                params.dc_root_row = d.ranks.root_row(blocks);
                params.dc_fault_cap = settings.fault_cap;
                // Until a frame shows its blocks, set aside only when the cache holds every
                // borrowed block.
                let fits = d.lines >= blocks - resident;
                params.dc_defer = defer_slots(settings, fits);
                let bufs = DcBuffers {
                    rows: super::row_table::RowTable::new(gpu, policy.block_rows())?,
                    faults: gpu.buffer(
                        "faults",
                        fault_bytes(settings.fault_cap),
                        U::STORAGE | U::COPY_SRC | U::COPY_DST,
                    ),
                    requested: gpu.buffer(
                        "requested",
                        4 * u64::from(blocks),
                        U::STORAGE | U::COPY_SRC | U::COPY_DST,
                    ),
                    requested_dirty: true.into(),
                    waiters: gpu.buffer(
                        "waiters",
                        4 * u64::from(d.lines),
                        U::STORAGE | U::COPY_SRC | U::COPY_DST,
                    ),
                    line_used: gpu.buffer(
                        "line used",
                        8 * u64::from(d.lines),
                        U::STORAGE | U::COPY_SRC | U::COPY_DST,
                    ),
                };
                let dc = Dc {
                    policy,
                    source: d.source,
                    trace: FrameTrace::default(),
                    looked_up: vec![false; blocks as usize],
                };
                (Some(dc), bufs, fits)
            }
        };
        let params_buf = init(
            "params",
            bytemuck::bytes_of(&params),
            U::UNIFORM | U::COPY_DST,
        );
        let shade_buf = gpu.buffer(
            "shading",
            size_of::<ShadeParams>() as u64,
            U::STORAGE | U::COPY_DST,
        );
        let batch = Batch::new(
            gpu,
            stack_size,
            settings.max_batch_rays,
            lines,
            settings.fault_cap,
            colored,
        )?;
        let mut tracer = Tracer {
            gpu,
            bound: BoundKernels::placeholder(),
            kernels,
            params,
            params_buf,
            meshes_buf,
            palette_buf,
            shade_buf,
            batch,
            settings,
            store,
            format,
            dc,
            dc_bufs,
            spares: Vec::new(),
            frame_start: Instant::now(),
            depth: model.depth,
            constants,
            progress: None,
            fit_pixels: None,
            density: None,
            next_density: None,
            batches_fit: fits,
            several_batches: false,
        };
        tracer.bound = tracer.bind_kernels();
        if fits {
            tracer.add_spare_lanes()?;
        }
        Ok(tracer)
    }

    /// With a cache and `Settings::overlap_batches`, allocates the spare lanes once and commits
    /// their memory: when the tracer is made if the cache holds every borrowed block, else after
    /// the first frame that took several batches for one rectangle (so outside a frame's time,
    /// and never for a cluster rank whose tiles are one batch each).
    fn add_spare_lanes(&mut self) -> Result<()> {
        let Some(dc) = &self.dc else {
            return Ok(());
        };
        let on = match self.settings.overlap_batches {
            OverlapMode::Auto => dc.policy.map() == CacheMap::Lru,
            OverlapMode::Always => true,
            OverlapMode::Never => false,
        };
        if !on || !self.spares.is_empty() {
            return Ok(());
        }
        let (gpu, lines) = (self.gpu, dc.policy.lines());
        let colored = self.kernels.albedo.is_some();
        let (max, count) = spare_lanes(self.batch.rays_cap, self.fit_pixels);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for l in 1..=count {
            let s = self.params.stack_size;
            let batch = Batch::new(gpu, s, max, lines, self.settings.fault_cap, colored)?;
            batch.commit(&mut enc);
            let params_buf = gpu.buffer(
                "params",
                size_of::<Params>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            );
            let bound = BoundKernels::placeholder();
            self.spares.push(Lane {
                batch,
                params_buf,
                bound,
            });
            self.swap_lanes(l);
            self.bound = self.bind_kernels();
            self.swap_lanes(l);
        }
        gpu.queue.submit([enc.finish()]);
        gpu.wait()
    }

    /// Makes lane `l` (1: the first spare) the current one (`self.batch`, `self.params_buf`,
    /// `self.bound`), and the current one lane `l`; calling it again swaps them back.
    pub(super) fn swap_lanes(&mut self, l: usize) {
        if let Some(l) = l.checked_sub(1).and_then(|i| self.spares.get_mut(i)) {
            std::mem::swap(&mut self.batch, &mut l.batch);
            std::mem::swap(&mut self.params_buf, &mut l.params_buf);
            std::mem::swap(&mut self.bound, &mut l.bound);
        }
    }

    /// The resource bound to WGSL variable `name` for a kernel reading live list `lists.input`.
    pub(super) fn resource(&self, name: &str, lists: Lists) -> Option<wgpu::BindingResource<'_>> {
        if let Some(b) = self.batch.resource(name, lists) {
            return Some(b.as_entire_binding());
        }
        let buf = match name {
            "blocks" | "blocks_1" | "blocks_2" | "blocks_3" => return self.store.resource(name),
            "block_rows" => return Some(self.dc_bufs.rows.binding()),
            "params" => &self.params_buf,
            "meshes" => &self.meshes_buf,
            "palette" => &self.palette_buf,
            "shading" => &self.shade_buf,
            "faults" => &self.dc_bufs.faults,
            "requested" => &self.dc_bufs.requested,
            "waiters" => &self.dc_bufs.waiters,
            "line_used" => &self.dc_bufs.line_used,
            _ => return None,
        };
        Some(buf.as_entire_binding())
    }

    fn bind_kernels(&self) -> BoundKernels {
        let k = &self.kernels;
        let gpu = self.gpu;
        let with = |lists: Lists| move |name: &str| self.resource(name, lists);
        let fill = Lists::FILL_FIRST;
        let each = |kernel: &super::kernels::Kernel| {
            [0, 1].map(|input| kernel.bind(gpu, with(Lists { input })))
        };
        BoundKernels {
            raygen: k.raygen.bind(gpu, with(fill)),
            trace: each(&k.trace),
            trace_suspending: k.trace_suspending.as_ref().map(each),
            args: each(&k.args),
            requesters: k.requesters.bind(gpu, with(fill)),
            shade: k.shade.bind(gpu, with(fill)),
            spawn: k.spawn.as_ref().map(|s| s.bind(gpu, with(fill))),
            gather: k.gather.as_ref().map(|g| g.bind(gpu, with(fill))),
            albedo: k.albedo.as_ref().map(|a| a.bind(gpu, with(fill))),
        }
    }

    /// Installs (or with `None` removes) what is told of each finished sample pass, so that a
    /// long render can say how far it is.
    pub fn set_progress(&mut self, progress: Option<PassProgress>) {
        self.progress = progress;
    }

    /// Changes the shading settings; the pipelines are rebuilt when the mode changes.
    pub fn set_shading(&mut self, shading: Shading) -> Result<()> {
        shading.validate()?;
        let rebuild = shading.mode != self.settings.shading.mode;
        self.settings.shading = shading;
        if rebuild {
            self.rebuild_kernels();
        }
        Ok(())
    }

    /// Turns the block counts of every following frame on or off (`Settings::block_counts`);
    /// the kernels are rebuilt when it changes.
    pub fn set_block_counts(&mut self, on: bool) {
        if on != self.settings.block_counts {
            self.settings.block_counts = on;
            for c in self.constants.iter_mut().filter(|c| c.0 == "BLOCK_COUNTS") {
                c.1 = block_counts_constant(on);
            }
            self.rebuild_kernels();
        }
    }

    /// Builds the kernels for the settings' shading mode and `constants`, and binds them in every
    /// lane.
    fn rebuild_kernels(&mut self) {
        let st = self.store.module();
        let colored = self.kernels.albedo.is_some();
        let mode = self.settings.shading.mode;
        self.kernels = Kernels::new(self.gpu, st, &self.constants, mode, colored);
        self.bound = self.bind_kernels();
        for l in 1..=self.spares.len() {
            self.swap_lanes(l);
            self.bound = self.bind_kernels();
            self.swap_lanes(l);
        }
    }

    /// Entries of a ray's traversal stack (without the set-aside slots).
    pub fn stack_size(&self) -> u32 {
        self.params.stack_size - self.stack_slots()
    }

    /// Set-aside slots after each ray's stack: `DEFER_SLOTS` with a cache, else none.
    pub(super) fn stack_slots(&self) -> u32 {
        if self.dc.is_some() { DEFER_SLOTS } else { 0 }
    }

    pub fn batch_rays(&self) -> u32 {
        self.batch.rays_cap
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
        self.end_frame(&mut stats)?;
        let frame = Frame {
            width,
            height,
            pixels,
        };
        Ok((frame, stats))
    }

    /// Starts a frame made of `render_rect` calls: clears the cache trace and the marks of the
    /// blocks the frame touches; the stats returned start the frame's clock.
    pub fn begin_frame(&mut self) -> FrameStats {
        if let Some(dc) = self.dc.as_mut() {
            dc.trace = FrameTrace::default();
            dc.looked_up.fill(false);
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
        let plan = self.begin_rect(basis, background, rect)?;
        let (tiles, tiles_per_batch) = (plan.tiles, plan.per_batch);
        let sh = self.settings.shading;
        let (fan, waves) = (sh.fan(), sh.waves());
        let passes = u64::from(tiles.div_ceil(tiles_per_batch)) * u64::from(sh.spp);
        if self.overlaps() {
            let mut one = OneRect {
                rect: Some(rect),
                pixels: None,
            };
            self.render_overlapped(basis, background, &mut one, Some(passes), stats)?;
            return one.pixels.ok_or_else(|| {
                Error::Gpu(format!(
                    "the overlapped batches of {rect:?} ended without its pixels"
                ))
            });
        }
        let mut pixels = vec![Pixel::default(); rect.pixels()];
        let mut first = 0;
        let mut passed = 0u64;
        while first < tiles {
            let n_tiles = tiles_per_batch.min(tiles - first);
            self.params.first_tile = first;
            self.params.batch_rays = n_tiles * TILE_RAYS;
            for s in 0..sh.spp {
                self.params.sample = sh.first_sample + s;
                self.params.flags = sample_flags(sh, basis, s);
                let t = Instant::now();
                self.params.albedo_stride = 1;
                stats.traced_rays += u64::from(self.trace_batch(stats, Gen::Primary)?);
                let t2 = Instant::now();
                stats.trace_seconds += (t2 - t).as_secs_f64();
                self.resolve_albedos(stats)?;
                self.run(&self.kernels.shade, &self.bound.shade);
                for _ in 0..waves {
                    let t = Instant::now();
                    self.params.albedo_stride = fan;
                    let live = self.trace_batch(stats, Gen::Secondary { fan })?;
                    stats.trace_seconds += t.elapsed().as_secs_f64();
                    // Only path tracing shades the hits of secondary rays.
                    if sh.mode == crate::shading::Mode::Path {
                        self.resolve_albedos(stats)?;
                    }
                    stats.secondary_rays += u64::from(live);
                    stats.traced_rays += u64::from(live);
                    if let (Some(g), Some(b)) = (&self.kernels.gather, &self.bound.gather) {
                        self.run(g, b);
                    }
                    if live == 0 {
                        break;
                    }
                }
                stats.shade_seconds += t2.elapsed().as_secs_f64();
                passed += 1;
                if let Some(p) = self.progress.as_mut() {
                    p(passed, passes);
                }
            }
            let t = Instant::now();
            self.read_pixels(first, n_tiles, (rect, plan.tiling), sh.spp, &mut pixels)?;
            stats.shade_seconds += t.elapsed().as_secs_f64();
            stats.batches += 1;
            first += n_tiles;
        }
        stats.samples = sh.spp;
        stats.rays += rect.pixels() as u64;
        Ok(pixels)
    }

    /// Traces and shades the rectangles `source` hands out, giving it each one's pixels (row-major
    /// within it) as soon as they are done, and adding to `stats`. With overlapping batches
    /// (docs/ARCHITECTURE.md, Overlapping batches) the next rectangle starts while the last rays
    /// of the ones in flight still wait for blocks; otherwise they are traced one by one, as
    /// `render_rect` does.
    pub fn render_rects(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
        source: &mut dyn RectSource,
        stats: &mut FrameStats,
    ) -> Result<()> {
        if self.overlaps() {
            return self.render_overlapped(basis, background, source, None, stats);
        }
        let mut rects = 0;
        loop {
            match source.next(false)? {
                Next::Rect(rect) => {
                    let pixels = self.render_rect(basis, background, rect, stats)?;
                    rects += 1;
                    self.several_batches |= rects > 1;
                    source.done(rect, pixels)?;
                }
                Next::Later => {}
                Next::End => return Ok(()),
            }
        }
    }

    /// Whether batches overlap: spare lanes exist, batches are known to fit the cache, and a
    /// batch is one trace (one sample, no secondary rays).
    fn overlaps(&self) -> bool {
        let sh = self.settings.shading;
        !self.spares.is_empty() && self.batches_fit && sh.spp == 1 && sh.waves() == 0
    }

    /// Checks a rectangle and sets `Params` for it (camera, image, rectangle, shading; also the
    /// first sample's number and flags), and how it is cut into batches.
    pub(super) fn begin_rect(
        &mut self,
        basis: &CameraBasis,
        background: [f32; 3],
        rect: Rect,
    ) -> Result<RectPlan> {
        let (w, h) = (basis.width, basis.height);
        if rect.w == 0 || rect.h == 0 || rect.x + rect.w > w || rect.y + rect.h > h {
            return Err(Error::Invalid(format!(
                "tile {rect:?} is empty or outside the {w}x{h} image"
            )));
        }
        let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
        self.params.origin = v4(basis.origin, 1.0);
        self.params.forward = v4(basis.forward, 0.0);
        self.params.right = v4(basis.right, 0.0);
        self.params.up = v4(basis.up, 0.0);
        self.params.background = v4(background, 1.0);
        self.params.width = w;
        self.params.height = h;
        let sh = self.settings.shading;
        let fan = sh.fan();
        self.gpu
            .write(&self.shade_buf, &ShadeParams::new(&sh, basis));
        self.params.seed = sh.seed;
        self.params.spp = sh.spp;
        self.params.sample = sh.first_sample;
        self.params.flags = sample_flags(sh, basis, 0);
        self.params.albedo_stride = 1;
        // A wave puts `fan` secondary rays per pixel in the ray buffer: fewer pixels per batch.
        let per_batch = self.batch.rays_cap / fan.max(1) / TILE_RAYS;
        if per_batch == 0 {
            return Err(Error::Gpu(format!(
                "{fan} secondary rays per pixel do not fit a batch of {} rays",
                self.batch.rays_cap
            )));
        }
        // A batch's rays advance in lockstep: when their blocks outnumber the cache's lines, a
        // block is evicted before all its rays have used it and fetched again. Smaller batches
        // trade rounds for fetches (docs/ARCHITECTURE.md, The distributed cache).
        let per_batch = match self.fit_pixels {
            Some(p) => per_batch.min((p.max(MIN_FIT_PIXELS) / TILE_RAYS).max(1)),
            None => per_batch,
        };
        let tiling = Tiling::new(rect.w, rect.h, per_batch);
        let tiles = tiling.tiles();
        self.set_rect(rect, tiling);
        self.several_batches |= tiles > per_batch;
        Ok(RectPlan {
            tiles,
            tiling,
            per_batch,
        })
    }

    /// The rectangle fields of `Params`.
    pub(super) fn set_rect(&mut self, rect: Rect, tiling: Tiling) {
        self.params.tiles_x = tiling.tiles_x;
        self.params.band_tiles = tiling.band;
        (self.params.rect_x, self.params.rect_y) = (rect.x, rect.y);
        (self.params.rect_w, self.params.rect_h) = (rect.w, rect.h);
    }

    /// Ends a frame begun with `begin_frame`: its wall time, and with a cache the distinct
    /// borrowed blocks it looked up. (The frame loop,
    /// `render::frames`, makes the trace's summary from the stats.)
    pub fn end_frame(&mut self, stats: &mut FrameStats) -> Result<()> {
        stats.seconds = self.frame_start.elapsed().as_secs_f64();
        if let Some(dc) = &self.dc {
            stats.distinct_blocks = dc.looked_up.iter().filter(|&&m| m).count() as u64;
            let lines = self
                .dc
                .as_ref()
                .map_or(0, |dc| u64::from(dc.policy.lines()));
            self.params.dc_defer = defer_slots(self.settings, stats.distinct_blocks <= lines);
            self.batches_fit = true;
            self.density = self.next_density.take();
            self.fit_pixels = self.dc.as_ref().and_then(|dc| {
                let lines = u64::from(dc.policy.lines());
                (stats.distinct_blocks > lines).then(|| {
                    let fit = stats.rays * lines / stats.distinct_blocks;
                    fit.min(u64::from(u32::MAX)) as u32
                })
            });
            if std::mem::take(&mut self.several_batches) {
                self.add_spare_lanes()?;
            }
        }
        Ok(())
    }

    /// Whether batches are sized to the cache (`fit_pixels`): the frame's blocks outnumber its
    /// lines.
    pub(super) fn fits_by_batches(&self) -> bool {
        self.fit_pixels.is_some()
    }

    /// Bytes of every lane's batch buffers (`Batch::bytes`).
    pub fn batch_bytes(&self) -> u64 {
        let spares = self.spares.iter().map(|l| l.batch.bytes());
        self.batch.bytes() + spares.sum::<u64>()
    }

    /// The rays each lane holds: the current one, then the spares (`spare_lanes`).
    pub fn lane_rays(&self) -> Vec<u32> {
        let spares = self.spares.iter().map(|l| l.batch.rays_cap);
        std::iter::once(self.batch.rays_cap).chain(spares).collect()
    }

    /// Submits one direct dispatch of a shading kernel over the batch's pixel slots (no wait).
    pub(super) fn run(&self, kernel: &super::kernels::Kernel, bound: &Bound) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let groups = Dispatch::Direct(self.params.batch_rays.div_ceil(WORKGROUP));
        kernel.dispatch(&mut enc, bound, groups, None);
        self.gpu.queue.submit([enc.finish()]);
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
        self.dc
            .as_ref()
            .map(|d| (d.policy.ranks(), d.policy.lines(), d.policy.map()))
    }

    /// Reads the batch's pixels back; colours are sums over `spp` samples, divided here.
    pub(super) fn read_pixels(
        &self,
        first_tile: u32,
        n_tiles: u32,
        (rect, tiling): (Rect, Tiling),
        spp: u32,
        out: &mut [Pixel],
    ) -> Result<()> {
        let gpu = self.gpu;
        let b = &self.batch;
        let n = n_tiles * TILE_RAYS;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        // A multiply by 1/spp: exactly the sum when spp is 1.
        let scale = 1.0 / spp as f32;
        let bytes = u64::from(n) * size_of::<Pixel>() as u64;
        enc.copy_buffer_to_buffer(&b.pixels, 0, &b.pixel_readback, 0, bytes);
        gpu.queue.submit([enc.finish()]);
        let data = gpu.map_read_prefix(&b.pixel_readback, bytes)?;
        // Tile by tile, each slot's place from its tile's corner and its Z-order offset, each
        // pixel read in place (mapped bytes carry no alignment promise: unaligned): half the
        // host's time of a copy of the batch and `tile_pixel`'s divisions for every slot
        // (about 1.5 against 3 ms a batch of 350k pixels).
        let px = size_of::<Pixel>();
        let offsets: [(u32, u32); TILE_RAYS as usize] =
            std::array::from_fn(|l| (z_x(l as u32), z_x(l as u32 >> 1)));
        for (t, tile) in data.chunks_exact(px * TILE_RAYS as usize).enumerate() {
            let (x0, y0) = tile_corner(first_tile + t as u32, tiling);
            for (&(dx, dy), bytes) in offsets.iter().zip(tile.chunks_exact(px)) {
                let (x, y) = (x0 + dx, y0 + dy);
                if x < rect.w && y < rect.h {
                    let mut p: Pixel = bytemuck::pod_read_unaligned(bytes);
                    p.rgb = p.rgb.map(|c| c * scale);
                    out[(y * rect.w + x) as usize] = p;
                }
            }
        }
        Ok(())
    }

    pub fn params(&self) -> Params {
        self.params
    }

    pub fn settings(&self) -> Settings {
        self.settings
    }

    /// Textures the block store spans (1 for a buffer store).
    pub fn store_parts(&self) -> u32 {
        self.store.parts()
    }

    /// Rows of the block store: resident blocks, then cache lines.
    pub fn store_rows(&self) -> u32 {
        self.store.rows()
    }

    /// What holds the blocks on the GPU: "1 texture", "2 textures", "1 buffer".
    pub fn store_description(&self) -> String {
        self.store.describe()
    }

    /// The per-batch ray states after the last batch (tests inspect them).
    pub fn read_rays(&self, n: u32) -> Result<Vec<RayState>> {
        let bytes = u64::from(n) * size_of::<RayState>() as u64;
        let data = self.gpu.read_buffer(&self.batch.rays, 0, bytes)?;
        Ok(bytemuck::pod_collect_to_vec(&data))
    }

    /// Traces arbitrary rays (tests, tools, secondary rays from the host) through the same trace
    /// kernel and round loop as rendering, in batches of at most `batch_rays()` rays; returns
    /// each ray's closest hit with `t` in `(0, tmax)`, in units of the direction's length.
    ///
    /// A ray with a NaN or infinite origin or direction component, a zero direction, or a `tmax`
    /// that is NaN or not positive is a miss (the trace kernel checks, so rays made on the GPU
    /// get the same treatment). `tmax = +inf` means no limit (the kernel's `FAR`, 3e38).
    ///
    /// The rays are taken to leave surfaces (spawned rays): a hit must be proven in front of
    /// the origin despite rounding. [`Tracer::trace_camera_rays`] traces rays that leave none.
    pub fn trace_rays(&mut self, rays: &[Ray]) -> Result<Vec<Option<RayHit>>> {
        self.trace_rays_flagged(rays, 0)
    }

    /// [`Tracer::trace_rays`] for rays from a camera, on no surface, as `raygen` makes them.
    pub fn trace_camera_rays(&mut self, rays: &[Ray]) -> Result<Vec<Option<RayHit>>> {
        self.trace_rays_flagged(rays, flags::FROM_CAMERA)
    }

    fn trace_rays_flagged(&mut self, rays: &[Ray], ray_flags: u32) -> Result<Vec<Option<RayHit>>> {
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
                    cur_index: 0,
                    cur_count: 0,
                    prim: NONE,
                    wait_block: NONE,
                    flags: ray_flags,
                    skip: NONE,
                    ..RayState::default()
                })
                .collect();
            let live: Vec<u32> = (0..n).collect();
            let gpu = self.gpu;
            self.params.batch_rays = n;
            gpu.write(&self.params_buf, &self.params);
            gpu.queue
                .write_buffer(&self.batch.rays, 0, bytemuck::cast_slice(&states));
            gpu.queue
                .write_buffer(&self.batch.live[0], 0, bytemuck::cast_slice(&live));
            let counter = Counter {
                count: n,
                dispatch: [0; 3],
            };
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            enc.clear_buffer(&self.batch.counters[1], 0, None);
            enc.clear_buffer(&self.batch.stats, 0, None);
            self.clear_faults(&mut enc);
            gpu.write(&self.batch.counters[0], &counter);
            let args = &self.bound.args[0];
            self.kernels
                .args
                .dispatch(&mut enc, args, Dispatch::Direct(1), None);
            self.run_rounds(enc, &mut stats)?;
            stats.batches += 1;
            out.extend(self.read_rays(n)?.into_iter().map(|r| {
                (r.status == status::DONE && r.hit != NONE).then_some(RayHit {
                    t: r.t,
                    prim: r.prim,
                    normal: r.normal,
                    point: r.hit_point,
                    error: r.hit_error,
                })
            }));
        }
        Ok(out)
    }
}

impl BoundKernels {
    /// Stands in until the tracer that owns the buffers exists.
    fn placeholder() -> BoundKernels {
        BoundKernels {
            raygen: Bound::empty(),
            trace: [Bound::empty(), Bound::empty()],
            trace_suspending: None,
            args: [Bound::empty(), Bound::empty()],
            requesters: Bound::empty(),
            shade: Bound::empty(),
            spawn: None,
            gather: None,
            albedo: None,
        }
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
    /// The hit point from its barycentrics, and how far along the normal a ray leaving it must
    /// start (`mirror::offset::offset_ray(point, n, error)` spawns as the kernels do).
    pub point: [f32; 3],
    pub error: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spare_lanes_fit_the_batches_in_the_memory_of_two_full_ones() {
        // No fit (the cache holds every block): two lanes as large as the current one.
        assert_eq!(spare_lanes(364_672, None), (364_672, SPARE_LANES));
        // rm 3M at 1/32: two fitted batches a lane, whole tiles, six lanes.
        let (rays, count) = spare_lanes(364_672, Some(57_878));
        assert_eq!((rays, count), (115_776, 6));
        assert_eq!(rays % TILE_RAYS, 0);
        assert!(rays >= 2 * 57_878 && count as u64 * u64::from(rays) <= 2 * 364_672);
        // Tiny batches: at most eight lanes; batches near the lane's size: two full lanes.
        assert_eq!(
            spare_lanes(364_672, Some(100)),
            (2 * MIN_FIT_PIXELS, MAX_FITTED_SPARES)
        );
        assert_eq!(spare_lanes(364_672, Some(231_406)), (364_672, SPARE_LANES));
    }

    #[test]
    fn a_batch_holds_at_most_the_rays_of_its_image() {
        let cast = Settings::default();
        // A ray a pixel, in whole tiles: 65x64 pixels are 9x8 tiles.
        assert_eq!(cast.for_image(64, 64).max_batch_rays, 4096);
        assert_eq!(cast.for_image(65, 64).max_batch_rays, 72 * TILE_RAYS);
        // A wave of ambient occlusion puts `ao_rays` secondary rays a pixel in the batch.
        let mut ao = cast;
        ao.shading.mode = crate::shading::Mode::Ao;
        let fan = ao.shading.ao_rays;
        assert_eq!(ao.for_image(64, 64).max_batch_rays, 4096 * fan);
        // Never more than the settings allow.
        assert_eq!(
            cast.for_image(4096, 4096).max_batch_rays,
            cast.max_batch_rays
        );
    }
}
