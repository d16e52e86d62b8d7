//! The marching-tetrahedra tables: for each sign pattern of a cube's corners, the triangles of
//! its six tetrahedra as cube edges, and where each cube edge's vertex index is kept.

use std::sync::OnceLock;

/// Where a cube edge's vertex index lives: `src` 0 = the near plane's in-plane edges, 1 = the far
/// plane's, 2 = the edges crossing the layer; `kind` is the edge type within that array; the
/// edge starts at node (j + dj, k + dk).
#[derive(Clone, Copy, Debug)]
pub(super) struct EdgeSlot {
    pub(super) src: u8,
    pub(super) kind: u8,
    pub(super) dj: u8,
    pub(super) dk: u8,
}

/// Per corner-sign mask of a cube (bit c set = corner c inside, c = dx + 2 dy + 4 dz), the
/// triangles of its six tetrahedra as cube-edge ids, facing the outside.
pub(super) struct Tables {
    pub(super) edges: Vec<EdgeSlot>,
    pub(super) start: [u16; 257],
    pub(super) tris: Vec<[u8; 3]>,
}

fn corner(c: usize) -> [i32; 3] {
    [(c & 1) as i32, ((c >> 1) & 1) as i32, ((c >> 2) & 1) as i32]
}

pub(super) fn tables() -> &'static Tables {
    static TABLES: OnceLock<Tables> = OnceLock::new();
    TABLES.get_or_init(build_tables)
}

fn build_tables() -> Tables {
    // The six tetrahedra around the main diagonal 0-7, each ordered to be positively oriented.
    let mut tets = Vec::new();
    for p in [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ] {
        let c1 = 1usize << p[0];
        let c2 = c1 | (1usize << p[1]);
        let mut t = [0usize, c1, c2, 7];
        let [a, b, c, d] = t.map(corner);
        let e = |u: [i32; 3]| [u[0] - a[0], u[1] - a[1], u[2] - a[2]];
        let (u, v, w) = (e(b), e(c), e(d));
        let det = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0]);
        assert!(det != 0);
        if det < 0 {
            t.swap(2, 3);
        }
        tets.push(t);
    }
    let mut edges: Vec<EdgeSlot> = Vec::new();
    let mut ids = [[u8::MAX; 8]; 8];
    let mut edge_id = |c1: usize, c2: usize| -> u8 {
        let (lo, hi) = (c1.min(c2), c1.max(c2));
        if ids[lo][hi] == u8::MAX {
            let (b, t) = (corner(lo), corner(hi));
            let d = [t[0] - b[0], t[1] - b[1], t[2] - b[2]];
            assert!(d.iter().all(|&x| x == 0 || x == 1), "edge {lo}-{hi}");
            let (src, kind) = if d[0] == 1 {
                (2, d[1] + 2 * d[2])
            } else {
                let kind = match (d[1], d[2]) {
                    (1, 0) => 0,
                    (0, 1) => 1,
                    _ => 2,
                };
                (b[0], kind)
            };
            ids[lo][hi] = edges.len() as u8;
            edges.push(EdgeSlot {
                src: src as u8,
                kind: kind as u8,
                dj: b[1] as u8,
                dk: b[2] as u8,
            });
        }
        ids[lo][hi]
    };
    let parity = |p: [usize; 4]| {
        let mut inv = 0;
        for i in 0..4 {
            for j in i + 1..4 {
                if p[i] > p[j] {
                    inv += 1;
                }
            }
        }
        inv % 2
    };
    let mut start = [0u16; 257];
    let mut tris = Vec::new();
    for (mask, first) in start.iter_mut().enumerate().take(256) {
        *first = tris.len() as u16;
        for t in &tets {
            let inside: Vec<usize> = (0..4).filter(|&q| mask >> t[q] & 1 == 1).collect();
            let outside: Vec<usize> = (0..4).filter(|&q| mask >> t[q] & 1 == 0).collect();
            let mut e = |p: usize, q: usize| edge_id(t[p], t[q]);
            match inside.len() {
                1 | 3 => {
                    let lone = if inside.len() == 1 {
                        inside[0]
                    } else {
                        outside[0]
                    };
                    let mut o: Vec<usize> = (0..4).filter(|&q| q != lone).collect();
                    if parity([lone, o[0], o[1], o[2]]) == 1 {
                        o.swap(1, 2);
                    }
                    // Faces away from the lone corner; flip when the lone corner is outside.
                    let tri = [e(lone, o[0]), e(lone, o[1]), e(lone, o[2])];
                    tris.push(if inside.len() == 1 {
                        tri
                    } else {
                        [tri[0], tri[2], tri[1]]
                    });
                }
                2 => {
                    let (a, b) = (inside[0], inside[1]);
                    let (mut c, mut d) = (outside[0], outside[1]);
                    if parity([a, b, c, d]) == 1 {
                        std::mem::swap(&mut c, &mut d);
                    }
                    let (ac, ad, bd, bc) = (e(a, c), e(a, d), e(b, d), e(b, c));
                    tris.push([ac, ad, bd]);
                    tris.push([ac, bd, bc]);
                }
                _ => {}
            }
        }
    }
    start[256] = tris.len() as u16;
    assert_eq!(edges.len(), 19);
    Tables { edges, start, tris }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marching_tables_are_complete() {
        let t = tables();
        assert_eq!(t.start[1] - t.start[0], 0);
        assert_eq!(t.start[256] - t.start[255], 0);
        for mask in 1..255 {
            let n = t.start[mask + 1] - t.start[mask];
            assert!((1..=12).contains(&n), "mask {mask}: {n}");
        }
    }
}
