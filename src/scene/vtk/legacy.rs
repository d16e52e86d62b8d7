//! The legacy VTK format (`.vtk`): `DATASET POLYDATA` and `DATASET UNSTRUCTURED_GRID`, ASCII or
//! BINARY (big endian), cells as count-prefixed lists (versions up to 4.2) or as `OFFSETS` and
//! `CONNECTIVITY` arrays (version 5.1, VTK 9's default). Point and cell data: `SCALARS`,
//! `COLOR_SCALARS`, `VECTORS`, `NORMALS`, `TEXTURE_COORDINATES`, `TENSORS`, `GLOBAL_IDS`,
//! `PEDIGREE_IDS` and `FIELD` arrays; lookup tables and `METADATA` blocks are skipped.
//!
//! Errors name the section and element and, in ASCII files, the line; in binary files, where
//! lines mean nothing, the byte offset.

use super::{Out, Type, snippet};
use crate::error::{Error, Result};
use crate::scene::data::{ArrayInfo, Assoc, Encoding, Keep, MeshData, Values};
use crate::scene::mesh::Mesh;
use std::path::Path;

/// Reads the legacy VTK file at `path`.
pub fn load_vtk(path: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_vtk(&bytes, path, keep)
}

/// Parses a legacy VTK file's bytes; `origin` names it in errors.
pub fn parse_vtk(bytes: &[u8], origin: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    let mut r = Reader {
        b: bytes,
        pos: 0,
        line: 1,
        binary: false,
        origin,
    };
    let version = r.header()?;
    let mut p = Parser {
        r,
        keep,
        new_cells: version >= 5.0,
        out: Out::default(),
        grid: None,
        sections: Default::default(),
        assoc: None,
        cells_total: None,
    };
    p.body()?;
    p.finish()
}

/// A byte cursor that knows its line.
struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
    line: usize,
    binary: bool,
    origin: &'a Path,
}

impl<'a> Reader<'a> {
    /// Where the cursor is, as an error names it.
    fn place(&self) -> String {
        if self.binary {
            format!("byte {}", self.pos)
        } else {
            format!("line {}", self.line)
        }
    }

    fn err(&self, msg: impl Into<String>) -> Error {
        Error::format(self.origin, Some(self.place()), msg)
    }

    fn err_at(&self, what: &str, msg: impl Into<String>) -> Error {
        Error::format(self.origin, Some(format!("{what} ({})", self.place())), msg)
    }

    /// One line, without its end; `None` at the end of the file.
    fn line_text(&mut self) -> Result<Option<&'a str>> {
        if self.pos >= self.b.len() {
            return Ok(None);
        }
        let rest = &self.b[self.pos..];
        let end = rest.iter().position(|&c| c == b'\n').unwrap_or(rest.len());
        let text = std::str::from_utf8(&rest[..end])
            .map_err(|_| self.err("not valid text where a header line was expected"))?;
        self.pos += (end + 1).min(rest.len());
        self.line += 1;
        Ok(Some(text.trim_end_matches('\r')))
    }

    /// The next whitespace-separated token, `None` at the end of the file.
    fn token(&mut self) -> Result<Option<&'a str>> {
        while let Some(&c) = self.b.get(self.pos) {
            if c == b'\n' {
                self.line += 1;
            } else if !c.is_ascii_whitespace() {
                break;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while self
            .b
            .get(self.pos)
            .is_some_and(|c| !c.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        if start == self.pos {
            return Ok(None);
        }
        std::str::from_utf8(&self.b[start..self.pos])
            .map(Some)
            .map_err(|_| self.err("not valid text where a keyword or number was expected"))
    }

    fn need(&mut self, what: &str) -> Result<&'a str> {
        self.token()?
            .ok_or_else(|| self.err(format!("file ends where {what} was expected")))
    }

    fn count(&mut self, what: &str) -> Result<u64> {
        let t = self.need(what)?;
        t.parse::<u64>()
            .map_err(|_| self.err(format!("expected {what}, found '{}'", snippet(t))))
    }

    /// Ends a statement line: in binary files the data starts right after its newline.
    fn end_line(&mut self) -> Result<()> {
        while let Some(&c) = self.b.get(self.pos) {
            match c {
                b'\n' => {
                    self.pos += 1;
                    self.line += 1;
                    return Ok(());
                }
                b' ' | b'\t' | b'\r' => self.pos += 1,
                _ => {
                    let rest = String::from_utf8_lossy(
                        &self.b[self.pos..(self.pos + 16).min(self.b.len())],
                    );
                    return Err(self.err(format!(
                        "unexpected '{}' at the end of a statement",
                        snippet(rest.split_ascii_whitespace().next().unwrap_or(""))
                    )));
                }
            }
        }
        Ok(())
    }

    /// Reads `n` values of type `ty`, handing each (index, value) to `f`; `what(i)` names value
    /// i's element in errors.
    fn values(
        &mut self,
        ty: Type,
        n: u64,
        what: &dyn Fn(u64) -> String,
        f: &mut dyn FnMut(u64, f64) -> std::result::Result<(), String>,
    ) -> Result<()> {
        if !self.binary {
            for i in 0..n {
                let t = self.token()?.ok_or_else(|| {
                    self.err_at(&what(i), format!("file ends after {i} of {n} values"))
                })?;
                let v = ty.parse(t).map_err(|m| self.err_at(&what(i), m))?;
                f(i, v).map_err(|m| self.err_at(&what(i), m))?;
            }
            return Ok(());
        }
        self.end_line()?;
        let bytes = if ty == Type::Bit {
            n.div_ceil(8)
        } else {
            n.saturating_mul(ty.size() as u64)
        };
        let left = (self.b.len() - self.pos) as u64;
        if bytes > left {
            let whole = if ty == Type::Bit {
                left * 8
            } else {
                left / ty.size() as u64
            };
            return Err(self.err_at(
                &what(whole),
                format!("file ends after {whole} of {n} values"),
            ));
        }
        let data = &self.b[self.pos..self.pos + bytes as usize];
        for i in 0..n {
            let v = if ty == Type::Bit {
                f64::from((data[(i / 8) as usize] >> (7 - i % 8)) & 1)
            } else {
                let s = ty.size();
                ty.decode(&data[i as usize * s..], true)
            };
            f(i, v).map_err(|m| self.err_at(&what(i), m))?;
        }
        self.pos += bytes as usize;
        Ok(())
    }
}

/// Cells of one PolyData section or of a grid, as offsets into a connectivity list.
#[derive(Default)]
struct CellList {
    offsets: Vec<u64>,
    ids: Vec<i64>,
}

impl CellList {
    fn cells(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    fn cell(&self, c: usize) -> &[i64] {
        &self.ids[self.offsets[c] as usize..self.offsets[c + 1] as usize]
    }
}

/// PolyData's sections in VTK's cell order.
const SECTIONS: [&str; 4] = ["VERTICES", "LINES", "POLYGONS", "TRIANGLE_STRIPS"];

struct Parser<'a> {
    r: Reader<'a>,
    keep: &'a Keep,
    /// Version 5 and later: cells as OFFSETS and CONNECTIVITY.
    new_cells: bool,
    out: Out,
    /// `Some(polydata)` once DATASET is read.
    grid: Option<bool>,
    /// PolyData sections by `SECTIONS` index; a grid's cells in 0 and types in `types`.
    sections: [Option<CellList>; 4],
    assoc: Option<(Assoc, u64)>,
    cells_total: Option<u64>,
}

impl Reader<'_> {
    /// The three header lines; returns the version.
    fn header(&mut self) -> Result<f64> {
        // Garbage is "not a VTK file", not "not text".
        let first = self.line_text().ok().flatten().unwrap_or("");
        let v = first
            .strip_prefix('#')
            .map(str::trim_start)
            .filter(|s| s.len() >= 12 && s[..12].eq_ignore_ascii_case("vtk DataFile"))
            .and_then(|s| s.split_ascii_whitespace().nth(3))
            .and_then(|v| v.parse::<f64>().ok());
        let Some(version) = v else {
            return Err(Error::format(
                self.origin,
                Some("line 1".into()),
                format!(
                    "not a legacy VTK file: expected '# vtk DataFile Version x.x', found '{}'",
                    snippet(&String::from_utf8_lossy(&self.b[..self.b.len().min(40)]))
                ),
            ));
        };
        if self.line_text()?.is_none() {
            return Err(self.err("file ends before the title line"));
        }
        let kind = self.line_text()?.unwrap_or("").trim();
        self.binary = match kind.to_ascii_uppercase().as_str() {
            "ASCII" => false,
            "BINARY" => true,
            _ => {
                return Err(Error::format(
                    self.origin,
                    Some("line 3".into()),
                    format!("expected ASCII or BINARY, found '{}'", snippet(kind)),
                ));
            }
        };
        Ok(version)
    }
}

impl Parser<'_> {
    fn body(&mut self) -> Result<()> {
        while let Some(word) = self.r.token()? {
            let word = word.to_ascii_uppercase();
            match word.as_str() {
                "DATASET" => {
                    let t = self.r.need("a dataset type")?.to_ascii_uppercase();
                    if self.grid.is_some() {
                        return Err(self.r.err("a second DATASET"));
                    }
                    self.grid = Some(match t.as_str() {
                        "POLYDATA" => false,
                        "UNSTRUCTURED_GRID" => true,
                        _ => {
                            return Err(self.r.err(format!(
                                "dataset type {} : dcrt reads POLYDATA and UNSTRUCTURED_GRID \
                                 (surfaces; in ParaView, Extract Surface and save as .vtk or .vtp)",
                                snippet(&t)
                            )));
                        }
                    });
                }
                "POINTS" => self.points()?,
                "FIELD" if self.assoc.is_none() => self.field(None)?,
                "METADATA" => self.metadata()?,
                s if SECTIONS.contains(&s) => self.poly_section(s)?,
                "CELLS" => self.grid_cells()?,
                "CELL_TYPES" => self.grid_types()?,
                "POINT_DATA" | "CELL_DATA" => self.data_header(&word)?,
                _ if self.assoc.is_some() => self.array(&word)?,
                _ => {
                    return Err(self.r.err(format!(
                        "unexpected '{}' (not a legacy VTK keyword here)",
                        snippet(&word)
                    )));
                }
            }
        }
        Ok(())
    }

    fn polydata(&self) -> Result<bool> {
        match self.grid {
            Some(grid) => Ok(!grid),
            None => Err(self
                .r
                .err("data before 'DATASET POLYDATA|UNSTRUCTURED_GRID'")),
        }
    }

    fn points(&mut self) -> Result<()> {
        self.polydata()?;
        if !self.out.mesh.positions.is_empty() {
            return Err(self.r.err("a second POINTS section"));
        }
        let n = self.r.count("a point count")?;
        if n > u64::from(u32::MAX) {
            return Err(self
                .r
                .err(format!("{n} points, at most {} supported", u32::MAX)));
        }
        let ty = self.value_type()?;
        let mut p = [0f64; 3];
        let positions = &mut self.out.mesh.positions;
        positions.reserve(n.min(1 << 20) as usize);
        self.r.values(
            ty,
            n.saturating_mul(3),
            &|i| format!("POINTS: point {}", i / 3),
            &mut |i, v| {
                p[(i % 3) as usize] = v;
                if i % 3 == 2 {
                    let q = p.map(|c| c as f32);
                    if !q.iter().all(|c| c.is_finite()) {
                        return Err(format!("coordinate is not finite: {q:?}"));
                    }
                    positions.push(q);
                }
                Ok(())
            },
        )
    }

    fn value_type(&mut self) -> Result<Type> {
        let t = self.r.need("a value type")?;
        Type::from_legacy(t).ok_or_else(|| {
            self.r.err(format!(
                "unknown value type '{}' (string arrays are not supported)",
                snippet(t)
            ))
        })
    }

    /// A count-prefixed list (`n size`, then per cell `k i0 .. ik-1`) or, from version 5, a
    /// header `offsets connectivity` followed by OFFSETS and CONNECTIVITY arrays.
    fn cell_list(&mut self, label: &str) -> Result<CellList> {
        let what = |s: &str| format!("the {label} {s}");
        let a = self.r.count(&what("count"))?;
        let b = self.r.count(&what("size"))?;
        let mut list = CellList::default();
        if self.new_cells {
            for (key, n) in [("OFFSETS", a), ("CONNECTIVITY", b)] {
                let k = self.r.need(key)?;
                if !k.eq_ignore_ascii_case(key) {
                    return Err(self
                        .r
                        .err(format!("expected {key}, found '{}'", snippet(k))));
                }
                let ty = self.value_type()?;
                if !ty.is_int() {
                    return Err(self
                        .r
                        .err(format!("{key} must be integers, not {}", ty.name())));
                }
                let (offsets, ids) = (&mut list.offsets, &mut list.ids);
                offsets.reserve(a.min(1 << 20) as usize);
                ids.reserve(b.min(1 << 22) as usize);
                self.r.values(
                    ty,
                    n,
                    &|i| format!("{label}: {} {i}", key.to_ascii_lowercase()),
                    &mut |i, v| {
                        if key == "CONNECTIVITY" {
                            ids.push(v as i64);
                            return Ok(());
                        }
                        let prev = offsets.last().copied();
                        let ok = match prev {
                            None => v == 0.0,
                            Some(p) => v >= p as f64 && v <= b as f64,
                        };
                        if !ok || (i + 1 == a && v != b as f64) {
                            return Err(format!(
                                "offset {v} breaks the rule: from 0, never decreasing, last = \
                                 the connectivity size {b}"
                            ));
                        }
                        offsets.push(v as u64);
                        Ok(())
                    },
                )?;
            }
            if a == 0 && b != 0 {
                return Err(self.r.err(format!("{label}: no offsets for {b} point ids")));
            }
            return Ok(list);
        }
        // Version 4 and older: `a` cells in `b` integers.
        let (offsets, ids) = (&mut list.offsets, &mut list.ids);
        offsets.push(0);
        let mut left = 0u64; // ids still due in the current cell
        let mut cells = 0u64;
        self.r.values(
            Type::I32,
            b,
            &|i| format!("{label}: integer {i} of {b}"),
            &mut |_, v| {
                if left == 0 {
                    if cells == a {
                        return Err(format!("more integers than {a} cells of this size need"));
                    }
                    if v < 0.0 {
                        return Err(format!("cell {cells} has a negative point count {v}"));
                    }
                    left = v as u64;
                    cells += 1;
                    if left == 0 {
                        offsets.push(ids.len() as u64);
                    }
                } else {
                    ids.push(v as i64);
                    left -= 1;
                    if left == 0 {
                        offsets.push(ids.len() as u64);
                    }
                }
                Ok(())
            },
        )?;
        if left != 0 {
            return Err(self.r.err(format!(
                "{label}: the size {b} ends inside cell {}: {left} point ids short",
                cells - 1
            )));
        }
        if cells != a {
            return Err(self.r.err(format!(
                "{label}: the size {b} holds {cells} whole cells, the header says {a}"
            )));
        }
        Ok(list)
    }

    fn poly_section(&mut self, label: &str) -> Result<()> {
        if !self.polydata()? {
            return Err(self
                .r
                .err(format!("{label} in an UNSTRUCTURED_GRID (it takes CELLS)")));
        }
        let k = SECTIONS.iter().position(|s| *s == label).unwrap_or(0);
        if self.sections[k].is_some() {
            return Err(self.r.err(format!("a second {label} section")));
        }
        let list = self.cell_list(label)?;
        self.sections[k] = Some(list);
        Ok(())
    }

    fn grid_cells(&mut self) -> Result<()> {
        if self.polydata()? {
            return Err(self
                .r
                .err("CELLS in POLYDATA (it takes POLYGONS, TRIANGLE_STRIPS, ...)"));
        }
        if self.sections[0].is_some() {
            return Err(self.r.err("a second CELLS section"));
        }
        let list = self.cell_list("CELLS")?;
        self.sections[0] = Some(list);
        Ok(())
    }

    fn grid_types(&mut self) -> Result<()> {
        let Some(cells) = self.sections[0]
            .as_ref()
            .filter(|_| self.grid == Some(true))
        else {
            return Err(self.r.err("CELL_TYPES before CELLS"));
        };
        let want = cells.cells() as u64;
        let n = self.r.count("a cell type count")?;
        if n != want {
            return Err(self.r.err(format!("{n} cell types for {want} cells")));
        }
        let mut types = Vec::with_capacity(n.min(1 << 20) as usize);
        self.r.values(
            Type::I32,
            n,
            &|i| format!("CELL_TYPES: cell {i}"),
            &mut |_, v| {
                types.push(v as i64);
                Ok(())
            },
        )?;
        self.sections[1] = Some(CellList {
            offsets: Vec::new(),
            ids: types,
        });
        self.cells_total = Some(n);
        Ok(())
    }

    /// The number of cells read so far, which cell data must match.
    fn cell_count(&self) -> u64 {
        if self.grid == Some(true) {
            return self.cells_total.unwrap_or(0);
        }
        self.sections
            .iter()
            .flatten()
            .map(|s| s.cells() as u64)
            .sum()
    }

    fn data_header(&mut self, word: &str) -> Result<()> {
        self.polydata()?;
        let n = self.r.count("a tuple count")?;
        let (assoc, want, what) = if word == "POINT_DATA" {
            (Assoc::Point, self.out.mesh.positions.len() as u64, "points")
        } else {
            if self.grid == Some(true) && self.cells_total.is_none() {
                return Err(self.r.err("CELL_DATA before CELL_TYPES"));
            }
            (Assoc::Cell, self.cell_count(), "cells")
        };
        if n != want {
            return Err(self
                .r
                .err(format!("{word} {n}, but the dataset has {want} {what}")));
        }
        self.assoc = Some((assoc, n));
        Ok(())
    }

    /// Skips a METADATA block: lines up to the first blank one.
    fn metadata(&mut self) -> Result<()> {
        self.r.end_line()?;
        while let Some(l) = self.r.line_text()? {
            if l.trim().is_empty() {
                break;
            }
        }
        Ok(())
    }

    /// One attribute array of the current POINT_DATA or CELL_DATA section.
    fn array(&mut self, word: &str) -> Result<()> {
        let Some((assoc, tuples)) = self.assoc else {
            return Err(self.r.err("an array outside POINT_DATA and CELL_DATA"));
        };
        let name = decode_name(self.r.need("an array name")?);
        match word {
            "SCALARS" => {
                let ty = self.value_type()?;
                // An optional component count, then the lookup table.
                let mut t = self.r.need("LOOKUP_TABLE")?;
                let mut comps = 1;
                if let Ok(c) = t.parse::<usize>() {
                    if !(1..=4).contains(&c) {
                        return Err(self.r.err(format!("SCALARS with {c} components (1 to 4)")));
                    }
                    comps = c;
                    t = self.r.need("LOOKUP_TABLE")?;
                }
                if !t.eq_ignore_ascii_case("LOOKUP_TABLE") {
                    return Err(self
                        .r
                        .err(format!("expected LOOKUP_TABLE, found '{}'", snippet(t))));
                }
                self.r.need("a lookup table name")?;
                self.read_array(name, assoc, tuples, comps, ty, None)
            }
            "COLOR_SCALARS" => {
                let comps = self.r.count("a component count")? as usize;
                if !(1..=4).contains(&comps) {
                    return Err(self
                        .r
                        .err(format!("COLOR_SCALARS with {comps} components (1 to 4)")));
                }
                // ASCII colours are floats in [0, 1], binary ones bytes.
                let ty = if self.r.binary { Type::U8 } else { Type::F32 };
                self.read_array(name, assoc, tuples, comps, ty, Some(Encoding::Srgb))
            }
            "LOOKUP_TABLE" => {
                let size = self.r.count("a table size")?;
                let ty = if self.r.binary { Type::U8 } else { Type::F32 };
                self.r.values(
                    ty,
                    size.saturating_mul(4),
                    &|i| format!("LOOKUP_TABLE {name}: entry {}", i / 4),
                    &mut |_, _| Ok(()),
                )
            }
            "VECTORS" | "NORMALS" => {
                let ty = self.value_type()?;
                self.read_array(name, assoc, tuples, 3, ty, None)
            }
            "TEXTURE_COORDINATES" => {
                let dim = self.r.count("a dimension")? as usize;
                if !(1..=3).contains(&dim) {
                    return Err(self
                        .r
                        .err(format!("TEXTURE_COORDINATES of dimension {dim}")));
                }
                let ty = self.value_type()?;
                self.read_array(name, assoc, tuples, dim, ty, None)
            }
            "TENSORS" | "TENSORS6" => {
                let ty = self.value_type()?;
                let comps = if word == "TENSORS" { 9 } else { 6 };
                self.read_array(name, assoc, tuples, comps, ty, None)
            }
            "GLOBAL_IDS" | "PEDIGREE_IDS" => {
                let ty = self.value_type()?;
                self.read_array(name, assoc, tuples, 1, ty, None)
            }
            "FIELD" => self.field_arrays(Some((assoc, tuples))),
            _ => Err(self.r.err(format!(
                "unexpected '{}' in {} data (not an attribute keyword)",
                snippet(word),
                assoc.name()
            ))),
        }
    }

    /// `FIELD name n` outside point and cell data: the dataset's own field data, read and
    /// dropped.
    fn field(&mut self, of: Option<(Assoc, u64)>) -> Result<()> {
        self.r.need("a field name")?;
        self.field_arrays(of)
    }

    /// The arrays of a FIELD (its name already read when inside point or cell data).
    fn field_arrays(&mut self, of: Option<(Assoc, u64)>) -> Result<()> {
        let n = self.r.count("an array count")?;
        for _ in 0..n {
            let name = decode_name(self.r.need("an array name")?);
            if name == "NULL_ARRAY" {
                continue;
            }
            let comps = self.r.count("a component count")? as usize;
            let count = self.r.count("a tuple count")?;
            let ty = self.value_type()?;
            match of {
                Some((assoc, tuples)) => {
                    if count != tuples {
                        return Err(self.r.err(format!(
                            "array '{name}' has {count} tuples, the {} data has {tuples}",
                            assoc.name()
                        )));
                    }
                    if comps == 0 {
                        return Err(self.r.err(format!("array '{name}' has 0 components")));
                    }
                    self.read_array(name, assoc, tuples, comps, ty, None)?;
                }
                None => {
                    let total = count.saturating_mul(comps as u64);
                    self.r.values(
                        ty,
                        total,
                        &|i| format!("FIELD {name}: value {i}"),
                        &mut |_, _| Ok(()),
                    )?;
                }
            }
        }
        Ok(())
    }

    fn read_array(
        &mut self,
        name: String,
        assoc: Assoc,
        tuples: u64,
        comps: usize,
        ty: Type,
        color: Option<crate::scene::data::Encoding>,
    ) -> Result<()> {
        // Unsigned bytes of 3 or 4 components are colours (as ParaView shows them with Map
        // Scalars off).
        let color =
            color.or((ty == Type::U8 && (comps == 3 || comps == 4)).then_some(Encoding::Srgb));
        let index = self.out.data.offer(ArrayInfo {
            name: name.clone(),
            assoc,
            components: comps,
            ty: ty.name().into(),
            color,
        });
        let keep = self.keep.wants(&name, assoc);
        let scale = if color.is_some() && ty.is_int() {
            1.0 / ty.int_max()
        } else {
            1.0
        };
        let mut values = Values::new(comps);
        if keep {
            values
                .data
                .reserve((tuples.saturating_mul(comps as u64)).min(1 << 22) as usize);
        }
        let label = format!("{} '{name}'", assoc.name());
        let total = tuples.saturating_mul(comps as u64);
        self.r.values(
            ty,
            total,
            &|i| format!("{label}: {} {}", assoc.name(), i / comps as u64),
            &mut |_, v| {
                if keep {
                    values.data.push((v * scale) as f32);
                }
                Ok(())
            },
        )?;
        if keep {
            self.out.data.kept.push((index, values));
        }
        Ok(())
    }

    /// Triangulates the cells in VTK's order and returns the mesh and its data.
    fn finish(mut self) -> Result<(Mesh, MeshData)> {
        let Some(grid) = self.grid else {
            return Err(self.r.err("no DATASET in the file"));
        };
        let origin = self.r.origin;
        let keep_cells = self.keep.cells();
        let sections = std::mem::take(&mut self.sections);
        let mut t = self.out.triangulator(keep_cells);
        let bad = |what: String, m: String| Error::format(origin, Some(what), m);
        if grid {
            let (Some(cells), Some(types)) = (&sections[0], &sections[1]) else {
                return Err(bad(
                    "CELLS".into(),
                    "an UNSTRUCTURED_GRID needs CELLS and CELL_TYPES".into(),
                ));
            };
            for c in 0..cells.cells() {
                t.grid_cell(c as u64, types.ids[c], cells.cell(c))
                    .map_err(|m| bad(format!("CELLS: cell {c}"), m))?;
            }
        } else {
            let mut id = 0u64;
            for (k, label) in SECTIONS.iter().enumerate() {
                let Some(list) = &sections[k] else { continue };
                for c in 0..list.cells() {
                    let ids = list.cell(c);
                    match k {
                        0 | 1 => t.skip(ids),
                        2 => t.polygon(id, ids),
                        _ => t.strip(id, ids),
                    }
                    .map_err(|m| bad(format!("{label}: cell {c}"), m))?;
                    id += 1;
                }
            }
        }
        Ok((self.out.mesh, self.out.data))
    }
}

/// VTK writes spaces and other special characters in array names as `%XX`.
fn decode_name(raw: &str) -> String {
    let b = raw.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && let Some(hex) = raw.get(i + 1..i + 3)
            && let Ok(v) = u8::from_str_radix(hex, 16)
        {
            out.push(v);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

#[cfg(test)]
pub(crate) mod tests;
