//! The single-process pipeline: scene → model → BVH → blocks → GPU frame, or a prepared block
//! file → GPU frame.

use crate::blocks::file::{DcbFile, Meta};
use crate::blocks::{Blocks, Format};
use crate::bvh::{Bvh, Preset};
use crate::dc::source::VirtualRanks;
use crate::dc::{CacheMap, CacheSize, Ranks};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::gpu::tracer::{DcSetup, Frame, FrameStats, GpuModel, Meshes, Settings, Tracer};
use crate::scene::{Camera, Model, Scene};
use std::path::Path;
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

    pub fn meshes(&self) -> Meshes {
        Meshes {
            first_prim: self.model.mesh_first.clone(),
            colors: self.model.colors.clone(),
        }
    }

    pub fn tracer<'g>(&self, gpu: &'g Gpu, settings: Settings) -> Result<Tracer<'g>> {
        tracer(
            gpu,
            &self.blocks,
            &self.meshes(),
            self.bvh.depth,
            settings,
            None,
        )
    }

    /// A tracer for one virtual rank of a distributed cache.
    pub fn tracer_dc<'g>(
        &self,
        gpu: &'g Gpu,
        settings: Settings,
        dc: &DcOptions,
    ) -> Result<Tracer<'g>> {
        tracer(
            gpu,
            &self.blocks,
            &self.meshes(),
            self.bvh.depth,
            settings,
            Some(dc),
        )
    }

    /// The block file's metadata for this model seen with `camera` at `width` x `height`.
    pub fn meta(&self, scene: &Scene, camera: Camera, width: u32, height: u32) -> Meta {
        Meta {
            camera,
            width,
            height,
            background: scene.background,
            mesh_first: self.model.mesh_first.clone(),
            colors: self.model.colors.clone(),
            triangles: self.model.triangles.len() as u64,
            nodes: self.bvh.nodes.len() as u64,
            bvh_depth: self.bvh.depth,
            bounds_min: self.model.bounds.min,
            bounds_max: self.model.bounds.max,
            source: scene.path.display().to_string(),
        }
    }
}

/// What a render needs, from a scene (built now) or a block file (built before).
pub struct Loaded {
    pub blocks: Blocks,
    pub meshes: Meshes,
    pub depth: u32,
    pub triangles: u64,
    pub camera: Camera,
    pub width: u32,
    pub height: u32,
    pub background: [f32; 3],
    /// BVH build and layout time when built now.
    pub build_seconds: Option<f64>,
}

impl Loaded {
    /// Loads `path`: a `.dcb` block file, a scene naming one with `model = "..."`, or a scene of
    /// meshes, prepared on the fly.
    pub fn open(path: &Path, preset: Preset, format: Format) -> Result<Loaded> {
        if path.extension().is_some_and(|e| e == "dcb") {
            return Loaded::from_dcb(path, None);
        }
        let scene = Scene::load(path)?;
        if let Some(model) = &scene.model {
            let dcb = path.parent().unwrap_or(Path::new(".")).join(model);
            return Loaded::from_dcb(&dcb, Some(&scene));
        }
        let p = Prepared::new(&scene, preset, format)?;
        let camera = scene.camera_or_default(&p.model);
        Ok(Loaded {
            meshes: p.meshes(),
            depth: p.bvh.depth,
            triangles: p.model.triangles.len() as u64,
            camera,
            width: scene.width,
            height: scene.height,
            background: scene.background,
            build_seconds: Some((p.bvh.build_time + p.bvh.layout_time).as_secs_f64()),
            blocks: p.blocks,
        })
    }

    /// A block file; a scene naming it may override the camera, image size and background.
    pub fn from_dcb(path: &Path, scene: Option<&Scene>) -> Result<Loaded> {
        let f = DcbFile::open(path)?;
        let m = &f.meta;
        if m.mesh_first.len() != m.colors.len() || m.mesh_first.first() != Some(&0) {
            return Err(Error::format(
                path,
                None,
                "metadata: inconsistent mesh table",
            ));
        }
        let blocks = f.read_all()?;
        let (camera, width, height, background) = match scene {
            Some(s) => (
                s.camera.unwrap_or(m.camera),
                if s.image_given { s.width } else { m.width },
                if s.image_given { s.height } else { m.height },
                s.background,
            ),
            None => (m.camera, m.width, m.height, m.background),
        };
        Ok(Loaded {
            meshes: Meshes {
                first_prim: m.mesh_first.clone(),
                colors: m.colors.clone(),
            },
            depth: m.bvh_depth,
            triangles: m.triangles,
            camera,
            width,
            height,
            background,
            build_seconds: None,
            blocks,
        })
    }

    pub fn tracer<'g>(
        &self,
        gpu: &'g Gpu,
        settings: Settings,
        dc: Option<&DcOptions>,
    ) -> Result<Tracer<'g>> {
        tracer(gpu, &self.blocks, &self.meshes, self.depth, settings, dc)
    }
}

/// How one process runs the distributed cache: `ranks` virtual ranks in one process, rendering
/// as `rank`, with a cache of `cache` and the `map` mapping.
#[derive(Clone, Copy, Debug)]
pub struct DcOptions {
    pub ranks: u32,
    pub rank: u32,
    pub cache: CacheSize,
    pub map: CacheMap,
}

/// Memory a rank holds for the model: its resident blocks (own + root) and its cache.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct RankMemory {
    pub resident_bytes: u64,
    pub cache_bytes: u64,
}

impl DcOptions {
    pub fn memory(&self, blocks: &Blocks) -> Result<RankMemory> {
        let ranks = Ranks::new(self.ranks, self.rank)?;
        let bb = u64::from(blocks.format.block_bytes);
        let resident = u64::from(ranks.owned(blocks.count()) + u32::from(!ranks.owns(0)));
        Ok(RankMemory {
            resident_bytes: resident * bb,
            cache_bytes: u64::from(self.cache.lines(blocks.count(), blocks.format.block_bytes))
                * bb,
        })
    }
}

fn tracer<'g>(
    gpu: &'g Gpu,
    blocks: &Blocks,
    meshes: &Meshes,
    depth: u32,
    settings: Settings,
    dc: Option<&DcOptions>,
) -> Result<Tracer<'g>> {
    let base = GpuModel {
        format: blocks.format,
        node_blocks: blocks.node_blocks,
        tri_blocks: blocks.tri_blocks,
        resident: &blocks.words,
        meshes,
        depth,
    };
    match dc {
        None => Tracer::new(gpu, &base, settings, None),
        Some(o) => {
            let ranks = Ranks::new(o.ranks, o.rank)?;
            let stores = VirtualRanks::new(blocks, o.ranks)?;
            let resident = stores.resident_rows(o.rank);
            let lines = o.cache.lines(blocks.count(), blocks.format.block_bytes);
            let model = GpuModel {
                resident: &resident,
                ..base
            };
            let setup = DcSetup {
                ranks,
                lines,
                map: o.map,
                source: Box::new(stores),
            };
            Tracer::new(gpu, &model, settings, Some(setup))
        }
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
