//! The single-process pipeline: scene → model → BVH → blocks → GPU frame.

use crate::blocks::{Blocks, Format};
use crate::bvh::{Bvh, Preset};
use crate::error::Result;
use crate::gpu::Gpu;
use crate::gpu::tracer::{Frame, FrameStats, Settings, Tracer};
use crate::scene::{Camera, Model, Scene};
use std::time::Instant;

/// A model ready for the GPU: triangles, BVH and blocks.
pub struct Prepared {
    pub model: Model,
    pub bvh: Bvh,
    pub blocks: Blocks,
    pub load_seconds: f64,
}

impl Prepared {
    pub fn new(scene: &Scene, preset: Preset, format: Format) -> Result<Prepared> {
        let t = Instant::now();
        let model = scene.load_model()?;
        let load_seconds = t.elapsed().as_secs_f64();
        Prepared::from_model(model, preset, format, load_seconds)
    }

    pub fn from_model(
        model: Model,
        preset: Preset,
        format: Format,
        load_seconds: f64,
    ) -> Result<Prepared> {
        let bvh = Bvh::build(&model, preset, format.nodes_per_block() as usize);
        let blocks = Blocks::pack(&bvh, format)?;
        Ok(Prepared {
            model,
            bvh,
            blocks,
            load_seconds,
        })
    }

    pub fn tracer<'g>(&self, gpu: &'g Gpu, settings: Settings) -> Result<Tracer<'g>> {
        Tracer::new(gpu, &self.blocks, &self.model, self.bvh.depth, settings)
    }
}

/// Renders one frame of `camera` at `width` x `height`.
pub fn render_frame(
    tracer: &mut Tracer<'_>,
    camera: &Camera,
    width: u32,
    height: u32,
    background: [f32; 3],
) -> Result<(Frame, FrameStats)> {
    tracer.render(&camera.basis(width, height), background)
}
