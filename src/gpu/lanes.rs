//! Lanes (docs/ARCHITECTURE.md, Overlapping batches): the sets of batch buffers a tracer traces
//! batches in, each with its parameter buffer and the kernels' bind groups over its buffers.
//! Lane 0 is the current one (`Tracer::batch`); with a cache, spare lanes hold the batches that
//! overlap it.

use super::batch::{Batch, Lists, TILE_RAYS};
use super::kernels::{Bound, Kernels};
use super::layout::Params;
use super::tracer::{MIN_FIT_PIXELS, OverlapMode, Tracer};
use crate::dc::CacheMap;
use crate::error::Result;
use std::mem::size_of;

/// The kernels' bind groups over this tracer's buffers.
pub(super) struct BoundKernels {
    /// Read no list; append to list 0.
    pub traverse_first: Bound,
    pub traverse_spawn: Option<Bound>,
    pub spawn: Option<Bound>,
    /// Reads list 0, which `spawn` fills; appends to list 1.
    pub traverse_listed: Option<Bound>,
    /// Indexed by the live list the round reads.
    pub traverse: [Bound; 2],
    pub traverse_suspending: Option<[Bound; 2]>,
    pub args: [Bound; 2],
    pub requesters: Bound,
    pub shade: Bound,
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
/// (`density::FaultDensity`), up to the lane's size. Two rather than four: twice the lanes in the
/// same memory let a batch start every round (`scheduler::fill_share`; rm 3M at 1/32, rank 0 of 8:
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

impl Tracer<'_> {
    /// With a cache and `Settings::overlap_batches`, allocates the spare lanes once and commits
    /// their memory: when the tracer is made if the cache holds every borrowed block, else after
    /// the first frame that took several batches for one rectangle (so outside a frame's time,
    /// and never for a cluster rank whose tiles are one batch each).
    pub(super) fn add_spare_lanes(&mut self) -> Result<()> {
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

    /// The batch buffers, parameter buffer and bind groups of lane `l`: 0 is the current lane,
    /// 1.. the spares (`Tracer::swap_lanes`).
    pub(super) fn lane(&self, l: usize) -> (&Batch, &wgpu::Buffer, &BoundKernels) {
        match l.checked_sub(1).and_then(|i| self.spares.get(i)) {
            Some(s) => (&s.batch, &s.params_buf, &s.bound),
            None => (&self.batch, &self.params_buf, &self.bound),
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

    pub(super) fn bind_kernels(&self) -> BoundKernels {
        let k = &self.kernels;
        let gpu = self.gpu;
        let with = |lists: Lists| move |name: &str| self.resource(name, lists);
        let fill = Lists::FILL_FIRST;
        let each = |kernel: &super::kernels::Kernel| {
            [0, 1].map(|input| kernel.bind(gpu, with(Lists { input })))
        };
        BoundKernels {
            traverse_first: k.traverse_first.bind(gpu, with(fill)),
            traverse: each(&k.traverse),
            traverse_suspending: k.traverse_suspending.as_ref().map(each),
            args: each(&k.args),
            requesters: k.requesters.bind(gpu, with(fill)),
            shade: k.shade.bind(gpu, with(fill)),
            traverse_spawn: k.traverse_spawn.as_ref().map(|s| s.bind(gpu, with(fill))),
            spawn: k.spawn.as_ref().map(|s| s.bind(gpu, with(fill))),
            traverse_listed: (k.traverse_listed.as_ref())
                .map(|t| t.bind(gpu, with(Lists { input: 0 }))),
            gather: k.gather.as_ref().map(|g| g.bind(gpu, with(fill))),
            albedo: k.albedo.as_ref().map(|a| a.bind(gpu, with(fill))),
        }
    }

    /// Builds the kernels for the settings' shading mode and `constants`, and binds them in every
    /// lane.
    pub(super) fn rebuild_kernels(&mut self) {
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
}

impl BoundKernels {
    /// Stands in until the tracer that owns the buffers exists.
    pub(super) fn placeholder() -> BoundKernels {
        BoundKernels {
            traverse_first: Bound::empty(),
            traverse: [Bound::empty(), Bound::empty()],
            traverse_suspending: None,
            args: [Bound::empty(), Bound::empty()],
            requesters: Bound::empty(),
            shade: Bound::empty(),
            traverse_spawn: None,
            spawn: None,
            traverse_listed: None,
            gather: None,
            albedo: None,
        }
    }
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
}
