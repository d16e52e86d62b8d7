//! The BVH: built with obvhs (BVH2, PLOC), converted to our 32-byte node format in the blocked
//! layout (docs/ARCHITECTURE.md, BVH and blocks; chapter 5.3.1), with triangles reordered in
//! BVH in-order (chapter 5.3.2).

mod coincident;
pub mod layout;

use crate::scene::Model;
use bytemuck::{Pod, Zeroable};
use obvhs::{BvhBuildParams, aabb::Aabb};
use std::time::{Duration, Instant};

/// A BVH node, 32 bytes. Byte layout (little endian, as the GPU reads it through
/// `shaders/common.wgsl` `load_node`: texel 0 = min.xyz, max.x; texel 1 = max.yz, index, count):
///
/// | bytes | field |
/// |-------|-------|
/// | 0..12  | `min` (f32 x3) |
/// | 12..24 | `max` (f32 x3) |
/// | 24..28 | `index`: inner node: the first of its two adjacent children; leaf: first triangle |
/// | 28..32 | `count`: 0 for an inner node, else the leaf's triangle count |
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    pub min: [f32; 3],
    pub max: [f32; 3],
    pub index: u32,
    pub count: u32,
}
const _: () = assert!(std::mem::size_of::<Node>() == 32);

impl Node {
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
}

/// The obvhs build presets we expose; `Fast` is the default, chosen by `dcrt bench --bvh-presets`
/// (see README: build time against trace speed).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    Fastest,
    VeryFast,
    Fast,
    Medium,
}

impl Preset {
    fn params(self) -> BvhBuildParams {
        match self {
            Preset::Fastest => BvhBuildParams::fastest_build(),
            Preset::VeryFast => BvhBuildParams::very_fast_build(),
            Preset::Fast => BvhBuildParams::fast_build(),
            Preset::Medium => BvhBuildParams::medium_build(),
        }
    }
}

/// A BVH in our node format, with triangles in BVH order.
#[derive(Clone, Debug)]
pub struct Bvh {
    /// Blocked layout: node 0 is the root, node 1 an unused pad so that every sibling pair starts
    /// at an even index and never straddles a block.
    pub nodes: Vec<Node>,
    /// Triangles in BVH in-order.
    pub triangles: Vec<[[f32; 3]; 3]>,
    /// `prim_ids[i]` is the input-order primitive id of `triangles[i]`.
    pub prim_ids: Vec<u32>,
    /// Number of node levels on the longest root-to-leaf path (the root alone is depth 1): the
    /// traversal stack never needs more entries than this.
    pub depth: u32,
    /// Time to build (obvhs) and to lay out (ours).
    pub build_time: Duration,
    pub layout_time: Duration,
}

impl Bvh {
    /// Builds over `model`'s triangles; `nodes_per_block` sets the treelet size of the layout.
    pub fn build(model: &Model, preset: Preset, nodes_per_block: usize) -> Bvh {
        let t0 = Instant::now();
        let aabbs: Vec<Aabb> = model
            .triangles
            .iter()
            .map(|t| {
                let mut b = Aabb::INVALID;
                for p in t {
                    b.extend(glam::Vec3A::from_array(*p));
                }
                b
            })
            .collect();
        let mut core = Duration::ZERO;
        let bvh2 = match coincident::find(&aabbs) {
            None => obvhs::bvh2::builder::build_bvh2(&aabbs, preset.params(), &mut core),
            Some(groups) => {
                let kept: Vec<Aabb> = groups.kept.iter().map(|&p| aabbs[p as usize]).collect();
                let mut b = obvhs::bvh2::builder::build_bvh2(&kept, preset.params(), &mut core);
                groups.restore(&mut b, &aabbs);
                b
            }
        };
        drop(aabbs);
        let build_time = t0.elapsed();
        let t1 = Instant::now();
        let out = layout::blocked(&bvh2, &model.triangles, nodes_per_block);
        Bvh {
            nodes: out.nodes,
            triangles: out.triangles,
            prim_ids: out.prim_ids,
            depth: out.depth,
            build_time,
            layout_time: t1.elapsed(),
        }
    }
}
