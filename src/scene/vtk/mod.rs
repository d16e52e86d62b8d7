//! VTK files: the legacy format (`.vtk`, POLYDATA and UNSTRUCTURED_GRID, ASCII and binary,
//! versions 2 to 5.1) and XML PolyData (`.vtp`: ascii, base64 and appended data, raw or zlib
//! compressed). Both are read whole into memory and checked strictly: every count against the
//! data, every point index against the points, every value against its type.
//!
//! Here: the value types both formats share, and the cell triangulation both use: cells become
//! triangles in VTK's cell order (PolyData: vertices, lines, polygons, then strips; a grid: its
//! cells in order), polygons fanned `(p0, pk, pk+1)`, strips split as VTK splits them; vertex and
//! line cells make no triangles but keep their cell ids, so cell data stays aligned.

pub mod legacy;
pub mod xml;

use crate::scene::data::MeshData;
use crate::scene::mesh::Mesh;

/// A value type, by its names in the legacy and the XML format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Type {
    Bit,
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Type {
    /// A legacy type name (`float`, `unsigned_char`, `vtktypeint64`, ...).
    pub fn from_legacy(name: &str) -> Option<Type> {
        Some(match name.to_ascii_lowercase().as_str() {
            "bit" => Type::Bit,
            "char" | "signed_char" => Type::I8,
            "unsigned_char" => Type::U8,
            "short" => Type::I16,
            "unsigned_short" => Type::U16,
            "int" => Type::I32,
            "unsigned_int" => Type::U32,
            "long" | "vtktypeint64" | "vtkidtype" => Type::I64,
            "unsigned_long" | "vtktypeuint64" => Type::U64,
            "float" => Type::F32,
            "double" => Type::F64,
            _ => return None,
        })
    }

    /// An XML type name (`Float32`, `UInt8`, ...).
    pub fn from_xml(name: &str) -> Option<Type> {
        Some(match name {
            "Int8" | "Char" => Type::I8,
            "UInt8" => Type::U8,
            "Int16" => Type::I16,
            "UInt16" => Type::U16,
            "Int32" => Type::I32,
            "UInt32" => Type::U32,
            "Int64" => Type::I64,
            "UInt64" => Type::U64,
            "Float32" => Type::F32,
            "Float64" => Type::F64,
            _ => return None,
        })
    }

    /// Bytes per value (bit arrays pack eight values a byte and are handled apart).
    pub fn size(self) -> usize {
        match self {
            Type::Bit | Type::I8 | Type::U8 => 1,
            Type::I16 | Type::U16 => 2,
            Type::I32 | Type::U32 | Type::F32 => 4,
            Type::I64 | Type::U64 | Type::F64 => 8,
        }
    }

    pub fn is_int(self) -> bool {
        !matches!(self, Type::F32 | Type::F64)
    }

    pub fn name(self) -> &'static str {
        match self {
            Type::Bit => "bit",
            Type::I8 => "int8",
            Type::U8 => "uint8",
            Type::I16 => "int16",
            Type::U16 => "uint16",
            Type::I32 => "int32",
            Type::U32 => "uint32",
            Type::I64 => "int64",
            Type::U64 => "uint64",
            Type::F32 => "float32",
            Type::F64 => "float64",
        }
    }

    /// Decodes one value from `b[..self.size()]`. 64-bit integers beyond 2^53 lose precision as
    /// f64, which no index or colour of a loadable model reaches.
    pub fn decode(self, b: &[u8], big: bool) -> f64 {
        macro_rules! get {
            ($t:ty) => {{
                let mut a = [0u8; size_of::<$t>()];
                a.copy_from_slice(&b[..size_of::<$t>()]);
                if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }
            }};
        }
        match self {
            Type::Bit | Type::U8 => f64::from(b[0]),
            Type::I8 => f64::from(b[0] as i8),
            Type::I16 => f64::from(get!(i16)),
            Type::U16 => f64::from(get!(u16)),
            Type::I32 => f64::from(get!(i32)),
            Type::U32 => f64::from(get!(u32)),
            Type::I64 => get!(i64) as f64,
            Type::U64 => get!(u64) as f64,
            Type::F32 => f64::from(get!(f32)),
            Type::F64 => get!(f64),
        }
    }

    /// Parses one ASCII value; integers must be integers within their type's range.
    pub fn parse(self, tok: &str) -> Result<f64, String> {
        let bad = || format!("expected a {} value, found '{}'", self.name(), snippet(tok));
        if !self.is_int() {
            return match self {
                Type::F32 => tok.parse::<f32>().map(f64::from),
                _ => tok.parse::<f64>(),
            }
            .map_err(|_| bad());
        }
        let v: i128 = tok.parse().map_err(|_| bad())?;
        let (lo, hi): (i128, i128) = match self {
            Type::Bit => (0, 1),
            Type::I8 => (i8::MIN.into(), i8::MAX.into()),
            Type::U8 => (0, u8::MAX.into()),
            Type::I16 => (i16::MIN.into(), i16::MAX.into()),
            Type::U16 => (0, u16::MAX.into()),
            Type::I32 => (i32::MIN.into(), i32::MAX.into()),
            Type::U32 => (0, u32::MAX.into()),
            Type::I64 => (i64::MIN.into(), i64::MAX.into()),
            _ => (0, u64::MAX.into()),
        };
        if (lo..=hi).contains(&v) {
            Ok(v as f64)
        } else {
            Err(format!("value {v} out of range for {}", self.name()))
        }
    }

    /// The largest value of an integer type: integer colours are scaled by it to [0, 1].
    pub fn int_max(self) -> f64 {
        match self {
            Type::Bit => 1.0,
            Type::I8 => 127.0,
            Type::U8 => 255.0,
            Type::I16 => 32767.0,
            Type::U16 => 65535.0,
            Type::I32 => 2147483647.0,
            Type::U32 => 4294967295.0,
            Type::I64 => 9.223372036854776e18,
            _ => 1.8446744073709552e19,
        }
    }
}

/// A token as a message shows it: short, control characters escaped.
pub(crate) fn snippet(tok: &str) -> String {
    tok.escape_debug().take(32).collect()
}

/// VTK cell types dcrt renders, skips (no surface) or refuses (volumes, higher order).
pub(crate) mod cell_type {
    pub const VERTEX: i64 = 1;
    pub const POLY_VERTEX: i64 = 2;
    pub const LINE: i64 = 3;
    pub const POLY_LINE: i64 = 4;
    pub const TRIANGLE: i64 = 5;
    pub const TRIANGLE_STRIP: i64 = 6;
    pub const POLYGON: i64 = 7;
    pub const PIXEL: i64 = 8;
    pub const QUAD: i64 = 9;

    /// A name for messages.
    pub fn name(t: i64) -> String {
        match t {
            10 => "tetrahedron (a volume cell)".into(),
            11 => "voxel (a volume cell)".into(),
            12 => "hexahedron (a volume cell)".into(),
            13 => "wedge (a volume cell)".into(),
            14 => "pyramid (a volume cell)".into(),
            15 => "pentagonal prism (a volume cell)".into(),
            16 => "hexagonal prism (a volume cell)".into(),
            42 => "polyhedron (a volume cell)".into(),
            t => format!("cell type {t}"),
        }
    }
}

/// Turns cells into the mesh's triangles in cell order, checking every point index.
pub(crate) struct Triangulator<'a> {
    pub mesh: &'a mut Mesh,
    /// Each triangle's cell, when cell data may be kept.
    pub cells: Option<&'a mut Vec<u32>>,
    pub points: u64,
}

impl Triangulator<'_> {
    fn point(&self, id: i64) -> Result<u32, String> {
        if id >= 0 && (id as u64) < self.points {
            Ok(id as u32)
        } else {
            Err(format!(
                "point index {id} out of range ({} points)",
                self.points
            ))
        }
    }

    fn push(&mut self, cell: u64, t: [u32; 3]) -> Result<(), String> {
        if self.mesh.triangles.len() as u64 >= u64::from(u32::MAX) - 1 {
            return Err("more than 2^32-1 triangles".into());
        }
        self.mesh.triangles.push(t);
        if let Some(c) = self.cells.as_mut() {
            c.push(cell as u32);
        }
        Ok(())
    }

    /// A polygon, fanned in order.
    pub fn polygon(&mut self, cell: u64, ids: &[i64]) -> Result<(), String> {
        if ids.len() < 3 {
            return Err(format!(
                "polygon has {} points, needs at least 3",
                ids.len()
            ));
        }
        let p: Vec<u32> = ids
            .iter()
            .map(|&i| self.point(i))
            .collect::<Result<_, _>>()?;
        for k in 1..p.len() - 1 {
            self.push(cell, [p[0], p[k], p[k + 1]])?;
        }
        Ok(())
    }

    /// A triangle strip, split as `vtkTriangleStrip::DecomposeStrip` does: every other
    /// triangle swaps its first two points to keep the orientation.
    pub fn strip(&mut self, cell: u64, ids: &[i64]) -> Result<(), String> {
        if ids.len() < 3 {
            return Err(format!(
                "triangle strip has {} points, needs at least 3",
                ids.len()
            ));
        }
        let p: Vec<u32> = ids
            .iter()
            .map(|&i| self.point(i))
            .collect::<Result<_, _>>()?;
        for i in 0..p.len() - 2 {
            let t = if i % 2 == 1 {
                [p[i + 1], p[i], p[i + 2]]
            } else {
                [p[i], p[i + 1], p[i + 2]]
            };
            self.push(cell, t)?;
        }
        Ok(())
    }

    /// Points and lines: no surface, but their indices must still be valid.
    pub fn skip(&mut self, ids: &[i64]) -> Result<(), String> {
        for &i in ids {
            self.point(i)?;
        }
        Ok(())
    }

    /// An unstructured grid's cell of VTK type `t`.
    pub fn grid_cell(&mut self, cell: u64, t: i64, ids: &[i64]) -> Result<(), String> {
        use cell_type::*;
        let exactly = |n: usize, what: &str| {
            if ids.len() == n {
                Ok(())
            } else {
                Err(format!("a {what} cell has {} points, not {n}", ids.len()))
            }
        };
        match t {
            VERTEX | POLY_VERTEX | LINE | POLY_LINE => self.skip(ids),
            TRIANGLE => {
                exactly(3, "triangle")?;
                self.polygon(cell, ids)
            }
            QUAD => {
                exactly(4, "quad")?;
                self.polygon(cell, ids)
            }
            // A pixel's points go (x0 y0), (x1 y0), (x0 y1), (x1 y1).
            PIXEL => {
                exactly(4, "pixel")?;
                self.polygon(cell, &[ids[0], ids[1], ids[3], ids[2]])
            }
            POLYGON => self.polygon(cell, ids),
            TRIANGLE_STRIP => self.strip(cell, ids),
            _ => Err(format!(
                "{} is not a surface cell dcrt renders (triangles, quads, pixels, polygons and \
                 strips; in ParaView, Extract Surface makes a surface of a volume mesh)",
                cell_type::name(t)
            )),
        }
    }
}

/// A mesh being read and the data found with it.
#[derive(Default)]
pub(crate) struct Out {
    pub mesh: Mesh,
    pub data: MeshData,
}

impl Out {
    pub fn triangulator(&mut self, keep_cells: bool) -> Triangulator<'_> {
        let points = self.mesh.positions.len() as u64;
        Triangulator {
            mesh: &mut self.mesh,
            cells: keep_cells.then_some(&mut self.data.triangle_cells),
            points,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_polygons_split_as_vtk_does() {
        let mut out = Out::default();
        out.mesh.positions = vec![[0.0; 3]; 6];
        let mut t = out.triangulator(true);
        t.strip(4, &[0, 1, 2, 3, 4]).unwrap();
        t.polygon(5, &[5, 0, 1, 2]).unwrap();
        assert_eq!(
            out.mesh.triangles,
            vec![[0, 1, 2], [2, 1, 3], [2, 3, 4], [5, 0, 1], [5, 1, 2]]
        );
        assert_eq!(out.data.triangle_cells, vec![4, 4, 4, 5, 5]);
        let mut t = out.triangulator(false);
        assert!(
            t.polygon(0, &[0, 1, 6])
                .unwrap_err()
                .contains("point index 6")
        );
        assert!(
            t.polygon(0, &[0, -1, 2])
                .unwrap_err()
                .contains("point index -1")
        );
        assert!(t.strip(0, &[0, 1]).unwrap_err().contains("2 points"));
        assert!(
            t.grid_cell(0, 10, &[0, 1, 2, 3])
                .unwrap_err()
                .contains("tetrahedron")
        );
        assert!(
            t.grid_cell(0, 9, &[0, 1, 2])
                .unwrap_err()
                .contains("quad cell has 3")
        );
        t.grid_cell(0, 8, &[0, 1, 2, 3]).unwrap();
        assert_eq!(out.mesh.triangles[5..], [[0, 1, 3], [0, 3, 2]]);
    }

    /// Every form VTK's own writers produce (`scripts/make-vtk-fixtures.py`: legacy 4.2 and
    /// 5.1, ASCII and binary, PolyData and unstructured grid; XML ascii, inline base64,
    /// appended raw and base64, uncompressed and zlib in several blocks, 32- and 64-bit headers)
    /// reads as the same mesh with the same arrays.
    #[test]
    fn reads_what_vtk_writes() {
        use crate::scene::data::{Assoc, Keep};
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/vtk");
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert_eq!(files.len(), 15);
        for f in &files {
            let (m, d) = crate::scene::load_mesh_data(f, &Keep::All).unwrap();
            let tris: Vec<[[f32; 3]; 3]> = (0..m.triangles.len()).map(|i| m.corners(i)).collect();
            let p = |i: usize| m.positions[i];
            assert_eq!(m.positions.len(), 7, "{f:?}");
            assert_eq!(
                tris,
                [[0, 1, 6], [0, 1, 2], [0, 2, 3], [1, 4, 2], [2, 4, 5]].map(|t| t.map(p)),
                "{f:?}"
            );
            assert_eq!(d.triangle_cells, vec![2, 3, 3, 4, 4], "{f:?}");
            let get = |name: &str, assoc| {
                let i = d
                    .arrays
                    .iter()
                    .position(|a| a.name == name && a.assoc == assoc)
                    .unwrap();
                (d.arrays[i].clone(), d.values(i).unwrap().data.clone())
            };
            let (t, tv) = get("temperature", Assoc::Point);
            assert_eq!((t.components, tv[6]), (1, 360.0), "{f:?}");
            let (v, vv) = get("velocity", Assoc::Point);
            assert_eq!(
                (v.components, &vv[15..18]),
                (3, &[5.0, 0.0, 1.0][..]),
                "{f:?}"
            );
            let (c, cv) = get("rgb", Assoc::Point);
            assert!(c.color.is_some(), "{f:?}");
            assert_eq!(
                cv[3..6],
                [40.0 / 255.0, 215.0 / 255.0, 128.0 / 255.0],
                "{f:?}"
            );
            let (_, rv) = get("region", Assoc::Cell);
            assert_eq!(rv, vec![1.0, 2.0, 3.0, 4.0, 5.0], "{f:?}");
            let (_, av) = get("area", Assoc::Cell);
            assert_eq!(av, vec![0.0, 0.25, 0.5, 0.75, 1.0], "{f:?}");
        }
    }

    #[test]
    fn values_are_checked_against_their_type() {
        assert_eq!(Type::U8.parse("255"), Ok(255.0));
        assert!(Type::U8.parse("256").unwrap_err().contains("out of range"));
        assert!(
            Type::I32
                .parse("1.5")
                .unwrap_err()
                .contains("expected a int32")
        );
        assert_eq!(Type::F32.parse("0.1"), Ok(f64::from(0.1f32)));
        assert_eq!(Type::I16.decode(&[0xff, 0xfe], true), -2.0);
        assert_eq!(Type::I16.decode(&[0xfe, 0xff], false), -2.0);
        assert_eq!(Type::from_legacy("vtktypeint64"), Some(Type::I64));
        assert_eq!(Type::from_xml("Float32"), Some(Type::F32));
    }
}
