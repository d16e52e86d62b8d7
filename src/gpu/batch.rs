//! The buffers of one batch of rays (docs/ARCHITECTURE.md, The round loop): ray states and their
//! stacks, the two live lists and counters that rounds alternate between, statistics, pixels,
//! path states, and the buffers the host reads back through.

use super::Gpu;
use super::layout::{Counter, FaultHeader, Path, Pixel, RayState, RoundReadback, Stats};
use crate::error::{Error, Result};
use std::mem::size_of;

/// 8x8 tiles of rays.
pub const TILE_RAYS: u32 = crate::mirror::tiles::TILE * crate::mirror::tiles::TILE;
/// Bytes of one traversal stack entry: the index, and the entry distance with the count in its
/// low bits (traverse.wgsl, pack_entry).
const STACK_ENTRY_BYTES: u64 = 8;

pub struct Batch {
    /// Rays a batch holds (whole tiles).
    pub rays_cap: u32,
    pub rays: wgpu::Buffer,
    stacks: wgpu::Buffer,
    /// Live lists and their counters: a round reads one pair and appends to the other.
    pub live: [wgpu::Buffer; 2],
    pub counters: [wgpu::Buffer; 2],
    pub stats: wgpu::Buffer,
    pub pixels: wgpu::Buffer,
    paths: wgpu::Buffer,
    /// Colour by data: the albedo of each ray slot's hit (a placeholder without attributes).
    pub albedos: wgpu::Buffer,
    /// A `RoundReadback`.
    pub readback: wgpu::Buffer,
    /// Two GPU timestamps around each submission's traversal rounds, and their resolve buffer.
    pub timestamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
    /// A `FaultHeader` and the fault list; per cache line the waiting rays, then `line_used`'s
    /// two halves (used, kept).
    pub fault_readback: wgpu::Buffer,
    pub waiter_readback: wgpu::Buffer,
    pub pixel_readback: wgpu::Buffer,
}

/// Which live list a kernel reads (`live_in`, `counter_in`, `produced`); it appends to the
/// other (`live_out`, `counter_out`, `consumed`). Ray generation and spawning write list 0.
#[derive(Clone, Copy, Debug)]
pub struct Lists {
    pub input: usize,
}

impl Lists {
    /// For kernels that fill list 0 from nothing.
    pub const FILL_FIRST: Lists = Lists { input: 1 };

    fn output(self) -> usize {
        1 - self.input
    }
}

/// Bytes of the fault list for `cap` blocks: the header, the blocks (`request` in
/// shaders/shared/dc.wgsl), then each block's least requester (shaders/requesters.wgsl).
pub fn fault_bytes(cap: u32) -> u64 {
    size_of::<FaultHeader>() as u64 + 8 * u64::from(cap)
}

impl Batch {
    /// Allocates per-batch buffers as large as `max_rays` and the adapter's limits allow.
    pub fn new(
        gpu: &Gpu,
        stack_size: u32,
        max_rays: u32,
        lines: u32,
        fault_cap: u32,
        albedos: bool,
    ) -> Result<Batch> {
        let limit = gpu.storage_limit();
        let ray_bytes = size_of::<RayState>() as u64;
        let path_bytes = size_of::<Path>() as u64;
        let pixel_bytes = size_of::<Pixel>() as u64;
        let per_ray_max = (u64::from(stack_size) * STACK_ENTRY_BYTES)
            .max(ray_bytes)
            .max(path_bytes);
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
        let rays_buf = gpu.buffer(
            "rays",
            n * ray_bytes,
            U::STORAGE | U::COPY_SRC | U::COPY_DST,
        );
        let stacks = gpu.buffer(
            "stacks",
            n * u64::from(stack_size) * STACK_ENTRY_BYTES,
            U::STORAGE | U::COPY_DST,
        );
        let live = [
            gpu.buffer("live0", n * 4, U::STORAGE | U::COPY_DST),
            gpu.buffer("live1", n * 4, U::STORAGE | U::COPY_DST),
        ];
        let counter_usage = U::STORAGE | U::INDIRECT | U::COPY_SRC | U::COPY_DST;
        let counter_bytes = size_of::<Counter>() as u64;
        let counters = [
            gpu.buffer("counter0", counter_bytes, counter_usage),
            gpu.buffer("counter1", counter_bytes, counter_usage),
        ];
        let stats = gpu.buffer(
            "stats",
            size_of::<Stats>() as u64,
            U::STORAGE | U::COPY_SRC | U::COPY_DST,
        );
        let pixels = gpu.buffer(
            "pixels",
            n * pixel_bytes,
            U::STORAGE | U::COPY_SRC | U::COPY_DST,
        );
        let readback = gpu.buffer(
            "readback",
            size_of::<RoundReadback>() as u64,
            U::MAP_READ | U::COPY_DST,
        );
        let paths = gpu.buffer("paths", n * path_bytes, U::STORAGE | U::COPY_DST);
        // Only models coloured by data have attribute blocks to resolve hits' albedos from.
        let albedo_bytes = if albedos { n * 16 } else { 16 };
        let albedos = gpu.buffer("albedos", albedo_bytes, U::STORAGE | U::COPY_DST);
        let fault_readback = gpu.buffer(
            "fault readback",
            fault_bytes(fault_cap),
            U::MAP_READ | U::COPY_DST,
        );
        let waiter_readback = gpu.buffer(
            "waiter readback",
            12 * u64::from(lines),
            U::MAP_READ | U::COPY_DST,
        );
        let pixel_readback =
            gpu.buffer("pixel readback", n * pixel_bytes, U::MAP_READ | U::COPY_DST);
        let timestamps = gpu
            .features
            .contains(wgpu::Features::TIMESTAMP_QUERY)
            .then(|| {
                let q = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("round timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                });
                let resolve = gpu.buffer("timestamps", 16, U::QUERY_RESOLVE | U::COPY_SRC);
                (q, resolve)
            });
        Ok(Batch {
            rays_cap,
            rays: rays_buf,
            stacks,
            live,
            counters,
            stats,
            pixels,
            paths,
            albedos,
            readback,
            timestamps,
            fault_readback,
            waiter_readback,
            pixel_readback,
        })
    }

    /// Clears the per-ray buffers, so that their memory is committed now rather than by the
    /// first batch that uses them (about 80 ms for a lavapipe batch of 128 MiB of stacks).
    pub fn commit(&self, enc: &mut wgpu::CommandEncoder) {
        let per_ray = [
            &self.rays,
            &self.stacks,
            &self.pixels,
            &self.paths,
            &self.albedos,
        ];
        for b in per_ray.into_iter().chain(&self.live) {
            enc.clear_buffer(b, 0, None);
        }
    }

    /// Bytes of the batch's buffers (GPU and read-back).
    pub fn bytes(&self) -> u64 {
        let mut all = vec![
            &self.rays,
            &self.stacks,
            &self.stats,
            &self.pixels,
            &self.paths,
        ];
        all.extend([&self.albedos, &self.readback, &self.fault_readback]);
        all.extend([&self.waiter_readback, &self.pixel_readback]);
        all.extend(self.live.iter().chain(&self.counters));
        all.iter().map(|b| b.size()).sum()
    }

    /// The batch buffer bound to WGSL variable `name` (group 1 of the kernels).
    pub fn resource(&self, name: &str, lists: Lists) -> Option<&wgpu::Buffer> {
        let (i, o) = (lists.input, lists.output());
        Some(match name {
            "rays" => &self.rays,
            "stacks" => &self.stacks,
            "live_in" => &self.live[i],
            "counter_in" | "produced" => &self.counters[i],
            "live_out" => &self.live[o],
            "counter_out" | "consumed" => &self.counters[o],
            "stats" => &self.stats,
            "pixels" => &self.pixels,
            "paths" => &self.paths,
            "albedos" => &self.albedos,
            _ => return None,
        })
    }
}
