//! The shading stage (docs/ARCHITECTURE.md, The GPU side): a traced batch's hits resolved to
//! albedos (colour by data), shaded, with waves of secondary rays for the modes that have them,
//! and its pixels read back into the rectangle's.

use super::batch::TILE_RAYS;
use super::frame::{FrameStats, Rect};
use super::kernels::{Bound, Dispatch, Kernel};
use super::layout::{Pixel, flags};
use super::rounds::Gen;
use super::tracer::Tracer;
use crate::error::Result;
use crate::mirror::tiles::{Tiling, tile_corner, z_x};
use crate::scene::CameraBasis;
use crate::shading::{Mode, Sampler, Shading};
use std::mem::size_of;
use std::time::Instant;

/// `Params::flags` for sample `s` (counted from the rectangle's first) of a shading setup.
pub(super) fn sample_flags(sh: Shading, basis: &CameraBasis, s: u32) -> u32 {
    (if sh.part_of_spp.unwrap_or(sh.spp) > 1 {
        flags::JITTER
    } else {
        0
    }) | if sh.cull { flags::CULL } else { 0 }
        | if s == 0 { flags::FIRST_SAMPLE } else { 0 }
        | match sh.sampler {
            Sampler::Sobol => 0,
            Sampler::Independent => flags::SAMPLER_INDEPENDENT,
        }
        | if basis.parallel { flags::PARALLEL } else { 0 }
}

impl Tracer<'_> {
    /// Every sample pass of the current batch (`Params::first_tile`, `batch_rays`): its primary
    /// rays traced and shaded, then, for modes with secondary rays, waves of `spawn`, trace
    /// rounds and `gather`. `passed` of `passes` counts the passes for the progress callback.
    pub(super) fn sample_batch(
        &mut self,
        basis: &CameraBasis,
        passed: &mut u64,
        passes: u64,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let sh = self.settings.shading;
        let (fan, waves) = (sh.fan(), sh.waves());
        for s in 0..sh.spp {
            self.params.sample = sh.first_sample + s;
            self.params.flags = sample_flags(sh, basis, s);
            let t = Instant::now();
            self.params.albedo_stride = 1;
            let traced = self.traverse_batch(stats, Gen::Primary)?;
            stats.traced_rays += u64::from(traced.started);
            let t2 = Instant::now();
            stats.trace_seconds += (t2 - t).as_secs_f64();
            self.resolve_albedos(stats)?;
            if !self.all_shaded(traced.opened) {
                self.run(&self.kernels.shade, &self.bound.shade);
            }
            // A path goes on only from a hit: when the rays before a wave found none (a batch
            // of sky, bounces that all left the model), the wave and those after it are not
            // traced (`Stats::closest_hits`).
            let mut closest_hits = traced.closest_hits;
            for wave in 0..waves {
                if closest_hits == 0 {
                    break;
                }
                let t = Instant::now();
                self.params.albedo_stride = fan;
                let gen_ = if wave < self.settings.spawned_waves_from {
                    Gen::Secondary { fan }
                } else {
                    Gen::Spawned { fan }
                };
                let traced = self.traverse_batch(stats, gen_)?;
                let live = traced.started;
                closest_hits = traced.closest_hits;
                stats.trace_seconds += t.elapsed().as_secs_f64();
                // Only path tracing shades the hits of secondary rays.
                if sh.mode == Mode::Path {
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
            *passed += 1;
            if let Some(p) = self.progress.as_mut() {
                p(*passed, passes);
            }
        }
        Ok(())
    }

    /// Whether a batch's first round of primary rays wrote every pixel: it shades the rays that
    /// end in it (`first_round_shades` in shaders/shared/pixel.wgsl: cast mode, no colour by
    /// data) and left `opened` rays live.
    pub(super) fn all_shaded(&self, opened: Option<u32>) -> bool {
        self.settings.shading.mode == Mode::Cast
            && self.kernels.albedo.is_none()
            && opened == Some(0)
    }

    /// Resolves albedos, shades (unless the first round shaded every ray: `opened`, `all_shaded`)
    /// and reads back the current lane's traced batch.
    pub(super) fn shade_batch(
        &mut self,
        (first, tiles): (u32, u32),
        place: (Rect, Tiling),
        opened: Option<u32>,
        pixels: &mut [Pixel],
        stats: &mut FrameStats,
    ) -> Result<()> {
        self.resolve_albedos(stats)?;
        if !self.all_shaded(opened) {
            self.run(&self.kernels.shade, &self.bound.shade);
        }
        self.read_pixels(first, tiles, place, 1, pixels)?;
        stats.batches += 1;
        Ok(())
    }

    /// Colour by data: the albedo of every hit on a mesh coloured by data, from the attribute
    /// blocks, for the ray slots `Params::albedo_stride` names (docs/ARCHITECTURE.md, Colour by
    /// data). With a distributed cache an absent attribute block is a fault: the round's faults
    /// are served as the traversal rounds' are and the kernel runs again, skipping the slots already
    /// resolved, until a dispatch faults on nothing. A model without attributes does nothing.
    pub(super) fn resolve_albedos(&mut self, stats: &mut FrameStats) -> Result<()> {
        if self.kernels.albedo.is_none() {
            return Ok(());
        }
        let gpu = self.gpu;
        gpu.write(&self.params_buf, &self.params);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.batch.albedos, 0, None);
        for round in 0.. {
            self.clear_faults(&mut enc);
            if let (Some(k), Some(b)) = (&self.kernels.albedo, &self.bound.albedo) {
                k.dispatch(&mut enc, b, Dispatch::Over(self.params.batch_rays), None);
            }
            let Some(dc) = &self.dc else {
                gpu.queue.submit([enc.finish()]);
                return Ok(());
            };
            let wait_bytes = 4 * u64::from(dc.policy.lines());
            self.copy_faults(&mut enc);
            let submitted = Instant::now();
            gpu.queue.submit([enc.finish()]);
            let faults = self.read_faults()?;
            let waiters = gpu.map_read(&self.batch.waiter_readback)?;
            let waited = submitted.elapsed();
            let when = (submitted, waited, None);
            if faults.header.count == 0 {
                // Nothing to load; this counts the blocks the dispatch found in lines.
                return self
                    .serve_faults(&faults, &waiters, 0, round, when, stats)
                    .map(drop);
            }
            let waiting: u32 =
                bytemuck::pod_collect_to_vec::<u8, u32>(&waiters[..wait_bytes as usize])
                    .iter()
                    .sum();
            self.serve_faults(&faults, &waiters, waiting, round, when, stats)?;
            enc = gpu.device.create_command_encoder(&Default::default());
        }
        Ok(())
    }

    /// Submits one direct dispatch of a shading kernel over the batch's pixel slots (no wait).
    pub(super) fn run(&self, kernel: &Kernel, bound: &Bound) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let groups = Dispatch::Over(self.params.batch_rays);
        kernel.dispatch(&mut enc, bound, groups, None);
        self.gpu.queue.submit([enc.finish()]);
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
        // Tile by tile, each slot's place from its tile's corner and its Z-order offset, each
        // pixel read in place from the mapped buffer (mapped bytes carry no alignment promise:
        // unaligned): half the host's time of a copy of the batch and `tile_pixel`'s divisions
        // for every slot (about 1.5 against 3 ms a batch of 350k pixels).
        let px = size_of::<Pixel>();
        let offsets: [(u32, u32); TILE_RAYS as usize] =
            std::array::from_fn(|l| (z_x(l as u32), z_x(l as u32 >> 1)));
        gpu.with_mapped(&b.pixel_readback, bytes, |data| {
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
        })?;
        Ok(())
    }
}
