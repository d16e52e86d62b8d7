//! Conversion of an obvhs BVH2 to our 4-wide node format in the blocked layout.
//!
//! Each wide node takes a BVH2 node's two children and, while it has fewer than `WIDTH`, opens
//! the inner child with the largest surface area in its place. Nodes are written treelet by
//! treelet: breadth-first over the first `B` nodes below a treelet root, a node's inner children
//! always adjacent, then the same, depth-first, for each node whose children the treelet left
//! out (chapter 5.3.1). A treelet takes at most the nodes left in the block it starts in, so
//! that it lies in one block and the next starts a block (a node's inner children, kept
//! adjacent, may still cross a boundary). Triangles follow in depth-first order, a node's leaves adjacent (chapter
//! 5.3.2), so neighbouring leaves share triangle blocks.

use super::{EMPTY, INNER, MAX_LEAF, Node, WIDTH};
use obvhs::bvh2::Bvh2;
use std::collections::VecDeque;

pub struct Laid {
    pub nodes: Vec<Node>,
    /// `prim_ids[i]` is the input index of the i-th triangle in layout order.
    pub prim_ids: Vec<u32>,
    pub depth: u32,
    /// Nodes of the first treelet (the root's), `nodes[..head]`.
    pub head: usize,
    /// Where each treelet starts, in order (the first at 0): each runs to the next.
    pub treelets: Vec<usize>,
}

/// The BVH2 nodes a wide node over BVH2 node `i` holds, in slot order.
pub(super) fn collapse(bvh: &Bvh2, i: usize) -> Vec<usize> {
    let old = &bvh.nodes;
    let n = &old[i];
    if n.prim_count > 0 {
        // A lone leaf (a root over few triangles) becomes the root's only child.
        return vec![i];
    }
    let c = n.first_index as usize;
    let mut kids = vec![c, c + 1];
    while kids.len() < WIDTH {
        let open = kids
            .iter()
            .enumerate()
            .filter(|&(_, &k)| old[k].prim_count == 0)
            .max_by(|a, b| {
                old[*a.1]
                    .aabb
                    .half_area()
                    .total_cmp(&old[*b.1].aabb.half_area())
            });
        let Some((at, &k)) = open else { break };
        let g = old[k].first_index as usize;
        kids[at] = g;
        kids.insert(at + 1, g + 1);
    }
    kids
}

/// Lays `bvh` out with treelets in blocks of `treelet` nodes, the first (the root's) of at most
/// `head` nodes, each other one of at most the nodes left in its block; triangles are numbered
/// depth-first (`Laid::prim_ids`). Blocks are counted in the layout's own numbering, or with
/// `rest_starts_a_block` from the first node after the head (an out-of-core part, whose nodes
/// after the head the join puts at the start of a block, `join::Top::join`).
pub fn blocked(bvh: &Bvh2, treelet: usize, head: usize, rest_starts_a_block: bool) -> Laid {
    let treelet = treelet.max(1);
    let head = head.max(1);
    let old = &bvh.nodes;
    let is_leaf = |k: usize| old[k].prim_count > 0;
    // Placement: `kids[n]` are the BVH2 nodes of wide node n's slots; its inner children are
    // placed adjacently, from `base[n]`.
    let mut kids: Vec<Vec<usize>> = vec![collapse(bvh, 0)];
    let mut base: Vec<u32> = vec![0];
    // Places the inner children of wide node `n`, returning their indices.
    let place = |kids: &mut Vec<Vec<usize>>, base: &mut Vec<u32>, n: usize| {
        let at = kids.len();
        base[n] = at as u32;
        let inner: Vec<usize> = kids[n].iter().copied().filter(|&k| !is_leaf(k)).collect();
        for &k in &inner {
            kids.push(collapse(bvh, k));
            base.push(0);
        }
        at..at + inner.len()
    };
    let inner_count =
        |kids: &Vec<Vec<usize>>, n: usize| kids[n].iter().filter(|&&k| !is_leaf(k)).count();
    // Each entry is a node whose children still have to be placed: it starts a treelet.
    let mut pending: Vec<usize> = Vec::new();
    let grow = |kids: &mut Vec<Vec<usize>>,
                base: &mut Vec<u32>,
                pending: &mut Vec<usize>,
                start: std::ops::Range<usize>,
                mut placed: usize,
                treelet: usize| {
        let mut queue: VecDeque<usize> = start.collect();
        let mut frontier = Vec::new();
        while let Some(n) = queue.pop_front() {
            let m = inner_count(kids, n);
            if m == 0 {
                continue;
            }
            if placed + m <= treelet {
                queue.extend(place(kids, base, n));
                placed += m;
            } else {
                frontier.push(n);
            }
        }
        // Depth-first over the frontier: push in reverse so the first is laid out next.
        pending.extend(frontier.into_iter().rev());
    };
    grow(&mut kids, &mut base, &mut pending, 0..1, 1, head);
    let head_nodes = kids.len();
    let origin = if rest_starts_a_block { head_nodes } else { 0 };
    let mut treelets = vec![0];
    while let Some(n) = pending.pop() {
        treelets.push(kids.len());
        // Treelets filled to `treelet` nodes wherever they started would straddle two blocks
        // (rm 1M: 4.33 node blocks entered a ray against 3.96 ending them at a boundary).
        let room = treelet - (kids.len() - origin) % treelet;
        let group = place(&mut kids, &mut base, n);
        let m = group.len();
        grow(&mut kids, &mut base, &mut pending, group, m, room.max(m));
    }

    // Triangles depth-first, each node's leaves adjacent in slot order; the depth on the way.
    let mut tri_base = vec![0u32; kids.len()];
    let mut prim_ids = Vec::with_capacity(bvh.primitive_indices.len());
    let mut depth = 0u32;
    let mut stack = vec![(0usize, 1u32)];
    while let Some((n, d)) = stack.pop() {
        depth = depth.max(d);
        tri_base[n] = prim_ids.len() as u32;
        for &k in kids[n].iter().filter(|&&k| is_leaf(k)) {
            let first = old[k].first_index as usize;
            prim_ids.extend_from_slice(
                &bvh.primitive_indices[first..first + old[k].prim_count as usize],
            );
        }
        let m = inner_count(&kids, n) as u32;
        for c in (0..m).rev() {
            stack.push(((base[n] + c) as usize, d + 1));
        }
    }

    let nodes = (0..kids.len())
        .map(|n| {
            let boxes: Vec<_> = kids[n]
                .iter()
                .map(|&k| (old[k].aabb.min.to_array(), old[k].aabb.max.to_array()))
                .collect();
            let mut node = Node::quantized(&boxes);
            node.child_base = base[n];
            node.tri_base = tri_base[n];
            for (i, &k) in kids[n].iter().enumerate() {
                let count = if is_leaf(k) {
                    assert!(
                        old[k].prim_count <= MAX_LEAF,
                        "leaf of {} triangles",
                        old[k].prim_count
                    );
                    old[k].prim_count
                } else {
                    INNER
                };
                node.counts |= count << (8 * i);
            }
            debug_assert!(kids[n].len() <= WIDTH && EMPTY == 0);
            node
        })
        .collect();
    Laid {
        nodes,
        prim_ids,
        depth,
        head: head_nodes,
        treelets,
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::Laid;
    use crate::bvh::{Build, Built, Bvh, Child, Node, Preset, WIDTH};
    use crate::scene::Model;

    pub(in crate::bvh) fn soup(n: usize) -> Model {
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

    /// A lower node cost makes smaller leaves and more nodes, a valid tree all the same.
    #[test]
    fn a_lower_node_cost_makes_smaller_leaves() {
        let model = soup(20000);
        let leaves = |bvh: &Bvh| -> (usize, usize) {
            let counts = bvh
                .nodes
                .iter()
                .flat_map(|n| (0..WIDTH).map(move |i| (n.counts >> (8 * i)) & 0xff));
            let leaf = counts.filter(|&c| c != crate::bvh::EMPTY && c != crate::bvh::INNER);
            leaf.fold((0, 0), |(k, t), c| (k + 1, t + c as usize))
        };
        let default = Bvh::build(&model, Build::default(), 256);
        let (k3, t3) = leaves(&default);
        for cost in [1.0, 0.5] {
            let build = Build {
                node_cost: cost,
                ..Build::default()
            };
            let bvh = Bvh::build(&model, build, 256);
            check_nodes(&bvh.nodes, &bvh.triangles, &bvh.prim_ids, &model, bvh.depth);
            let (k, t) = leaves(&bvh);
            assert_eq!(t, t3, "cost {cost}: every triangle in one leaf");
            assert!(
                k * 2 > k3 * 3 && bvh.nodes.len() > default.nodes.len(),
                "cost {cost}: {k} leaves and {} nodes against {k3} and {} at the default",
                bvh.nodes.len(),
                default.nodes.len()
            );
        }
    }

    /// Walks the tree of `model`: every triangle once, every node reached once, children after
    /// parents, every decoded child box around its triangles, leaf ranges covering the triangle
    /// list in depth-first order, the depth as said.
    fn check_tree(model: &Model, b: usize) -> Bvh {
        let bvh = Bvh::build(model, Preset::Fast, b);
        check_nodes(&bvh.nodes, &bvh.triangles, &bvh.prim_ids, model, bvh.depth);
        bvh
    }

    /// The checks of `check_tree` on a tree given as its parts: `nodes`, `triangles` in layout
    /// order with their input ids `prim_ids`, over `model`, of depth `depth`.
    pub(in crate::bvh) fn check_nodes(
        nodes: &[Node],
        triangles: &[[[f32; 3]; 3]],
        prim_ids: &[u32],
        model: &Model,
        depth_said: u32,
    ) {
        let n = model.triangles.len();
        let mut seen = vec![false; n];
        for &p in prim_ids {
            assert!(!seen[p as usize], "primitive {p} twice");
            seen[p as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
        for (i, t) in triangles.iter().enumerate() {
            assert_eq!(*t, model.triangles[prim_ids[i] as usize]);
        }
        let inside = |(lo, hi): ([f32; 3], [f32; 3]), t: &[[f32; 3]; 3]| {
            t.iter()
                .all(|v| (0..3).all(|a| lo[a] <= v[a] && v[a] <= hi[a]))
        };
        // The triangles below node i, checked against every box on the way down.
        let mut reached = vec![0u32; nodes.len()];
        let mut next_tri = 0u32;
        let mut depth = 0;
        // (node, depth, the boxes of its ancestors' slots that lead to it)
        let mut stack = vec![(0usize, 1u32, vec![nodes[0].bounds()])];
        while let Some((i, d, boxes)) = stack.pop() {
            depth = depth.max(d);
            reached[i] += 1;
            let node = nodes[i];
            assert_eq!(
                node.tri_base, next_tri,
                "node {i}: depth-first triangle ranges"
            );
            let mut inner = Vec::new();
            for s in 0..WIDTH {
                let mut bs = boxes.clone();
                bs.push(node.child_box(s));
                match node.child(s) {
                    Child::Empty => {}
                    Child::Inner(c) => {
                        assert!(c as usize > i, "children after parents");
                        inner.push((c as usize, d + 1, bs));
                    }
                    Child::Leaf { first, count } => {
                        assert_eq!(first, next_tri, "node {i} slot {s}: leaves adjacent");
                        for t in first..first + count {
                            let tri = &triangles[t as usize];
                            assert!(bs.iter().all(|&b| inside(b, tri)), "node {i} slot {s}");
                        }
                        next_tri += count;
                    }
                }
            }
            let want: Vec<usize> = (0..inner.len())
                .map(|k| node.child_base as usize + k)
                .collect();
            assert_eq!(inner.iter().map(|c| c.0).collect::<Vec<_>>(), want);
            stack.extend(inner.into_iter().rev());
        }
        // Inner children's boxes are checked through their own leaves' triangles above.
        assert_eq!(next_tri as usize, n);
        assert_eq!(depth, depth_said);
        // Every node once, but the out-of-core join's padding, which no node reaches.
        for (i, &r) in reached.iter().enumerate() {
            assert!(
                r == 1 || (r == 0 && nodes[i] == Node::PADDING),
                "node {i} reached {r} times"
            );
        }
    }

    /// Each treelet (`start..end` in `nodes`) lies in one block of `t` nodes, or is one node's
    /// inner children.
    pub(in crate::bvh) fn check_treelets(nodes: &[Node], treelets: &[(usize, usize)], t: usize) {
        for &(s, e) in treelets {
            if s / t == (e - 1) / t {
                continue;
            }
            // Across a boundary: only a node's inner children, kept adjacent.
            assert!(e - s <= WIDTH, "treelet {s}..{e} straddles a boundary");
            let parent = nodes[..s].iter().filter(|p| p.child_base as usize == s);
            assert_eq!(
                parent.count(),
                1,
                "treelet {s}..{e} is not one node's children"
            );
        }
    }

    #[test]
    fn a_treelet_lies_in_one_block_or_is_one_group_of_siblings() {
        // Small blocks, so that there are many treelets and the room left in a block is often
        // smaller than a node's inner children.
        let t = 16;
        let laid = Built::over(&soup(20000).triangles, Build::default(), t, t, false).laid;
        let n = laid.nodes.len();
        assert!(
            laid.treelets.len() > n / t,
            "{} treelets",
            laid.treelets.len()
        );
        check_treelets(&laid.nodes, &treelet_ranges(&laid), t);
    }

    /// `laid`'s treelets as node ranges.
    pub(in crate::bvh) fn treelet_ranges(laid: &Laid) -> Vec<(usize, usize)> {
        let ends = laid.treelets[1..].iter().copied().chain([laid.nodes.len()]);
        laid.treelets.iter().copied().zip(ends).collect()
    }

    #[test]
    fn first_block_is_breadth_first() {
        let bvh = Bvh::build(&soup(20000), Preset::Fast, 256);
        // The root's four children are at 1..5, theirs from 5 on: breadth-first order.
        let n = &bvh.nodes;
        assert_eq!(n[0].child_base, 1);
        assert_eq!(n[1].child_base, 5);
        for i in 1..4 {
            let inner = (0..WIDTH).filter(|&s| matches!(n[i].child(s), Child::Inner(_)));
            assert_eq!(n[i + 1].child_base, n[i].child_base + inner.count() as u32);
        }
    }
}
