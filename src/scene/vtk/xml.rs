//! XML PolyData (`.vtp`), as `vtkXMLPolyDataWriter` writes it: `DataArray`s in `ascii`,
//! `binary` (base64, inline) or `appended` format (raw or base64 `AppendedData`), uncompressed
//! or zlib-compressed (`vtkZLibDataCompressor`), little or big endian, 32- or 64-bit headers,
//! one or more pieces. `vtkLZ4DataCompressor` and `vtkLZMADataCompressor` are refused by name.
//!
//! The XML goes through quick-xml; the appended data, which is not XML, is cut out of the text
//! before parsing and read at each array's offset. Errors name the piece, the array and the
//! line of its element.

use super::{Out, Type, snippet};
use crate::error::{Error, Result};
use crate::scene::data::{ArrayInfo, Assoc, Encoding, Keep, MeshData, Values};
use crate::scene::mesh::Mesh;
use base64::Engine;
use std::io::Read;
use std::path::Path;

/// Reads the XML PolyData file at `path`.
pub fn load_vtp(path: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_vtp(&bytes, path, keep)
}

/// An XML element: what dcrt reads of it.
#[derive(Debug, Default)]
struct Elem {
    name: String,
    attrs: Vec<(String, String)>,
    /// Its own text, children's excluded.
    text: String,
    children: Vec<Elem>,
    line: usize,
}

impl Elem {
    fn attr(&self, key: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
    fn child(&self, name: &str) -> Option<&Elem> {
        self.children.iter().find(|c| c.name == name)
    }
    fn children<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Elem> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }
}

/// Parses an XML PolyData file's bytes; `origin` names it in errors.
pub fn parse_vtp(bytes: &[u8], origin: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    let (xml, appended) = split_appended(bytes, origin)?;
    let root = parse_xml(&xml, origin)?;
    let f = File::new(&root, appended, origin)?;
    let poly = root
        .child("PolyData")
        .ok_or_else(|| f.err(&root, "VTKFile", "has no PolyData element"))?;
    let mut out = Out::default();
    let mut cells_before = 0u64;
    for (p, piece) in poly.children("Piece").enumerate() {
        f.piece(p, piece, keep, &mut out, &mut cells_before)?;
    }
    if poly.children("Piece").next().is_none() {
        return Err(f.err(poly, "PolyData", "has no Piece"));
    }
    Ok((out.mesh, out.data))
}

/// Cuts the appended data (from the `_` after `<AppendedData ...>` to `</AppendedData>`) out of
/// the bytes: the XML without it, and the data.
fn split_appended<'a>(bytes: &'a [u8], origin: &Path) -> Result<(Vec<u8>, Option<&'a [u8]>)> {
    let Some(tag) = find(bytes, b"<AppendedData") else {
        return Ok((bytes.to_vec(), None));
    };
    let bad = |m: &str| Error::format(origin, Some("AppendedData".into()), m.to_string());
    let open_end = tag
        + bytes[tag..]
            .iter()
            .position(|&c| c == b'>')
            .ok_or_else(|| bad("the element's tag never ends"))?;
    let mark = open_end
        + 1
        + bytes[open_end + 1..]
            .iter()
            .position(|c| !c.is_ascii_whitespace())
            .ok_or_else(|| bad("no data after the tag"))?;
    if bytes[mark] != b'_' {
        return Err(bad("the data must start with '_'"));
    }
    let close = rfind(bytes, b"</AppendedData>")
        .filter(|&c| c > mark)
        .ok_or_else(|| bad("no '</AppendedData>' after the data"))?;
    let mut xml = bytes[..mark].to_vec();
    xml.extend_from_slice(&bytes[close..]);
    Ok((xml, Some(&bytes[mark + 1..close])))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn rfind(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).rposition(|w| w == needle)
}

/// The element tree of the XML text (the appended data already cut out).
fn parse_xml(xml: &[u8], origin: &Path) -> Result<Elem> {
    use quick_xml::events::Event;
    let mut reader = quick_xml::Reader::from_reader(xml);
    let line_of = |pos: u64| {
        1 + xml[..(pos as usize).min(xml.len())]
            .iter()
            .filter(|&&c| c == b'\n')
            .count()
    };
    let mut stack: Vec<Elem> = vec![Elem::default()];
    let mut buf = Vec::new();
    loop {
        let pos = reader.buffer_position();
        let event = reader.read_event_into(&mut buf).map_err(|e| {
            Error::format(
                origin,
                Some(format!("line {}", line_of(reader.error_position()))),
                format!("not well-formed XML: {e}"),
            )
        })?;
        let open = |e: &quick_xml::events::BytesStart<'_>| -> Result<Elem> {
            let name = e.name().as_ref().to_string();
            let mut attrs = Vec::new();
            for a in e.attributes() {
                let a = a.map_err(|err| {
                    Error::format(
                        origin,
                        Some(format!("line {}", line_of(pos))),
                        format!("bad attribute in <{name}>: {err}"),
                    )
                })?;
                let key = a.key.as_ref().to_string();
                attrs.push((key, a.value.trim().to_string()));
            }
            Ok(Elem {
                name,
                attrs,
                line: line_of(pos),
                ..Elem::default()
            })
        };
        match event {
            Event::Start(e) => {
                let el = open(&e)?;
                stack.push(el);
            }
            Event::Empty(e) => {
                let el = open(&e)?;
                if let Some(parent) = stack.last_mut() {
                    parent.children.push(el);
                }
            }
            Event::End(_) => {
                let el = stack.pop().unwrap_or_default();
                match stack.last_mut() {
                    Some(parent) => parent.children.push(el),
                    None => {
                        return Err(Error::format(
                            origin,
                            Some(format!("line {}", line_of(pos))),
                            "a closing tag without its opening tag",
                        ));
                    }
                }
            }
            Event::Text(t) => {
                if let Some(el) = stack.last_mut() {
                    el.text.push_str(&t.xml10_content());
                }
            }
            Event::CData(t) => {
                if let Some(el) = stack.last_mut() {
                    el.text.push_str(&t.xml10_content());
                }
            }
            Event::GeneralRef(_) => {
                return Err(Error::format(
                    origin,
                    Some(format!("line {}", line_of(pos))),
                    "an entity reference where data was expected",
                ));
            }
            Event::Eof => break,
            _ => {}
        }
        buf.clear();
    }
    let mut top = stack.pop().unwrap_or_default();
    if !stack.is_empty() {
        return Err(Error::format(
            origin,
            Some(format!("line {}", line_of(xml.len() as u64))),
            format!("file ends inside <{}>", top.name),
        ));
    }
    let root = top
        .children
        .pop()
        .filter(|r| top.children.is_empty() && r.name == "VTKFile");
    root.ok_or_else(|| {
        Error::format(
            origin,
            Some("line 1".into()),
            "not a VTK XML file: the document's element must be one <VTKFile>",
        )
    })
}

/// The file-wide settings every array is read with.
struct File<'a> {
    origin: &'a Path,
    big: bool,
    /// Bytes of each header word: 4 (`UInt32`) or 8 (`UInt64`).
    header: usize,
    zlib: bool,
    appended: Option<&'a [u8]>,
    /// Appended data is base64 text rather than raw bytes.
    appended_base64: bool,
}

/// Where an array's values are, for errors.
struct Place<'a> {
    piece: usize,
    what: &'a str,
    line: usize,
}

impl Place<'_> {
    fn name(&self) -> String {
        format!("Piece {}: {} (line {})", self.piece, self.what, self.line)
    }
}

impl<'a> File<'a> {
    fn new(root: &Elem, appended: Option<&'a [u8]>, origin: &'a Path) -> Result<File<'a>> {
        let bad = |m: String| Error::format(origin, Some(format!("line {}", root.line)), m);
        match root.attr("type") {
            Some("PolyData") => {}
            Some(t) => {
                return Err(bad(format!(
                    "VTK XML type '{}': dcrt reads PolyData (.vtp); in ParaView, Extract \
                     Surface and save as .vtp",
                    snippet(t)
                )));
            }
            None => return Err(bad("VTKFile has no type".into())),
        }
        let big = match root.attr("byte_order").unwrap_or("LittleEndian") {
            "LittleEndian" => false,
            "BigEndian" => true,
            o => return Err(bad(format!("unknown byte_order '{}'", snippet(o)))),
        };
        let header = match root.attr("header_type").unwrap_or("UInt32") {
            "UInt32" => 4,
            "UInt64" => 8,
            h => return Err(bad(format!("unknown header_type '{}'", snippet(h)))),
        };
        let zlib = match root.attr("compressor") {
            None | Some("") => false,
            Some("vtkZLibDataCompressor") => true,
            Some(c) => {
                return Err(bad(format!(
                    "compressor '{}' is not supported: write with vtkZLibDataCompressor or none",
                    snippet(c)
                )));
            }
        };
        let appended_base64 = match root.child("AppendedData").map(|a| a.attr("encoding")) {
            None | Some(Some("raw")) => false,
            Some(Some("base64")) => true,
            Some(e) => {
                return Err(bad(format!(
                    "AppendedData encoding '{}': expected raw or base64",
                    snippet(e.unwrap_or(""))
                )));
            }
        };
        Ok(File {
            origin,
            big,
            header,
            zlib,
            appended,
            appended_base64,
        })
    }

    fn err(&self, el: &Elem, what: &str, msg: impl Into<String>) -> Error {
        Error::format(self.origin, Some(format!("{what} (line {})", el.line)), msg)
    }

    fn count(&self, el: &Elem, key: &str, what: &str) -> Result<u64> {
        match el.attr(key) {
            None => Ok(0),
            Some(v) => v.parse().map_err(|_| {
                self.err(el, what, format!("{key}=\"{}\" is not a count", snippet(v)))
            }),
        }
    }

    fn piece(
        &self,
        p: usize,
        piece: &Elem,
        keep: &Keep,
        out: &mut Out,
        cells_before: &mut u64,
    ) -> Result<()> {
        let what = format!("Piece {p}");
        let n_points = self.count(piece, "NumberOfPoints", &what)?;
        let first_point = out.mesh.positions.len() as u64;
        if first_point + n_points > u64::from(u32::MAX) {
            return Err(self.err(piece, &what, "more than 2^32-1 points"));
        }
        let counts = [
            ("Verts", self.count(piece, "NumberOfVerts", &what)?),
            ("Lines", self.count(piece, "NumberOfLines", &what)?),
            ("Polys", self.count(piece, "NumberOfPolys", &what)?),
            ("Strips", self.count(piece, "NumberOfStrips", &what)?),
        ];
        let n_cells: u64 = counts.iter().map(|c| c.1).sum();
        // Points.
        if n_points > 0 {
            let points = piece
                .child("Points")
                .and_then(|e| e.child("DataArray"))
                .ok_or_else(|| self.err(piece, &what, "has points but no Points DataArray"))?;
            let place = Place {
                piece: p,
                what: "Points",
                line: points.line,
            };
            let positions = &mut out.mesh.positions;
            positions.reserve(n_points.min(1 << 20) as usize);
            let mut xyz = [0f64; 3];
            self.array(points, &place, n_points, Some(3), &mut |i, v| {
                xyz[(i % 3) as usize] = v;
                if i % 3 == 2 {
                    let q = xyz.map(|c| c as f32);
                    if !q.iter().all(|c| c.is_finite()) {
                        return Err(format!("point {}: coordinate is not finite: {q:?}", i / 3));
                    }
                    positions.push(q);
                }
                Ok(())
            })?;
        }
        // Cells, in VTK's order: vertices, lines, polygons, strips.
        let mut t = out.triangulator(keep.cells());
        t.points = first_point + n_points;
        let mut cell = *cells_before;
        for (name, n) in counts {
            if n == 0 {
                continue;
            }
            let sec = piece.child(name).ok_or_else(|| {
                self.err(
                    piece,
                    &what,
                    format!("declares {n} {name} but has no {name} element"),
                )
            })?;
            let arr = |key: &str| {
                sec.children("DataArray")
                    .find(|a| a.attr("Name") == Some(key))
                    .ok_or_else(|| {
                        self.err(
                            sec,
                            &format!("{what}: {name}"),
                            format!("has no '{key}' DataArray"),
                        )
                    })
            };
            let (conn, offs) = (arr("connectivity")?, arr("offsets")?);
            let mut offsets = Vec::with_capacity(n.min(1 << 20) as usize);
            let place = Place {
                piece: p,
                what: &format!("{name} offsets"),
                line: offs.line,
            };
            self.array(offs, &place, n, Some(1), &mut |_, v| {
                if v < 0.0 || v.fract() != 0.0 {
                    return Err(format!("offset {v} is not a count"));
                }
                let prev = offsets.last().copied().unwrap_or(0.0);
                if v < prev {
                    return Err(format!("offset {v} is below the one before it ({prev})"));
                }
                offsets.push(v);
                Ok(())
            })?;
            let size = offsets.last().copied().unwrap_or(0.0) as u64;
            let mut ids: Vec<i64> = Vec::with_capacity(size.min(1 << 22) as usize);
            let place = Place {
                piece: p,
                what: &format!("{name} connectivity"),
                line: conn.line,
            };
            // Point indices are local to the piece.
            let base = first_point as i64;
            self.array(conn, &place, size, Some(1), &mut |_, v| {
                if v.fract() != 0.0 {
                    return Err(format!("point index {v} is not an integer"));
                }
                ids.push(base.saturating_add(v as i64));
                Ok(())
            })?;
            let mut start = 0usize;
            for (c, &end) in offsets.iter().enumerate() {
                let end = end as usize;
                let cell_ids = &ids[start..end];
                match name {
                    "Verts" | "Lines" => t.skip(cell_ids),
                    "Polys" => t.polygon(cell, cell_ids),
                    _ => t.strip(cell, cell_ids),
                }
                .map_err(|m| self.err(sec, &format!("{what}: {name} cell {c}"), m))?;
                start = end;
                cell += 1;
            }
        }
        *cells_before += n_cells;
        // Point and cell data.
        for (tag, assoc, tuples) in [
            ("PointData", Assoc::Point, n_points),
            ("CellData", Assoc::Cell, n_cells),
        ] {
            let Some(sec) = piece.child(tag) else {
                continue;
            };
            for (k, a) in sec.children("DataArray").enumerate() {
                self.data_array(p, k, a, assoc, tuples, keep, &mut out.data)?;
            }
        }
        Ok(())
    }

    /// A PointData or CellData array: listed (from piece 0), kept when asked for, its values
    /// appended piece after piece.
    #[allow(clippy::too_many_arguments)]
    fn data_array(
        &self,
        p: usize,
        k: usize,
        a: &Elem,
        assoc: Assoc,
        tuples: u64,
        keep: &Keep,
        data: &mut MeshData,
    ) -> Result<()> {
        let name = a.attr("Name").unwrap_or("").to_string();
        let what = format!("{} array '{}'", assoc.name(), snippet(&name));
        let place = Place {
            piece: p,
            what: &what,
            line: a.line,
        };
        let ty = self.type_of(a, &place)?;
        let comps = a
            .attr("NumberOfComponents")
            .map_or(Ok(1), |c| c.parse::<usize>())
            .ok()
            .filter(|&c| c >= 1)
            .ok_or_else(|| {
                Error::format(
                    self.origin,
                    Some(place.name()),
                    "NumberOfComponents is not a positive count",
                )
            })?;
        let color = (ty == Type::U8 && (comps == 3 || comps == 4)).then_some(Encoding::Srgb);
        let info = ArrayInfo {
            name: name.clone(),
            assoc,
            components: comps,
            ty: ty.name().into(),
            color,
        };
        let index = if p == 0 {
            data.offer(info)
        } else {
            // Later pieces must carry the same arrays.
            let same = data
                .arrays
                .iter()
                .enumerate()
                .filter(|(_, x)| x.assoc == assoc)
                .nth(k)
                .filter(|(_, x)| **x == info)
                .map(|(i, _)| i);
            same.ok_or_else(|| {
                Error::format(
                    self.origin,
                    Some(place.name()),
                    "differs from piece 0's arrays (pieces must carry the same arrays)",
                )
            })?
        };
        let wanted = keep.wants(&name, assoc);
        let scale = if color.is_some() {
            1.0 / ty.int_max()
        } else {
            1.0
        };
        let mut values = Values::new(comps);
        self.array(a, &place, tuples, Some(comps), &mut |_, v| {
            if wanted {
                values.data.push((v * scale) as f32);
            }
            Ok(())
        })?;
        if wanted {
            match data.kept.iter_mut().find(|(i, _)| *i == index) {
                Some((_, v)) => v.data.extend_from_slice(&values.data),
                None => data.kept.push((index, values)),
            }
        }
        Ok(())
    }

    fn type_of(&self, a: &Elem, place: &Place<'_>) -> Result<Type> {
        let t = a.attr("type").unwrap_or("");
        Type::from_xml(t).ok_or_else(|| {
            Error::format(
                self.origin,
                Some(place.name()),
                format!(
                    "unknown or unsupported type '{}' (String arrays are not read)",
                    snippet(t)
                ),
            )
        })
    }

    /// Reads a DataArray of `tuples` tuples of `comps` components (checked against the
    /// element's NumberOfComponents when given), handing each (index, value) to `f`.
    fn array(
        &self,
        a: &Elem,
        place: &Place<'_>,
        tuples: u64,
        comps: Option<usize>,
        f: &mut dyn FnMut(u64, f64) -> std::result::Result<(), String>,
    ) -> Result<()> {
        let fail = |m: String| Error::format(self.origin, Some(place.name()), m);
        let ty = self.type_of(a, place)?;
        let declared = a
            .attr("NumberOfComponents")
            .map_or(Ok(1), |c| c.parse::<usize>())
            .map_err(|_| fail("NumberOfComponents is not a count".into()))?;
        let comps = comps.unwrap_or(declared);
        if declared != comps {
            return Err(fail(format!("has {declared} components, expected {comps}")));
        }
        let n = tuples.saturating_mul(comps as u64);
        let format = a.attr("format").unwrap_or("ascii");
        if format == "ascii" {
            let mut toks = a.text.split_ascii_whitespace();
            for i in 0..n {
                let tok = toks.next().ok_or_else(|| {
                    fail(format!(
                        "{i} values where {tuples} tuples of {comps} need {n}"
                    ))
                })?;
                let v = ty.parse(tok).map_err(|m| fail(format!("value {i}: {m}")))?;
                f(i, v).map_err(fail)?;
            }
            let extra = toks.count();
            if extra > 0 {
                return Err(fail(format!(
                    "{} values where {tuples} tuples of {comps} need {n}",
                    n + extra as u64
                )));
            }
            return Ok(());
        }
        if ty == Type::Bit {
            return Err(fail("binary bit arrays are not supported".into()));
        }
        let want = n
            .checked_mul(ty.size() as u64)
            .filter(|&b| b <= isize::MAX as u64)
            .ok_or_else(|| fail(format!("{n} values are more than memory holds")))?;
        let bytes = match format {
            "binary" => self.inline(&a.text, want).map_err(fail)?,
            "appended" => {
                let data = self.appended.ok_or_else(|| {
                    fail("format=\"appended\" but the file has no AppendedData".into())
                })?;
                let off: usize = a
                    .attr("offset")
                    .and_then(|o| o.parse().ok())
                    .ok_or_else(|| fail("an appended array needs an offset".into()))?;
                let at = data.get(off..).ok_or_else(|| {
                    fail(format!(
                        "offset {off} is past the appended data ({} bytes)",
                        data.len()
                    ))
                })?;
                self.appended_block(at, want).map_err(fail)?
            }
            other => return Err(fail(format!("unknown format '{}'", snippet(other)))),
        };
        // Whatever the encoding promised (a compressed block may inflate to less).
        if (bytes.len() as u64) < want {
            return Err(fail(format!(
                "{} bytes of data, the array needs {want}",
                bytes.len()
            )));
        }
        let s = ty.size();
        for i in 0..n {
            let v = ty.decode(&bytes[i as usize * s..], self.big);
            f(i, v).map_err(fail)?;
        }
        Ok(())
    }

    /// A header word at `b[k * header..]`.
    fn word(&self, b: &[u8], k: usize) -> u64 {
        let t = if self.header == 4 {
            Type::U32
        } else {
            Type::U64
        };
        t.decode(&b[k * self.header..], self.big) as u64
    }

    /// The header's words and its length in bytes, read from `get(len)` (which returns the
    /// first `len` header bytes).
    fn header_of(
        &self,
        get: &mut dyn FnMut(usize) -> std::result::Result<Vec<u8>, String>,
        want: u64,
    ) -> std::result::Result<Vec<u64>, String> {
        // `get` may return less (base64 text whose padding ends it early).
        let mut get = |len: usize| {
            let h = get(len)?;
            match h.len() < len {
                true => Err(format!("its header has {} bytes, not {len}", h.len())),
                false => Ok(h),
            }
        };
        if !self.zlib {
            let h = get(self.header)?;
            let nbytes = self.word(&h, 0);
            if nbytes != want {
                return Err(format!(
                    "its header gives {nbytes} bytes of data, the array needs {want}"
                ));
            }
            return Ok(vec![nbytes]);
        }
        let h = get(3 * self.header)?;
        let (blocks, size, last) = (self.word(&h, 0), self.word(&h, 1), self.word(&h, 2));
        let total = if blocks == 0 {
            0
        } else {
            (blocks - 1)
                .saturating_mul(size)
                .saturating_add(if last == 0 { size } else { last })
        };
        if total != want || (blocks > 0 && (size == 0 || last > size)) {
            return Err(format!(
                "its compression header gives {blocks} blocks of {size} bytes (last {last}), \
                 not the {want} bytes the array needs"
            ));
        }
        let h = get((3 + blocks as usize) * self.header)?;
        Ok((0..3 + blocks as usize).map(|k| self.word(&h, k)).collect())
    }

    /// Decompresses blocks whose compressed sizes are `head[3..]` from `data` (which may run
    /// on past them); returns the bytes and how many compressed bytes were used.
    fn inflate(&self, head: &[u64], data: &[u8]) -> std::result::Result<(Vec<u8>, usize), String> {
        let (size, last) = (head[1], head[2]);
        let blocks = head.len() - 3;
        let mut out = Vec::new();
        let mut at = 0usize;
        for (b, &c) in head[3..].iter().enumerate() {
            let raw = if b + 1 == blocks && last != 0 {
                last
            } else {
                size
            };
            let end = at
                .checked_add(c as usize)
                .filter(|&e| e <= data.len())
                .ok_or_else(|| format!("compressed block {b} ({c} bytes) runs past the data"))?;
            let mut d = flate2::read::ZlibDecoder::new(&data[at..end]);
            let before = out.len();
            (&mut d)
                .take(raw)
                .read_to_end(&mut out)
                .map_err(|e| format!("compressed block {b} is damaged: {e}"))?;
            if (out.len() - before) as u64 != raw {
                return Err(format!(
                    "compressed block {b} inflates to {} bytes, its header says {raw}",
                    out.len() - before
                ));
            }
            at = end;
        }
        Ok((out, at))
    }

    /// A `format="binary"` array: base64 of the header and the data (one stream), or when
    /// compressed of the header and of the blocks (two streams).
    fn inline(&self, text: &str, want: u64) -> std::result::Result<Vec<u8>, String> {
        let text: String = text.split_ascii_whitespace().collect();
        let b64 = base64::engine::general_purpose::STANDARD;
        let decode = |s: &str| {
            b64.decode(s)
                .map_err(|e| format!("the base64 data is damaged: {e}"))
        };
        if !self.zlib {
            let all = decode(&text)?;
            self.header_of(
                &mut |len| {
                    all.get(..len)
                        .map(<[u8]>::to_vec)
                        .ok_or_else(|| "the data is shorter than its header".to_string())
                },
                want,
            )?;
            let data = &all[self.header..];
            if data.len() as u64 != want {
                return Err(format!(
                    "{} bytes of data, the array needs {want}",
                    data.len()
                ));
            }
            return Ok(data.to_vec());
        }
        // The header is its own base64 stream: 4 characters per 3 bytes, padded.
        let chars = |bytes: usize| bytes.div_ceil(3) * 4;
        let mut used = 0;
        let head = self.header_of(
            &mut |len| {
                // The first three words are a multiple of 3 bytes: they decode on their own.
                let n = if len == 3 * self.header {
                    len / 3 * 4
                } else {
                    chars(len)
                };
                used = n;
                let s = text.get(..n).ok_or("the data is shorter than its header")?;
                let mut h = decode(s)?;
                h.truncate(len);
                Ok(h)
            },
            want,
        )?;
        let data = decode(text.get(used..).unwrap_or(""))?;
        let (out, at) = self.inflate(&head, &data)?;
        if at != data.len() {
            return Err(format!(
                "{} bytes after the compressed blocks",
                data.len() - at
            ));
        }
        Ok(out)
    }

    /// An appended array starting at `at`: raw bytes, or base64 text of the same layout.
    fn appended_block(&self, at: &[u8], want: u64) -> std::result::Result<Vec<u8>, String> {
        let b64 = base64::engine::general_purpose::STANDARD;
        if !self.appended_base64 {
            let head = self.header_of(
                &mut |len| {
                    at.get(..len).map(<[u8]>::to_vec).ok_or_else(|| {
                        "the appended data ends inside the array's header".to_string()
                    })
                },
                want,
            )?;
            let body = &at[head.len() * self.header..];
            if !self.zlib {
                return body
                    .get(..want as usize)
                    .map(<[u8]>::to_vec)
                    .ok_or_else(|| {
                        format!("the appended data ends before the array's {want} bytes")
                    });
            }
            return self.inflate(&head, body).map(|(b, _)| b);
        }
        // base64: the header and data are one stream uncompressed, two when compressed.
        let text = std::str::from_utf8(at).map_err(|_| "the base64 appended data is not text")?;
        let decode = |s: &str| {
            b64.decode(s)
                .map_err(|e| format!("the base64 appended data is damaged: {e}"))
        };
        let chars = |bytes: usize| bytes.div_ceil(3) * 4;
        let piece = |from: usize, n: usize| {
            text.get(from..from + n)
                .ok_or_else(|| "the appended data ends inside the array".to_string())
        };
        if !self.zlib {
            let first = decode(piece(0, chars(self.header))?)?;
            self.header_of(
                &mut |len| {
                    first
                        .get(..len)
                        .map(<[u8]>::to_vec)
                        .ok_or_else(|| "short header".to_string())
                },
                want,
            )?;
            let all = decode(piece(0, chars(self.header + want as usize))?)?;
            return Ok(all[self.header..].to_vec());
        }
        let mut used = 0;
        let head = self.header_of(
            &mut |len| {
                let n = if len == 3 * self.header {
                    len / 3 * 4
                } else {
                    chars(len)
                };
                used = n;
                let mut h = decode(piece(0, n)?)?;
                h.truncate(len);
                Ok(h)
            },
            want,
        )?;
        let compressed: u64 = head[3..].iter().sum();
        let data = decode(piece(used, chars(compressed as usize))?)?;
        self.inflate(&head, &data).map(|(b, _)| b)
    }
}

#[cfg(test)]
mod tests;
