//! Stanford PLY loading: `ascii`, `binary_little_endian` and `binary_big_endian` 1.0.
//!
//! Vertex positions (`x`, `y`, `z` of element `vertex`) and face index lists (`vertex_indices`
//! or `vertex_index` of element `face`) make the mesh; the other scalar properties of vertices
//! and faces are its point and cell data arrays (`header::data_arrays`), kept when asked for.
//! Every other property and element is still parsed, so that its bytes are skipped correctly
//! and a file whose data does not match its header is reported instead of being misread.
//!
//! Here: the load API and the record builder the body readers share; `header`: the header
//! parser; `ascii` and `binary`: the body readers.

mod ascii;
mod binary;
#[cfg(test)]
mod fixtures;
mod header;

use crate::error::{Error, Result};
use crate::scene::data::{Keep, MeshData, Values};
use crate::scene::mesh::{Mesh, Piece};
use ascii::read_ascii;
use binary::read_binary;
use header::{Format, Header, KeptArray, Role, Target};
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

/// Most elements a header count may reserve room for up front. A corrupt count must not allocate
/// gigabytes before truncation is noticed; bigger real meshes grow the vectors as they are read.
const MAX_RESERVE: u64 = 1 << 20;

/// Reads the PLY file at `path`.
pub fn load_ply(path: &Path) -> Result<Mesh> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    parse_ply(BufReader::with_capacity(1 << 18, file), path)
}

/// Parses a PLY file from `reader` (e.g. a `BufReader<File>` or a `&[u8]`); `origin` names the
/// source in errors.
///
/// Polygons are fan-triangulated in order, (v0,v1,v2), (v0,v2,v3), ..., so triangle ids follow
/// file order. Header errors name the header line; data errors name the element and its index
/// (and the line, for ascii files).
pub fn parse_ply<R: BufRead>(reader: R, origin: &Path) -> Result<Mesh> {
    parse_ply_data(reader, origin, &Keep::None).map(|(mesh, _)| mesh)
}

/// Reads the PLY file at `path` with its data arrays, keeping the values of those `keep` asks
/// for.
pub fn load_ply_data(path: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    parse_ply_data(BufReader::with_capacity(1 << 18, file), path, keep)
}

/// `parse_ply` with the data arrays (see `load_ply_data`).
pub fn parse_ply_data<R: BufRead>(
    reader: R,
    origin: &Path,
    keep: &Keep,
) -> Result<(Mesh, MeshData)> {
    read_ply(reader, origin, keep, None)
}

/// Reads the PLY file at `path` as `load_ply` does, handing its triangles to `piece` with the
/// vertices, `PIECE` at a time, so that the triangles are never all held: every vertex is kept
/// (a face may use any), so a file of more than `max_vertices` vertices is refused at its
/// header. Faces written before the vertices are held until the vertices are read. Data arrays
/// are not read.
pub fn stream_ply(path: &Path, max_vertices: u64, piece: &mut Piece) -> Result<()> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = BufReader::with_capacity(1 << 18, file);
    read_ply(&mut reader, path, &Keep::None, Some((max_vertices, piece))).map(drop)
}

/// Triangles handed on at a time when streaming.
const PIECE: usize = 1 << 16;

fn read_ply<'a, 'p, R: BufRead>(
    mut reader: R,
    origin: &Path,
    keep: &Keep,
    stream: Option<(u64, &'a mut Piece<'p>)>,
) -> Result<(Mesh, MeshData)> {
    let mut header = Header::read(&mut reader, origin)?;
    let mut data = MeshData::default();
    let (kept, slots) = header::data_arrays(&mut header, keep, &mut data);
    let count = |target| {
        header
            .elements
            .iter()
            .find(|e| e.target == target)
            .map_or(0, |e| e.count)
    };
    let vertex_count = count(Target::Vertices);
    if let Some((max, _)) = &stream
        && vertex_count > *max
    {
        return Err(Error::format(
            origin,
            None,
            format!(
                "{vertex_count} vertices: more than the {max} the memory budget holds (every \
                 vertex of a mesh file is kept while its faces are read); raise --memory"
            ),
        ));
    }
    let mut b = Builder {
        mesh: Mesh {
            positions: Vec::with_capacity(vertex_count.min(MAX_RESERVE) as usize),
            triangles: Vec::with_capacity(count(Target::Faces).min(MAX_RESERVE) as usize),
        },
        vertex_count,
        xyz: [0.0; 3],
        poly: Vec::new(),
        piece: stream.map(|s| s.1),
        failed: None,
        values: kept.iter().map(|k| Values::new(k.slots.len())).collect(),
        kept,
        record: vec![0.0; slots],
        cells: keep.cells().then(Vec::new),
        faces: 0,
    };
    let read = match header.format {
        Format::Ascii => read_ascii(&mut reader, &header, &mut b, origin),
        Format::Binary { big_endian } => {
            read_binary(&mut reader, &header, big_endian, &mut b, origin)
        }
    };
    // A failure of the piece's consumer is reported as itself, not as bad data.
    if let Some(e) = b.failed.take() {
        return Err(e);
    }
    read?;
    if b.flush(true).is_err() {
        return Err(b.failed.take().unwrap_or_else(|| {
            Error::Internal("a streamed PLY's consumer failed without an error".into())
        }));
    }
    data.kept = b.kept.iter().map(|k| k.index).zip(b.values).collect();
    data.triangle_cells = b.cells.unwrap_or_default();
    Ok((b.mesh, data))
}

/// Collects decoded values into the mesh, one record at a time; when streaming, hands on the
/// triangles a piece at a time.
struct Builder<'a, 'p> {
    mesh: Mesh,
    vertex_count: u64,
    xyz: [f64; 3],
    poly: Vec<u32>,
    piece: Option<&'a mut Piece<'p>>,
    /// What the piece's consumer failed with.
    failed: Option<Error>,
    /// The kept data arrays, their values, and the current record's values by slot.
    kept: Vec<KeptArray>,
    values: Vec<Values>,
    record: Vec<f64>,
    /// Each triangle's face, when cell arrays may be kept.
    cells: Option<Vec<u32>>,
    faces: u32,
}

impl Builder<'_, '_> {
    /// A decoded scalar property.
    #[inline]
    fn scalar(&mut self, role: Role, v: f64) {
        match role {
            Role::Coord(k) => self.xyz[k] = v,
            Role::Value(s) => self.record[s] = v,
            Role::Skip | Role::Indices => {}
        }
    }

    /// Appends the current record's values to the kept arrays of `target`.
    fn keep(&mut self, target: Target) {
        for (k, v) in self.kept.iter().zip(&mut self.values) {
            if k.target == target {
                v.data
                    .extend(k.slots.iter().map(|&s| (self.record[s] * k.scale) as f32));
            }
        }
    }

    /// Hands the triangles read so far on, when streaming and every vertex has been read (at
    /// the end, `last`, whatever is left). `Err` when the consumer failed: its error is in
    /// `failed`.
    fn flush(&mut self, last: bool) -> std::result::Result<(), ()> {
        let Some(piece) = &mut self.piece else {
            return Ok(());
        };
        let ready = self.mesh.positions.len() as u64 == self.vertex_count;
        if self.mesh.triangles.is_empty() || !ready || (!last && self.mesh.triangles.len() < PIECE)
        {
            return Ok(());
        }
        match piece(&self.mesh.positions, &self.mesh.triangles) {
            Ok(()) => {
                self.mesh.triangles.clear();
                Ok(())
            }
            Err(e) => {
                self.failed = Some(e);
                Err(())
            }
        }
    }

    #[inline]
    fn index(&mut self, v: f64) -> std::result::Result<(), String> {
        // Also rejects negative values; the header limits vertex_count to u32 range.
        if v >= 0.0 && v < self.vertex_count as f64 {
            self.poly.push(v as u32);
            Ok(())
        } else {
            Err(format!(
                "vertex index {v} out of range ({} vertices)",
                self.vertex_count
            ))
        }
    }

    /// Completes the record just read for an element of kind `target`.
    #[inline]
    fn finish(&mut self, target: Target) -> std::result::Result<(), String> {
        match target {
            Target::Vertices => {
                let p = self.xyz.map(|c| c as f32);
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(format!("coordinate is not finite: {p:?}"));
                }
                self.mesh.positions.push(p);
                self.keep(target);
            }
            Target::Faces => {
                let poly = &self.poly;
                if poly.len() < 3 {
                    return Err(format!(
                        "face has {} vertices, needs at least 3",
                        poly.len()
                    ));
                }
                for k in 1..poly.len() - 1 {
                    self.mesh.triangles.push([poly[0], poly[k], poly[k + 1]]);
                }
                if let Some(c) = self.cells.as_mut() {
                    c.extend(std::iter::repeat_n(self.faces, poly.len() - 2));
                }
                self.faces = self.faces.wrapping_add(1);
                self.poly.clear();
                self.keep(target);
                self.flush(false)
                    .map_err(|()| "the triangles read could not be passed on".to_string())?;
            }
            Target::Other => {}
        }
        Ok(())
    }
}

enum Line {
    Eof,
    Text,
    TooLong,
}

/// Reads one line, newline included, of at most `limit` bytes into `buf`.
fn read_line<R: BufRead>(r: &mut R, buf: &mut Vec<u8>, limit: u64) -> io::Result<Line> {
    buf.clear();
    let n = r.by_ref().take(limit).read_until(b'\n', buf)?;
    Ok(if n == 0 {
        Line::Eof
    } else if n as u64 == limit && buf.last() != Some(&b'\n') {
        Line::TooLong
    } else {
        Line::Text
    })
}

/// A token as it can be shown in a message: short, and with control characters escaped.
fn snippet(tok: &str) -> String {
    tok.escape_debug().take(32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use fixtures::*;

    #[test]
    fn cube_round_trips_in_every_format() {
        let want = expected_cube();
        for format in FORMATS {
            let mesh = parse(&write_ply(format, &cube_elements("float", "uchar", "int"))).unwrap();
            assert_same(&mesh, &want);
        }
    }

    #[test]
    fn every_scalar_type() {
        let want = expected_cube();
        let coords = ["float", "float32", "double", "float64"];
        let ints = ["char", "int8", "short", "int16", "int", "int32"];
        let uints = ["uchar", "uint8", "ushort", "uint16", "uint", "uint32"];
        for format in FORMATS {
            for (k, index) in ints.iter().chain(&uints).enumerate() {
                let coord = coords[k % coords.len()];
                let count = ints.iter().chain(&uints).nth(k * 5 % 12).unwrap();
                let file = write_ply(format, &cube_elements(coord, count, index));
                assert_same(&parse(&file).unwrap(), &want);
            }
            // Integer coordinates (the cube's z is fractional, so use a unit cube here).
            for coord in ints.iter().chain(&uints).copied() {
                let mut els = cube_elements(coord, "uchar", "uint");
                for row in &mut els[1].rows {
                    row[4] = 1.0;
                }
                let mesh = parse(&write_ply(format, &els)).unwrap();
                assert_eq!(mesh.positions[7], [1.0, 1.0, 1.0]);
                assert_eq!(mesh.triangles, want.triangles);
            }
        }
    }

    #[test]
    fn faces_before_vertices_and_vertex_index_name() {
        for format in FORMATS {
            let mut els = cube_elements("float", "uchar", "int");
            els.swap(1, 3);
            if let P::L(_, _, name) = &mut els[1].props[1] {
                *name = "vertex_index";
            }
            assert_same(&parse(&write_ply(format, &els)).unwrap(), &expected_cube());
        }
    }

    #[test]
    fn pentagon_fans_in_order_and_no_faces_is_empty() {
        let text = b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\n\
            property list uchar uint vertex_indices\nend_header\n\
            0 0 0\n1 0 0\n1 1 0\n0.5 2 0\n0 1 0\n\n5 0 1 2 3 4\n\n";
        let mesh = parse(text).unwrap();
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
        let points = b"ply\r\nformat ascii 1.0\r\nelement vertex 1\r\nproperty float x\r\n\
            property float y\r\nproperty float z\r\nend_header\r\n1 2 3\r\n";
        let mesh = parse(points).unwrap();
        assert_eq!(mesh.positions, vec![[1.0, 2.0, 3.0]]);
        assert!(mesh.triangles.is_empty());
    }

    #[test]
    fn trailing_data() {
        for format in &FORMATS[1..] {
            let mut file = write_ply(format, &cube_elements("float", "uchar", "int"));
            file.extend_from_slice(b"abc");
            assert_err(&file, "test.ply", "3 bytes of data after the last element");
        }
        let mut file = write_ply("ascii", &cube_elements("float", "uchar", "int"));
        file.extend_from_slice(b"\n3 0 1 2\n3 0 2 1\n\n");
        assert_err(&file, "line 44", "2 lines of data after the last element");
    }

    #[test]
    fn data_errors() {
        let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                    property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                    end_header\n";
        let file = |data: &str| format!("{head}{data}").into_bytes();
        assert_err(
            &file("0 0 0\n1 abc 0\n0 1 0\n3 0 1 2\n"),
            "vertex 1 (line 11)",
            "expected a number, found 'abc'",
        );
        assert_err(
            &file("0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"),
            "vertex 1",
            "not finite",
        );
        assert_err(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1 17\n"),
            "face 0 (line 13)",
            "vertex index 17 out of range (3 vertices)",
        );
        assert_err(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"),
            "face 0",
            "vertex index -1 out of range",
        );
        assert_err(
            &file("0 0 0\n1 0 0\n0 1 0\n2 0 1\n"),
            "face 0",
            "face has 2 vertices, needs at least 3",
        );
        assert_err(
            &file("0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n"),
            "face 0",
            "expected an integer, found '1.5'",
        );
        assert_err(
            &file("0 0 0\n1 0 0\n0 1 0\n300 0 1 2\n"),
            "face 0",
            "value 300 out of range for uchar",
        );
        let mut bad = file("0 0 0\n");
        bad.extend_from_slice(b"\xff 0 0\n");
        assert_err(&bad, "vertex 1 (line 11)", "not valid UTF-8");

        // The same checks on binary data.
        let bin = |x: f32, idx: i32| {
            let mut els = cube_elements("float", "uchar", "int");
            els[1].rows[3][1] = f64::from(x);
            els[3].rows[2][3] = f64::from(idx);
            write_ply("binary_big_endian", &els)
        };
        assert_err(&bin(f32::INFINITY, 1), "vertex 3", "not finite");
        assert_err(
            &bin(0.0, 8),
            "face 2",
            "vertex index 8 out of range (8 vertices)",
        );
        assert_err(&bin(0.0, -3), "face 2", "vertex index -3 out of range");
        let mut els = cube_elements("float", "uchar", "int");
        els[3].rows[4] = vec![3.0, 2.0, 0.0, 1.0, 0.0];
        assert_err(
            &write_ply("binary_little_endian", &els),
            "face 4",
            "face has 2 vertices",
        );
        let mut els = cube_elements("float", "int", "int");
        els[3].rows[4] = vec![3.0, -1.0, 0.0];
        assert_err(
            &write_ply("binary_little_endian", &els),
            "face 4",
            "negative length",
        );
    }

    #[test]
    fn absurd_counts_fail_as_truncation() {
        for format in FORMATS {
            let file = format!(
                "ply\nformat {format} 1.0\nelement vertex 4000000000\nproperty float x\n\
                 property float y\nproperty float z\nelement face 4000000000\n\
                 property list uint uint vertex_indices\nend_header\n"
            );
            assert_err(
                file.as_bytes(),
                "vertex 0",
                "file ends after 0 of 4000000000 vertices",
            );
        }
        // A face claiming four billion corners.
        let mut file = write_ply(
            "binary_little_endian",
            &cube_elements("float", "uint", "int"),
        );
        file.truncate(file.len() - 6 * (1 + 4 + 4 * 4 + 1 + 2 * 4));
        file.extend_from_slice(&[3, 0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0]);
        assert_err(&file, "face 0", "file ends after 0 of 6 faces");
    }

    #[test]
    fn vertex_and_face_properties_are_data_arrays() {
        use crate::scene::data::Assoc;
        // The cube's vertices carry nx, s, red and u; faces flags (and a texcoord list, not an
        // array). With red, green, blue the vertices get an "RGB" colour array.
        let mut els = cube_elements("float", "uchar", "int");
        els[1].props.push(P::S("uchar", "green"));
        els[1].props.push(P::S("uchar", "blue"));
        for (i, row) in els[1].rows.iter_mut().enumerate() {
            row[6] = i as f64;
            row.extend([51.0, 0.0]);
        }
        for (i, row) in els[3].rows.iter_mut().enumerate() {
            row[0] = 10.0 * i as f64;
        }
        for format in FORMATS {
            let file = write_ply(format, &els);
            let (mesh, d) = parse_ply_data(&file[..], Path::new("t.ply"), &Keep::All).unwrap();
            assert_same(&mesh, &expected_cube());
            let names: Vec<String> = d.arrays.iter().map(|a| a.to_string()).collect();
            assert_eq!(
                names,
                [
                    "nx (point data, 1 x float)",
                    "s (point data, 1 x short)",
                    "RGB (point data, 3 x uchar, colours)",
                    "u (point data, 1 x double)",
                    "flags (cell data, 1 x uchar)"
                ]
            );
            assert_eq!(
                d.values(3).unwrap().data,
                (0..8).map(|i| i as f32).collect::<Vec<_>>()
            );
            assert_eq!(d.values(2).unwrap().data[..3], [1.0, 0.2, 0.0]);
            // Two triangles per face, each of its face.
            assert_eq!(d.triangle_cells, vec![0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5]);
            assert_eq!(
                d.values(4).unwrap().data,
                vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0]
            );
            // Only what is asked for is kept.
            let keep = Keep::One {
                name: "u".into(),
                assoc: Assoc::Point,
            };
            let (_, d) = parse_ply_data(&file[..], Path::new("t.ply"), &keep).unwrap();
            assert_eq!(d.kept.len(), 1);
            assert!(d.triangle_cells.is_empty());
        }
    }

    #[test]
    fn missing_file_is_an_io_error() {
        let err = load_ply(Path::new("/nonexistent/missing.ply")).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert!(err.to_string().contains("missing.ply"), "{err}");
    }

    #[test]
    fn random_input_never_panics() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let valid: Vec<Vec<u8>> = FORMATS
            .iter()
            .map(|f| write_ply(f, &cube_elements("float", "uchar", "int")))
            .collect();
        for round in 0..4000 {
            let mut bytes = match round % 4 {
                3 => (0..next() % 200).map(|_| next() as u8).collect(),
                k => valid[k].clone(),
            };
            // Mutate a few bytes (often in the header, where counts and types live), then maybe
            // truncate or append.
            for _ in 0..1 + next() % 4 {
                if bytes.is_empty() {
                    break;
                }
                let r = next();
                let at = if r % 2 == 0 {
                    r as usize % bytes.len().min(200)
                } else {
                    r as usize % bytes.len()
                };
                bytes[at] = match (r >> 32) % 3 {
                    0 => (r >> 40) as u8,
                    1 => b"0123456789 \n-."[(r >> 40) as usize % 14],
                    _ => bytes[at].wrapping_add(1),
                };
            }
            match next() % 3 {
                0 => bytes.truncate(next() as usize % (bytes.len() + 1)),
                1 => bytes.push(next() as u8),
                _ => {}
            }
            let result = if round % 5 == 0 {
                let capacity = 1 + next() as usize % 64;
                parse_ply(
                    io::BufReader::with_capacity(capacity, &bytes[..]),
                    Path::new("f"),
                )
            } else {
                parse(&bytes)
            };
            if let Ok(mesh) = result {
                mesh.validate(Path::new("fuzz.ply")).unwrap();
            }
        }
    }

    /// An n x n grid of vertices and its quads in `format`, faces first or last.
    fn grid_ply(format: &str, n: usize, faces_first: bool) -> Vec<u8> {
        let vertices = El {
            name: "vertex",
            props: vec![P::S("float", "x"), P::S("float", "y"), P::S("float", "z")],
            rows: (0..n * n)
                .map(|i| vec![(i % n) as f64, (i / n) as f64, 0.5])
                .collect(),
        };
        let mut rows = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = (y * n + x) as f64;
                rows.push(vec![4.0, v, v + 1.0, v + n as f64 + 1.0, v + n as f64]);
            }
        }
        let faces = El {
            name: "face",
            props: vec![P::L("uchar", "int", "vertex_indices")],
            rows,
        };
        let els = if faces_first {
            vec![faces, vertices]
        } else {
            vec![vertices, faces]
        };
        write_ply(format, &els)
    }

    /// Streaming hands on the triangles of the whole-file parse, in order, in pieces (one piece
    /// when the faces come before the vertices); too many vertices are refused at the header; a
    /// consumer's failure comes back as itself.
    #[test]
    fn streaming_hands_on_the_parsed_triangles_in_pieces() {
        for format in FORMATS {
            for faces_first in [false, true] {
                let bytes = grid_ply(format, 200, faces_first);
                let whole = parse(&bytes).unwrap();
                let want: Vec<_> = (0..whole.triangle_count())
                    .map(|i| whole.corners(i).map(|p| p.map(f32::to_bits)))
                    .collect();
                let (mut got, mut pieces) = (Vec::new(), 0);
                read_ply(
                    &bytes[..],
                    Path::new("s.ply"),
                    &Keep::None,
                    Some((u64::MAX, &mut |pos: &[[f32; 3]], t: &[[u32; 3]]| {
                        got.extend(
                            t.iter()
                                .map(|x| x.map(|v| pos[v as usize].map(f32::to_bits))),
                        );
                        pieces += 1;
                        Ok(())
                    })),
                )
                .unwrap();
                assert!(got == want, "{format}: streamed triangles differ");
                assert_eq!(pieces, if faces_first { 1 } else { 2 }, "{format}");
            }
            let bytes = grid_ply(format, 200, false);
            let mut none = |_: &[[f32; 3]], _: &[[u32; 3]]| Ok(());
            let e = read_ply(
                &bytes[..],
                Path::new("s.ply"),
                &Keep::None,
                Some((1000, &mut none)),
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.contains("40000 vertices") && e.contains("raise --memory"),
                "{e}"
            );
            let mut calls = 0;
            let mut fail = |_: &[[f32; 3]], _: &[[u32; 3]]| {
                calls += 1;
                Err(Error::Invalid("disk full".into()))
            };
            let e = read_ply(
                &bytes[..],
                Path::new("s.ply"),
                &Keep::None,
                Some((u64::MAX, &mut fail)),
            )
            .unwrap_err();
            assert_eq!((calls, e.to_string()), (1, "disk full".to_string()));
        }
    }
}
