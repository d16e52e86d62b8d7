//! One layer of cells at a time: the field sampled on x-planes into sign bits, a vertex on each
//! grid edge the surface crosses (welded through per-plane edge-index arrays), and the triangles
//! of the cells the surface passes through.

use super::chunk::{ChunkOut, TAG};
use super::tables::Tables;
use super::{ColumnField, Grid};

/// Vertices are kept at least this fraction of an edge away from its ends, so no triangle
/// collapses onto a grid node.
const T_EPS: f32 = 0.01;

/// One x-plane of nodes: values, sign bits (set = negative) and the indices of the vertices on
/// its three in-plane edge types (+y, +z, +y+z) at each node.
pub(super) struct Plane {
    vals: Vec<f32>,
    bits: Vec<u64>,
    idx: Vec<u32>,
}

impl Plane {
    pub(super) fn new(grid: &Grid) -> Self {
        Plane {
            vals: vec![0.0; grid.nodes_per_plane()],
            bits: vec![0; (grid.n + 1) * grid.words()],
            idx: vec![0; 3 * grid.nodes_per_plane()],
        }
    }
}

/// The row's bits shifted down by one node (bit k = node k + 1).
#[inline]
fn shr1(row: &[u64], w: usize) -> u64 {
    let next = if w + 1 < row.len() {
        row[w + 1] << 63
    } else {
        0
    };
    (row[w] >> 1) | next
}

#[inline]
fn bit(row: &[u64], k: usize) -> usize {
    ((row[k >> 6] >> (k & 63)) & 1) as usize
}

/// Calls `f(k)` for every set bit of `word` (word `w` of a row).
#[inline]
fn for_bits(mut word: u64, w: usize, mut f: impl FnMut(usize)) {
    while word != 0 {
        f(w * 64 + word.trailing_zeros() as usize);
        word &= word - 1;
    }
}

pub(super) fn eval_plane(field: &impl ColumnField, grid: &Grid, i: usize, plane: &mut Plane) {
    let (s, words) = (grid.stride(), grid.words());
    let x = grid.xy(i);
    for j in 0..=grid.n {
        let vals = &mut plane.vals[j * s..(j + 1) * s];
        field.eval_column(x, grid.xy(j), grid, vals);
        let row = &mut plane.bits[j * words..(j + 1) * words];
        for (word, chunk) in row.iter_mut().zip(vals.chunks_mut(64)) {
            let mut bits = 0u64;
            for (b, v) in chunk.iter_mut().enumerate() {
                if *v == 0.0 {
                    *v = f32::MIN_POSITIVE;
                }
                bits |= u64::from(v.to_bits() >> 31) << b;
            }
            *word = bits;
        }
    }
}

/// The vertex on the edge from node `pa` (value `va`) to `pb` (value `vb`), of opposite signs.
#[inline]
fn edge_vertex(pa: [f64; 3], va: f32, pb: [f64; 3], vb: f32) -> [f32; 3] {
    let t = f64::from((va / (va - vb)).clamp(T_EPS, 1.0 - T_EPS));
    [
        (pa[0] + t * (pb[0] - pa[0])) as f32,
        (pa[1] + t * (pb[1] - pa[1])) as f32,
        (pa[2] + t * (pb[2] - pa[2])) as f32,
    ]
}

/// Creates the vertices on plane `i`'s in-plane edges in a fixed scan order (row, edge type,
/// z), recording their indices. Owned vertices are appended to `out.positions`; the far plane of
/// a chunk that is not the last is owned by the next chunk, which numbers them the same way, so
/// they get tagged indices 0, 1, 2, ... in the same order (and their positions go to `out.far`).
pub(super) fn scan_plane(
    grid: &Grid,
    i: usize,
    plane: &mut Plane,
    lt_nz: &[u64],
    owned: bool,
    out: &mut ChunkOut,
) {
    let (s, words) = (grid.stride(), grid.words());
    let x = grid.xy(i);
    let Plane { vals, bits, idx } = plane;
    let pos = |j: usize, k: usize| [x, grid.xy(j), grid.z(k)];
    let add = |out: &mut ChunkOut, na: (usize, usize), nb: (usize, usize)| -> u32 {
        let p = edge_vertex(
            pos(na.0, na.1),
            vals[na.0 * s + na.1],
            pos(nb.0, nb.1),
            vals[nb.0 * s + nb.1],
        );
        if owned {
            out.positions.push(p);
            (out.positions.len() - 1) as u32
        } else {
            // The next chunk makes the same vertex from the same node values; a copy here makes
            // this chunk's triangles complete on their own (`ChunkOut::piece`).
            out.far.push(p);
            TAG | (out.far.len() - 1) as u32
        }
    };
    for j in 0..=grid.n {
        let r0 = &bits[j * words..(j + 1) * words];
        if j < grid.n {
            let r1 = &bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits(r0[w] ^ r1[w], w, |k| {
                    idx[3 * (j * s + k)] = add(out, (j, k), (j + 1, k));
                });
            }
        }
        for w in 0..words {
            for_bits((r0[w] ^ shr1(r0, w)) & lt_nz[w], w, |k| {
                idx[3 * (j * s + k) + 1] = add(out, (j, k), (j, k + 1));
            });
        }
        if j < grid.n {
            let r1 = &bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits((r0[w] ^ shr1(r1, w)) & lt_nz[w], w, |k| {
                    idx[3 * (j * s + k) + 2] = add(out, (j, k), (j + 1, k + 1));
                });
            }
        }
    }
}

/// Creates the vertices on the edges from plane `i` (`a`) to plane `i + 1` (`b`).
pub(super) fn scan_cross(
    grid: &Grid,
    i: usize,
    a: &Plane,
    b: &Plane,
    work_cross: &mut [u32],
    lt_nz: &[u64],
    out: &mut ChunkOut,
) {
    let (s, words) = (grid.stride(), grid.words());
    let (xa, xb) = (grid.xy(i), grid.xy(i + 1));
    let mut add = |j: usize, k: usize, jb: usize, kb: usize| -> u32 {
        let p = edge_vertex(
            [xa, grid.xy(j), grid.z(k)],
            a.vals[j * s + k],
            [xb, grid.xy(jb), grid.z(kb)],
            b.vals[jb * s + kb],
        );
        out.positions.push(p);
        (out.positions.len() - 1) as u32
    };
    for j in 0..=grid.n {
        let a0 = &a.bits[j * words..(j + 1) * words];
        let b0 = &b.bits[j * words..(j + 1) * words];
        for w in 0..words {
            for_bits(a0[w] ^ b0[w], w, |k| {
                work_cross[4 * (j * s + k)] = add(j, k, j, k);
            });
        }
        if j < grid.n {
            let b1 = &b.bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits(a0[w] ^ b1[w], w, |k| {
                    work_cross[4 * (j * s + k) + 1] = add(j, k, j + 1, k);
                });
            }
        }
        for w in 0..words {
            for_bits((a0[w] ^ shr1(b0, w)) & lt_nz[w], w, |k| {
                work_cross[4 * (j * s + k) + 2] = add(j, k, j, k + 1);
            });
        }
        if j < grid.n {
            let b1 = &b.bits[(j + 1) * words..(j + 2) * words];
            for w in 0..words {
                for_bits((a0[w] ^ shr1(b1, w)) & lt_nz[w], w, |k| {
                    work_cross[4 * (j * s + k) + 3] = add(j, k, j + 1, k + 1);
                });
            }
        }
    }
}

/// Emits (or only counts) the triangles of the cells between planes `a` and `b`.
#[allow(clippy::too_many_arguments)]
pub(super) fn march_layer(
    grid: &Grid,
    tables: &Tables,
    a: &Plane,
    b: &Plane,
    cross: &[u32],
    lt_nz: &[u64],
    or: &mut [u64],
    and: &mut [u64],
    emit: bool,
    out: &mut ChunkOut,
) {
    let (s, words) = (grid.stride(), grid.words());
    for j in 0..grid.n {
        let a0 = &a.bits[j * words..(j + 1) * words];
        let a1 = &a.bits[(j + 1) * words..(j + 2) * words];
        let b0 = &b.bits[j * words..(j + 1) * words];
        let b1 = &b.bits[(j + 1) * words..(j + 2) * words];
        for w in 0..words {
            or[w] = a0[w] | a1[w] | b0[w] | b1[w];
            and[w] = a0[w] & a1[w] & b0[w] & b1[w];
        }
        for w in 0..words {
            let mixed = (or[w] | shr1(or, w)) & !(and[w] & shr1(and, w)) & lt_nz[w];
            for_bits(mixed, w, |k| {
                let mask = bit(a0, k)
                    | bit(b0, k) << 1
                    | bit(a1, k) << 2
                    | bit(b1, k) << 3
                    | bit(a0, k + 1) << 4
                    | bit(b0, k + 1) << 5
                    | bit(a1, k + 1) << 6
                    | bit(b1, k + 1) << 7;
                let range = tables.start[mask] as usize..tables.start[mask + 1] as usize;
                if !emit {
                    out.count += range.len() as u64;
                    return;
                }
                let vertex = |e: u8| -> u32 {
                    let slot = tables.edges[e as usize];
                    let node = (j + slot.dj as usize) * s + k + slot.dk as usize;
                    match slot.src {
                        0 => a.idx[3 * node + slot.kind as usize],
                        1 => b.idx[3 * node + slot.kind as usize],
                        _ => cross[4 * node + slot.kind as usize],
                    }
                };
                for t in &tables.tris[range] {
                    out.triangles
                        .push([vertex(t[0]), vertex(t[1]), vertex(t[2])]);
                }
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::generate::rm::{chunks::extract, rm};
    use crate::scene::mesh::Mesh;
    use std::collections::HashMap;

    fn normal(m: &Mesh, i: usize) -> [f64; 3] {
        let c = m.corners(i).map(|p| p.map(f64::from));
        let e1 = [c[1][0] - c[0][0], c[1][1] - c[0][1], c[1][2] - c[0][2]];
        let e2 = [c[2][0] - c[0][0], c[2][1] - c[0][1], c[2][2] - c[0][2]];
        [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ]
    }

    #[test]
    fn no_repeated_indices_and_no_zero_area() {
        let m = rm(100_000, 4);
        let mut zero = 0;
        for (i, t) in m.triangles.iter().enumerate() {
            assert!(
                t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
                "triangle {i}: {t:?}"
            );
            if normal(&m, i) == [0.0; 3] {
                zero += 1;
            }
        }
        assert!(
            zero * 10_000 <= m.triangle_count(),
            "{zero} zero-area triangles"
        );
    }

    /// Directed edge counts of a mesh.
    fn edges(m: &Mesh) -> HashMap<(u32, u32), u32> {
        let mut e = HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                *e.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        e
    }

    /// Every edge is used once in each direction (so there are no cracks and the orientation is
    /// consistent), except on the sides of the domain, where the sheet is cut off.
    #[test]
    fn crack_free_and_consistently_oriented() {
        let m = rm(20_000, 2);
        let on_side = |v: u32| {
            let p = m.positions[v as usize];
            [p[0] == -1.0, p[0] == 1.0, p[1] == -1.0, p[1] == 1.0]
        };
        let e = edges(&m);
        let mut border = 0;
        for (&(a, b), &n) in &e {
            assert_eq!(n, 1, "edge {a}-{b} used twice in the same direction");
            if !e.contains_key(&(b, a)) {
                let (sa, sb) = (on_side(a), on_side(b));
                assert!(
                    (0..4).any(|s| sa[s] && sb[s]),
                    "open edge {a}-{b} inside the domain: {:?} {:?}",
                    m.positions[a as usize],
                    m.positions[b as usize]
                );
                border += 1;
            }
        }
        assert!(border > 0);
    }

    #[test]
    fn faces_the_light_fluid() {
        let m = rm(50_000, 8);
        let (mut up, mut total) = (0.0, 0.0);
        for i in 0..m.triangle_count() {
            let n = normal(&m, i);
            up += n[2];
            total += (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        }
        assert!(up > 0.3 * total, "up {up} of {total}");
    }

    /// A ball, to check closure and orientation on a surface with no border.
    struct Ball;

    impl ColumnField for Ball {
        fn eval_column(&self, x: f64, y: f64, grid: &Grid, out: &mut [f32]) {
            for (k, v) in out.iter_mut().enumerate() {
                let (dx, dy, dz) = (x - 0.1, y + 0.05, grid.z(k) - 0.02);
                *v = ((dx * dx + dy * dy + dz * dz).sqrt() - 0.3) as f32;
            }
        }

        fn z_range(&self) -> (f64, f64) {
            (-0.28, 0.32)
        }
    }

    #[test]
    fn ball_is_closed_and_faces_out() {
        let grid = Grid::new(40, Ball.z_range());
        let m = extract(&Ball, &grid, 5, 0.0);
        let e = edges(&m);
        for (&(a, b), &n) in &e {
            assert_eq!(n, 1);
            assert!(
                e.contains_key(&(b, a)),
                "open edge {a}-{b} {:?} {:?}",
                m.positions[a as usize],
                m.positions[b as usize]
            );
        }
        // Signed volume by the divergence theorem: positive when the triangles face out.
        let volume: f64 = (0..m.triangle_count())
            .map(|i| {
                let c = m.corners(i).map(|p| p.map(f64::from));
                (c[0][0] * (c[1][1] * c[2][2] - c[1][2] * c[2][1])
                    - c[0][1] * (c[1][0] * c[2][2] - c[1][2] * c[2][0])
                    + c[0][2] * (c[1][0] * c[2][1] - c[1][1] * c[2][0]))
                    / 6.0
            })
            .sum();
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 0.3f64.powi(3);
        assert!((volume / exact - 1.0).abs() < 0.05, "{volume} vs {exact}");
    }
}
