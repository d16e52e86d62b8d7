//! `dcrt prepare`: a scene's BVH and blocks written once to a block file, within a memory budget
//! (docs/ARCHITECTURE.md, Out-of-core prepare).
//!
//! The scene's triangles are streamed in (`Scene::stream`). While they fit the budget's
//! in-memory build they are held, and the model is built whole, exactly as a render builds it.
//! Beyond that they are spilled to a temporary file and the model is built out of core:
//! `partition` cuts them into parts of what a part's build may use, and the tree of its cuts is
//! the top tree (`bvh::join`); each part is built with obvhs and laid out, its nodes and triangle
//! order spilled, and the block file is written from those, node blocks first (the joined tree's
//! numbering), then the parts' triangles in tree order. Temporary files live in a `Scratch`
//! directory beside the output, removed on success, failure and interruption; the block file is
//! written under a temporary name and renamed when complete (`files::write_atomic`).

pub mod budget;
pub mod partition;
pub mod spill;

use crate::blocks::Format;
use crate::blocks::file::{BlockWriter, Meta};
use crate::bvh::join::{Joined, PartShape, Run, Top};
use crate::bvh::{Build, Built, Node};
use crate::error::{Error, Result};
use crate::files::Scratch;
use crate::progress::Progress;
use crate::render::Prepared;
use crate::scene::stream::Sink;
use crate::scene::{Bounds, Model, Scene};
use budget::Budget;
use indicatif::ProgressBar;
use obvhs::aabb::Aabb;
use partition::{Part, TriangleFile};
use spill::{Record, Triangle, Writer};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How to prepare.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    pub build: Build,
    pub format: Format,
    pub budget: Budget,
    pub progress: Progress,
}

/// What was written.
#[derive(Clone, Debug)]
pub struct Report {
    pub triangles: u64,
    pub node_blocks: u32,
    pub tri_blocks: u32,
    /// Attribute blocks (colours by data), after the triangle blocks; 0 out of core.
    pub attr_blocks: u32,
    pub block_bytes: u32,
    pub depth: u32,
    /// Out of core: the parts, the largest's triangles and the most a part may have; `None`
    /// when the model was built in memory.
    pub parts: Option<Parts>,
    pub seconds: f64,
    /// Seconds per phase: reading the input, then (out of core) partitioning, building the
    /// parts and writing the blocks, or (in memory) building and writing.
    pub phases: Vec<(&'static str, f64)>,
}

/// How a model was cut out of core.
#[derive(Clone, Copy, Debug)]
pub struct Parts {
    pub count: usize,
    pub largest: u64,
    pub capacity: u64,
}

impl Report {
    pub fn bytes(&self) -> u64 {
        let blocks = u64::from(self.node_blocks) + u64::from(self.tri_blocks);
        (blocks + u64::from(self.attr_blocks)) * u64::from(self.block_bytes)
    }
}

/// Prepares `scene` into the block file `output`.
pub fn prepare(scene: &Scene, output: &Path, o: &Options) -> Result<Report> {
    let t = Instant::now();
    if let Some(why) = scene.needs_whole_meshes() {
        // Colours by data and glTF parts are carried by `load_model` only: in memory or not at
        // all, never silently dropped.
        let model = scene.load_model()?;
        let limit = o.budget.in_core_triangles();
        if model.triangles.len() as u64 > limit {
            return Err(Error::Invalid(format!(
                "{}: {why}, which only an in-memory build carries, but its {} triangles are \
                 more than the {limit} that --memory {} MiB builds in memory; raise --memory",
                scene.path.display(),
                model.triangles.len(),
                o.budget.bytes >> 20
            )));
        }
        let read = t.elapsed().as_secs_f64();
        return in_core(scene, model, output, o, t, read);
    }
    let mut scratch = None;
    let bar = o.progress.counter("reading triangles");
    let mut intake = Intake {
        held: Vec::new(),
        limit: o.budget.in_core_triangles(),
        mesh_first: Vec::new(),
        colors: Vec::new(),
        count: 0,
        centres: Aabb::INVALID,
        spill: None,
        scratch: &mut scratch,
        output,
        budget: o.budget,
        bar: &bar,
    };
    let streamed = scene.stream(&mut intake)?;
    bar.finish_and_clear();
    let read = t.elapsed().as_secs_f64();
    let Intake {
        held,
        mesh_first,
        colors,
        count,
        centres,
        spill,
        ..
    } = intake;
    let Some(spill) = spill else {
        let model = Model {
            triangles: held,
            mesh_first,
            colors,
            looks: Vec::new(),
            attributes: None,
            bounds: streamed.bounds,
        };
        return in_core(scene, model, output, o, t, read);
    };
    let (path, written) = spill.finish()?;
    debug_assert_eq!(written, count);
    let Some(scratch) = scratch else {
        return Err(Error::Internal(
            "spilled without a scratch directory".into(),
        ));
    };
    let input = Input {
        spill: path,
        count,
        centres,
        mesh_first,
        colors,
        bounds: streamed.bounds,
    };
    out_of_core(scene, input, &scratch, output, o, t, read)
}

/// The whole model in memory: the same build and file as a render of the scene makes.
fn in_core(
    scene: &Scene,
    model: Model,
    output: &Path,
    o: &Options,
    t: Instant,
    read: f64,
) -> Result<Report> {
    let bar = o.progress.counter("building in memory");
    bar.tick();
    let p = Prepared::from_model(model, o.build, o.format, 0.0)?;
    let camera = scene.camera_or_default(&p.model);
    let meta = p.meta(scene, camera, scene.width, scene.height);
    crate::blocks::file::write(output, &p.blocks, &meta)?;
    bar.finish_and_clear();
    Ok(Report {
        triangles: p.model.triangles.len() as u64,
        node_blocks: p.blocks.node_blocks,
        tri_blocks: p.blocks.tri_blocks,
        attr_blocks: p.blocks.attrs.blocks,
        block_bytes: o.format.block_bytes,
        depth: p.bvh.depth,
        parts: None,
        seconds: t.elapsed().as_secs_f64(),
        phases: vec![
            ("read", read),
            ("build and write", t.elapsed().as_secs_f64() - read),
        ],
    })
}

/// Takes the streamed triangles: holds them while the in-memory build would fit the budget,
/// then spills them (those held first) to a temporary file.
struct Intake<'a> {
    held: Vec<Triangle>,
    limit: u64,
    mesh_first: Vec<u32>,
    colors: Vec<[f32; 3]>,
    count: u64,
    /// The bounds of the triangles' box centres, which the partition's grid covers.
    centres: Aabb,
    spill: Option<Writer<Triangle>>,
    scratch: &'a mut Option<Scratch>,
    output: &'a Path,
    budget: Budget,
    bar: &'a ProgressBar,
}

impl Sink for Intake<'_> {
    fn mesh(&mut self, color: [f32; 3]) -> Result<()> {
        self.mesh_first.push(self.count as u32);
        self.colors.push(color);
        Ok(())
    }

    fn triangles(&mut self, triangles: &[Triangle]) -> Result<()> {
        self.count += triangles.len() as u64;
        for t in triangles {
            let c = glam::Vec3A::from_array(partition::centre(t));
            self.centres = self.centres.union(&Aabb { min: c, max: c });
        }
        if self.spill.is_none() && self.count > self.limit {
            let scratch = Scratch::beside(self.output)?;
            let mut w = Writer::create(&scratch.path("triangles"), self.budget.buffer_bytes(1))?;
            *self.scratch = Some(scratch);
            w.push(&self.held)?;
            self.held = Vec::new();
            self.spill = Some(w);
        }
        match &mut self.spill {
            Some(w) => w.push(triangles)?,
            None => self.held.extend_from_slice(triangles),
        }
        self.bar.inc(triangles.len() as u64);
        Ok(())
    }

    /// A mesh file's vertices (12 bytes each) may take half the budget.
    fn vertex_limit(&self) -> u64 {
        self.budget.bytes.saturating_sub(budget::FIXED_BYTES) / 2 / 12
    }
}

/// The spilled model: its triangles in input order, the bounds of their centres, the mesh table
/// and the model's bounds.
struct Input {
    spill: PathBuf,
    count: u64,
    centres: Aabb,
    mesh_first: Vec<u32>,
    colors: Vec<[f32; 3]>,
    bounds: Bounds,
}

fn out_of_core(
    scene: &Scene,
    input: Input,
    scratch: &Scratch,
    output: &Path,
    o: &Options,
    t: Instant,
    read: f64,
) -> Result<Report> {
    let mut phases = vec![("read", read)];
    let mark = |name, phases: &mut Vec<(&'static str, f64)>| {
        let done: f64 = phases.iter().map(|p| p.1).sum();
        phases.push((name, t.elapsed().as_secs_f64() - done));
    };
    let count = input.count;
    let format = o.format;
    let npb = format.nodes_per_block() as usize;
    let cap = o.budget.part_triangles();
    let bar = o.progress.bar(2 * count, "partitioning");
    let spill = TriangleFile::Spill {
        path: input.spill.clone(),
        count,
    };
    let (parts, cuts) = partition::split(&spill, &input.centres, cap, scratch, &o.budget, &bar)?;
    bar.finish_and_clear();
    std::fs::remove_file(&input.spill).map_err(|e| Error::io(&input.spill, e))?;
    mark("partition", &mut phases);
    let boxes: Vec<Aabb> = parts.iter().map(|p| p.bounds).collect();
    let top = Top::new(&cuts, &boxes);
    let parts: Vec<Part> = top.order.iter().map(|&i| parts[i].clone()).collect();
    let head = (top.head(npb), top.rests_start_blocks());

    let built = build_parts(&parts, o, head, scratch)?;
    mark("build parts", &mut phases);
    let joined = top.join(&built.shapes, npb);
    if joined.nodes >= u64::from(u32::MAX) {
        return Err(Error::Invalid(format!(
            "the model needs {} BVH nodes, more than 2^32",
            joined.nodes
        )));
    }
    let node_blocks = joined.nodes.div_ceil(npb as u64);
    let tri_blocks = count.div_ceil(u64::from(format.tris_per_block()));
    if node_blocks + tri_blocks > u64::from(u32::MAX) {
        return Err(Error::Invalid(format!(
            "model needs {} blocks, more than 2^32",
            node_blocks + tri_blocks
        )));
    }
    let (node_blocks, tri_blocks) = (node_blocks as u32, tri_blocks as u32);
    let meta = Meta {
        camera: scene.camera_for(input.bounds),
        width: scene.width,
        height: scene.height,
        background: scene.background,
        mesh_first: input.mesh_first,
        colors: input.colors,
        triangles: count,
        nodes: joined.nodes,
        bvh_depth: joined.depth,
        bounds_min: input.bounds.min,
        bounds_max: input.bounds.max,
        source: scene.path.display().to_string(),
        // Streamed meshes are coloured by mesh (`Scene::needs_whole_meshes`).
        looks: Vec::new(),
        attrs: Default::default(),
    };
    let bar = o.progress.bar(
        u64::from(node_blocks) + u64::from(tri_blocks),
        "writing blocks",
    );
    crate::files::write_atomic(output, |w| {
        let mut out = BlockWriter::start(w, output, format, node_blocks, tri_blocks, &meta)?;
        write_blocks(&mut out, format, &joined, &parts, &built, &bar)?;
        out.finish()
    })?;
    bar.finish_and_clear();
    mark("write", &mut phases);
    Ok(Report {
        triangles: count,
        node_blocks,
        tri_blocks,
        attr_blocks: 0,
        block_bytes: format.block_bytes,
        depth: joined.depth,
        parts: Some(Parts {
            count: parts.len(),
            largest: built.shapes.iter().map(|s| s.triangles).max().unwrap_or(0),
            capacity: cap,
        }),
        seconds: t.elapsed().as_secs_f64(),
        phases,
    })
}

/// The parts built: their shapes, and where each one's nodes and triangle order start in the
/// two temporary files that hold them.
struct BuiltParts {
    shapes: Vec<PartShape>,
    at: Vec<(u64, u64)>,
    nodes: PathBuf,
    order: PathBuf,
}

/// Builds and lays out each part (its first treelet `head.0` nodes at most; with `head.1` its
/// treelets counted from the first node after the head, `Top::rests_start_blocks`), spilling
/// its nodes and triangle order.
fn build_parts(
    parts: &[Part],
    o: &Options,
    head: (usize, bool),
    scratch: &Scratch,
) -> Result<BuiltParts> {
    let count = parts.iter().map(|p| p.count).sum();
    let bar = o
        .progress
        .bar(count, &format!("building {} parts", parts.len()));
    let npb = o.format.nodes_per_block() as usize;
    let buffer = o.budget.buffer_bytes(2);
    let mut nodes = Writer::<Node>::create(&scratch.path("nodes"), buffer)?;
    let mut order = Writer::<u32>::create(&scratch.path("order"), buffer)?;
    let mut shapes = Vec::with_capacity(parts.len());
    let mut at = Vec::with_capacity(parts.len());
    for p in parts {
        let mut tris = Vec::with_capacity(p.count as usize);
        let mut r = spill::Reader::<Record>::open(&p.path, p.count)?;
        while let Some(chunk) = r.next_chunk()? {
            tris.extend(chunk.iter().map(|r| r.tri));
        }
        let built = Built::over(&tris, o.build, npb, head.0, head.1);
        drop(tris);
        at.push((nodes.count, order.count));
        nodes.push(&built.laid.nodes)?;
        order.push(&built.laid.prim_ids)?;
        shapes.push(PartShape {
            nodes: built.laid.nodes.len() as u32,
            head: built.laid.head as u32,
            depth: built.laid.depth,
            triangles: p.count,
        });
        bar.inc(p.count);
    }
    bar.finish_and_clear();
    Ok(BuiltParts {
        shapes,
        at,
        nodes: nodes.finish()?.0,
        order: order.finish()?.0,
    })
}

/// The blocks of the joined tree: node blocks in the joined numbering (top nodes from memory,
/// part nodes read back and mapped), then each part's triangles in its order, part by part
/// (each part's file read whole, then removed).
fn write_blocks(
    out: &mut BlockWriter,
    format: Format,
    joined: &Joined,
    parts: &[Part],
    built: &BuiltParts,
    bar: &ProgressBar,
) -> Result<()> {
    let open = |p: &Path| std::fs::File::open(p).map_err(|e| Error::io(p, e));
    let (node_file, order_file) = (open(&built.nodes)?, open(&built.order)?);
    let mut nodes = Packer::new(format, format.nodes_per_block());
    for run in joined.runs() {
        match run {
            Run::Top(t) => {
                let node = joined.top_node(t);
                nodes.push(out, bar, |b, s| format.put_node(b, s, &node))?
            }
            Run::Pad(count) => {
                for _ in 0..count {
                    nodes.push(out, bar, |b, s| format.put_node(b, s, &Node::PADDING))?;
                }
            }
            Run::Part { part, first, count } => {
                let mut l = first;
                while l < first + count {
                    let n = (first + count - l).min(1 << 14);
                    let at = built.at[part].0 + u64::from(l);
                    let local: Vec<Node> =
                        spill::read_at(&node_file, &built.nodes, at, n as usize)?;
                    for node in &local {
                        let node = joined.map(part, *node);
                        nodes.push(out, bar, |b, s| format.put_node(b, s, &node))?;
                    }
                    l += n;
                }
            }
        }
    }
    nodes.finish(out, bar)?;
    let mut tris = Packer::new(format, format.tris_per_block());
    for (i, p) in parts.iter().enumerate() {
        let records = spill::Reader::<Record>::open(&p.path, p.count)?.read_all()?;
        let local: Vec<u32> =
            spill::read_at(&order_file, &built.order, built.at[i].1, p.count as usize)?;
        for &l in &local {
            let r = &records[l as usize];
            tris.push(out, bar, |b, s| format.put_triangle(b, s, &r.tri, r.id))?;
        }
        drop(records);
        std::fs::remove_file(&p.path).map_err(|e| Error::io(&p.path, e))?;
    }
    tris.finish(out, bar)
}

/// Fills blocks of `per_block` slots (nodes or triangles) as they come, zeros after the last,
/// and writes each when full.
struct Packer {
    block: Vec<u32>,
    per_block: usize,
    filled: usize,
}

impl Packer {
    fn new(format: Format, per_block: u32) -> Packer {
        Packer {
            block: vec![0; format.words() as usize],
            per_block: per_block as usize,
            filled: 0,
        }
    }

    /// Fills the next slot with `put(block, slot)`.
    fn push(
        &mut self,
        out: &mut BlockWriter,
        bar: &ProgressBar,
        put: impl FnOnce(&mut [u32], usize),
    ) -> Result<()> {
        put(&mut self.block, self.filled);
        self.filled += 1;
        if self.filled == self.per_block {
            out.block(&self.block)?;
            self.block.fill(0);
            self.filled = 0;
            bar.inc(1);
        }
        Ok(())
    }

    /// Writes the last block if it holds anything.
    fn finish(self, out: &mut BlockWriter, bar: &ProgressBar) -> Result<()> {
        if self.filled > 0 {
            out.block(&self.block)?;
            bar.inc(1);
        }
        Ok(())
    }
}
