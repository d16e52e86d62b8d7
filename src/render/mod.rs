//! The single-process pipeline: scene → model → BVH → blocks → GPU frame, or a prepared block
//! file → GPU frame; `frames` is the loop over a sequence of frames.

pub mod frames;
pub mod memory;

use crate::blocks::file::{DcbFile, Meta};
use crate::blocks::ranks::Ranks;
use crate::blocks::{Blocks, Format};
use crate::bvh::{Build, Bvh};
use crate::dc::source::{LocalFile, VirtualRanks};
use crate::dc::{CacheMap, CacheSize, Replicate};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::gpu::tracer::{DcSetup, GpuModel, Meshes, Settings, Tracer};
use crate::scene::{Camera, Model, Scene};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A model ready for the GPU: triangles, BVH and blocks.
pub struct Prepared {
    pub model: Model,
    pub bvh: Bvh,
    pub blocks: Blocks,
    pub load_seconds: f64,
}

impl Prepared {
    pub fn new(scene: &Scene, build: Build, format: Format) -> Result<Prepared> {
        memory::check_generators(scene)?;
        let t = Instant::now();
        let model = scene.load_model()?;
        let load_seconds = t.elapsed().as_secs_f64();
        Prepared::from_model(model, build, format, load_seconds)
    }

    pub fn from_model(
        model: Model,
        build: Build,
        format: Format,
        load_seconds: f64,
    ) -> Result<Prepared> {
        let bvh = Bvh::build(&model, build, format.nodes_per_block() as usize);
        let mut blocks = Blocks::pack(&bvh, format)?;
        if let Some(a) = &model.attributes {
            blocks = blocks.with_attributes(&bvh, a)?;
        }
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
            looks: self.model.looks.clone(),
        }
    }

    /// A tracer for the replicated model.
    pub fn tracer<'g>(&self, gpu: &'g Gpu, settings: Settings) -> Result<Tracer<'g>> {
        self.tracer_with(gpu, settings, None)
    }

    /// A tracer for one virtual rank of a distributed cache.
    pub fn tracer_dc<'g>(
        &self,
        gpu: &'g Gpu,
        settings: Settings,
        dc: &DcOptions,
    ) -> Result<Tracer<'g>> {
        self.tracer_with(gpu, settings, Some(dc))
    }

    /// A tracer for the replicated model (`dc` None), or for one virtual rank.
    pub fn tracer_with<'g>(
        &self,
        gpu: &'g Gpu,
        settings: Settings,
        dc: Option<&DcOptions>,
    ) -> Result<Tracer<'g>> {
        let meshes = self.meshes();
        tracer(gpu, &self.blocks, &meshes, self.bvh.depth, settings, dc)
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
            looks: self.model.looks.clone(),
            attrs: self.blocks.attrs,
        }
    }
}

/// Where a render's blocks are: built now, or in a block file that each rank reads its own part
/// of.
pub enum BlocksAt {
    Built(Blocks),
    File(Box<DcbFile>),
}

/// What a render needs, from a scene (built now) or a block file (built before).
pub struct Loaded {
    pub source: BlocksAt,
    pub meshes: Meshes,
    pub depth: u32,
    pub triangles: u64,
    pub camera: Camera,
    pub width: u32,
    pub height: u32,
    pub background: [f32; 3],
    /// The scene's shading settings (defaults for a bare block file).
    pub shading: crate::shading::Shading,
    /// BVH build and layout time when built now.
    pub build_seconds: Option<f64>,
}

impl Loaded {
    /// Loads `path`: a `.dcb` block file, a scene naming one with `model = "..."`, or a scene of
    /// meshes, prepared on the fly. A block file holds the tree and blocks it was prepared with:
    /// another `build` or `format` for one is an error, not ignored.
    pub fn open(path: &Path, build: Build, format: Format) -> Result<Loaded> {
        let scene = match Input::resolve(path)? {
            Input::Dcb(dcb, scene) => {
                if build != Build::default() || format != Format::default() {
                    return Err(Error::Invalid(format!(
                        "{}: a block file holds the BVH and blocks it was prepared with; \
                         --bvh-preset, --bvh-node-cost and --block-size apply to scenes (give \
                         them to `dcrt prepare`)",
                        dcb.display()
                    )));
                }
                return Loaded::from_dcb(&dcb, scene.as_ref());
            }
            Input::Scene(scene) => scene,
        };
        let p = Prepared::new(&scene, build, format)?;
        let camera = scene.camera_or_default(&p.model);
        Ok(Loaded {
            meshes: p.meshes(),
            depth: p.bvh.depth,
            triangles: p.model.triangles.len() as u64,
            camera,
            width: scene.width,
            height: scene.height,
            background: scene.background,
            shading: scene.shading,
            build_seconds: Some((p.bvh.build_time + p.bvh.layout_time).as_secs_f64()),
            source: BlocksAt::Built(p.blocks),
        })
    }

    /// A block file; a scene naming it may override the camera, image size and background.
    /// Only the header, metadata and checksums are read here: blocks are read by `tracer`.
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
                looks: m.looks.clone(),
            },
            depth: m.bvh_depth,
            triangles: m.triangles,
            camera,
            width,
            height,
            background,
            shading: scene.map(|s| s.shading).unwrap_or_default(),
            build_seconds: None,
            source: BlocksAt::File(Box::new(f)),
        })
    }

    pub fn format(&self) -> Format {
        match &self.source {
            BlocksAt::Built(b) => b.format,
            BlocksAt::File(f) => f.format,
        }
    }

    pub fn block_count(&self) -> u32 {
        match &self.source {
            BlocksAt::Built(b) => b.count(),
            BlocksAt::File(f) => f.count(),
        }
    }

    pub fn node_blocks(&self) -> u32 {
        match &self.source {
            BlocksAt::Built(b) => b.node_blocks,
            BlocksAt::File(f) => f.node_blocks,
        }
    }

    pub fn model_bytes(&self) -> u64 {
        u64::from(self.block_count()) * u64::from(self.format().block_bytes)
    }

    /// A tracer for the whole model, or for one rank of a distributed cache. From a block file,
    /// a rank reads only its own blocks and the replicated ones; borrowed blocks are read from
    /// the file when they fault.
    pub fn tracer<'g>(
        &self,
        gpu: &'g Gpu,
        settings: Settings,
        dc: Option<&DcOptions>,
    ) -> Result<Tracer<'g>> {
        let f = match &self.source {
            BlocksAt::Built(b) => return tracer(gpu, b, &self.meshes, self.depth, settings, dc),
            BlocksAt::File(f) => f,
        };
        let Some(o) = dc else {
            let blocks = f.read_all(1)?;
            return tracer(gpu, &blocks, &self.meshes, self.depth, settings, None);
        };
        let ranks = o.ranks(f.node_blocks)?;
        let resident = f.read_resident(ranks)?;
        let setup = DcSetup {
            ranks,
            lines: o.lines(f.count(), f.format),
            map: o.map,
            source: Box::new(LocalFile::new(DcbFile::open(&f.path)?, ranks)),
        };
        self.dc_tracer(gpu, settings, &resident, setup)
    }
}

impl Loaded {
    /// The blocks rank `ranks.rank` keeps on its GPU without a cache, in row order: its own
    /// blocks by slot, then the replicated blocks it does not own. From a block file only these
    /// blocks are read.
    pub fn resident(&self, ranks: Ranks) -> Result<Vec<u32>> {
        match &self.source {
            BlocksAt::File(f) => f.read_resident(ranks),
            BlocksAt::Built(b) => Ok(ranks
                .resident_blocks(b.count())
                .flat_map(|k| b.block(k).iter().copied())
                .collect()),
        }
    }

    /// A tracer for one rank of a distributed cache whose borrowed blocks come from `setup`'s
    /// source; `resident` is what `resident` returned for the same ranks.
    pub fn dc_tracer<'g>(
        &self,
        gpu: &'g Gpu,
        settings: Settings,
        resident: &[u32],
        setup: DcSetup,
    ) -> Result<Tracer<'g>> {
        let (node_blocks, tri_blocks, attrs) = match &self.source {
            BlocksAt::Built(b) => (b.node_blocks, b.tri_blocks, b.attrs),
            BlocksAt::File(f) => (f.node_blocks, f.tri_blocks, f.meta.attrs),
        };
        let model = GpuModel {
            format: self.format(),
            node_blocks,
            tri_blocks,
            attrs,
            resident,
            meshes: &self.meshes,
            depth: self.depth,
        };
        Tracer::new(gpu, &model, settings, Some(setup))
    }

    /// Identifies the model: the same on every rank that has the same blocks, whether built
    /// from a scene or read from a block file.
    pub fn fingerprint(&self) -> u64 {
        let crc = match &self.source {
            BlocksAt::Built(b) => b.fingerprint(),
            BlocksAt::File(f) => f.fingerprint(),
        };
        (u64::from(crc) << 32) | u64::from(self.block_count())
    }

    /// What a path renders (image size, background, shading) without building or reading the
    /// model: what the display and the balancer need.
    pub fn image_of(path: &Path) -> Result<ImageOf> {
        let from = |l: Loaded| ImageOf {
            width: l.width,
            height: l.height,
            background: l.background,
            shading: l.shading,
        };
        let scene = match Input::resolve(path)? {
            Input::Dcb(dcb, scene) => return Loaded::from_dcb(&dcb, scene.as_ref()).map(from),
            Input::Scene(scene) => scene,
        };
        Ok(ImageOf {
            width: scene.width,
            height: scene.height,
            background: scene.background,
            shading: scene.shading,
        })
    }
}

/// The colour legend of what `path` renders (`--legend`), without building the model: from a
/// block file's metadata, or by loading only a scene's meshes that are coloured by data (their
/// ranges are all the legend needs). What a cluster's display draws.
pub fn legend_of(path: &Path) -> Result<crate::legend::Legend> {
    match Input::resolve(path)? {
        Input::Dcb(dcb, scene) => {
            let f = DcbFile::open(&dcb)?;
            let bg = scene.map_or(f.meta.background, |s| s.background);
            crate::legend::Legend::new(&f.meta.looks, bg)
        }
        Input::Scene(mut scene) => {
            scene.meshes.retain(|m| m.color_by.is_some());
            let looks = if scene.meshes.is_empty() {
                Vec::new()
            } else {
                scene.load_model()?.looks
            };
            crate::legend::Legend::new(&looks, scene.background)
        }
    }
}

/// What a render's path names: a block file, with the scene that names it if any, or a scene of
/// meshes.
enum Input {
    Dcb(PathBuf, Option<Scene>),
    Scene(Scene),
}

impl Input {
    fn resolve(path: &Path) -> Result<Input> {
        if path.extension().is_some_and(|e| e == "dcb") {
            return Ok(Input::Dcb(path.to_path_buf(), None));
        }
        let scene = Scene::load(path)?;
        Ok(match &scene.model {
            Some(model) => {
                let dcb = path.parent().unwrap_or(Path::new(".")).join(model);
                Input::Dcb(dcb, Some(scene))
            }
            None => Input::Scene(scene),
        })
    }
}

/// See `Loaded::image_of`.
#[derive(Clone, Debug)]
pub struct ImageOf {
    pub width: u32,
    pub height: u32,
    pub background: [f32; 3],
    pub shading: crate::shading::Shading,
}

/// How one process runs the distributed cache: `ranks` virtual ranks in one process, rendering
/// as `rank`, with a cache of `cache`, the `map` mapping, and `replicate` on every rank.
#[derive(Clone, Copy, Debug)]
pub struct DcOptions {
    pub ranks: u32,
    pub rank: u32,
    pub cache: CacheSize,
    pub map: CacheMap,
    pub replicate: Replicate,
}

/// Memory a rank holds for the model: its resident blocks (own + replicated) and its cache.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct RankMemory {
    pub resident_bytes: u64,
    pub cache_bytes: u64,
}

impl DcOptions {
    /// Cache lines for a model of `count` blocks.
    pub fn lines(&self, count: u32, format: Format) -> u32 {
        self.cache.lines(count, format.block_bytes)
    }

    /// This rank, with what it replicates of a model of `node_blocks` node blocks.
    pub fn ranks(&self, node_blocks: u32) -> Result<Ranks> {
        Ok(Ranks::new(self.ranks, self.rank)?.replicating(self.replicate.blocks(node_blocks)))
    }

    pub fn memory(&self, count: u32, node_blocks: u32, format: Format) -> Result<RankMemory> {
        let ranks = self.ranks(node_blocks)?;
        let bb = u64::from(format.block_bytes);
        let resident = u64::from(ranks.resident_rows(count));
        Ok(RankMemory {
            resident_bytes: resident * bb,
            cache_bytes: u64::from(self.lines(count, format)) * bb,
        })
    }
}

/// Mebibytes of `bytes`, as messages and reports give memory.
pub fn mib(bytes: u64) -> f64 {
    bytes as f64 / 1048576.0
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
        attrs: blocks.attrs,
        resident: &blocks.words,
        meshes,
        depth,
    };
    match dc {
        None => Tracer::new(gpu, &base, settings, None),
        Some(o) => {
            let ranks = o.ranks(blocks.node_blocks)?;
            let stores = VirtualRanks::new(blocks, o.ranks)?;
            let resident: Vec<u32> = ranks
                .resident_blocks(blocks.count())
                .flat_map(|k| blocks.block(k).iter().copied())
                .collect();
            let lines = o.lines(blocks.count(), blocks.format);
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
