//! Arbitrary rays (tests, tools, secondary rays from the host) through the same traversal kernel and
//! round loop as rendering.

use super::frame::FrameStats;
use super::kernels::Dispatch;
use super::layout::{Counter, FAR, NONE, RayState, flags, status};
use super::tracer::Tracer;
use crate::error::Result;
use crate::scene::ray::Ray;

impl Tracer<'_> {
    /// Traces arbitrary rays (tests, tools, secondary rays from the host) through the same trace
    /// kernel and round loop as rendering, in batches of at most `batch_rays()` rays; returns
    /// each ray's closest hit with `t` in `(0, tmax)`, in units of the direction's length.
    ///
    /// A ray with a NaN or infinite origin or direction component, a zero direction, or a `tmax`
    /// that is NaN or not positive is a miss (the traversal kernel checks, so rays made on the GPU
    /// get the same treatment). `tmax = +inf` means no limit (the kernel's `FAR`, 3e38).
    ///
    /// The rays are taken to leave surfaces (spawned rays): a hit must be proven in front of
    /// the origin despite rounding. [`Tracer::trace_camera_rays`] traces rays that leave none.
    pub fn trace_rays(&mut self, rays: &[Ray]) -> Result<Vec<Option<RayHit>>> {
        self.trace_rays_flagged(rays, 0)
    }

    /// [`Tracer::trace_rays`] for rays from a camera, on no surface, as a batch's first round
    /// makes them (`camera_ray` in shaders/shared/camera.wgsl).
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
                .dispatch(&mut enc, args, Dispatch::Over(1), None);
            self.run_rounds(enc, 0, None, &mut stats)?;
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
