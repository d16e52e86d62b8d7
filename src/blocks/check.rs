//! Plausibility of a block file's contents beyond its checksums: the metadata against the header,
//! and the structure of each block where it is read. A CRC proves a block is what was written,
//! not that what was written is a tree; these checks keep an edited file from rendering a wrong
//! image or walking the GPU off its stack. Each is linear in what is read, so it runs on load.

use super::file::Meta;
use super::{Blocks, Format, NODE_WORDS, TRI_WORDS};
use crate::bvh::{Child, EMPTY, INNER, Node, WIDTH};

/// The metadata agrees with the header's block counts and is itself consistent.
pub fn meta(m: &Meta, format: Format, node_blocks: u32, tri_blocks: u32) -> Result<(), String> {
    let npb = u64::from(format.nodes_per_block());
    let tpb = u64::from(format.tris_per_block());
    if m.nodes == 0 || m.nodes.div_ceil(npb) != u64::from(node_blocks) {
        return Err(format!(
            "{} nodes do not fill the header's {node_blocks} node blocks of {npb}",
            m.nodes
        ));
    }
    if m.triangles == 0
        || m.triangles > u64::from(u32::MAX)
        || m.triangles.div_ceil(tpb) != u64::from(tri_blocks)
    {
        return Err(format!(
            "{} triangles do not fill the header's {tri_blocks} triangle blocks of {tpb}",
            m.triangles
        ));
    }
    if m.bvh_depth == 0 || u64::from(m.bvh_depth) > m.nodes {
        return Err(format!(
            "BVH depth {} is impossible for {} nodes",
            m.bvh_depth, m.nodes
        ));
    }
    let increasing = m.mesh_first.windows(2).all(|w| w[0] < w[1]);
    if m.mesh_first.first() != Some(&0)
        || !increasing
        || m.mesh_first.len() != m.colors.len()
        || m.mesh_first
            .last()
            .is_some_and(|&f| u64::from(f) >= m.triangles)
    {
        return Err("inconsistent mesh table (mesh_first, colors)".into());
    }
    let finite_nonneg = |c: &[f32; 3]| c.iter().all(|v| v.is_finite() && *v >= 0.0);
    if !m.colors.iter().all(finite_nonneg) || !finite_nonneg(&m.background) {
        return Err("colours must be finite and non-negative".into());
    }
    let bounded = (0..3).all(|a| {
        m.bounds_min[a].is_finite()
            && m.bounds_max[a].is_finite()
            && m.bounds_min[a] <= m.bounds_max[a]
    });
    if !bounded {
        return Err(format!(
            "bounds {:?}..{:?} are not a finite box",
            m.bounds_min, m.bounds_max
        ));
    }
    m.camera.validate().map_err(|e| e.to_string())?;
    crate::scene::check_image_size(m.width, m.height).map_err(|e| e.to_string())?;
    looks(m, format)
}

/// The looks fit the mesh table and the attribute layout fits the looks and the triangles.
fn looks(m: &Meta, format: Format) -> Result<(), String> {
    use crate::scene::color::Look;
    if !m.looks.is_empty() && m.looks.len() != m.mesh_first.len() {
        return Err(format!(
            "{} looks for {} mesh-table entries",
            m.looks.len(),
            m.mesh_first.len()
        ));
    }
    for (i, l) in m.looks.iter().enumerate() {
        match l {
            Look::Scalars { array, range, .. }
                if array.is_empty()
                    || !(range[0].is_finite() && range[1].is_finite() && range[0] <= range[1]) =>
            {
                return Err(format!("look {i}: not an array and a finite range"));
            }
            Look::Colors { array, .. } if array.is_empty() => {
                return Err(format!("look {i}: no array"));
            }
            _ => {}
        }
    }
    let uses = m.looks.iter().any(Look::uses_attributes);
    let corners = m.looks.iter().any(Look::per_corner);
    let want = match (uses, corners) {
        (false, _) => 0,
        (true, false) => 1,
        (true, true) => 3,
    };
    let layout = super::AttrLayout::new(format, want, m.triangles);
    if m.attrs != layout {
        return Err(format!(
            "attribute layout {:?} does not fit the looks and triangles ({layout:?})",
            m.attrs
        ));
    }
    Ok(())
}

/// Block `k` is well formed: in a node block every node's children lie after it and inside the
/// node list and every leaf's triangles inside the triangle list; in a triangle block every
/// triangle is finite and its primitive id in range.
pub fn block(
    k: u32,
    words: &[u32],
    format: Format,
    node_blocks: u32,
    m: &Meta,
) -> Result<(), String> {
    let tri_blocks = m.triangles.div_ceil(u64::from(format.tris_per_block()));
    if u64::from(k) >= u64::from(node_blocks) + tri_blocks {
        // Attributes: any bits are a colour the kernels can map; only the padding after the
        // last triangle's words must be zero.
        let w = m.attrs.words;
        let per = u64::from(format.attrs_per_block(w));
        let first = (u64::from(k) - u64::from(node_blocks) - tri_blocks) * per;
        let used = m.triangles.saturating_sub(first).min(per) * u64::from(w);
        if words[used as usize..].iter().any(|&x| x != 0) {
            return Err(format!(
                "attribute block past triangle {}: non-zero padding",
                m.triangles
            ));
        }
    } else if k < node_blocks {
        let npb = format.nodes_per_block();
        for s in 0..npb {
            let i = u64::from(k) * u64::from(npb) + u64::from(s);
            if i >= m.nodes {
                break;
            }
            let w = &words[(s * NODE_WORDS) as usize..((s + 1) * NODE_WORDS) as usize];
            node(i, bytemuck::from_bytes(bytemuck::cast_slice(w)), m)
                .map_err(|e| format!("node {i}: {e}"))?;
        }
    } else {
        let tpb = format.tris_per_block();
        let id0 = format.id_word() as usize;
        for s in 0..tpb {
            let t = u64::from(k - node_blocks) * u64::from(tpb) + u64::from(s);
            if t >= m.triangles {
                break;
            }
            let w = &words[(s * TRI_WORDS) as usize..((s + 1) * TRI_WORDS) as usize];
            if !w.iter().all(|&b| f32::from_bits(b).is_finite()) {
                return Err(format!("triangle {t}: a coordinate is not finite"));
            }
            let id = words[id0 + s as usize];
            if u64::from(id) >= m.triangles {
                return Err(format!(
                    "triangle {t}: primitive id {id} past the {} triangles",
                    m.triangles
                ));
            }
        }
    }
    Ok(())
}

/// Node `i`'s children lie after it within the node list, its leaves' triangles within the
/// triangle list, its grid is finite and each used slot's box is not inside out; or, but for
/// the root, it is `Node::PADDING`.
fn node(i: u64, n: &Node, m: &Meta) -> Result<(), String> {
    let counts: Vec<u32> = (0..WIDTH).map(|s| (n.counts >> (8 * s)) & 0xff).collect();
    if counts.iter().all(|&c| c == EMPTY) {
        // Padding that lines a part's nodes up with a block (never the root), or a node
        // without children.
        return if i > 0 && *n == Node::PADDING {
            Ok(())
        } else {
            Err("no children".into())
        };
    }
    let inner = counts.iter().filter(|&&c| c == INNER).count() as u64;
    let base = u64::from(n.child_base);
    if inner > 0 && (base <= i || base + inner > m.nodes) {
        return Err(format!(
            "children at {base}..{} do not lie after it within the {} nodes",
            base + inner,
            m.nodes
        ));
    }
    let leaf: u64 = counts
        .iter()
        .filter(|&&c| c != INNER)
        .map(|&c| u64::from(c))
        .sum();
    let first = u64::from(n.tri_base);
    if first + leaf > m.triangles {
        return Err(format!(
            "leaf triangles {first}..{} past the {} triangles",
            first + leaf,
            m.triangles
        ));
    }
    let far = |a: usize| n.origin[a] + 255.0 * n.step(a);
    if !(0..3).all(|a| n.origin[a].is_finite() && far(a).is_finite()) {
        return Err("its grid is not finite".into());
    }
    for (s, &c) in counts.iter().enumerate() {
        let (l, h) = n.child_box(s);
        if c != EMPTY && !(0..3).all(|a| l[a] <= h[a]) {
            return Err(format!("slot {s}: bounds {l:?}..{h:?} are inside out"));
        }
    }
    Ok(())
}

/// With every block at hand: the tree reaches no `Node::PADDING`, and its depth is the declared
/// one (the GPU's traversal stack is sized by it). Run after `block` has checked each block, so children lie after parents and the
/// walk ends.
pub fn depth(blocks: &Blocks, declared: u32) -> Result<(), String> {
    let mut stack = vec![(0u32, 1u32)];
    let mut deepest = 0;
    while let Some((i, d)) = stack.pop() {
        let n = blocks.node(i);
        if n == Node::PADDING {
            // `block` lets padding pass (it cannot tell what reaches a node): reached, it would
            // hide a subtree.
            return Err(format!("node {i} is padding, which no node may reach"));
        }
        deepest = deepest.max(d);
        if deepest > declared {
            return Err(format!(
                "the tree is deeper than the declared BVH depth {declared}"
            ));
        }
        for s in 0..WIDTH {
            if let Child::Inner(c) = n.child(s) {
                stack.push((c, d + 1));
            }
        }
    }
    if deepest != declared {
        return Err(format!(
            "the tree has depth {deepest}, the metadata declares {declared}"
        ));
    }
    Ok(())
}
