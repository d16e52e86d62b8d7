//! STL loading, binary and ASCII: triangles only (STL has no shared vertices and no data
//! arrays; facet normals are ignored, as dcrt computes geometric normals, and so are binary
//! STL's attribute bytes, whose colour conventions differ between tools).
//!
//! A file is binary when its length is exactly `84 + 50 n` for the count `n` its header gives
//! (binary files may start with `solid` too); otherwise it must be ASCII, starting with `solid`.
//! ASCII files are read strictly, statement by statement, so that a damaged file fails with the
//! line that is wrong.

use crate::error::{Error, Result};
use crate::scene::mesh::Mesh;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

const HEADER: u64 = 84;
const RECORD: u64 = 50;
/// Longest ASCII line accepted (binary data read as text has no newlines).
const MAX_LINE: u64 = 1 << 16;
/// Most triangles a header count may reserve room for up front.
const MAX_RESERVE: u64 = 1 << 20;

/// Reads the STL file at `path`.
pub fn load_stl(path: &Path) -> Result<Mesh> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    parse_stl(BufReader::with_capacity(1 << 18, file), len, path)
}

/// Parses an STL file of `len` bytes from `reader`; `origin` names it in errors.
pub fn parse_stl<R: BufRead>(mut reader: R, len: u64, origin: &Path) -> Result<Mesh> {
    let mut head = Vec::with_capacity(HEADER as usize);
    (&mut reader)
        .take(HEADER)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(origin, e))?;
    let declared = (head.len() as u64 == HEADER)
        .then(|| u64::from(u32::from_le_bytes([head[80], head[81], head[82], head[83]])));
    if let Some(n) = declared
        && HEADER + RECORD * n == len
    {
        return read_binary(reader, n, origin);
    }
    let text = head.trim_ascii_start();
    if text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"solid") {
        return read_ascii(head.chain(reader), origin);
    }
    Err(Error::format(
        origin,
        None,
        match declared {
            Some(n) => format!(
                "not an STL file: not ASCII (no 'solid' at the start), and as binary STL its \
                 header declares {n} triangles ({} bytes) where the file has {len}",
                HEADER + RECORD * n
            ),
            None => format!(
                "not an STL file: {len} bytes, shorter than a binary STL header, and no 'solid' \
                 at the start"
            ),
        },
    ))
}

fn read_binary<R: BufRead>(mut r: R, n: u64, origin: &Path) -> Result<Mesh> {
    let mut mesh = Mesh::default();
    if n >= u64::from(u32::MAX) / 3 {
        return Err(Error::format(
            origin,
            None,
            format!("{n} triangles: at most {} supported", u32::MAX / 3 - 1),
        ));
    }
    mesh.positions.reserve(3 * n.min(MAX_RESERVE) as usize);
    mesh.triangles.reserve(n.min(MAX_RESERVE) as usize);
    let mut rec = [0u8; RECORD as usize];
    for i in 0..n {
        r.read_exact(&mut rec).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                Error::format(
                    origin,
                    Some(format!("triangle {i}")),
                    format!("file ends after {i} of {n} triangles"),
                )
            } else {
                Error::io(origin, e)
            }
        })?;
        let f = |k: usize| {
            f32::from_le_bytes([rec[4 * k], rec[4 * k + 1], rec[4 * k + 2], rec[4 * k + 3]])
        };
        let base = mesh.positions.len() as u32;
        for v in 0..3 {
            let p = [f(3 + 3 * v), f(4 + 3 * v), f(5 + 3 * v)];
            if !p.iter().all(|c| c.is_finite()) {
                return Err(Error::format(
                    origin,
                    Some(format!("triangle {i}")),
                    format!("vertex {v}: coordinate is not finite: {p:?}"),
                ));
            }
            mesh.positions.push(p);
        }
        mesh.triangles.push([base, base + 1, base + 2]);
    }
    Ok(mesh)
}

/// Where the ASCII reader is in the statement grammar.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// Before `solid` (start of file, or after `endsolid`).
    Outside,
    /// Inside a solid, expecting `facet` or `endsolid`.
    Solid,
    /// After `facet normal`, expecting `outer loop`.
    Facet,
    /// Inside a loop with this many vertices read.
    Loop(u8),
    /// After the third vertex's `endloop`, expecting `endfacet`.
    EndLoop,
}

impl State {
    fn expecting(self) -> &'static str {
        match self {
            State::Outside => "'solid'",
            State::Solid => "'facet normal' or 'endsolid'",
            State::Facet => "'outer loop'",
            State::Loop(3) => "'endloop'",
            State::Loop(_) => "'vertex'",
            State::EndLoop => "'endfacet'",
        }
    }
}

fn read_ascii<R: BufRead>(mut r: R, origin: &Path) -> Result<Mesh> {
    let mut mesh = Mesh::default();
    let mut state = State::Outside;
    let mut line = Vec::new();
    let mut n = 0usize;
    let mut solids = 0usize;
    loop {
        line.clear();
        let read = (&mut r)
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
            .map_err(|_| at("not valid UTF-8 text (a damaged binary STL?)".into()))?;
        let mut words = text.split_ascii_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let keyword = keyword.to_ascii_lowercase();
        let unexpected = || {
            at(format!(
                "expected {}, found '{}'",
                state.expecting(),
                keyword.escape_debug().take(32).collect::<String>()
            ))
        };
        state = match (state, keyword.as_str()) {
            // `solid` takes an optional name: any words.
            (State::Outside, "solid") => {
                solids += 1;
                State::Solid
            }
            (State::Solid, "endsolid") => State::Outside,
            (State::Solid, "facet") => {
                if !words
                    .next()
                    .is_some_and(|w| w.eq_ignore_ascii_case("normal"))
                {
                    return Err(at("expected 'facet normal nx ny nz'".into()));
                }
                numbers(&mut words, "the normal").map_err(at)?;
                State::Facet
            }
            (State::Facet, "outer") => {
                if !words.next().is_some_and(|w| w.eq_ignore_ascii_case("loop")) {
                    return Err(at("expected 'outer loop'".into()));
                }
                State::Loop(0)
            }
            (State::Loop(k), "vertex") if k < 3 => {
                let p = numbers(&mut words, "a vertex").map_err(at)?;
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(at(format!("coordinate is not finite: {p:?}")));
                }
                mesh.positions.push(p);
                State::Loop(k + 1)
            }
            (State::Loop(k), "endloop") => {
                if k != 3 {
                    return Err(at(format!("a facet has {k} vertices, STL needs exactly 3")));
                }
                State::EndLoop
            }
            (State::EndLoop, "endfacet") => {
                let base = mesh.positions.len() as u32 - 3;
                mesh.triangles.push([base, base + 1, base + 2]);
                State::Solid
            }
            _ => return Err(unexpected()),
        };
        // Only `solid` and `endsolid` take free text (the name).
        if !matches!(keyword.as_str(), "solid" | "endsolid")
            && let Some(w) = words.next()
        {
            return Err(at(format!(
                "unexpected '{}' after '{keyword}'",
                w.escape_debug().take(32).collect::<String>()
            )));
        }
        if mesh.triangles.len() as u64 >= u64::from(u32::MAX) / 3 {
            return Err(at("too many triangles".into()));
        }
    }
    if state != State::Outside || solids == 0 {
        return Err(Error::format(
            origin,
            Some(format!("line {n}")),
            format!("file ends where {} was expected", state.expecting()),
        ));
    }
    Ok(mesh)
}

/// Three numbers and nothing after them.
fn numbers<'a>(
    words: &mut impl Iterator<Item = &'a str>,
    what: &str,
) -> std::result::Result<[f32; 3], String> {
    let mut p = [0f32; 3];
    for (k, c) in p.iter_mut().enumerate() {
        let w = words
            .next()
            .ok_or_else(|| format!("{what} has {k} coordinates, needs 3"))?;
        *c = w.parse().map_err(|_| {
            format!(
                "expected a number, found '{}'",
                w.escape_debug().take(32).collect::<String>()
            )
        })?;
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    pub const ASCII: &str = "solid cube part\n  facet normal 0 0 -1\n    outer loop\n      \
        vertex 0 0 0\n      vertex 1 1 0\n      vertex 1 0 0\n    endloop\n  endfacet\n  \
        facet normal 0 0 1\n    outer loop\n      vertex 0 0 1\n      vertex 1 0 1\n      \
        vertex 1 1 1\n    endloop\n  endfacet\nendsolid cube part\n";

    pub fn binary(tris: &[[[f32; 3]; 3]], header: &[u8]) -> Vec<u8> {
        let mut b = vec![0u8; 80];
        b[..header.len()].copy_from_slice(header);
        b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
        for t in tris {
            b.extend_from_slice(&[0u8; 12]);
            for v in t {
                for c in v {
                    b.extend_from_slice(&c.to_le_bytes());
                }
            }
            b.extend_from_slice(&[0u8; 2]);
        }
        b
    }

    fn parse(bytes: &[u8]) -> Result<Mesh> {
        parse_stl(bytes, bytes.len() as u64, Path::new("t.stl"))
    }

    fn assert_err(bytes: &[u8], place: &str, what: &str) {
        let e = parse(bytes).expect_err(what).to_string();
        assert!(
            e.contains("t.stl") && e.contains(place) && e.contains(what),
            "{e}"
        );
    }

    #[test]
    fn ascii_and_binary_read_the_same() {
        let a = parse(ASCII.as_bytes()).unwrap();
        assert_eq!(a.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        let tris: Vec<[[f32; 3]; 3]> = (0..2).map(|i| a.corners(i)).collect();
        // A binary header that starts with "solid" is still binary by its length.
        let b = parse(&binary(&tris, b"solid but binary")).unwrap();
        assert_eq!(b.positions, a.positions);
        assert_eq!(b.triangles, a.triangles);
        // Several solids, CRLF, upper case.
        let two = format!("{ASCII}{}", ASCII.replace('\n', "\r\n").to_uppercase());
        assert_eq!(parse(two.as_bytes()).unwrap().triangles.len(), 4);
        // An empty solid is an empty mesh.
        assert!(
            parse(b"solid x\nendsolid x\n")
                .unwrap()
                .triangles
                .is_empty()
        );
    }

    #[test]
    fn ascii_errors_name_the_line() {
        let edit = |from: &str, to: &str| ASCII.replacen(from, to, 1).into_bytes();
        assert_err(&edit("vertex 1 1 0", "vertex 1 x 0"), "line 5", "found 'x'");
        assert_err(
            &edit("vertex 1 1 0", "vertex 1 nan 0"),
            "line 5",
            "not finite",
        );
        assert_err(
            &edit("vertex 1 1 0", "vertex 1 1"),
            "line 5",
            "has 2 coordinates",
        );
        assert_err(
            &edit("vertex 1 1 0", "vertex 1 1 0 7"),
            "line 5",
            "unexpected '7'",
        );
        assert_err(
            &edit("      vertex 1 0 0\n", ""),
            "line 6",
            "a facet has 2 vertices",
        );
        assert_err(
            &edit("    endloop\n", "      vertex 2 2 2\n    endloop\n"),
            "line 7",
            "expected 'endloop', found 'vertex'",
        );
        assert_err(
            &edit("outer loop", "outer lop"),
            "line 3",
            "expected 'outer loop'",
        );
        assert_err(
            &edit("endfacet", "endfacets"),
            "line 8",
            "expected 'endfacet'",
        );
        assert_err(
            &edit("facet normal 0 0 -1", "facet 0 0 -1"),
            "line 2",
            "facet normal",
        );
        let cut = ASCII.find("      vertex 1 1 0").unwrap();
        assert_err(
            &ASCII.as_bytes()[..cut],
            "line 4",
            "file ends where 'vertex' was expected",
        );
        assert_err(
            &ASCII.as_bytes()[..cut + 7],
            "line 5",
            "expected 'vertex', found 'v'",
        );
        assert_err(&edit("endsolid cube part\n", ""), "line 15", "'endsolid'");
        let mut bad = ASCII.as_bytes().to_vec();
        bad[70] = 0xff;
        assert_err(&bad, "line 4", "not valid UTF-8");
        assert_err(
            b"solid\nfacet normal 0 0 1\n",
            "line 2",
            "where 'outer loop'",
        );
        assert_err(b"hello", "", "shorter than a binary STL header");
        assert_err(&[7u8; 200], "", "declares 117901063 triangles");
    }

    #[test]
    fn binary_errors_name_the_triangle() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut bad = t;
        bad[2][1] = f32::NAN;
        assert_err(
            &binary(&[t, bad], b""),
            "triangle 1",
            "vertex 2: coordinate is not finite",
        );
        // A count that does not match the length: neither binary nor ASCII.
        let mut short = binary(&[t, t], b"");
        short.truncate(short.len() - 10);
        assert_err(
            &short,
            "",
            "declares 2 triangles (184 bytes) where the file has 174",
        );
        // A truncated stream (the length lied, as a file shrinking while read would).
        let b = binary(&[t, t], b"");
        let e = parse_stl(&b[..120], b.len() as u64, Path::new("t.stl"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("triangle 0") && e.contains("after 0 of 2"),
            "{e}"
        );
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
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let valid = [ASCII.as_bytes().to_vec(), binary(&[t, t, t], b"solid")];
        for round in 0..2000 {
            let mut b = valid[round % 2].clone();
            for _ in 0..1 + next() % 4 {
                let i = next() as usize % b.len();
                b[i] = next() as u8;
            }
            if next() % 3 == 0 {
                b.truncate(next() as usize % (b.len() + 1));
            }
            if let Ok(m) = parse(&b) {
                m.validate(Path::new("fuzz.stl")).unwrap();
            }
        }
    }
}
