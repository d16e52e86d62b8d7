//! Stanford PLY loading: `ascii`, `binary_little_endian` and `binary_big_endian` 1.0.
//!
//! Only vertex positions (`x`, `y`, `z` of element `vertex`) and face index lists
//! (`vertex_indices` or `vertex_index` of element `face`) are kept. Every other property and
//! element is still parsed, so that its bytes are skipped correctly and a file whose data does
//! not match its header is reported instead of being misread.

use crate::error::{Error, Result};
use crate::scene::mesh::Mesh;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

/// Most elements a header count may reserve room for up front. A corrupt count must not allocate
/// gigabytes before truncation is noticed; bigger real meshes grow the vectors as they are read.
const MAX_RESERVE: u64 = 1 << 20;
/// Longest header line accepted, so binary data is not slurped while looking for a newline.
const MAX_HEADER_LINE: u64 = 1 << 16;
/// Longest ascii data line accepted (a polygon of a few hundred thousand vertices).
const MAX_DATA_LINE: u64 = 1 << 22;

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
pub fn parse_ply<R: BufRead>(mut reader: R, origin: &Path) -> Result<Mesh> {
    let header = Header::read(&mut reader, origin)?;
    let count = |target| {
        header
            .elements
            .iter()
            .find(|e| e.target == target)
            .map_or(0, |e| e.count)
    };
    let vertex_count = count(Target::Vertices);
    let mut b = Builder {
        mesh: Mesh {
            positions: Vec::with_capacity(vertex_count.min(MAX_RESERVE) as usize),
            triangles: Vec::with_capacity(count(Target::Faces).min(MAX_RESERVE) as usize),
        },
        vertex_count,
        xyz: [0.0; 3],
        poly: Vec::new(),
    };
    match header.format {
        Format::Ascii => read_ascii(&mut reader, &header, &mut b, origin)?,
        Format::Binary { big_endian } => {
            read_binary(&mut reader, &header, big_endian, &mut b, origin)?;
        }
    }
    Ok(b.mesh)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

/// Reads a fixed-size number from the front of a slice the caller has sized for it.
macro_rules! decode {
    ($t:ty, $b:expr, $big:expr) => {{
        let mut a = [0u8; size_of::<$t>()];
        a.copy_from_slice(&$b[..size_of::<$t>()]);
        if $big {
            <$t>::from_be_bytes(a)
        } else {
            <$t>::from_le_bytes(a)
        }
    }};
}

impl Scalar {
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }

    /// Range of an integer type; every PLY integer fits an f64 exactly, so values travel as f64.
    fn int_range(self) -> (i64, i64) {
        match self {
            Self::I8 => (i8::MIN.into(), i8::MAX.into()),
            Self::U8 => (0, u8::MAX.into()),
            Self::I16 => (i16::MIN.into(), i16::MAX.into()),
            Self::U16 => (0, u16::MAX.into()),
            Self::I32 => (i32::MIN.into(), i32::MAX.into()),
            Self::U32 | Self::F32 | Self::F64 => (0, u32::MAX.into()),
        }
    }

    /// Decodes a binary value from `b[..self.size()]`.
    #[inline]
    fn decode(self, b: &[u8], big: bool) -> f64 {
        match self {
            Self::I8 => f64::from(decode!(i8, b, big)),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(decode!(i16, b, big)),
            Self::U16 => f64::from(decode!(u16, b, big)),
            Self::I32 => f64::from(decode!(i32, b, big)),
            Self::U32 => f64::from(decode!(u32, b, big)),
            Self::F32 => f64::from(decode!(f32, b, big)),
            Self::F64 => decode!(f64, b, big),
        }
    }

    /// Parses an ascii value. Integers must be integers in range of their type, so that a line of
    /// one element misread as another (a count mismatch) fails here rather than later.
    fn parse_text(self, tok: &str) -> std::result::Result<f64, String> {
        match self {
            // Parsing as f32 directly avoids double rounding through f64.
            Self::F32 => tok.parse::<f32>().map(f64::from),
            Self::F64 => tok.parse::<f64>(),
            _ => {
                let v: i64 = tok
                    .parse()
                    .map_err(|_| format!("expected an integer, found '{}'", snippet(tok)))?;
                let (lo, hi) = self.int_range();
                return if (lo..=hi).contains(&v) {
                    Ok(v as f64)
                } else {
                    Err(format!("value {v} out of range for {}", self.name()))
                };
            }
        }
        .map_err(|_| format!("expected a number, found '{}'", snippet(tok)))
    }

    fn name(self) -> &'static str {
        match self {
            Self::I8 => "char",
            Self::U8 => "uchar",
            Self::I16 => "short",
            Self::U16 => "ushort",
            Self::I32 => "int",
            Self::U32 => "uint",
            Self::F32 => "float",
            Self::F64 => "double",
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// What the loader does with a property's value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Skip,
    Coord(usize),
    Indices,
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
    role: Role,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Target {
    Vertices,
    Faces,
    Other,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    target: Target,
    /// Header line of the `element` statement, for errors about the element as a whole.
    line: usize,
}

impl Element {
    /// Record size in bytes if every property is a scalar.
    fn fixed_size(&self) -> Option<usize> {
        self.props.iter().try_fold(0, |sum, p| match p.kind {
            Kind::Scalar(t) => Some(sum + t.size()),
            Kind::List { .. } => None,
        })
    }

    fn plural(&self) -> String {
        match self.name.as_str() {
            "vertex" => "vertices".into(),
            n if n.ends_with('x') || n.ends_with('s') => format!("{n}es"),
            n => format!("{n}s"),
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Format {
    Ascii,
    Binary { big_endian: bool },
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Number of header lines, `end_header` included; ascii data line numbers continue from it.
    lines: usize,
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

impl Header {
    fn read<R: BufRead>(r: &mut R, origin: &Path) -> Result<Header> {
        let at = |n: usize, msg: String| Error::format(origin, Some(format!("line {n}")), msg);
        let mut buf = Vec::new();
        let first = read_line(r, &mut buf, MAX_HEADER_LINE).map_err(|e| Error::io(origin, e))?;
        if !matches!(first, Line::Text) || buf.trim_ascii_end() != b"ply" {
            let start = String::from_utf8_lossy(&buf[..buf.len().min(16)]).into_owned();
            return Err(at(
                1,
                format!(
                    "not a PLY file: expected 'ply', found '{}'",
                    snippet(start.trim_end())
                ),
            ));
        }
        let mut format = None;
        let mut elements: Vec<Element> = Vec::new();
        let mut n = 1;
        loop {
            let got = read_line(r, &mut buf, MAX_HEADER_LINE).map_err(|e| Error::io(origin, e))?;
            n += 1;
            match got {
                Line::Eof => return Err(at(n, "file ends before 'end_header'".into())),
                Line::TooLong => {
                    return Err(at(n, "header line too long ('end_header' missing?)".into()));
                }
                Line::Text => {}
            }
            let text = std::str::from_utf8(&buf)
                .map_err(|_| at(n, "header line is not text ('end_header' missing?)".into()))?;
            let words: Vec<&str> = text.split_ascii_whitespace().collect();
            match words.as_slice() {
                [] | ["comment" | "obj_info", ..] => {}
                ["format", f, version] => {
                    if format.is_some() {
                        return Err(at(n, "second 'format' line".into()));
                    }
                    format = Some(match *f {
                        "ascii" => Format::Ascii,
                        "binary_little_endian" => Format::Binary { big_endian: false },
                        "binary_big_endian" => Format::Binary { big_endian: true },
                        f => return Err(at(n, format!("unknown format '{}'", snippet(f)))),
                    });
                    if version.parse::<f64>() != Ok(1.0) {
                        let v = snippet(version);
                        return Err(at(n, format!("unsupported PLY version '{v}'")));
                    }
                }
                ["element", name, count] => {
                    let count: u64 = count.parse().map_err(|_| {
                        at(
                            n,
                            format!("expected an element count, found '{}'", snippet(count)),
                        )
                    })?;
                    let target = match *name {
                        "vertex" => Target::Vertices,
                        "face" => Target::Faces,
                        _ => Target::Other,
                    };
                    if target != Target::Other && elements.iter().any(|e| e.target == target) {
                        return Err(at(n, format!("second '{name}' element")));
                    }
                    if target == Target::Vertices && count > u64::from(u32::MAX) {
                        return Err(at(
                            n,
                            format!("{count} vertices, at most {} supported", u32::MAX),
                        ));
                    }
                    elements.push(Element {
                        name: (*name).to_owned(),
                        count,
                        props: Vec::new(),
                        target,
                        line: n,
                    });
                }
                ["property", rest @ ..] => {
                    let Some(element) = elements.last_mut() else {
                        return Err(at(n, "property before any element".into()));
                    };
                    let scalar = |name: &str| {
                        Scalar::from_name(name)
                            .ok_or_else(|| at(n, format!("unknown type '{}'", snippet(name))))
                    };
                    let (kind, name) = match rest {
                        ["list", count, item, name] => {
                            let count = scalar(count)?;
                            if !count.is_int() {
                                let t = count.name();
                                return Err(at(
                                    n,
                                    format!("list count type '{t}' is not an integer type"),
                                ));
                            }
                            (
                                Kind::List {
                                    count,
                                    item: scalar(item)?,
                                },
                                name,
                            )
                        }
                        [ty, name] if *ty != "list" => (Kind::Scalar(scalar(ty)?), name),
                        _ => {
                            return Err(at(
                                n,
                                "expected 'property <type> <name>' or \
                                 'property list <count type> <item type> <name>'"
                                    .into(),
                            ));
                        }
                    };
                    element.props.push(Property {
                        name: (*name).to_owned(),
                        kind,
                        role: Role::Skip,
                    });
                }
                ["end_header"] => break,
                ["format", ..] => {
                    let msg =
                        "expected 'format <ascii|binary_little_endian|binary_big_endian> 1.0'";
                    return Err(at(n, msg.into()));
                }
                ["element", ..] => {
                    return Err(at(n, "expected 'element <name> <count>'".into()));
                }
                [word, ..] => {
                    return Err(at(
                        n,
                        format!("unexpected header line starting with '{}'", snippet(word)),
                    ));
                }
            }
        }
        let Some(format) = format else {
            return Err(at(n, "header has no 'format' line".into()));
        };
        if !elements.iter().any(|e| e.target == Target::Vertices) {
            return Err(at(n, "header declares no 'vertex' element".into()));
        }
        for e in &mut elements {
            assign_roles(e).map_err(|msg| at(e.line, msg))?;
        }
        Ok(Header {
            format,
            elements,
            lines: n,
        })
    }
}

/// Marks the properties the mesh needs and checks they have usable types.
fn assign_roles(e: &mut Element) -> std::result::Result<(), String> {
    match e.target {
        Target::Vertices => {
            for (k, axis) in ["x", "y", "z"].into_iter().enumerate() {
                let p = e
                    .props
                    .iter_mut()
                    .find(|p| p.name == axis && matches!(p.kind, Kind::Scalar(_)))
                    .ok_or_else(|| format!("vertex element has no scalar '{axis}' property"))?;
                p.role = Role::Coord(k);
            }
        }
        Target::Faces => {
            let p = e
                .props
                .iter_mut()
                .find(|p| p.name == "vertex_indices" || p.name == "vertex_index")
                .ok_or("face element has no 'vertex_indices' property")?;
            match p.kind {
                Kind::List { item, .. } if item.is_int() => p.role = Role::Indices,
                Kind::List { item, .. } => {
                    return Err(format!(
                        "face vertex indices have type '{}', not an integer type",
                        item.name()
                    ));
                }
                Kind::Scalar(_) => return Err(format!("face property '{}' is not a list", p.name)),
            }
        }
        Target::Other => {}
    }
    Ok(())
}

/// Collects decoded values into the mesh, one record at a time.
struct Builder {
    mesh: Mesh,
    vertex_count: u64,
    xyz: [f64; 3],
    poly: Vec<u32>,
}

impl Builder {
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
                self.poly.clear();
            }
            Target::Other => {}
        }
        Ok(())
    }
}

/// Why reading one binary record failed.
enum Fault {
    Io(io::Error),
    Bad(String),
}

impl From<io::Error> for Fault {
    fn from(e: io::Error) -> Self {
        Fault::Io(e)
    }
}

impl From<String> for Fault {
    fn from(msg: String) -> Self {
        Fault::Bad(msg)
    }
}

fn read_binary<R: BufRead>(
    r: &mut R,
    header: &Header,
    big: bool,
    b: &mut Builder,
    origin: &Path,
) -> Result<()> {
    for el in &header.elements {
        let fail = |i: u64, fault: Fault| match fault {
            Fault::Io(e) if e.kind() == io::ErrorKind::UnexpectedEof => Error::format(
                origin,
                Some(format!("{} {i}", el.name)),
                format!("file ends after {i} of {} {}", el.count, el.plural()),
            ),
            Fault::Io(e) => Error::io(origin, e),
            Fault::Bad(msg) => Error::format(origin, Some(format!("{} {i}", el.name)), msg),
        };
        match el.fixed_size() {
            Some(0) => {}
            // Nothing to keep: skip the whole element in one copy.
            Some(size) if el.target == Target::Other => {
                let size = size as u64;
                let want = el.count.saturating_mul(size);
                let got = skip(r, want).map_err(|e| fail(0, e.into()))?;
                if got < want {
                    let eof = io::Error::from(io::ErrorKind::UnexpectedEof);
                    return Err(fail(got / size, eof.into()));
                }
            }
            _ => {
                let mut scratch = [0u8; 1024];
                let mut i = 0;
                while i < el.count {
                    // Decode the records lying wholly in the reader's buffer in place: no copy
                    // and no read call per record.
                    let data = r.fill_buf().map_err(|e| fail(i, e.into()))?;
                    let mut used = 0;
                    while i < el.count {
                        b.poly.clear();
                        let Some(len) = record_from_slice(&data[used..], el, big, b)
                            .map_err(|m| fail(i, m.into()))?
                        else {
                            break;
                        };
                        b.finish(el.target).map_err(|m| fail(i, m.into()))?;
                        used += len;
                        i += 1;
                    }
                    r.consume(used);
                    if used == 0 && i < el.count {
                        // The record straddles the buffer's end, is bigger than the buffer, or
                        // is cut short by the end of the file: read it piece by piece.
                        b.poly.clear();
                        binary_record(r, el, big, b, &mut scratch).map_err(|f| fail(i, f))?;
                        b.finish(el.target).map_err(|m| fail(i, m.into()))?;
                        i += 1;
                    }
                }
            }
        }
    }
    let extra = skip(r, u64::MAX).map_err(|e| Error::io(origin, e))?;
    if extra > 0 {
        return Err(Error::format(
            origin,
            None,
            format!("{extra} bytes of data after the last element"),
        ));
    }
    Ok(())
}

/// Decodes one binary record from the front of `data`, returning its length in bytes, or `None`
/// if `data` holds only part of it.
#[inline]
fn record_from_slice(
    data: &[u8],
    el: &Element,
    big: bool,
    b: &mut Builder,
) -> std::result::Result<Option<usize>, String> {
    let mut at = 0;
    for p in &el.props {
        match p.kind {
            Kind::Scalar(t) => {
                let Some(v) = data.get(at..at + t.size()) else {
                    return Ok(None);
                };
                if let Role::Coord(k) = p.role {
                    b.xyz[k] = t.decode(v, big);
                }
                at += t.size();
            }
            Kind::List { count, item } => {
                let Some(c) = data.get(at..at + count.size()) else {
                    return Ok(None);
                };
                let n = count.decode(c, big);
                if n < 0.0 {
                    return Err(format!("list '{}' has negative length {n}", p.name));
                }
                at += count.size();
                let len = (n as usize).saturating_mul(item.size());
                let Some(items) = data.get(at..at.saturating_add(len)) else {
                    return Ok(None);
                };
                if p.role == Role::Indices {
                    for v in items.chunks_exact(item.size()) {
                        b.index(item.decode(v, big))?;
                    }
                }
                at += len;
            }
        }
    }
    Ok(Some(at))
}

/// Reads one binary record piece by piece, for records not wholly in the reader's buffer.
fn binary_record<R: BufRead>(
    r: &mut R,
    el: &Element,
    big: bool,
    b: &mut Builder,
    scratch: &mut [u8; 1024],
) -> std::result::Result<(), Fault> {
    for p in &el.props {
        match p.kind {
            Kind::Scalar(t) => {
                let bytes = &mut scratch[..t.size()];
                r.read_exact(bytes)?;
                if let Role::Coord(k) = p.role {
                    b.xyz[k] = t.decode(bytes, big);
                }
            }
            Kind::List { count, item } => {
                let bytes = &mut scratch[..count.size()];
                r.read_exact(bytes)?;
                let n = count.decode(bytes, big);
                if n < 0.0 {
                    return Err(format!("list '{}' has negative length {n}", p.name).into());
                }
                let (n, size) = (n as u64, item.size());
                if p.role != Role::Indices {
                    let want = n.saturating_mul(size as u64);
                    if skip(r, want)? < want {
                        return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into());
                    }
                    continue;
                }
                // Whole chunks at a time: one read for a typical face.
                let per_chunk = (scratch.len() / size) as u64;
                let mut left = n;
                while left > 0 {
                    let k = left.min(per_chunk);
                    let bytes = &mut scratch[..k as usize * size];
                    r.read_exact(bytes)?;
                    for v in bytes.chunks_exact(size) {
                        b.index(item.decode(v, big))?;
                    }
                    left -= k;
                }
            }
        }
    }
    Ok(())
}

/// Discards up to `n` bytes, returning how many there were.
fn skip<R: BufRead>(r: &mut R, n: u64) -> io::Result<u64> {
    io::copy(&mut r.by_ref().take(n), &mut io::sink())
}

fn read_ascii<R: BufRead>(
    r: &mut R,
    header: &Header,
    b: &mut Builder,
    origin: &Path,
) -> Result<()> {
    let mut line_no = header.lines;
    let mut buf = Vec::new();
    for el in &header.elements {
        // A record without properties has no values, hence no line to read.
        if el.props.is_empty() {
            continue;
        }
        for i in 0..el.count {
            // Next non-blank line.
            loop {
                let got =
                    read_line(r, &mut buf, MAX_DATA_LINE).map_err(|e| Error::io(origin, e))?;
                let place = || Some(format!("{} {i} (line {})", el.name, line_no + 1));
                match got {
                    Line::Eof => {
                        let msg = format!("file ends after {i} of {} {}", el.count, el.plural());
                        return Err(Error::format(origin, Some(format!("{} {i}", el.name)), msg));
                    }
                    Line::TooLong => {
                        let msg = format!("line is longer than {MAX_DATA_LINE} bytes");
                        return Err(Error::format(origin, place(), msg));
                    }
                    Line::Text => {}
                }
                line_no += 1;
                if !buf.iter().all(u8::is_ascii_whitespace) {
                    break;
                }
            }
            let at = |msg: String| {
                Error::format(
                    origin,
                    Some(format!("{} {i} (line {line_no})", el.name)),
                    msg,
                )
            };
            let text =
                std::str::from_utf8(&buf).map_err(|_| at("line is not valid UTF-8 text".into()))?;
            ascii_record(text, el, b).map_err(at)?;
            b.finish(el.target).map_err(at)?;
        }
    }
    let mut extra = 0u64;
    let mut first = 0;
    loop {
        match read_line(r, &mut buf, MAX_DATA_LINE).map_err(|e| Error::io(origin, e))? {
            Line::Eof => break,
            Line::Text | Line::TooLong => {}
        }
        // A line cut at the length cap is counted again as its continuation; close enough.
        line_no += 1;
        if !buf.iter().all(u8::is_ascii_whitespace) {
            if extra == 0 {
                first = line_no;
            }
            extra += 1;
        }
    }
    if extra > 0 {
        let lines = if extra == 1 { "line" } else { "lines" };
        return Err(Error::format(
            origin,
            Some(format!("line {first}")),
            format!("{extra} {lines} of data after the last element"),
        ));
    }
    Ok(())
}

/// Parses one ascii record; each record must be exactly one line.
fn ascii_record(text: &str, el: &Element, b: &mut Builder) -> std::result::Result<(), String> {
    let mut tokens = text.split_ascii_whitespace();
    // Without lists the number of values is known: check it first, since a wrong count says
    // "this line belongs to another element" better than the first value that fails to parse.
    if el.fixed_size().is_some() {
        let found = tokens.clone().count();
        if found != el.props.len() {
            let more = if found > el.props.len() {
                "many"
            } else {
                "few"
            };
            return Err(format!(
                "too {more} values for element '{}': expected {}, found {found}",
                el.name,
                el.props.len()
            ));
        }
    }
    let mut used = 0usize;
    let mut next = |p: &Property| {
        let tok = tokens.next().ok_or_else(|| {
            format!(
                "too few values for element '{}': line ends after {used}, before '{}'",
                el.name, p.name
            )
        })?;
        used += 1;
        Ok::<_, String>(tok)
    };
    for p in &el.props {
        match p.kind {
            Kind::Scalar(t) => {
                let v = t.parse_text(next(p)?)?;
                if let Role::Coord(k) = p.role {
                    b.xyz[k] = v;
                }
            }
            Kind::List { count, item } => {
                let n = count.parse_text(next(p)?)?;
                if n < 0.0 {
                    return Err(format!("list '{}' has negative length {n}", p.name));
                }
                for _ in 0..n as u64 {
                    let v = item.parse_text(next(p)?)?;
                    if p.role == Role::Indices {
                        b.index(v)?;
                    }
                }
            }
        }
    }
    let rest = tokens.count();
    if rest > 0 {
        return Err(format!(
            "too many values for element '{}': expected {used}, found {}",
            el.name,
            used + rest
        ));
    }
    Ok(())
}

/// A token as it can be shown in a message: short, and with control characters escaped.
fn snippet(tok: &str) -> String {
    tok.escape_debug().take(32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A property of a test element: (type, name) or (count type, item type, name).
    enum P {
        S(&'static str, &'static str),
        L(&'static str, &'static str, &'static str),
    }

    /// A test element; each row lists its values in order, a list as its length then its items.
    struct El {
        name: &'static str,
        props: Vec<P>,
        rows: Vec<Vec<f64>>,
    }

    fn ty(name: &str) -> Scalar {
        Scalar::from_name(name).unwrap()
    }

    fn encode(out: &mut Vec<u8>, t: Scalar, v: f64, big: bool) {
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
    fn write_ply(format: &str, elements: &[El]) -> Vec<u8> {
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

    const CUBE_FACES: [[u32; 4]; 6] = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];

    fn cube_corner(i: usize) -> [f32; 3] {
        [
            (i & 1) as f32,
            ((i >> 1) & 1) as f32,
            ((i >> 2) & 1) as f32 * 0.5 - 0.25,
        ]
    }

    /// A cube with extra elements before, between and after the ones that matter, extra vertex
    /// properties around x/y/z, and coordinates and indices of the given types.
    fn cube_elements(coord: &'static str, count: &'static str, index: &'static str) -> Vec<El> {
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

    fn expected_cube() -> Mesh {
        Mesh {
            positions: (0..8).map(cube_corner).collect(),
            triangles: CUBE_FACES
                .iter()
                .flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]])
                .collect(),
        }
    }

    fn parse(bytes: &[u8]) -> Result<Mesh> {
        parse_ply(bytes, Path::new("test.ply"))
    }

    fn assert_same(a: &Mesh, b: &Mesh) {
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
    }

    /// Asserts that parsing fails with a message naming the file, `place` and `what`.
    fn assert_err(bytes: &[u8], place: &str, what: &str) {
        let err = parse_ply(bytes, Path::new("dir/test.ply"))
            .expect_err("parse should fail")
            .to_string();
        assert!(err.contains("dir/test.ply"), "{err}");
        assert!(err.contains(place), "{err} lacks {place}");
        assert!(err.contains(what), "{err} lacks {what}");
    }

    const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

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
    fn records_straddling_the_read_buffer() {
        // Tiny buffers force the piecewise path for records cut by the buffer's end.
        let want = expected_cube();
        for format in FORMATS {
            let file = write_ply(format, &cube_elements("double", "ushort", "uint"));
            for capacity in 1..48 {
                let reader = io::BufReader::with_capacity(capacity, &file[..]);
                assert_same(&parse_ply(reader, Path::new("t.ply")).unwrap(), &want);
                let cut = io::BufReader::with_capacity(capacity, &file[..file.len() - 6]);
                let err = parse_ply(cut, Path::new("t.ply")).unwrap_err().to_string();
                assert!(err.contains("face 5"), "{err}");
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
    fn header_errors() {
        let ok =
            String::from_utf8(write_ply("ascii", &cube_elements("float", "uchar", "int"))).unwrap();
        let edit = |from: &str, to: &str| ok.replacen(from, to, 1).into_bytes();
        assert_err(b"\x00\xff garbage", "line 1", "not a PLY file");
        assert_err(b"", "line 1", "not a PLY file");
        assert_err(
            &edit("ply\n", "plx\n"),
            "line 1",
            "expected 'ply', found 'plx'",
        );
        assert_err(
            &edit("format ascii", "format ebcdic"),
            "line 2",
            "unknown format 'ebcdic'",
        );
        assert_err(
            &edit("ascii 1.0", "ascii 2.0"),
            "line 2",
            "unsupported PLY version '2.0'",
        );
        assert_err(
            &edit("property uchar red", "property flot red"),
            "line 6",
            "unknown type 'flot'",
        );
        assert_err(
            &edit(
                "property list uchar float spec",
                "property list float float spec",
            ),
            "line 7",
            "'float' is not an integer type",
        );
        assert_err(
            &edit("element material 2\n", ""),
            "line 5",
            "property before any element",
        );
        assert_err(
            &edit("element edge 2", "element edge many"),
            "line 17",
            "found 'many'",
        );
        assert_err(
            &edit("end_header", "end_headr"),
            "line 24",
            "unexpected header line",
        );
        assert_err(
            &edit("ascii 1.0", "ascii"),
            "line 2",
            "expected 'format <ascii|",
        );
        assert_err(
            &edit("element face 6", "element face"),
            "line 20",
            "expected 'element <name> <count>'",
        );
        assert_err(
            &edit("property int vertex2", "property int"),
            "line 19",
            "expected 'property <type> <name>'",
        );
        assert_err(
            &edit("property float z", "property float w"),
            "line 9",
            "no scalar 'z'",
        );
        assert_err(
            &edit("vertex_indices", "corners"),
            "line 20",
            "no 'vertex_indices'",
        );
        assert_err(
            &edit("format ascii 1.0\n", ""),
            "line 23",
            "no 'format' line",
        );
        assert_err(
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x",
            "line 5",
            "file ends before 'end_header'",
        );
        assert_err(
            b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999999\n",
            "line 3",
            "99999999999 vertices",
        );
    }

    #[test]
    fn truncated_binary() {
        for format in &FORMATS[1..] {
            let file = write_ply(format, &cube_elements("float", "uchar", "int"));
            let header = file.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
            let material = (1 + 1 + 2 * 4 + 8) + (1 + 1 + 8);
            let vertex = 4 + 3 * 4 + 2 + 1 + 8;
            // Cut inside the 8th vertex (index 7).
            let cut = header + material + 7 * vertex + 5;
            assert_err(&file[..cut], "vertex 7", "file ends after 7 of 8 vertices");
            // Cut inside the skipped edge element and inside the last face.
            assert_err(
                &file[..cut + vertex + 9],
                "edge 1",
                "file ends after 1 of 2 edges",
            );
            assert_err(
                &file[..file.len() - 3],
                "face 5",
                "file ends after 5 of 6 faces",
            );
            assert_err(
                &file[..header],
                "material 0",
                "file ends after 0 of 2 materials",
            );
        }
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
    fn ascii_count_mismatch() {
        let ok =
            String::from_utf8(write_ply("ascii", &cube_elements("float", "uchar", "int"))).unwrap();
        // Header promises 9 vertices: the 9th "vertex" is the first edge line, short of values.
        let more = ok.replacen("element vertex 8", "element vertex 9", 1);
        assert_err(
            more.as_bytes(),
            "vertex 8 (line 35)",
            "too few values for element 'vertex': expected 7, found 2",
        );
        // 7 vertices: the 8th vertex line is read as the first edge and has too many values.
        let fewer = ok.replacen("element vertex 8", "element vertex 7", 1);
        assert_err(
            fewer.as_bytes(),
            "edge 0 (line 34)",
            "too many values for element 'edge': expected 2, found 7",
        );
        // 7 faces but only 6 lines.
        let faces = ok.replacen("element face 6", "element face 7", 1);
        assert_err(faces.as_bytes(), "face 6", "file ends after 6 of 7 faces");
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
}
