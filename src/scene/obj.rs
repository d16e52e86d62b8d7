//! Wavefront OBJ loading: vertex positions and polygonal faces only.
//!
//! Everything the renderer does not use (normals, texture coordinates, groups, materials,
//! free-form geometry) is skipped, but the lines that are used are checked strictly so that a
//! corrupt or mistaken file fails with the line that is wrong instead of rendering garbage.

use crate::error::{Error, Result};
use crate::scene::mesh::{Mesh, Piece};
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// Longest line accepted. Without a cap, binary data with no newlines would be read into memory
/// whole before the UTF-8 check could reject it.
const MAX_LINE: u64 = 1 << 22;

/// Reads the OBJ file at `path`.
pub fn load_obj(path: &Path) -> Result<Mesh> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    parse_obj(BufReader::with_capacity(1 << 18, file), path)
}

/// Parses OBJ text from `reader` (e.g. a `BufReader<File>` or a `&[u8]`); `origin` names the
/// source in errors.
///
/// Polygons are fan-triangulated in order, (v0,v1,v2), (v0,v2,v3), ..., so triangle ids follow
/// file order. Faces may refer to vertices defined further down; those indices are checked once
/// the whole file has been read. A file without faces gives an empty triangle list, not an error.
pub fn parse_obj<R: BufRead>(reader: R, origin: &Path) -> Result<Mesh> {
    read_obj(reader, origin, None)
}

/// Reads the OBJ file at `path` as `load_obj` does, handing its triangles to `piece` with the
/// vertices read so far, `PIECE` at a time, so that the triangles are never all held: every
/// vertex is kept (a face may use any earlier one), and more than `max_vertices` is an error.
/// Faces that refer to vertices further down are held until those are read.
pub fn stream_obj(path: &Path, max_vertices: u64, piece: &mut Piece) -> Result<()> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let reader = BufReader::with_capacity(1 << 18, file);
    read_obj(reader, path, Some((max_vertices, piece))).map(drop)
}

/// Triangles handed on at a time when streaming.
const PIECE: usize = 1 << 16;

fn read_obj<R: BufRead>(
    mut reader: R,
    origin: &Path,
    mut stream: Option<(u64, &mut Piece)>,
) -> Result<Mesh> {
    let mut mesh = Mesh::default();
    // The largest vertex index of the triangles not yet handed on.
    let mut largest = 0u32;
    let mut line = Vec::new();
    let mut poly: Vec<u32> = Vec::new();
    // (line, largest 0-based index) of every face that refers past the vertices read so far.
    // Normal files have none, so this costs nothing, and it lets the error name the face's line.
    let mut forward: Vec<(usize, u32)> = Vec::new();
    let mut n = 0usize;
    loop {
        line.clear();
        let read = reader
            .by_ref()
            .take(MAX_LINE)
            .read_until(b'\n', &mut line)
            .map_err(|e| Error::io(origin, e))?;
        if read == 0 {
            break;
        }
        n += 1;
        let at = |msg: String| Error::format(origin, Some(format!("line {n}")), msg);
        if read as u64 == MAX_LINE && line.last() != Some(&b'\n') {
            return Err(at(format!("line is longer than {MAX_LINE} bytes")));
        }
        let text = std::str::from_utf8(&line)
            .map_err(|_| at("not valid UTF-8 text (is this a binary file?)".into()))?;
        // Comments are whole lines in the spec, but trailing ones occur in the wild.
        let text = text.split_once('#').map_or(text, |(before, _)| before);
        let mut tokens = text.split_ascii_whitespace();
        let Some(keyword) = tokens.next() else {
            continue;
        };
        match keyword {
            "v" => {
                let mut p = [0f32; 3];
                for (k, c) in p.iter_mut().enumerate() {
                    let tok = tokens
                        .next()
                        .ok_or_else(|| at(format!("vertex has {k} coordinates, needs 3")))?;
                    *c = parse_number(tok).map_err(at)?;
                }
                // An optional w, or the common "x y z r g b" colour extension: numbers, unused.
                for tok in tokens {
                    parse_number(tok).map_err(at)?;
                }
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(at(format!("coordinate is not finite: {p:?}")));
                }
                if let Some((max, _)) = &stream
                    && mesh.positions.len() as u64 >= *max
                {
                    return Err(at(format!(
                        "more than {max} vertices, what the memory budget holds (every vertex \
                         of a mesh file is kept while its faces are read); raise --memory"
                    )));
                }
                mesh.positions.push(p);
            }
            "f" => {
                poly.clear();
                let defined = mesh.positions.len();
                let mut ahead: Option<u32> = None;
                for tok in tokens {
                    let v = resolve_index(tok, defined).map_err(at)?;
                    if v as usize >= defined {
                        ahead = ahead.max(Some(v));
                    }
                    poly.push(v);
                }
                if poly.len() < 3 {
                    return Err(at(format!(
                        "face has {} vertices, needs at least 3",
                        poly.len()
                    )));
                }
                if let Some(v) = ahead {
                    forward.push((n, v));
                }
                for k in 1..poly.len() - 1 {
                    mesh.triangles.push([poly[0], poly[k], poly[k + 1]]);
                }
                largest = poly.iter().fold(largest, |m, &v| m.max(v));
                if let Some((_, piece)) = &mut stream
                    && mesh.triangles.len() >= PIECE
                    && (largest as usize) < mesh.positions.len()
                {
                    piece(&mesh.positions, &mesh.triangles)?;
                    mesh.triangles.clear();
                    largest = 0;
                }
            }
            k if IGNORED.contains(&k) => {}
            k => {
                return Err(at(format!(
                    "not an OBJ statement: '{}' (dcrt reads v and f and ignores {})",
                    k.escape_debug().take(32).collect::<String>(),
                    IGNORED.join(", ")
                )));
            }
        }
    }
    let count = mesh.positions.len();
    if let Some((line, v)) = forward.into_iter().find(|&(_, v)| v as usize >= count) {
        return Err(Error::format(
            origin,
            Some(format!("line {line}")),
            format!(
                "vertex index {} out of range ({count} vertices)",
                u64::from(v) + 1
            ),
        ));
    }
    if let Some((_, piece)) = &mut stream
        && !mesh.triangles.is_empty()
    {
        piece(&mesh.positions, &mesh.triangles)?;
        mesh.triangles.clear();
    }
    Ok(mesh)
}

/// Statements that carry nothing dcrt renders (texture coordinates, normals, groups, materials,
/// lines and points) and are skipped; any other keyword is an error, so a typo (`F` for `f`) is
/// not dropped in silence. The README lists them too.
const IGNORED: &[&str] = &[
    "vt", "vn", "vp", "o", "g", "s", "mtllib", "usemtl", "l", "p",
];

fn parse_number(tok: &str) -> std::result::Result<f32, String> {
    tok.parse::<f32>()
        .map_err(|_| format!("expected a number, found '{}'", snippet(tok)))
}

/// Turns one face corner (`i`, `i/t`, `i//n` or `i/t/n`) into a 0-based vertex index. Negative
/// indices count back from the last vertex defined so far (`defined` of them). Positive indices
/// past `defined` are returned as they are and checked at the end of the file.
fn resolve_index(tok: &str, defined: usize) -> std::result::Result<u32, String> {
    // A byte scan: tokens are short, and this is the hottest line of a big OBJ file.
    let digits = match tok.bytes().position(|c| c == b'/') {
        None => tok,
        Some(end) => {
            check_corner_rest(&tok[end + 1..])
                .map_err(|()| format!("malformed face corner '{}'", snippet(tok)))?;
            &tok[..end]
        }
    };
    let i: i64 = digits
        .parse()
        .map_err(|_| format!("expected a vertex index, found '{}'", snippet(tok)))?;
    let resolved = match i {
        0 => return Err("vertex index 0 is invalid (OBJ indices start at 1)".into()),
        i if i > 0 => i - 1,
        i => i64::try_from(defined).unwrap_or(i64::MAX).saturating_add(i),
    };
    u32::try_from(resolved).map_err(|_| {
        if i < 0 {
            format!("vertex index {i} out of range ({defined} vertices defined so far)")
        } else {
            format!("vertex index {i} out of range")
        }
    })
}

/// What follows the vertex index of a corner: `t`, `/n` or `t/n`, each an integer index.
fn check_corner_rest(rest: &str) -> std::result::Result<(), ()> {
    let index = |p: &str| p.parse::<i64>().map(|_| ()).map_err(|_| ());
    match rest.split_once('/') {
        None => index(rest),
        Some(("", n)) => index(n),
        Some((t, n)) => index(t).and(index(n)),
    }
}

/// A token as it can be shown in a message: short, and with control characters escaped.
fn snippet(tok: &str) -> String {
    tok.escape_debug().take(32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Mesh> {
        parse_obj(text.as_bytes(), Path::new("test.obj"))
    }

    /// Asserts that parsing fails with a message naming the file, `place` and `what`.
    fn assert_err(text: &[u8], place: &str, what: &str) {
        let err = parse_obj(text, Path::new("dir/test.obj"))
            .expect_err("parse should fail")
            .to_string();
        assert!(err.contains("dir/test.obj"), "{err}");
        assert!(err.contains(place), "{err} lacks {place}");
        assert!(err.contains(what), "{err} lacks {what}");
    }

    #[test]
    fn parses_all_face_forms_and_fans() {
        let mesh = parse(
            "# a quad, a pentagon and a negative-index triangle\n\
             mtllib x.mtl\no quad\ng g1\ns off\nusemtl red\n\
             v 0 0 0\nv 1 0 0\r\nv 1 1 0 1.0\nv 0 1 0\n\
             vt 0 0\nvt 1 0\nvn 0 0 1\n\
             \n\
             f 1/1 2/2 3/1 4/2\n\
             v 2 0 0\n\
             f 1//1 2//1 5//1 3//1 4//1 # trailing comment\n\
             f -1/1/1 -4/2/1 -3/1/1\n",
        )
        .unwrap();
        assert_eq!(mesh.positions.len(), 5);
        assert_eq!(mesh.positions[2], [1.0, 1.0, 0.0]);
        assert_eq!(
            mesh.triangles,
            vec![
                [0, 1, 2],
                [0, 2, 3],
                [0, 1, 4],
                [0, 4, 2],
                [0, 2, 3],
                [4, 1, 2],
            ]
        );
    }

    #[test]
    fn cube_with_forward_references() {
        // Faces first, vertices after: allowed, resolved at the end.
        let mesh = parse(
            "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n\
             v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n",
        )
        .unwrap();
        assert_eq!(mesh.positions.len(), 8);
        assert_eq!(mesh.triangle_count(), 12);
        mesh.validate(Path::new("test.obj")).unwrap();
    }

    #[test]
    fn no_faces_is_an_empty_mesh() {
        let mesh = parse("# nothing\nv 1 2 3\nvn 0 0 1\n").unwrap();
        assert_eq!(mesh.positions.len(), 1);
        assert!(mesh.triangles.is_empty());
        assert!(parse("").unwrap().triangles.is_empty());
    }

    #[test]
    fn bad_coordinates() {
        assert_err(
            b"v 0 0 0\nv 1 abc 0\n",
            "line 2",
            "expected a number, found 'abc'",
        );
        assert_err(
            b"v 0 0 0\n\nv 1 2\n",
            "line 3",
            "vertex has 2 coordinates, needs 3",
        );
        assert_err(b"v\n", "line 1", "vertex has 0 coordinates");
        assert_err(b"v 0 nan 0\n", "line 1", "not finite");
        assert_err(b"v 0 0 inf\n", "line 1", "not finite");
        assert_err(b"v 1e39 0 0\n", "line 1", "not finite");
        assert_err(b"v 0 0 0 w\n", "line 1", "found 'w'");
    }

    #[test]
    fn bad_faces() {
        let v = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        assert_err(
            format!("{v}f 1 2\n").as_bytes(),
            "line 4",
            "face has 2 vertices",
        );
        assert_err(
            format!("{v}f\n").as_bytes(),
            "line 4",
            "face has 0 vertices",
        );
        assert_err(format!("{v}f 1 0 2\n").as_bytes(), "line 4", "index 0");
        assert_err(format!("{v}f 1 x 2\n").as_bytes(), "line 4", "found 'x'");
        assert_err(format!("{v}f 1 /2 3\n").as_bytes(), "line 4", "found '/2'");
        assert_err(
            format!("{v}f 1 2 3\nf 1 2 17\nv 1 1 1\n").as_bytes(),
            "line 5",
            "vertex index 17 out of range (4 vertices)",
        );
        assert_err(
            format!("{v}f -1 -2 -4\n").as_bytes(),
            "line 4",
            "vertex index -4 out of range (3 vertices defined so far)",
        );
        assert_err(
            format!("{v}f 1 2 99999999999\n").as_bytes(),
            "line 4",
            "99999999999 out of range",
        );
    }

    #[test]
    fn garbage_is_rejected_with_its_line() {
        assert_err(b"\x00\xff garbage", "line 1", "not valid UTF-8");
        assert_err(b"v 0 0 0\n\x89PNG\r\n", "line 2", "not valid UTF-8");
        assert_err(
            b"v 0 0 0\n0.5 1 2\n",
            "line 2",
            "not an OBJ statement: '0.5'",
        );
        assert_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0 0 0\n",
            "line 1",
            "not an OBJ statement: 'ply'",
        );
        assert_err(b"\x00\x01\x02", "line 1", "not an OBJ statement");
    }

    #[test]
    fn unknown_statements_and_corners_are_refused() {
        let v = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n";
        assert_err(format!("{v}F 1 3 4\n").as_bytes(), "line 5", "'F'");
        assert_err(format!("{v}curv 0 1 1 2\n").as_bytes(), "line 5", "'curv'");
        assert_err(
            format!("{v}f 1/x/y 2 4\n").as_bytes(),
            "line 5",
            "malformed face corner '1/x/y'",
        );
        for bad in ["1/", "1/2/", "1//", "1/2/3/4", "1/x"] {
            assert_err(
                format!("{v}f {bad} 2 4\n").as_bytes(),
                "line 5",
                "malformed",
            );
        }
        parse(&format!("{v}vp 0 1\nl 1 2\np 3\nf 1/-1/2 2//-1 4/3\n")).unwrap();
    }

    #[test]
    fn missing_file_is_an_io_error() {
        let err = load_obj(Path::new("/nonexistent/missing.obj")).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert!(err.to_string().contains("missing.obj"), "{err}");
    }

    #[test]
    fn random_input_never_panics() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let valid = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1 2//2 -1\nf 1 2 3 3\n";
        // Printable-leaning alphabet so the parser gets past the UTF-8 check most of the time.
        let alphabet = b"vf 0123456789-+./#\neE\tnaix\xff\x00";
        for _ in 0..3000 {
            let len = (next() % 80) as usize;
            let mut bytes: Vec<u8> = if next() % 2 == 0 {
                valid.to_vec()
            } else {
                Vec::new()
            };
            for _ in 0..len {
                let r = next();
                let b = if r % 4 == 0 {
                    r as u8
                } else {
                    alphabet[(r >> 8) as usize % alphabet.len()]
                };
                if !bytes.is_empty() && r % 3 == 0 {
                    let at = (r >> 16) as usize % bytes.len();
                    bytes[at] = b;
                } else {
                    bytes.push(b);
                }
            }
            if let Ok(mesh) = parse_obj(&bytes[..], Path::new("fuzz.obj")) {
                mesh.validate(Path::new("fuzz.obj")).unwrap();
            }
        }
    }

    /// An n x n grid of vertices and its quads, fan-triangulated by the loader.
    fn grid_obj(n: usize) -> String {
        let mut t = String::new();
        for i in 0..n * n {
            t += &format!("v {} {} 0\n", i % n, i / n);
        }
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x + 1;
                t += &format!("f {} {} {} {}\n", v, v + 1, v + n + 1, v + n);
            }
        }
        t
    }

    type Corners = Vec<[[u32; 3]; 3]>;

    /// The triangles `read_obj` streams from `text` (corner bits), and the pieces.
    fn streamed(text: &str, max: u64) -> Result<(Corners, usize)> {
        let (mut tris, mut pieces) = (Vec::new(), 0);
        read_obj(
            text.as_bytes(),
            Path::new("s.obj"),
            Some((max, &mut |pos: &[[f32; 3]], t: &[[u32; 3]]| {
                tris.extend(
                    t.iter()
                        .map(|x| x.map(|v| pos[v as usize].map(f32::to_bits))),
                );
                pieces += 1;
                Ok(())
            })),
        )?;
        Ok((tris, pieces))
    }

    fn corners(m: &Mesh) -> Corners {
        (0..m.triangle_count())
            .map(|i| m.corners(i).map(|p| p.map(f32::to_bits)))
            .collect()
    }

    /// Streaming hands on the triangles of the whole-file parse, in order, in pieces; faces that
    /// refer ahead or back count like any other; too many vertices and a consumer's failure stop
    /// it with their own errors.
    #[test]
    fn streaming_hands_on_the_parsed_triangles_in_pieces() {
        let grid = grid_obj(260);
        let text = format!("f 1 2 3\n{grid}f -1 -2 -3\n");
        let whole = parse(&text).unwrap();
        let (got, pieces) = streamed(&text, u64::MAX).unwrap();
        assert!(got == corners(&whole), "streamed triangles differ");
        assert!(pieces >= 3, "{pieces} pieces");
        // A face that uses the last vertex, which comes last: everything is held until then.
        let last = grid.lines().nth(260 * 260 - 1).unwrap();
        let rest: Vec<&str> = grid.lines().filter(|l| *l != last).collect();
        let ahead = format!("f 1 2 {}\n{}\n{last}\n", 260 * 260, rest.join("\n"));
        let whole = parse(&ahead).unwrap();
        let (got, pieces) = streamed(&ahead, u64::MAX).unwrap();
        assert!(got == corners(&whole), "streamed triangles differ");
        assert_eq!(pieces, 1);
        let e = streamed(&text, 1000).unwrap_err().to_string();
        assert!(
            e.contains("s.obj: line 1002") && e.contains("raise --memory"),
            "{e}"
        );
        let e = streamed(&ahead, 1000).unwrap_err().to_string();
        assert!(e.contains("s.obj: line 1002"), "{e}");
        // A face past the last vertex is found at the end, as by the whole-file parse.
        let bad = format!("{grid}f 1 2 {}\n", 260 * 260 + 1);
        let e = streamed(&bad, u64::MAX).unwrap_err().to_string();
        assert!(e.contains("out of range"), "{e}");
        let mut calls = 0;
        let e = read_obj(
            text.as_bytes(),
            Path::new("s.obj"),
            Some((u64::MAX, &mut |_: &[[f32; 3]], _: &[[u32; 3]]| {
                calls += 1;
                Err(Error::Invalid("disk full".into()))
            })),
        )
        .unwrap_err();
        assert_eq!((calls, e.to_string()), (1, "disk full".to_string()));
    }
}
