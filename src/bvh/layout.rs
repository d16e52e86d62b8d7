//! Conversion of an obvhs BVH2 to our node format in the blocked layout.
//!
//! Nodes are written treelet by treelet: breadth-first over the first `B` nodes below a treelet
//! root, then the same, depth-first, for each child pair the treelet left out. Smaller treelets
//! follow each other with no gaps (chapter 5.3.1), so a node block mostly holds one complete
//! subtree and a ray entering it takes about log2(B) steps before it needs another block.

use super::Node;
use obvhs::bvh2::Bvh2;
use std::collections::VecDeque;

pub struct Laid {
    pub nodes: Vec<Node>,
    pub triangles: Vec<[[f32; 3]; 3]>,
    pub prim_ids: Vec<u32>,
    pub depth: u32,
}

/// Index of the pad node that follows the root so that sibling pairs start at even indices.
pub const PAD: usize = 1;

pub fn blocked(bvh: &Bvh2, input: &[[[f32; 3]; 3]], treelet: usize) -> Laid {
    let treelet = treelet.max(4);
    let old = &bvh.nodes;
    // Triangles in BVH in-order (left subtree first), so that neighbouring leaves share blocks.
    let mut leaf_first = vec![0u32; old.len()];
    let mut triangles = Vec::with_capacity(input.len());
    let mut prim_ids = Vec::with_capacity(input.len());
    let mut depth = 0u32;
    let mut stack = vec![(0usize, 1u32)];
    while let Some((i, d)) = stack.pop() {
        depth = depth.max(d);
        let n = &old[i];
        if n.prim_count > 0 {
            leaf_first[i] = triangles.len() as u32;
            let first = n.first_index as usize;
            for &p in &bvh.primitive_indices[first..first + n.prim_count as usize] {
                triangles.push(input[p as usize]);
                prim_ids.push(p);
            }
        } else {
            let c = n.first_index as usize;
            stack.push((c + 1, d + 1));
            stack.push((c, d + 1));
        }
    }

    let convert = |i: usize| {
        let n = &old[i];
        Node {
            min: n.aabb.min.to_array(),
            max: n.aabb.max.to_array(),
            index: if n.prim_count > 0 { leaf_first[i] } else { 0 },
            count: n.prim_count,
        }
    };
    let mut nodes = Vec::with_capacity(old.len() + 1);
    nodes.push(convert(0));
    nodes.push(Node::default());

    // Places the child pair of `(old, new)`, returning the two children.
    let place_pair = |nodes: &mut Vec<Node>, (o, n): (usize, usize)| {
        let c = old[o].first_index as usize;
        let at = nodes.len();
        debug_assert!(at.is_multiple_of(2));
        nodes[n].index = at as u32;
        nodes.push(convert(c));
        nodes.push(convert(c + 1));
        [(c, at), (c + 1, at + 1)]
    };
    // Each entry is a node whose children still have to be placed: it starts a treelet.
    let mut pending: Vec<(usize, usize)> = Vec::new();
    let grow = |nodes: &mut Vec<Node>,
                pending: &mut Vec<(usize, usize)>,
                start: &[(usize, usize)],
                mut placed: usize| {
        let mut queue: VecDeque<(usize, usize)> = start.iter().copied().collect();
        let mut frontier = Vec::new();
        while let Some(e) = queue.pop_front() {
            if old[e.0].prim_count > 0 {
                continue;
            }
            if placed + 2 <= treelet {
                queue.extend(place_pair(nodes, e));
                placed += 2;
            } else {
                frontier.push(e);
            }
        }
        // Depth-first over the frontier: push in reverse so the first is laid out next.
        pending.extend(frontier.into_iter().rev());
    };
    grow(&mut nodes, &mut pending, &[(0, 0)], 2);
    while let Some(e) = pending.pop() {
        let pair = place_pair(&mut nodes, e);
        grow(&mut nodes, &mut pending, &pair, 2);
    }
    Laid {
        nodes,
        triangles,
        prim_ids,
        depth,
    }
}

#[cfg(test)]
mod tests {
    use crate::bvh::{Bvh, Node, Preset};
    use crate::scene::Model;

    fn soup(n: usize) -> Model {
        let mut s = 12345u64;
        let mut r = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        let tris = (0..n)
            .map(|_| {
                let c = [r() * 10.0, r() * 10.0, r() * 10.0];
                std::array::from_fn(|_| std::array::from_fn(|a| c[a] + r() * 0.3))
            })
            .collect();
        Model::from_triangles(tris)
    }

    fn contains(outer: &Node, inner: &Node) -> bool {
        (0..3).all(|a| outer.min[a] <= inner.min[a] && inner.max[a] <= outer.max[a])
    }

    /// A soup with groups of identical triangles among its own: 20,000 copies of one, 100 of
    /// another, interleaved with the rest.
    fn soup_with_coincident(n: usize) -> Model {
        let mut tris = soup(n).triangles;
        let (a, b) = (tris[0], tris[1]);
        for i in 0..20_000 {
            tris.insert((i * 7) % tris.len(), a);
            if i < 100 {
                tris.push(b);
            }
        }
        Model::from_triangles(tris)
    }

    #[test]
    fn layout_is_a_valid_tree_over_every_triangle() {
        for (n, b) in [(1, 256), (2, 256), (1000, 256), (5000, 16), (20000, 256)] {
            check_tree(&soup(n), b);
        }
    }

    /// Coincident triangles cannot be split apart: they end up in a balanced tree by index, in
    /// near-linear time, instead of a chain as deep as the group is large.
    #[test]
    fn coincident_triangles_make_a_shallow_tree() {
        let model = soup_with_coincident(3000);
        let t = std::time::Instant::now();
        let bvh = check_tree(&model, 256);
        assert!(bvh.depth <= 40, "depth {}", bvh.depth);
        assert!(t.elapsed().as_secs() < 10, "{:?}", t.elapsed());
        let same = Model::from_triangles(vec![model.triangles[0]; 20_000]);
        let bvh = check_tree(&same, 256);
        assert!(bvh.depth <= 16, "depth {}", bvh.depth);
    }

    /// Walks the tree of `model`: every triangle once, every node reached once, pairs even and
    /// inside their parent, leaf ranges covering the triangle list in order, the depth as said.
    fn check_tree(model: &Model, b: usize) -> Bvh {
        {
            let n = model.triangles.len();
            let bvh = Bvh::build(model, Preset::Fast, b);
            let mut seen = vec![false; n];
            for &p in &bvh.prim_ids {
                assert!(!seen[p as usize], "primitive {p} twice");
                seen[p as usize] = true;
            }
            assert!(seen.iter().all(|&s| s));
            for (i, t) in bvh.triangles.iter().enumerate() {
                assert_eq!(*t, model.triangles[bvh.prim_ids[i] as usize]);
            }
            // Walk the tree: every node reached once, pairs even and inside their parent, leaf
            // ranges cover the triangle list in order.
            let mut reached = vec![0u32; bvh.nodes.len()];
            let mut next_tri = 0u32;
            let mut stack = vec![(0usize, 1u32)];
            let mut depth = 0;
            while let Some((i, d)) = stack.pop() {
                depth = depth.max(d);
                reached[i] += 1;
                let node = bvh.nodes[i];
                if node.is_leaf() {
                    assert_eq!(node.index, next_tri, "in-order triangle ranges");
                    next_tri += node.count;
                } else {
                    let c = node.index as usize;
                    assert_eq!(c % 2, 0, "pair at odd index");
                    assert!(c > i, "children after parents");
                    assert!(contains(&node, &bvh.nodes[c]) && contains(&node, &bvh.nodes[c + 1]));
                    stack.push((c + 1, d + 1));
                    stack.push((c, d + 1));
                }
            }
            assert_eq!(next_tri as usize, n);
            assert_eq!(depth, bvh.depth);
            assert_eq!(reached[1], 0, "pad node is never referenced");
            assert!(reached.iter().enumerate().all(|(i, &r)| r == 1 || i == 1));
            bvh
        }
    }

    #[test]
    fn first_block_is_breadth_first() {
        let bvh = Bvh::build(&soup(20000), Preset::Fast, 256);
        // The root's children are at 2, 3; theirs at 4..8: breadth-first order.
        assert_eq!(bvh.nodes[0].index, 2);
        assert_eq!(bvh.nodes[2].index, 4);
        assert_eq!(bvh.nodes[3].index, 6);
    }
}
