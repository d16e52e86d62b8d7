//! The PLY header: format, elements and their typed properties, and which properties the mesh
//! needs.

use super::{Line, read_line, snippet};
use crate::error::{Error, Result};
use std::io::BufRead;
use std::path::Path;

/// Longest header line accepted, so binary data is not slurped while looking for a newline.
const MAX_HEADER_LINE: u64 = 1 << 16;

/// A PLY scalar type. Its binary decoding is in `binary`, its text parsing in `ascii`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    pub(super) fn from_name(name: &str) -> Option<Self> {
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

    pub(super) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    pub(super) fn is_int(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }

    /// Range of an integer type; every PLY integer fits an f64 exactly, so values travel as f64.
    pub(super) fn int_range(self) -> (i64, i64) {
        match self {
            Self::I8 => (i8::MIN.into(), i8::MAX.into()),
            Self::U8 => (0, u8::MAX.into()),
            Self::I16 => (i16::MIN.into(), i16::MAX.into()),
            Self::U16 => (0, u16::MAX.into()),
            Self::I32 => (i32::MIN.into(), i32::MAX.into()),
            Self::U32 | Self::F32 | Self::F64 => (0, u32::MAX.into()),
        }
    }

    pub(super) fn name(self) -> &'static str {
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
pub(super) enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// What the loader does with a property's value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Role {
    Skip,
    Coord(usize),
    Indices,
    /// A component of a kept data array: the record slot it goes to.
    Value(usize),
}

#[derive(Debug)]
pub(super) struct Property {
    pub(super) name: String,
    pub(super) kind: Kind,
    pub(super) role: Role,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Target {
    Vertices,
    Faces,
    Other,
}

#[derive(Debug)]
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: u64,
    pub(super) props: Vec<Property>,
    pub(super) target: Target,
    /// Header line of the `element` statement, for errors about the element as a whole.
    line: usize,
}

impl Element {
    /// Record size in bytes if every property is a scalar.
    pub(super) fn fixed_size(&self) -> Option<usize> {
        self.props.iter().try_fold(0, |sum, p| match p.kind {
            Kind::Scalar(t) => Some(sum + t.size()),
            Kind::List { .. } => None,
        })
    }

    pub(super) fn plural(&self) -> String {
        match self.name.as_str() {
            "vertex" => "vertices".into(),
            n if n.ends_with('x') || n.ends_with('s') => format!("{n}es"),
            n => format!("{n}s"),
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub(super) enum Format {
    Ascii,
    Binary { big_endian: bool },
}

#[derive(Debug)]
pub(super) struct Header {
    pub(super) format: Format,
    pub(super) elements: Vec<Element>,
    /// Number of header lines, `end_header` included; ascii data line numbers continue from it.
    pub(super) lines: usize,
}

impl Header {
    pub(super) fn read<R: BufRead>(r: &mut R, origin: &Path) -> Result<Header> {
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

/// A kept data array of the vertex or face element.
pub(super) struct KeptArray {
    /// Index into `MeshData::arrays` (and `kept`).
    pub(super) index: usize,
    pub(super) target: Target,
    /// The record slots of its components, in order.
    pub(super) slots: Vec<usize>,
    /// Integer colours are scaled to [0, 1] by this.
    pub(super) scale: f64,
}

/// Lists the data arrays of the vertex and face elements, as ParaView names them where it reads
/// them (`red`, `green`, `blue` and `alpha` make one colour array "RGB", `nx`, `ny`, `nz`
/// "Normals"; every other scalar property is an array of its own name), and marks the
/// properties of those `keep` asks for. Returns the kept arrays and the record slots they use.
pub(super) fn data_arrays(
    header: &mut Header,
    keep: &crate::scene::data::Keep,
    data: &mut crate::scene::data::MeshData,
) -> (Vec<KeptArray>, usize) {
    use crate::scene::data::{ArrayInfo, Assoc, Encoding};
    let mut kept = Vec::new();
    let mut slots = 0;
    for e in &mut header.elements {
        let assoc = match e.target {
            Target::Vertices => Assoc::Point,
            Target::Faces => Assoc::Cell,
            Target::Other => continue,
        };
        // (array name, property indices, colour)
        let mut groups: Vec<(String, Vec<usize>, bool)> = Vec::new();
        let find = |n: &str| {
            e.props
                .iter()
                .position(|p| p.name == n && matches!(p.kind, Kind::Scalar(_)))
        };
        let colour: Vec<usize> = ["red", "green", "blue", "alpha"]
            .iter()
            .map_while(|n| find(n))
            .collect();
        if colour.len() >= 3 {
            groups.push(("RGB".into(), colour, true));
        }
        let normal: Vec<usize> = ["nx", "ny", "nz"].iter().map_while(|n| find(n)).collect();
        if normal.len() == 3 {
            groups.push(("Normals".into(), normal, false));
        }
        for (i, p) in e.props.iter().enumerate() {
            if p.role == Role::Skip
                && matches!(p.kind, Kind::Scalar(_))
                && !groups.iter().any(|g| g.1.contains(&i))
            {
                groups.push((p.name.clone(), vec![i], false));
            }
        }
        groups.sort_by_key(|g| g.1[0]);
        for (name, props, color) in groups {
            let Kind::Scalar(t) = e.props[props[0]].kind else {
                continue;
            };
            let index = data.offer(ArrayInfo {
                name: name.clone(),
                assoc,
                components: props.len(),
                ty: t.name().into(),
                color: color.then_some(Encoding::Srgb),
            });
            if !keep.wants(&name, assoc) {
                continue;
            }
            let mut used = Vec::new();
            for &i in &props {
                e.props[i].role = Role::Value(slots);
                used.push(slots);
                slots += 1;
            }
            let scale = if color && t.is_int() {
                1.0 / t.int_range().1 as f64
            } else {
                1.0
            };
            kept.push(KeptArray {
                index,
                target: e.target,
                slots: used,
                scale,
            });
        }
    }
    (kept, slots)
}

#[cfg(test)]
mod tests {
    use crate::scene::ply::fixtures::*;

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
}
