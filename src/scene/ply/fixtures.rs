//! Test fixtures of the PLY loader: a writer of PLY files in every format from element
//! descriptions, a cube with extra elements and properties around the kept ones, and checks.

use super::header::Scalar;
use super::parse_ply;
use crate::error::Result;
use crate::scene::mesh::Mesh;
use std::path::Path;

/// A property of a test element: (type, name) or (count type, item type, name).
pub(super) enum P {
    S(&'static str, &'static str),
    L(&'static str, &'static str, &'static str),
}

/// A test element; each row lists its values in order, a list as its length then its items.
pub(super) struct El {
    pub(super) name: &'static str,
    pub(super) props: Vec<P>,
    pub(super) rows: Vec<Vec<f64>>,
}

pub(super) fn ty(name: &str) -> Scalar {
    Scalar::from_name(name).unwrap()
}

pub(super) fn encode(out: &mut Vec<u8>, t: Scalar, v: f64, big: bool) {
    macro_rules! put {
        ($x:expr) => {
            out.extend_from_slice(&if big {
                $x.to_be_bytes()
            } else {
                $x.to_le_bytes()
            })
        };
    }
    match t {
        Scalar::I8 => put!(v as i8),
        Scalar::U8 => put!(v as u8),
        Scalar::I16 => put!(v as i16),
        Scalar::U16 => put!(v as u16),
        Scalar::I32 => put!(v as i32),
        Scalar::U32 => put!(v as u32),
        Scalar::F32 => put!(v as f32),
        Scalar::F64 => put!(v),
    }
}

/// Serialises `elements` as a PLY file in `format` ("ascii", "binary_little_endian", ...).
pub(super) fn write_ply(format: &str, elements: &[El]) -> Vec<u8> {
    let mut out = format!("ply\nformat {format} 1.0\ncomment test file\nobj_info none\n");
    for e in elements {
        out += &format!("element {} {}\n", e.name, e.rows.len());
        for p in &e.props {
            out += &match p {
                P::S(t, n) => format!("property {t} {n}\n"),
                P::L(c, i, n) => format!("property list {c} {i} {n}\n"),
            };
        }
    }
    out += "end_header\n";
    let mut out = out.into_bytes();
    for e in elements {
        for row in &e.rows {
            let mut values = row.iter().copied();
            let mut line = Vec::new();
            for p in &e.props {
                let (count, t) = match p {
                    P::S(t, _) => (None, ty(t)),
                    P::L(c, i, _) => (Some(ty(c)), ty(i)),
                };
                let n = match count {
                    Some(c) => {
                        let n = values.next().unwrap();
                        line.push((c, n));
                        n as usize
                    }
                    None => 1,
                };
                for _ in 0..n {
                    line.push((t, values.next().unwrap()));
                }
            }
            match format {
                "ascii" => {
                    let words: Vec<String> = line.iter().map(|(_, v)| v.to_string()).collect();
                    out.extend_from_slice(words.join(" ").as_bytes());
                    out.push(b'\n');
                }
                _ => {
                    let big = format == "binary_big_endian";
                    for (t, v) in line {
                        encode(&mut out, t, v, big);
                    }
                }
            }
        }
    }
    out
}

pub(super) const CUBE_FACES: [[u32; 4]; 6] = [
    [0, 2, 3, 1],
    [4, 5, 7, 6],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 4, 6, 2],
    [1, 3, 7, 5],
];

pub(super) fn cube_corner(i: usize) -> [f32; 3] {
    [
        (i & 1) as f32,
        ((i >> 1) & 1) as f32,
        ((i >> 2) & 1) as f32 * 0.5 - 0.25,
    ]
}

/// A cube with extra elements before, between and after the ones that matter, extra vertex
/// properties around x/y/z, and coordinates and indices of the given types.
pub(super) fn cube_elements(
    coord: &'static str,
    count: &'static str,
    index: &'static str,
) -> Vec<El> {
    let material = El {
        name: "material",
        props: vec![
            P::S("uchar", "red"),
            P::L("uchar", "float", "spec"),
            P::S("double", "ior"),
        ],
        rows: vec![vec![200.0, 2.0, 0.5, 0.25, 1.5], vec![10.0, 0.0, 1.0]],
    };
    let vertex = El {
        name: "vertex",
        props: vec![
            P::S("float", "nx"),
            P::S(coord, "x"),
            P::S("short", "s"),
            P::S(coord, "y"),
            P::S(coord, "z"),
            P::S("uchar", "red"),
            P::S("double", "u"),
        ],
        rows: (0..8)
            .map(|i| {
                let [x, y, z] = cube_corner(i).map(f64::from);
                vec![0.5, x, -7.0, y, z, 255.0, 0.125]
            })
            .collect(),
    };
    let edge = El {
        name: "edge",
        props: vec![P::S("int", "vertex1"), P::S("int", "vertex2")],
        rows: vec![vec![0.0, 1.0], vec![1.0, 3.0]],
    };
    let face = El {
        name: "face",
        props: vec![
            P::S("uchar", "flags"),
            P::L(count, index, "vertex_indices"),
            P::L("uchar", "float", "texcoord"),
        ],
        rows: CUBE_FACES
            .iter()
            .map(|f| {
                let mut row = vec![3.0, 4.0];
                row.extend(f.iter().map(|&v| f64::from(v)));
                row.extend([2.0, 0.5, 0.5]);
                row
            })
            .collect(),
    };
    vec![material, vertex, edge, face]
}

pub(super) fn expected_cube() -> Mesh {
    Mesh {
        positions: (0..8).map(cube_corner).collect(),
        triangles: CUBE_FACES
            .iter()
            .flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]])
            .collect(),
    }
}

pub(super) fn parse(bytes: &[u8]) -> Result<Mesh> {
    parse_ply(bytes, Path::new("test.ply"))
}

pub(super) fn assert_same(a: &Mesh, b: &Mesh) {
    assert_eq!(a.positions, b.positions);
    assert_eq!(a.triangles, b.triangles);
}

/// Asserts that parsing fails with a message naming the file, `place` and `what`.
pub(super) fn assert_err(bytes: &[u8], place: &str, what: &str) {
    let err = parse_ply(bytes, Path::new("dir/test.ply"))
        .expect_err("parse should fail")
        .to_string();
    assert!(err.contains("dir/test.ply"), "{err}");
    assert!(err.contains(place), "{err} lacks {place}");
    assert!(err.contains(what), "{err} lacks {what}");
}

pub(super) const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];
