//! Colouring a mesh by one of its data arrays (ParaView's "Color By").

use super::data::Values;

/// The scalar of tuple `t`: the value itself, or the magnitude of a multi-component tuple (as
/// ParaView colours vectors by default).
pub fn scalar(v: &Values, t: usize) -> f32 {
    let c = v.components.max(1);
    let tuple = &v.data[t * c..(t + 1) * c];
    if c == 1 {
        tuple[0]
    } else {
        tuple
            .iter()
            .map(|x| f64::from(*x).powi(2))
            .sum::<f64>()
            .sqrt() as f32
    }
}

/// The range of an array's scalars over its finite values (`None` when there is none), as
/// ParaView's "Rescale to Data Range" takes it.
pub fn range_of(v: &Values) -> Option<(f32, f32)> {
    let mut r: Option<(f32, f32)> = None;
    for t in 0..v.tuples() {
        let s = scalar(v, t);
        if s.is_finite() {
            r = Some(r.map_or((s, s), |(lo, hi)| (lo.min(s), hi.max(s))));
        }
    }
    r
}

use super::data::{Assoc, Encoding, MeshData};
use super::mesh::Mesh;
use crate::colormap::{Colormap, linear_to_srgb, pack_srgb};
use crate::error::{Error, Result};
use std::path::Path;

/// How one entry of the mesh table is coloured.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Look {
    /// The entry's colour.
    #[default]
    Constant,
    /// An array's values mapped through `colormap` over `range` (point values interpolated at
    /// the hit, as ParaView interpolates scalars before mapping; cell values per triangle).
    Scalars {
        array: String,
        colormap: Colormap,
        range: [f32; 2],
        cell: bool,
    },
    /// An array of direct colours.
    Colors { array: String, cell: bool },
}

impl Look {
    /// Whether the entry reads attribute blocks.
    pub fn uses_attributes(&self) -> bool {
        !matches!(self, Look::Constant)
    }

    /// Whether its attributes are three per triangle (point data).
    pub fn per_corner(&self) -> bool {
        match self {
            Look::Constant => false,
            Look::Scalars { cell, .. } | Look::Colors { cell, .. } => !cell,
        }
    }
}

/// What a `[[mesh]]` entry asks: `color_by`, `cell`, `colormap`, `range`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColorBy {
    pub array: String,
    pub cell: bool,
    pub colormap: Option<Colormap>,
    pub range: Option<[f32; 2]>,
}

impl ColorBy {
    pub fn assoc(&self) -> Assoc {
        if self.cell { Assoc::Cell } else { Assoc::Point }
    }
}

/// One mesh's colouring: its attribute words, three per triangle in mesh order (a cell value
/// repeated), and its look with the range still to settle when none was given.
#[derive(Clone, Debug)]
pub struct MeshColors {
    pub words: Vec<[u32; 3]>,
    pub look: Look,
    /// The data range of its scalars, when the scene gave no range.
    pub data_range: Option<(f32, f32)>,
}

/// Colours `mesh` by the array `by` names: checks that the array exists with that association,
/// has a value for every point or cell, and has only finite values; scalars become f32 words,
/// colours packed 8-bit sRGB words. Errors name `origin` and list the arrays there are.
pub fn resolve(mesh: &Mesh, data: &MeshData, by: &ColorBy, origin: &Path) -> Result<MeshColors> {
    let assoc = by.assoc();
    let bad = |m: String| Error::format(origin, None, m);
    let Some(index) = data
        .arrays
        .iter()
        .position(|a| a.name == by.array && a.assoc == assoc)
    else {
        let other = match assoc {
            Assoc::Point => Assoc::Cell,
            Assoc::Cell => Assoc::Point,
        };
        let hint = if data
            .arrays
            .iter()
            .any(|a| a.name == by.array && a.assoc == other)
        {
            format!(
                " ('{}' is {} data: {})",
                by.array,
                other.name(),
                if other == Assoc::Cell {
                    "add cell = true"
                } else {
                    "remove cell = true"
                }
            )
        } else {
            String::new()
        };
        return Err(bad(format!(
            "color_by '{}': no {} array of that name{hint}; point arrays: {}; cell arrays: {}",
            by.array,
            assoc.name(),
            data.names(Assoc::Point),
            data.names(Assoc::Cell)
        )));
    };
    let info = &data.arrays[index];
    let values = data.values(index).ok_or_else(|| {
        Error::Internal(format!(
            "{}: array '{}' was not kept",
            origin.display(),
            info.name
        ))
    })?;
    let what = |t: usize| format!("array '{}': {} {t}", info.name, assoc.name());
    let tuples = values.tuples();
    // The tuple of each triangle corner (point data) or of each triangle (cell data).
    let tuple_of: Box<dyn Fn(usize, usize) -> usize> = match assoc {
        Assoc::Point => {
            if tuples != mesh.positions.len() {
                return Err(bad(format!(
                    "array '{}' has {tuples} values, the mesh has {} points",
                    info.name,
                    mesh.positions.len()
                )));
            }
            Box::new(|t, c| mesh.triangles[t][c] as usize)
        }
        Assoc::Cell => {
            let cells = &data.triangle_cells;
            let need = cells.iter().max().map_or(0, |&c| c as usize + 1);
            if cells.len() != mesh.triangles.len() || tuples < need {
                return Err(bad(format!(
                    "array '{}' has {tuples} values, the mesh has {need} cells",
                    info.name
                )));
            }
            Box::new(move |t, _| cells[t] as usize)
        }
    };
    let per_triangle = |f: &dyn Fn(usize) -> u32| -> Vec<[u32; 3]> {
        (0..mesh.triangles.len())
            .map(|t| [0, 1, 2].map(|c| f(tuple_of(t, c))))
            .collect()
    };
    let comps = values.components.max(1);
    if let Some(enc) = info.color {
        if by.colormap.is_some() || by.range.is_some() {
            return Err(bad(format!(
                "color_by '{}': the array holds colours; colormap and range apply to values",
                info.name
            )));
        }
        let mut packed = Vec::with_capacity(tuples);
        for t in 0..tuples {
            let v = &values.data[t * comps..(t + 1) * comps];
            let rgb = if comps >= 3 {
                [v[0], v[1], v[2]]
            } else {
                [v[0]; 3]
            };
            if !rgb.iter().all(|c| c.is_finite()) {
                return Err(bad(format!("{} is not a colour: {rgb:?}", what(t))));
            }
            packed.push(pack_srgb(rgb.map(|c| match enc {
                Encoding::Srgb => (f64::from(c).clamp(0.0, 1.0) * 255.0).round() as u8,
                Encoding::Linear => linear_to_srgb(c),
            })));
        }
        return Ok(MeshColors {
            words: per_triangle(&|t| packed[t]),
            look: Look::Colors {
                array: info.name.clone(),
                cell: by.cell,
            },
            data_range: None,
        });
    }
    let scalars: Vec<f32> = (0..tuples).map(|t| scalar(values, t)).collect();
    if let Some(t) = scalars.iter().position(|s| !s.is_finite()) {
        return Err(bad(format!(
            "{} is {} (colouring needs finite values)",
            what(t),
            scalars[t]
        )));
    }
    let data_range = match by.range {
        Some(_) => None,
        None => range_of(values),
    };
    Ok(MeshColors {
        words: per_triangle(&|t| scalars[t].to_bits()),
        look: Look::Scalars {
            array: info.name.clone(),
            colormap: by.colormap.unwrap_or_default(),
            range: by.range.unwrap_or([0.0, 0.0]),
            cell: by.cell,
        },
        data_range,
    })
}

/// Per-triangle attribute words of a model, in primitive-id order: `words` (1 or 3) per
/// triangle; `None` in a model that colours nothing by data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Attributes {
    pub words: u32,
    pub data: Vec<u32>,
}

/// Settles the ranges of looks without one: meshes colouring by the same array name with the
/// same colormap share one range, the union of their data ranges, as ParaView shares one
/// lookup table per array. `pending[i]` is mesh i's look and data range.
pub fn settle_ranges(pending: &mut [(Look, Option<(f32, f32)>)]) {
    let key = |l: &Look| match l {
        Look::Scalars {
            array, colormap, ..
        } => Some((array.clone(), *colormap)),
        _ => None,
    };
    let unions: Vec<Option<(f32, f32)>> = pending
        .iter()
        .map(|(l, _)| {
            let k = key(l)?;
            pending
                .iter()
                .filter(|(m, r)| r.is_some() && key(m).as_ref() == Some(&k))
                .filter_map(|(_, r)| *r)
                .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
        })
        .collect();
    for ((look, data), u) in pending.iter_mut().zip(unions) {
        if let (Look::Scalars { range, .. }, Some(_), Some((lo, hi))) = (look, *data, u) {
            *range = [lo, hi];
        }
    }
}
