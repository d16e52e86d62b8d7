//! Trees built apart joined under a top tree, in one blocked layout: how the out-of-core build
//! (docs/ARCHITECTURE.md, Out-of-core prepare) makes one BVH of its parts.
//!
//! The top tree is the tree of the cuts that made the parts (`Cuts`), one part per leaf,
//! collapsed to wide nodes as the parts' trees are (`layout::collapse`); a part's root is an
//! inner child of a top node. The joined tree numbers its nodes:
//!
//! 1. the top nodes and the parts' roots, breadth-first, each node's children adjacent;
//! 2. each part's first treelet but its root, part after part (the treelets are grown to
//!    `Top::head` nodes, so that with a few dozen parts the top of every part is in block 0 with
//!    the top tree, replicated on every rank);
//! 3. the rest of each part, part after part, in its own blocked layout, each starting a block
//!    (after `Node::PADDING` nodes) unless it fits in what is left of the block before, so that
//!    its treelets lie in blocks as the part laid them out.
//!
//! Parts are numbered depth-first over the top tree, and their triangles follow each other in
//! that order, so the joined tree's triangles are in depth-first order as a tree built whole has
//! them. A single part is its own tree: the numbering is then the part's own.

use super::{INNER, Node, WIDTH, layout::collapse};
use obvhs::aabb::Aabb;
use obvhs::bvh2::{Bvh2, node::Bvh2Node};

/// A slot of a top node: another top node, or a part's root (by depth-first part number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Slot {
    Top(usize),
    Part(usize),
}

/// The top tree over the parts, before the parts are built.
pub struct Top {
    bvh: Bvh2,
    /// Top node t's slots: BVH2 nodes and what they are.
    slots: Vec<Vec<(usize, Slot)>>,
    /// Top node t's children start here in the numbering.
    child_base: Vec<u32>,
    /// The breadth-first numbering of top nodes and part roots.
    entries: Vec<Slot>,
    /// `order[p]` is the input index of depth-first part p.
    pub order: Vec<usize>,
    /// Depth-first part p's root: its number and its level (the root is level 1).
    root_at: Vec<u32>,
    level: Vec<u32>,
}

/// A part as built: its node count, the nodes of its first treelet (root included), its depth
/// and its triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PartShape {
    pub nodes: u32,
    pub head: u32,
    pub depth: u32,
    pub triangles: u64,
}

/// How parts were cut: a binary tree whose leaves are parts (their index). The top tree is this
/// tree, its nodes' boxes the unions of their parts' boxes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Cuts {
    Part(usize),
    Two(Box<Cuts>, Box<Cuts>),
}

impl Cuts {
    /// The parts, left to right.
    pub fn parts(&self) -> Vec<usize> {
        match self {
            Cuts::Part(p) => vec![*p],
            Cuts::Two(a, b) => {
                let mut v = a.parts();
                v.extend(b.parts());
                v
            }
        }
    }

    /// The tree as an obvhs BVH2 over parts of bounds `boxes`: a leaf per part.
    fn bvh2(&self, boxes: &[Aabb]) -> Bvh2 {
        fn go(c: &Cuts, i: usize, boxes: &[Aabb], b: &mut Bvh2) {
            b.nodes[i] = match c {
                Cuts::Part(p) => {
                    b.primitive_indices.push(*p as u32);
                    Bvh2Node {
                        aabb: boxes[*p],
                        prim_count: 1,
                        first_index: b.primitive_indices.len() as u32 - 1,
                        ..Default::default()
                    }
                }
                Cuts::Two(l, r) => {
                    let k = b.nodes.len();
                    b.nodes.extend([Bvh2Node::default(); 2]);
                    go(l, k, boxes, b);
                    go(r, k + 1, boxes, b);
                    Bvh2Node {
                        aabb: b.nodes[k].aabb.union(&b.nodes[k + 1].aabb),
                        prim_count: 0,
                        first_index: k as u32,
                        ..Default::default()
                    }
                }
            };
        }
        let mut b = Bvh2::default();
        b.nodes.push(Bvh2Node::default());
        go(self, 0, boxes, &mut b);
        b
    }
}

impl Top {
    /// The top tree of parts cut as `cuts`, whose triangles have the bounds `boxes`.
    pub fn new(cuts: &Cuts, boxes: &[Aabb]) -> Top {
        assert_eq!(cuts.parts().len(), boxes.len(), "a leaf per part");
        if let Cuts::Part(_) = cuts {
            return Top {
                bvh: Bvh2::default(),
                slots: Vec::new(),
                child_base: Vec::new(),
                entries: vec![Slot::Part(0)],
                order: cuts.parts(),
                root_at: vec![0],
                level: vec![1],
            };
        }
        let bvh = cuts.bvh2(boxes);
        // Which input part a BVH2 leaf holds.
        let part_of = |k: usize| {
            let n = &bvh.nodes[k];
            bvh.primitive_indices[n.first_index as usize] as usize
        };
        // Top nodes, breadth-first; a leaf kid is a part, numbered depth-first below.
        let mut tops: Vec<Vec<usize>> = vec![collapse(&bvh, 0)];
        let mut kinds: Vec<Vec<Option<usize>>> = Vec::new();
        let mut t = 0;
        while t < tops.len() {
            let mut kind = Vec::new();
            for i in 0..tops[t].len() {
                let k = tops[t][i];
                if bvh.nodes[k].prim_count > 0 {
                    kind.push(None);
                } else {
                    kind.push(Some(tops.len()));
                    tops.push(collapse(&bvh, k));
                }
            }
            kinds.push(kind);
            t += 1;
        }
        // Parts numbered depth-first, in slot order.
        fn walk(
            t: usize,
            tops: &[Vec<usize>],
            kinds: &[Vec<Option<usize>>],
            part_of: &dyn Fn(usize) -> usize,
            order: &mut Vec<usize>,
        ) {
            for (i, &k) in tops[t].iter().enumerate() {
                match kinds[t][i] {
                    None => order.push(part_of(k)),
                    Some(c) => walk(c, tops, kinds, part_of, order),
                }
            }
        }
        let mut order = Vec::with_capacity(boxes.len());
        walk(0, &tops, &kinds, &part_of, &mut order);
        let mut dfs_of = vec![usize::MAX; boxes.len()];
        for (p, &input) in order.iter().enumerate() {
            dfs_of[input] = p;
        }
        // Breadth-first numbering: top node t's children are adjacent from child_base[t].
        let mut entries = vec![Slot::Top(0)];
        let mut child_base = vec![0u32; tops.len()];
        let mut root_at = vec![0u32; boxes.len()];
        let mut level = vec![0u32; boxes.len()];
        let mut top_level = vec![1u32; tops.len()];
        let mut slots = Vec::with_capacity(tops.len());
        for t in 0..tops.len() {
            child_base[t] = entries.len() as u32;
            let mut s = Vec::with_capacity(tops[t].len());
            for (i, &k) in tops[t].iter().enumerate() {
                let slot = match kinds[t][i] {
                    None => {
                        let p = dfs_of[part_of(k)];
                        root_at[p] = entries.len() as u32;
                        level[p] = top_level[t] + 1;
                        Slot::Part(p)
                    }
                    Some(c) => {
                        top_level[c] = top_level[t] + 1;
                        Slot::Top(c)
                    }
                };
                entries.push(slot);
                s.push((k, slot));
            }
            slots.push(s);
        }
        // Top nodes were created breadth-first, so entries list them in creation order.
        debug_assert!(
            entries
                .iter()
                .filter_map(|e| match e {
                    Slot::Top(t) => Some(*t),
                    Slot::Part(_) => None,
                })
                .eq(0..tops.len())
        );
        Top {
            bvh,
            slots,
            child_base,
            entries,
            order,
            root_at,
            level,
        }
    }

    pub fn parts(&self) -> usize {
        self.order.len()
    }

    /// Top nodes (0 for a single part).
    pub fn nodes(&self) -> usize {
        self.slots.len()
    }

    /// The most nodes each part's first treelet may have: a whole treelet for a single part;
    /// else an equal share of what block 0 has left after the top nodes and the part roots.
    pub fn head(&self, nodes_per_block: usize) -> usize {
        let (p, t) = (self.parts(), self.nodes());
        if p == 1 {
            nodes_per_block
        } else {
            1 + nodes_per_block.saturating_sub(t + p) / p
        }
    }

    /// Whether the join puts each part's nodes after its head at the start of a block, so that
    /// parts lay their treelets out counting blocks from there (`layout::blocked`): with
    /// several parts; a single part is numbered as laid out.
    pub fn rests_start_blocks(&self) -> bool {
        self.parts() > 1
    }

    /// The joined tree, once every part is built; `parts[p]` is depth-first part p, in blocks of
    /// `nodes_per_block` nodes.
    pub fn join(&self, parts: &[PartShape], nodes_per_block: usize) -> Joined {
        assert_eq!(parts.len(), self.parts());
        let npb = nodes_per_block.max(1) as u64;
        let first = self.entries.len() as u64;
        let mut head_base = Vec::with_capacity(parts.len());
        let mut at = first;
        for s in parts {
            head_base.push(at);
            at += u64::from(s.head) - 1;
        }
        let mut rest_base = Vec::with_capacity(parts.len());
        let mut pads = Vec::with_capacity(parts.len());
        for s in parts {
            let rest = u64::from(s.nodes - s.head);
            let room = npb - at % npb;
            let pad = if self.rests_start_blocks() && rest > room && room < npb {
                room
            } else {
                0
            };
            pads.push(pad as u32);
            at += pad;
            rest_base.push(at);
            at += rest;
        }
        let mut tri_base = Vec::with_capacity(parts.len());
        let mut tris = 0u64;
        for s in parts {
            tri_base.push(tris);
            tris += s.triangles;
        }
        let depth = parts
            .iter()
            .zip(&self.level)
            .map(|(s, &l)| l + s.depth - 1)
            .max()
            .unwrap_or(1);
        // A top node's first triangle is its first part's (the depth-first position).
        let first_part = |t: usize| -> usize {
            let mut t = t;
            loop {
                match self.slots[t][0].1 {
                    Slot::Part(p) => return p,
                    Slot::Top(c) => t = c,
                }
            }
        };
        let top_nodes = (0..self.nodes())
            .map(|t| {
                let boxes: Vec<_> = self.slots[t]
                    .iter()
                    .map(|&(k, _)| {
                        let b = &self.bvh.nodes[k].aabb;
                        (b.min.to_array(), b.max.to_array())
                    })
                    .collect();
                let mut node = Node::quantized(&boxes);
                node.child_base = self.child_base[t];
                node.tri_base = tri_base[first_part(t)] as u32;
                for i in 0..boxes.len() {
                    node.counts |= INNER << (8 * i);
                }
                debug_assert!(boxes.len() <= WIDTH);
                node
            })
            .collect();
        Joined {
            nodes: at,
            depth,
            triangles: tris,
            top_nodes,
            entries: self.entries.clone(),
            parts: parts.to_vec(),
            root_at: self.root_at.clone(),
            head_base,
            rest_base,
            pads,
            tri_base,
        }
    }
}

/// The joined tree's numbering: where each part's nodes go and how their indices change.
pub struct Joined {
    /// Nodes and triangles in all, and the depth.
    pub nodes: u64,
    pub depth: u32,
    pub triangles: u64,
    top_nodes: Vec<Node>,
    entries: Vec<Slot>,
    parts: Vec<PartShape>,
    root_at: Vec<u32>,
    head_base: Vec<u64>,
    rest_base: Vec<u64>,
    /// `Node::PADDING` nodes before each part's rest.
    pads: Vec<u32>,
    tri_base: Vec<u64>,
}

/// A run of the joined tree's nodes, in numbering order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Run {
    /// A top node, given whole.
    Top(usize),
    /// Part `part`'s nodes `first..first + count`, to be read and mapped (`Joined::map`).
    Part { part: usize, first: u32, count: u32 },
    /// `Node::PADDING`, this many.
    Pad(u32),
}

impl Joined {
    /// Every node of the joined tree, in order, as runs.
    pub fn runs(&self) -> Vec<Run> {
        let mut runs: Vec<Run> = self
            .entries
            .iter()
            .map(|e| match *e {
                Slot::Top(t) => Run::Top(t),
                Slot::Part(p) => Run::Part {
                    part: p,
                    first: 0,
                    count: 1,
                },
            })
            .collect();
        for (p, s) in self.parts.iter().enumerate() {
            runs.push(Run::Part {
                part: p,
                first: 1,
                count: s.head - 1,
            });
        }
        for (p, s) in self.parts.iter().enumerate() {
            runs.push(Run::Pad(self.pads[p]));
            runs.push(Run::Part {
                part: p,
                first: s.head,
                count: s.nodes - s.head,
            });
        }
        runs.retain(|r| !matches!(r, Run::Part { count: 0, .. } | Run::Pad(0)));
        runs
    }

    pub fn top_node(&self, t: usize) -> Node {
        self.top_nodes[t]
    }

    /// Part `part`'s node, as laid out in the part, with its indices in the joined numbering.
    pub fn map(&self, part: usize, mut node: Node) -> Node {
        let s = &self.parts[part];
        let inner = (0..WIDTH).any(|i| (node.counts >> (8 * i)) & 0xff == INNER);
        if inner {
            let c = node.child_base;
            debug_assert!(c >= 1 && c < s.nodes, "children follow their parent");
            node.child_base = if c < s.head {
                self.head_base[part] + u64::from(c) - 1
            } else {
                self.rest_base[part] + u64::from(c - s.head)
            } as u32;
        }
        node.tri_base = (self.tri_base[part] + u64::from(node.tri_base)) as u32;
        node
    }

    /// Where part `part`'s node `local` is in the joined numbering.
    pub fn position(&self, part: usize, local: u32) -> u64 {
        let s = &self.parts[part];
        if local == 0 {
            u64::from(self.root_at[part])
        } else if local < s.head {
            self.head_base[part] + u64::from(local) - 1
        } else {
            self.rest_base[part] + u64::from(local - s.head)
        }
    }

    /// Part `part`'s first triangle in the joined order.
    pub fn first_triangle(&self, part: usize) -> u64 {
        self.tri_base[part]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::layout::tests::{check_nodes, check_treelets, soup, treelet_ranges};
    use crate::bvh::{Build, Built, Bvh, Preset, triangle_box};
    use crate::scene::Model;

    /// `model` cut into `parts` slabs along x (as a partition would), each built with the top
    /// tree's head, joined: the nodes, triangles and input ids of the joined tree, and its depth.
    fn joined(model: &Model, parts: usize, npb: usize) -> (Vec<Node>, Vec<u32>, u32, Top) {
        let mut ids: Vec<u32> = (0..model.triangles.len() as u32).collect();
        let cx = |i: &u32| {
            let t = &model.triangles[*i as usize];
            t[0][0] + t[1][0] + t[2][0]
        };
        ids.sort_by(|a, b| cx(a).total_cmp(&cx(b)));
        let chunk = ids.len().div_ceil(parts);
        let groups: Vec<Vec<u32>> = ids.chunks(chunk).map(<[u32]>::to_vec).collect();
        let boxes: Vec<Aabb> = groups
            .iter()
            .map(|g| {
                let mut b = Aabb::INVALID;
                for &i in g {
                    b = b.union(&triangle_box(&model.triangles[i as usize]));
                }
                b
            })
            .collect();
        fn balanced(a: usize, b: usize) -> Cuts {
            if b - a == 1 {
                return Cuts::Part(a);
            }
            let m = (a + b) / 2;
            Cuts::Two(Box::new(balanced(a, m)), Box::new(balanced(m, b)))
        }
        let top = Top::new(&balanced(0, groups.len()), &boxes);
        let head = top.head(npb);
        let built: Vec<(Vec<u32>, Built)> = top
            .order
            .iter()
            .map(|&g| {
                let tris: Vec<_> = groups[g]
                    .iter()
                    .map(|&i| model.triangles[i as usize])
                    .collect();
                (
                    groups[g].clone(),
                    Built::over(&tris, Build::default(), npb, head, top.rests_start_blocks()),
                )
            })
            .collect();
        let shapes: Vec<PartShape> = built
            .iter()
            .map(|(g, b)| PartShape {
                nodes: b.laid.nodes.len() as u32,
                head: b.laid.head as u32,
                depth: b.laid.depth,
                triangles: g.len() as u64,
            })
            .collect();
        let j = top.join(&shapes, npb);
        let mut nodes = Vec::new();
        for run in j.runs() {
            match run {
                Run::Top(t) => nodes.push(j.top_node(t)),
                Run::Pad(n) => nodes.extend((0..n).map(|_| Node::PADDING)),
                Run::Part { part, first, count } => {
                    for l in first..first + count {
                        assert_eq!(j.position(part, l), nodes.len() as u64);
                        nodes.push(j.map(part, built[part].1.laid.nodes[l as usize]));
                    }
                }
            }
        }
        assert_eq!(nodes.len() as u64, j.nodes);
        let prim_ids: Vec<u32> = built
            .iter()
            .flat_map(|(g, b)| b.laid.prim_ids.iter().map(|&l| g[l as usize]))
            .collect();
        // Each part's treelets after its head lie in blocks of the joined tree as in the part.
        for (p, (_, b)) in built.iter().enumerate() {
            let at = |l: usize| j.position(p, l as u32) as usize;
            let ranges: Vec<(usize, usize)> = treelet_ranges(&b.laid)
                .into_iter()
                .filter(|&(s, _)| s >= b.laid.head)
                .map(|(s, e)| (at(s), at(e - 1) + 1))
                .collect();
            check_treelets(&nodes, &ranges, npb);
        }
        (nodes, prim_ids, j.depth, top)
    }

    /// Joined trees are valid trees over every triangle (every node reached once, children after
    /// parents, every box around its triangles, triangles depth-first, the depth as said), for
    /// one part, a few, and more than block 0 holds; with a few parts, every part's root and
    /// first treelet are in block 0.
    #[test]
    fn joined_parts_make_one_valid_tree() {
        let model = soup(20_000);
        for parts in [1, 2, 5, 24, 150] {
            let (nodes, ids, depth, top) = joined(&model, parts, 128);
            let tris: Vec<_> = ids.iter().map(|&i| model.triangles[i as usize]).collect();
            check_nodes(&nodes, &tris, &ids, &model, depth);
            assert_eq!(top.parts(), parts);
            if parts == 24 {
                let head = top.head(128);
                assert!(head > 1, "room for heads");
                assert!(top.entries.len() + parts * (head - 1) <= 128);
            }
            if parts == 150 {
                assert_eq!(top.head(128), 1);
            }
        }
    }

    /// A single part is laid out exactly as a tree built whole.
    #[test]
    fn one_part_is_the_tree_built_whole() {
        let model = soup(5_000);
        let (nodes, ids, depth, _) = joined(&model, 1, 128);
        let mut sorted = model.clone();
        let order = {
            let mut ids: Vec<u32> = (0..model.triangles.len() as u32).collect();
            let cx = |i: &u32| {
                let t = &model.triangles[*i as usize];
                t[0][0] + t[1][0] + t[2][0]
            };
            ids.sort_by(|a, b| cx(a).total_cmp(&cx(b)));
            ids
        };
        sorted.triangles = order.iter().map(|&i| model.triangles[i as usize]).collect();
        let whole = Bvh::build(&sorted, Preset::Fast, 128);
        assert_eq!(nodes, whole.nodes);
        assert_eq!(depth, whole.depth);
        let whole_ids: Vec<u32> = whole.prim_ids.iter().map(|&p| order[p as usize]).collect();
        assert_eq!(ids, whole_ids);
    }
}
