//! Fixed-size blocks: the unit of storage, ownership and caching (docs/ARCHITECTURE.md, Blocks).
//!
//! One id space holds all blocks: node blocks first (`0..node_blocks`), then triangle blocks. A
//! block is `block_bytes` long, seen by the GPU as one row of `block_bytes / 16` `Rgba32Uint`
//! texels. Byte layouts (little-endian u32 words):
//!
//! - node block: `nodes_per_block = block_bytes / 64` nodes of 16 words (`bvh::Node`).
//! - triangle block: `tris_per_block = block_bytes / 40` triangles of 9 words (v0, v1, v2 as f32
//!   xyz) from word 0, then their primitive ids (one u32 each) from word `9 * tris_per_block`;
//!   zeros after. Keeping the id in the block costs 4 bytes a triangle and means the block a ray
//!   hits is all it needs to report the id.
//! - attribute block (only in models coloured by data, after the triangle blocks): the colour
//!   attributes of `block_bytes / (4 words)` triangles in BVH triangle order, `words` (1 or 3)
//!   each: a scalar's f32 bits or a packed 8-bit sRGB colour, per triangle (cell data) or per
//!   corner (point data, in the triangle's vertex order); zeros after. Only shading reads them,
//!   so traversal never fetches them (docs/ARCHITECTURE.md, Colour by data).

pub mod check;
pub mod file;
pub mod ranks;

use crate::bvh::{Bvh, Child, Node};
use crate::error::{Error, Result};

pub const DEFAULT_BLOCK_BYTES: u32 = 8192;
pub const TEXEL_BYTES: u32 = 16;
const NODE_WORDS: u32 = 16;
const TRI_WORDS: u32 = 9;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Format {
    pub block_bytes: u32,
}

/// A model's attribute blocks: none (`words` 0), or `blocks` blocks of `words` words per
/// triangle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct AttrLayout {
    pub words: u32,
    pub blocks: u32,
}

impl AttrLayout {
    /// The layout of `triangles` triangles' attributes of `words` words each (0: none).
    pub fn new(format: Format, words: u32, triangles: u64) -> AttrLayout {
        if words == 0 {
            return AttrLayout::default();
        }
        let per = u64::from(format.attrs_per_block(words));
        AttrLayout {
            words,
            blocks: triangles.div_ceil(per) as u32,
        }
    }
}

impl Format {
    pub fn new(block_bytes: u32) -> Result<Format> {
        // 64 bytes is one node; the texture row width caps the top.
        if !(64..=256 * 1024).contains(&block_bytes) || !block_bytes.is_multiple_of(64) {
            return Err(Error::Invalid(format!(
                "block size {block_bytes} bytes: must be a multiple of 64 from 64 to 262144"
            )));
        }
        Ok(Format { block_bytes })
    }
    pub fn words(&self) -> u32 {
        self.block_bytes / 4
    }
    pub fn texels(&self) -> u32 {
        self.block_bytes / TEXEL_BYTES
    }
    pub fn nodes_per_block(&self) -> u32 {
        self.block_bytes / (NODE_WORDS * 4)
    }
    pub fn tris_per_block(&self) -> u32 {
        self.block_bytes / ((TRI_WORDS + 1) * 4)
    }
    /// Word offset of the primitive ids in a triangle block.
    pub fn id_word(&self) -> u32 {
        TRI_WORDS * self.tris_per_block()
    }

    /// Puts `node` in slot `s` of node block `block`.
    pub fn put_node(&self, block: &mut [u32], s: usize, node: &Node) {
        let w = NODE_WORDS as usize;
        block[s * w..(s + 1) * w].copy_from_slice(bytemuck::cast_slice(std::slice::from_ref(node)));
    }

    /// The blocks node block `k` (its words `block`) leads to, each once, in slot order: the node
    /// blocks of its inner children other than `k`, and the triangle blocks of its leaves. The
    /// cache fetches them ahead of the rays (`dc::policy`).
    pub fn child_blocks(&self, k: u32, block: &[u32], node_blocks: u32) -> Vec<u32> {
        let (npb, tpb) = (self.nodes_per_block(), self.tris_per_block());
        let w = NODE_WORDS as usize;
        let mut out = Vec::new();
        let mut add = |b: u32| {
            if b != k && !out.contains(&b) {
                out.push(b);
            }
        };
        for words in block.chunks_exact(w) {
            let node: Node = bytemuck::pod_read_unaligned(bytemuck::cast_slice(words));
            for i in 0..crate::bvh::WIDTH {
                match node.child(i) {
                    Child::Empty => {}
                    Child::Inner(j) => add(j / npb),
                    Child::Leaf { first, count } => {
                        for b in first / tpb..=(first + count - 1) / tpb {
                            add(node_blocks + b);
                        }
                    }
                }
            }
        }
        out
    }

    /// Puts triangle `tri`, of primitive id `id`, in slot `s` of triangle block `block`.
    pub fn put_triangle(&self, block: &mut [u32], s: usize, tri: &[[f32; 3]; 3], id: u32) {
        let w = TRI_WORDS as usize;
        block[s * w..(s + 1) * w].copy_from_slice(bytemuck::cast_slice(tri));
        block[self.id_word() as usize + s] = id;
    }

    /// Triangles per attribute block at `words` words each.
    pub fn attrs_per_block(&self, words: u32) -> u32 {
        self.words() / words.max(1)
    }
}

impl Default for Format {
    fn default() -> Self {
        Format {
            block_bytes: DEFAULT_BLOCK_BYTES,
        }
    }
}

/// All blocks of a model, in block-id order.
#[derive(Clone, Debug)]
pub struct Blocks {
    pub format: Format,
    pub node_blocks: u32,
    pub tri_blocks: u32,
    /// The attribute blocks after the triangle blocks.
    pub attrs: AttrLayout,
    pub words: Vec<u32>,
}

impl Blocks {
    pub fn pack(bvh: &Bvh, format: Format) -> Result<Blocks> {
        let npb = format.nodes_per_block() as usize;
        let tpb = format.tris_per_block() as usize;
        let node_blocks = bvh.nodes.len().div_ceil(npb);
        let tri_blocks = bvh.triangles.len().div_ceil(tpb);
        let total = node_blocks as u64 + tri_blocks as u64;
        if total > u64::from(u32::MAX) {
            return Err(Error::Invalid(format!(
                "model needs {total} blocks, more than 2^32"
            )));
        }
        let bw = format.words() as usize;
        let mut words = vec![0u32; (node_blocks + tri_blocks) * bw];
        let (node_words, tri_words) = words.split_at_mut(node_blocks * bw);
        for (chunk, block) in bvh.nodes.chunks(npb).zip(node_words.chunks_mut(bw)) {
            let bytes: &[u32] = bytemuck::cast_slice(chunk);
            block[..bytes.len()].copy_from_slice(bytes);
        }
        for (b, block) in tri_words.chunks_mut(bw).enumerate() {
            let first = b * tpb;
            let last = (first + tpb).min(bvh.triangles.len());
            for (s, t) in (first..last).enumerate() {
                format.put_triangle(block, s, &bvh.triangles[t], bvh.prim_ids[t]);
            }
        }
        Ok(Blocks {
            format,
            node_blocks: node_blocks as u32,
            tri_blocks: tri_blocks as u32,
            attrs: AttrLayout::default(),
            words,
        })
    }

    /// Appends the attribute blocks of `attrs` (primitive-id order) in the BVH's triangle order.
    pub fn with_attributes(
        mut self,
        bvh: &Bvh,
        attrs: &crate::scene::color::Attributes,
    ) -> Result<Blocks> {
        let w = attrs.words as usize;
        let n = bvh.triangles.len();
        if !(w == 1 || w == 3) || attrs.data.len() != n * w {
            return Err(Error::Internal(format!(
                "{} attribute words for {n} triangles of {w}",
                attrs.data.len()
            )));
        }
        let layout = AttrLayout::new(self.format, attrs.words, n as u64);
        if u64::from(self.count()) + u64::from(layout.blocks) > u64::from(u32::MAX) {
            return Err(Error::Invalid("model needs more than 2^32 blocks".into()));
        }
        let per = self.format.attrs_per_block(attrs.words) as usize;
        let bw = self.format.words() as usize;
        let start = self.words.len();
        self.words.resize(start + layout.blocks as usize * bw, 0);
        for (t, &prim) in bvh.prim_ids.iter().enumerate() {
            let at = start + (t / per) * bw + (t % per) * w;
            let from = prim as usize * w;
            self.words[at..at + w].copy_from_slice(&attrs.data[from..from + w]);
        }
        self.attrs = layout;
        Ok(self)
    }

    pub fn count(&self) -> u32 {
        self.node_blocks + self.tri_blocks + self.attrs.blocks
    }

    /// The attribute words of triangle `t` (BVH order): the CPU mirror of the `albedo` kernel's
    /// read.
    pub fn attribute(&self, t: u32) -> &[u32] {
        let w = self.attrs.words;
        let per = self.format.attrs_per_block(w);
        let b = self.block(self.node_blocks + self.tri_blocks + t / per);
        let at = ((t % per) * w) as usize;
        &b[at..at + w as usize]
    }

    /// CRC-32 of the per-block CRC-32 table: equal to the block file's `fingerprint` when
    /// the file holds these blocks.
    pub fn fingerprint(&self) -> u32 {
        let mut h = crc32fast::Hasher::new();
        for k in 0..self.count() {
            h.update(&crc32fast::hash(bytemuck::cast_slice(self.block(k))).to_le_bytes());
        }
        h.finalize()
    }

    pub fn block(&self, k: u32) -> &[u32] {
        let bw = self.format.words() as usize;
        &self.words[k as usize * bw..(k as usize + 1) * bw]
    }

    pub fn bytes(&self) -> u64 {
        self.words.len() as u64 * 4
    }

    /// Node `i`, read back from its block (the CPU mirror of the shader's `node_at`).
    pub fn node(&self, i: u32) -> Node {
        let npb = self.format.nodes_per_block();
        let b = self.block(i / npb);
        let w = ((i % npb) * NODE_WORDS) as usize;
        *bytemuck::from_bytes(bytemuck::cast_slice(&b[w..w + NODE_WORDS as usize]))
    }

    /// Triangle `t` (BVH order) and its primitive id.
    pub fn triangle(&self, t: u32) -> ([[f32; 3]; 3], u32) {
        let tpb = self.format.tris_per_block();
        let b = self.block(self.node_blocks + t / tpb);
        let s = (t % tpb) as usize;
        let tri: [[f32; 3]; 3] =
            std::array::from_fn(|v| std::array::from_fn(|a| f32::from_bits(b[s * 9 + v * 3 + a])));
        (tri, b[self.format.id_word() as usize + s])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::Preset;
    use crate::scene::Model;

    #[test]
    fn default_format_matches_the_design() {
        let f = Format::default();
        assert_eq!(f.nodes_per_block(), 128);
        assert_eq!(f.tris_per_block(), 204);
        assert_eq!(f.texels(), 512);
        assert!(f.id_word() + f.tris_per_block() <= f.words());
        assert!(Format::new(100).is_err());
        assert!(Format::new(0).is_err());
    }

    #[test]
    fn packed_blocks_read_back() {
        let tris: Vec<_> = (0..1000)
            .map(|i| {
                let x = i as f32;
                [[x, 0.0, 0.0], [x + 0.5, 1.0, 0.0], [x, 0.0, 1.0 + x]]
            })
            .collect();
        let model = Model::from_triangles(tris);
        let format = Format::new(1024).unwrap();
        let bvh = Bvh::build(&model, Preset::Fast, format.nodes_per_block() as usize);
        let blocks = Blocks::pack(&bvh, format).unwrap();
        for (i, n) in bvh.nodes.iter().enumerate() {
            assert_eq!(blocks.node(i as u32), *n);
        }
        for t in 0..bvh.triangles.len() {
            let (tri, id) = blocks.triangle(t as u32);
            assert_eq!(tri, bvh.triangles[t]);
            assert_eq!(id, bvh.prim_ids[t]);
        }
    }

    /// From the root block, the node blocks' children reach every node and triangle block, and
    /// name only blocks the tree uses: what a node of a block points to, in another block.
    #[test]
    fn child_blocks_reach_every_block_from_the_root() {
        let tris: Vec<_> = (0..3000)
            .map(|i| {
                let (x, y) = ((i % 60) as f32, (i / 60) as f32);
                [[x, y, 0.0], [x + 1.0, y, 0.5], [x, y + 1.0, 1.0]]
            })
            .collect();
        let model = Model::from_triangles(tris);
        let format = Format::new(1024).unwrap();
        let bvh = Bvh::build(&model, Preset::Fast, format.nodes_per_block() as usize);
        let blocks = Blocks::pack(&bvh, format).unwrap();
        let nb = blocks.node_blocks;
        let mut reached = vec![false; blocks.count() as usize];
        let mut todo = vec![0u32];
        reached[0] = true;
        while let Some(k) = todo.pop() {
            let children = format.child_blocks(k, blocks.block(k), nb);
            assert!(!children.contains(&k), "block {k} names itself");
            for c in children {
                assert!(c < blocks.count(), "block {k}: child {c}");
                if !std::mem::replace(&mut reached[c as usize], true) && c < nb {
                    todo.push(c);
                }
            }
        }
        assert!(nb > 2, "a tree of several node blocks: {nb}");
        let missed: Vec<usize> = (0..reached.len()).filter(|&k| !reached[k]).collect();
        assert!(
            missed.is_empty(),
            "blocks no node block leads to: {missed:?}"
        );
    }
}
