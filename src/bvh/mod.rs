//! The BVH: built with obvhs (BVH2, PLOC), collapsed to our 4-wide 64-byte node format in the blocked
//! layout (docs/ARCHITECTURE.md, BVH and blocks; chapter 5.3.1), with triangles reordered in
//! BVH in-order (chapter 5.3.2).

mod coincident;
pub mod join;
pub mod layout;

use crate::scene::Model;
use bytemuck::{Pod, Zeroable};
use obvhs::{BvhBuildParams, aabb::Aabb};
use std::time::{Duration, Instant};

/// A 4-wide BVH node, 64 bytes (4 texels), with its children's boxes quantized to 8 bits per
/// bound on a per-node grid (docs/ARCHITECTURE.md, BVH and blocks). Byte layout, little endian:
///
/// | words | field |
/// |-------|-------|
/// | 0..3   | `origin`: the grid's corner (f32 x3), the minimum of the children's boxes |
/// | 3      | `exponents`: per axis (bytes 0..3) the biased f32 exponent of the grid step |
/// | 4      | `child_base`: the first inner child; inner children are adjacent, in slot order |
/// | 5      | `tri_base`: the first triangle of the leaf children, adjacent in slot order |
/// | 6      | `counts`: per slot (byte i) `EMPTY`, `INNER`, or the leaf's triangle count |
/// | 7      | zero |
/// | 8..11  | `lo`: per axis, byte i the lower bound of slot i in grid steps |
/// | 11..14 | `hi`: the same for the upper bounds |
/// | 14..16 | zero |
///
/// A child's box is `origin + q * 2^(exponent - 127)` per bound: `q * step` is exact and the
/// single rounding of the sum is checked at build time to fall outside the exact box, so the
/// decoded box (`Node::child_box`, the mirror of the shader's `child_box`) always contains it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    pub origin: [f32; 3],
    pub exponents: u32,
    pub child_base: u32,
    pub tri_base: u32,
    pub counts: u32,
    pub zero0: u32,
    pub lo: [u32; 3],
    pub hi: [u32; 3],
    pub zero1: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<Node>() == 64);

/// Children per node.
pub const WIDTH: usize = 4;
/// `Node::counts` byte of an unused slot.
pub const EMPTY: u32 = 0;
/// `Node::counts` byte of an inner child; any other nonzero byte is a leaf's triangle count.
pub const INNER: u32 = 255;
/// The most triangles a leaf may hold.
pub const MAX_LEAF: u32 = INNER - 1;

/// What a slot of a node holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Child {
    Empty,
    /// Node index.
    Inner(u32),
    /// Triangles `first..first + count` (BVH order).
    Leaf {
        first: u32,
        count: u32,
    },
}

impl Node {
    /// A node no tree reaches: the out-of-core build puts these before a part's nodes so that
    /// they start a block (`join::Top::join`). Every slot is `EMPTY`.
    pub const PADDING: Node = Node {
        origin: [0.0; 3],
        exponents: 0,
        child_base: 0,
        tri_base: 0,
        counts: 0,
        zero0: 0,
        lo: [0; 3],
        hi: [0; 3],
        zero1: [0; 2],
    };

    /// The byte of slot `i` in a per-slot word.
    fn byte(word: u32, i: usize) -> u32 {
        (word >> (8 * i)) & 0xff
    }

    /// The grid step on `axis`, a power of two (0 when every child is flat on that axis).
    pub fn step(&self, axis: usize) -> f32 {
        f32::from_bits((Node::byte(self.exponents, axis)) << 23)
    }

    /// Slot `i`'s child: inner children and leaf triangles follow each other in slot order.
    pub fn child(&self, i: usize) -> Child {
        let count = |s| Node::byte(self.counts, s);
        match count(i) {
            EMPTY => Child::Empty,
            INNER => {
                Child::Inner(self.child_base + (0..i).filter(|&s| count(s) == INNER).count() as u32)
            }
            n => Child::Leaf {
                first: self.tri_base + (0..i).map(count).filter(|&c| c != INNER).sum::<u32>(),
                count: n,
            },
        }
    }

    /// Slot `i`'s decoded box, as the shader's `child_box` computes it (one f32 rounding of an
    /// exact product added to the origin).
    pub fn child_box(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        let at = |q: &[u32; 3]| {
            std::array::from_fn(|a| self.origin[a] + Node::byte(q[a], i) as f32 * self.step(a))
        };
        (at(&self.lo), at(&self.hi))
    }

    /// A node with `boxes` (at most `WIDTH`) quantized on its grid: the smallest power-of-two step
    /// whose 255 steps reach the far bound, and for each bound the nearest grid point on its outer
    /// side after the f32 rounding `Node::child_box` does. Slots, bases and counts are left 0.
    pub fn quantized(boxes: &[([f32; 3], [f32; 3])]) -> Node {
        let mut node = Node::default();
        for a in 0..3 {
            let lo = boxes.iter().map(|b| b.0[a]).fold(f32::INFINITY, f32::min);
            let hi = boxes
                .iter()
                .map(|b| b.1[a])
                .fold(f32::NEG_INFINITY, f32::max);
            node.origin[a] = lo;
            let reach = |e: u32| lo + 255.0 * f32::from_bits(e << 23) >= hi;
            // Step 0 (exponent byte 0) when every child is flat at `lo`; else the smallest normal
            // power of two that reaches.
            let mut e = 0u32;
            if hi > lo {
                let need = ((f64::from(hi) - f64::from(lo)) / 255.0).log2().floor() as i32 + 127;
                e = need.clamp(1, 254) as u32;
                while !reach(e) {
                    assert!(e < 254, "axis {a}: {lo}..{hi} does not fit a grid");
                    e += 1;
                }
            }
            node.exponents |= e << (8 * a);
            let step = f32::from_bits(e << 23);
            let at = |q: u32| lo + q as f32 * step;
            for (i, b) in boxes.iter().enumerate() {
                let (mut ql, mut qh) = if e == 0 {
                    (0, 0)
                } else {
                    let s = f64::from(step);
                    let ql = ((f64::from(b.0[a]) - f64::from(lo)) / s)
                        .floor()
                        .clamp(0.0, 255.0);
                    let qh = ((f64::from(b.1[a]) - f64::from(lo)) / s)
                        .ceil()
                        .clamp(0.0, 255.0);
                    (ql as u32, qh as u32)
                };
                while ql > 0 && at(ql) > b.0[a] {
                    ql -= 1;
                }
                while at(qh) < b.1[a] {
                    qh += 1;
                }
                debug_assert!(qh <= 255 && at(ql) <= b.0[a] && at(qh) >= b.1[a]);
                node.lo[a] |= ql << (8 * i);
                node.hi[a] |= qh << (8 * i);
            }
        }
        node
    }

    /// The union of the used slots' boxes (the shader's `node_bounds`): the root's holds the
    /// scene.
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut b = ([f32::MAX; 3], [f32::MIN; 3]);
        for i in (0..WIDTH).filter(|&i| self.child(i) != Child::Empty) {
            let (lo, hi) = self.child_box(i);
            for a in 0..3 {
                b.0[a] = b.0[a].min(lo[a]);
                b.1[a] = b.1[a].max(hi[a]);
            }
        }
        b
    }
}

/// The obvhs build presets we expose; `Fast` is the default, chosen by `dcrt bench rays
/// --bvh-presets` (docs/benchmarks.md has build times beside trace speed).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    Fastest,
    VeryFast,
    Fast,
    Medium,
}

/// How a tree is built: the obvhs preset, and what a node visit costs beside a triangle test
/// when the build decides which subtrees become leaves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Build {
    pub preset: Preset,
    /// obvhs's `collapse_traversal_cost`, a triangle test costing 1. Its presets' 3 makes leaves
    /// of up to 8 triangles (`fastest` makes leaves of one and ignores it); one iteration of
    /// dcrt's traversal loop visits a node or tests a triangle, so a lower cost makes a ray run
    /// fewer iterations through a larger tree (docs/ARCHITECTURE.md, BVH and blocks).
    pub node_cost: f32,
}

/// The node cost of obvhs's presets, dcrt's default: the smaller, slower tree.
pub const DEFAULT_NODE_COST: f32 = 3.0;

impl Default for Build {
    fn default() -> Build {
        Build::from(Preset::Fast)
    }
}

impl From<Preset> for Build {
    fn from(preset: Preset) -> Build {
        Build {
            preset,
            node_cost: DEFAULT_NODE_COST,
        }
    }
}

impl Build {
    fn params(self) -> BvhBuildParams {
        let mut p = match self.preset {
            Preset::Fastest => BvhBuildParams::fastest_build(),
            Preset::VeryFast => BvhBuildParams::very_fast_build(),
            Preset::Fast => BvhBuildParams::fast_build(),
            Preset::Medium => BvhBuildParams::medium_build(),
        };
        p.collapse_traversal_cost = self.node_cost;
        p
    }
}

/// A BVH in our node format, with triangles in BVH order.
#[derive(Clone, Debug)]
pub struct Bvh {
    /// Blocked layout: node 0 is the root, always an inner node (a lone leaf is its only child).
    pub nodes: Vec<Node>,
    /// Triangles in BVH in-order.
    pub triangles: Vec<[[f32; 3]; 3]>,
    /// `prim_ids[i]` is the input-order primitive id of `triangles[i]`.
    pub prim_ids: Vec<u32>,
    /// Number of node levels on the longest root-to-leaf path (the root alone is depth 1): a
    /// visit pushes at most `WIDTH - 1` entries, so the stack never needs more than
    /// `(WIDTH - 1) * depth`.
    pub depth: u32,
    /// Time to build (obvhs) and to lay out (ours).
    pub build_time: Duration,
    pub layout_time: Duration,
}

impl Bvh {
    /// Builds over `model`'s triangles; `nodes_per_block` sets the treelet size of the layout.
    pub fn build(model: &Model, build: impl Into<Build>, nodes_per_block: usize) -> Bvh {
        let built = Built::over(
            &model.triangles,
            build.into(),
            nodes_per_block,
            nodes_per_block,
            false,
        );
        let triangles = built
            .laid
            .prim_ids
            .iter()
            .map(|&p| model.triangles[p as usize])
            .collect();
        Bvh {
            nodes: built.laid.nodes,
            triangles,
            prim_ids: built.laid.prim_ids,
            depth: built.laid.depth,
            build_time: built.build_time,
            layout_time: built.layout_time,
        }
    }
}

/// A tree over a list of triangles in the blocked layout, the triangles left where they are:
/// `laid.prim_ids` says which comes where (the out-of-core build lays out one part at a time
/// and writes its triangles later).
pub struct Built {
    pub laid: layout::Laid,
    pub build_time: Duration,
    pub layout_time: Duration,
}

impl Built {
    /// Builds over `triangles` with obvhs and lays the tree out with treelets in blocks of
    /// `nodes_per_block` nodes, the root's of at most `head` (`layout::blocked`, which says what
    /// `rest_starts_a_block` means).
    pub fn over(
        triangles: &[[[f32; 3]; 3]],
        build: Build,
        nodes_per_block: usize,
        head: usize,
        rest_starts_a_block: bool,
    ) -> Built {
        let t0 = Instant::now();
        let aabbs: Vec<Aabb> = triangles.iter().map(triangle_box).collect();
        let mut core = Duration::ZERO;
        let bvh2 = match coincident::find(&aabbs) {
            None => obvhs::bvh2::builder::build_bvh2(&aabbs, build.params(), &mut core),
            Some(groups) => {
                let kept: Vec<Aabb> = groups.kept.iter().map(|&p| aabbs[p as usize]).collect();
                let mut b = obvhs::bvh2::builder::build_bvh2(&kept, build.params(), &mut core);
                groups.restore(&mut b, &aabbs);
                b
            }
        };
        drop(aabbs);
        let build_time = t0.elapsed();
        let t1 = Instant::now();
        let laid = layout::blocked(&bvh2, nodes_per_block, head, rest_starts_a_block);
        Built {
            laid,
            build_time,
            layout_time: t1.elapsed(),
        }
    }
}

/// A triangle's bounding box, as the build sees it.
pub fn triangle_box(t: &[[f32; 3]; 3]) -> Aabb {
    let mut b = Aabb::INVALID;
    for p in t {
        b.extend(glam::Vec3A::from_array(*p));
    }
    b
}
