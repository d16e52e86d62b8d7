//! Coincident triangles: primitives whose boxes are exactly equal cannot be separated by any
//! split, and PLOC merges them into a chain (quadratic build, one level per triangle: 6k
//! identical triangles overflowed the traversal stack at depth 5,993). Large groups of them are
//! set aside before the build, which sees one representative per group, and put back after it
//! as a balanced tree by index below the representative's leaf, so the depth grows by about
//! log2 of the group's size. A model without such groups is built exactly as before.

use obvhs::aabb::Aabb;
use obvhs::bvh2::{Bvh2, node::Bvh2Node};
use rayon::prelude::*;
use std::collections::HashMap;

/// Smallest group set aside: smaller ones are left to the builder (real models have a few
/// duplicates, and their BVHs must not change).
const MIN_GROUP: usize = 16;
/// Most triangles in a leaf of a group's tree.
const LEAF: usize = 4;

/// The groups of a model's boxes.
pub struct Groups {
    /// The primitives the builder sees: every primitive outside a group and each group's first.
    pub kept: Vec<u32>,
    /// A group's members in input order, by its first member.
    members: HashMap<u32, Vec<u32>>,
}

fn key(b: &Aabb) -> [u32; 6] {
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]].map(f32::to_bits)
}

/// The large groups of exactly equal boxes; `None` when there is none.
pub fn find(aabbs: &[Aabb]) -> Option<Groups> {
    let mut order: Vec<([u32; 6], u32)> = aabbs
        .par_iter()
        .enumerate()
        .map(|(i, b)| (key(b), i as u32))
        .collect();
    order.par_sort_unstable();
    let mut members = HashMap::new();
    for run in order.chunk_by(|a, b| a.0 == b.0) {
        if run.len() >= MIN_GROUP {
            // Sorted by (key, index): the run is in input order.
            members.insert(run[0].1, run.iter().map(|e| e.1).collect::<Vec<_>>());
        }
    }
    if members.is_empty() {
        return None;
    }
    let mut set_aside = vec![false; aabbs.len()];
    for m in members.values() {
        for &p in &m[1..] {
            set_aside[p as usize] = true;
        }
    }
    let kept = (0..aabbs.len() as u32)
        .filter(|&p| !set_aside[p as usize])
        .collect();
    Some(Groups { kept, members })
}

impl Groups {
    /// Puts the groups back into `bvh`, built over the boxes of `kept` (in that order): its
    /// primitive indices become input indices, and each leaf holding a group's representative
    /// becomes a balanced tree over the leaf's primitives with every group expanded.
    pub fn restore(&self, bvh: &mut Bvh2, aabbs: &[Aabb]) {
        let old_prims = std::mem::take(&mut bvh.primitive_indices);
        let mut prims = Vec::with_capacity(aabbs.len());
        for i in 0..bvh.nodes.len() {
            let n = bvh.nodes[i];
            if n.prim_count == 0 {
                continue;
            }
            let first = n.first_index as usize;
            let list: Vec<u32> = old_prims[first..first + n.prim_count as usize]
                .iter()
                .flat_map(|&p| {
                    let p = self.kept[p as usize];
                    match self.members.get(&p) {
                        Some(m) => m.clone(),
                        None => vec![p],
                    }
                })
                .collect();
            bvh.nodes[i] = balanced(&mut bvh.nodes, &mut prims, aabbs, &list);
        }
        bvh.primitive_indices = prims;
    }
}

/// A node over `list` (input indices): a leaf when it is small, else two halves by position.
fn balanced(
    nodes: &mut Vec<Bvh2Node>,
    prims: &mut Vec<u32>,
    aabbs: &[Aabb],
    list: &[u32],
) -> Bvh2Node {
    if list.len() <= LEAF {
        let mut b = Aabb::INVALID;
        for &p in list {
            b = b.union(&aabbs[p as usize]);
        }
        let first = prims.len() as u32;
        prims.extend_from_slice(list);
        return Bvh2Node::new(b, list.len() as u32, first);
    }
    let at = nodes.len();
    nodes.extend([Bvh2Node::default(); 2]);
    let (l, r) = list.split_at(list.len() / 2);
    let left = balanced(nodes, prims, aabbs, l);
    let right = balanced(nodes, prims, aabbs, r);
    nodes[at] = left;
    nodes[at + 1] = right;
    Bvh2Node::new(left.aabb.union(&right.aabb), 0, at as u32)
}
