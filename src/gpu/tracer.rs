//! The tracer (docs/ARCHITECTURE.md, The GPU side): a model's blocks on one GPU, the kernels of a
//! shading mode, and the calls that trace frames, image rectangles or arbitrary rays with them.
//!
//! A frame is traced in batches of 8x8 tiles, stage by stage, a file a stage:
//! - `gpu::rounds`: a batch's rays are generated and traced in rounds until none is live;
//! - `gpu::faults`: between rounds, the distributed cache's GPU half serves the rounds' faults;
//! - `gpu::shade`: the batch's hits are shaded, with waves of secondary rays for modes that have
//!   them, and its pixels read back;
//! - `gpu::scheduler`: with a cache, batches overlap in the lanes of `gpu::lanes`, scheduled by
//!   the fault density of `gpu::density`;
//! - `gpu::rays`: arbitrary rays through the same rounds.
//!
//! This file holds the tracer's state and its public calls.

use super::Gpu;
use super::batch::{Batch, TILE_RAYS};
use super::density::FaultDensity;
use super::faults::{DEFER_SLOTS, Dc, DcBuffers, defer_slots};
use super::frame::{Frame, FrameStats, Rect};
use super::kernels::{Constants, Kernels};
use super::lanes::{BoundKernels, Lane};
use super::layout::{MeshInfo, Params, Pixel, RayState, ShadeParams, look};
use super::scheduler::{Next, OneRect, RectPlan, RectSource};
use super::shade::sample_flags;
use super::shaders::{Override, Store};
use super::store::{BlockStore, Rows};
use crate::blocks::ranks::Ranks;
use crate::blocks::{AttrLayout, Format};
use crate::dc::CacheMap;
use crate::dc::source::BlockSource;
use crate::error::{Error, Result};
use crate::mirror::tiles::{TILE, Tiling};
use crate::scene::CameraBasis;
use crate::shading::Shading;
use crate::traces::record::FrameTrace;
use std::mem::size_of;
use std::time::Instant;

/// lavapipe stops any shader loop after 65,535 iterations per invocation; a budget plus the
/// largest leaf (255 triangles) must stay below that.
pub const MAX_STEP_BUDGET: u32 = 60_000;
pub const DEFAULT_STEP_BUDGET: u32 = 4096;
/// Deeper BVHs than this get this many stack entries, and a ray that would overflow is reported
/// as an error rather than traced wrongly. 16 bytes an entry: a stack this deep still leaves room
/// for 2048 rays a batch in a 128 MiB storage buffer.
pub const MAX_STACK: u32 = 4096;
const DEFAULT_MAX_BATCH_RAYS: u32 = 1 << 20;
/// The fewest pixels a batch is cut to so that its blocks fit the cache: the top of the tree is
/// fetched again for every batch, and a smaller batch's rays share too little of the rest.
pub(super) const MIN_FIT_PIXELS: u32 = 4096;
/// The most distinct faults one round records (more fault again next round), and the default
/// (`Settings::fault_cap`).
pub const FAULT_CAP: u32 = 1 << 16;

#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Loop iterations a ray may run per traversal dispatch.
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
    /// With an `lru` cache: each round also fetches the children of the node blocks its faults
    /// load, into lines nothing needs, so that their rays go on into them without a round of
    /// their own (`dc::policy`).
    pub fetch_ahead: bool,
    /// Shading mode, samples, lights: the pipelines are built for this mode.
    pub shading: Shading,
    /// With a cache: the distinct faults a round records, 1..=`FAULT_CAP` (the rest fault again
    /// next round). Tests set it small so that rounds drop faults.
    pub fault_cap: u32,
    /// Count node visits and node- and triangle-block entries in every traversal round
    /// (`FrameStats::node_visits` and the two after it; 0 without). Off by default: the counts
    /// cost the trace loop time (`BLOCK_COUNTS` in shaders/traverse.wgsl), and the benchmarks take
    /// them from a frame of their own (`Tracer::set_block_counts`).
    pub block_counts: bool,
    /// The first wave of a sample made by the `spawn` kernel instead of by its first traversal
    /// round (`rounds::Gen`): 1, a path's later waves, whose dead paths `spawn` compacts away.
    /// Tests set it to 0 and to `u32::MAX` to compare the two makers of a wave.
    pub spawned_waves_from: u32,
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
            fetch_ahead: true,
            shading: Shading::default(),
            fault_cap: FAULT_CAP,
            block_counts: false,
            spawned_waves_from: 1,
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

pub struct Tracer<'g> {
    pub(super) gpu: &'g Gpu,
    pub(super) kernels: Kernels,
    pub(super) bound: BoundKernels,
    pub(super) params: Params,
    pub(super) params_buf: wgpu::Buffer,
    pub(super) meshes_buf: wgpu::Buffer,
    /// The colormaps and the sRGB decode table (`colormap::palette`).
    pub(super) palette_buf: wgpu::Buffer,
    pub(super) shade_buf: wgpu::Buffer,
    pub(super) batch: Batch,
    pub(super) settings: Settings,
    pub(super) store: BlockStore,
    pub(super) format: Format,
    pub(super) dc: Option<Dc>,
    pub(super) dc_bufs: DcBuffers,
    /// With a cache, more lanes of batch buffers (`Settings::overlap_batches`).
    pub(super) spares: Vec<Lane>,
    pub(super) frame_start: Instant,
    /// The BVH depth the model declared (the stack holds `min(3 depth, MAX_STACK)` entries).
    pub(super) depth: u32,
    pub(super) constants: Constants,
    /// Called after each sample pass of a batch with (passes done, passes in the rectangle).
    pub(super) progress: Option<PassProgress>,
    /// With a cache, the pixels a batch may hold so that its blocks fit the cache, from the last
    /// frame's distinct blocks (`None`: they fit, or no frame has ended yet).
    pub(super) fit_pixels: Option<u32>,
    /// With a cache, whether a batch's blocks are known to fit it: the cache holds every
    /// borrowed block, or a frame has ended and sized `fit_pixels`. Only then do batches overlap:
    /// two batches too big for the cache evict each other's blocks.
    pub(super) batches_fit: bool,
    /// With a short cache, last frame's first-round faults per tile, and this frame's so far
    /// (`Tracer::batch_tiles`).
    pub(super) density: Option<FaultDensity>,
    pub(super) next_density: Option<FaultDensity>,
    /// Whether a `render_rect` call of the frame took more than one batch: spare lanes are
    /// worth their memory (`add_spare_lanes`).
    pub(super) several_batches: bool,
    /// A finished frame's pixels handed back (`recycle_pixels`) for the next rectangle of the
    /// same size: its pages are mapped already, where a fresh allocation of a frame's pixels
    /// page-faults on every 4 KiB the read-back writes.
    pub(super) spare_pixels: Vec<Pixel>,
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
        let slots = if dc.is_some() { DEFER_SLOTS } else { 0 };
        // The mapping's code alone in the kernels (`cache_line` in shaders/shared/dc.wgsl).
        let map = dc.as_ref().map_or(1, |d| match d.map {
            CacheMap::Ize => 0,
            CacheMap::Demarle | CacheMap::Lru => 1,
        });
        let colored = attrs.words > 0;
        let mut constants = Constants::default();
        constants
            .flag(Override::Dc, dc.is_some())
            .count(Override::NodesPerBlock, format.nodes_per_block())
            .count(Override::TrisPerBlock, format.tris_per_block())
            .count(Override::TexelsPerBlock, format.texels())
            .count(Override::AttrsPerBlock, format.attrs_per_block(attrs.words))
            .count(Override::AttrWords, attrs.words.max(1))
            .count(Override::DeferSlots, slots)
            .count(Override::DcMap, map)
            .count(Override::RowTableWidth, super::row_table::WIDTH)
            .flag(Override::Colored, colored)
            .flag(Override::BlockCounts, settings.block_counts);
        store.set_constants(&mut constants);
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
            None => (None, DcBuffers::placeholder(gpu), true),
            Some(d) => {
                let blocks = (blocks, model.node_blocks);
                let (dc, bufs, fits) = Dc::new(gpu, d, &rows, settings, blocks, &mut params)?;
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
            spare_pixels: Vec::new(),
        };
        tracer.bound = tracer.bind_kernels();
        if fits {
            tracer.add_spare_lanes()?;
        }
        Ok(tracer)
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

    /// Hands a finished frame's pixels back, to be written over by the next rectangle of as many
    /// pixels (every pixel of a rectangle is written by its batches' read-backs).
    pub fn recycle_pixels(&mut self, pixels: Vec<Pixel>) {
        self.spare_pixels = pixels;
    }

    /// The pixels for a rectangle of `n` pixels: the recycled ones when they are as many, else
    /// zeroed.
    pub(super) fn take_pixels(&mut self, n: usize) -> Vec<Pixel> {
        match std::mem::take(&mut self.spare_pixels) {
            spare if spare.len() == n => spare,
            _ => Pixel::zeroed_vec(n),
        }
    }

    /// Turns the block counts of every following frame on or off (`Settings::block_counts`);
    /// the kernels are rebuilt when it changes.
    pub fn set_block_counts(&mut self, on: bool) {
        if on != self.settings.block_counts {
            self.settings.block_counts = on;
            self.constants.flag(Override::BlockCounts, on);
            self.rebuild_kernels();
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
        let mut pixels = self.take_pixels(rect.pixels());
        let mut first = 0;
        let mut passed = 0u64;
        while first < tiles {
            let n_tiles = tiles_per_batch.min(tiles - first);
            self.params.first_tile = first;
            self.params.batch_rays = n_tiles * TILE_RAYS;
            self.sample_batch(basis, &mut passed, passes, stats)?;
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
            stats.fault_round_bound = dc.policy.fault_round_bound(&dc.looked_up);
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
