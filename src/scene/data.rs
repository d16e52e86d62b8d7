//! Data arrays of mesh files, as ParaView has them: point data (one tuple per vertex) and cell
//! data (one per polygon, strip or face), each a named array of one or more components. Loaders
//! list every array a file offers and keep the values of those asked for; `scene::color` turns
//! the one a mesh is coloured by into per-triangle attributes.

use std::fmt;

/// Where an array's tuples belong.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Assoc {
    Point,
    Cell,
}

impl Assoc {
    /// ParaView's word for it.
    pub fn name(self) -> &'static str {
        match self {
            Assoc::Point => "point",
            Assoc::Cell => "cell",
        }
    }
}

/// How a colour array's values read: display (sRGB) colours, as PLY, VTK and STL tools write
/// them, or linear ones (glTF's `COLOR_0`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Srgb,
    Linear,
}

/// One array a file offers.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayInfo {
    pub name: String,
    pub assoc: Assoc,
    pub components: usize,
    /// The file's type name for its values (`float`, `uchar`, `Float32`, ...).
    pub ty: String,
    /// Direct colours (RGB or RGBA in [0, 1] once read) rather than values to map.
    pub color: Option<Encoding>,
}

impl fmt::Display for ArrayInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ({} data, {} x {}",
            self.name,
            self.assoc.name(),
            self.components,
            self.ty
        )?;
        if self.color.is_some() {
            write!(f, ", colours")?;
        }
        write!(f, ")")
    }
}

/// An array's values in file order: `components` numbers per tuple. Integer colours are scaled
/// to [0, 1] by their type's maximum when read.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Values {
    pub components: usize,
    pub data: Vec<f32>,
}

impl Values {
    pub fn new(components: usize) -> Values {
        Values {
            components,
            data: Vec::new(),
        }
    }

    pub fn tuples(&self) -> usize {
        self.data.len() / self.components.max(1)
    }
}

/// Which arrays a loader keeps the values of.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Keep {
    /// None: only their names and types are listed.
    #[default]
    None,
    One {
        name: String,
        assoc: Assoc,
    },
    /// Every array (`dcrt info FILE`).
    All,
}

impl Keep {
    pub fn wants(&self, name: &str, assoc: Assoc) -> bool {
        match self {
            Keep::None => false,
            Keep::One { name: n, assoc: a } => n == name && *a == assoc,
            Keep::All => true,
        }
    }

    /// Whether any cell array may be kept (loaders then record each triangle's cell).
    pub fn cells(&self) -> bool {
        match self {
            Keep::None => false,
            Keep::One { assoc, .. } => *assoc == Assoc::Cell,
            Keep::All => true,
        }
    }
}

/// A range of a mesh's triangles with a colour of the file's own (a glTF material's base
/// colour), linear RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    pub first: u32,
    pub color: [f32; 3],
}

/// What a loader found besides positions and triangles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshData {
    /// Every array the file offers, in file order.
    pub arrays: Vec<ArrayInfo>,
    /// The values of the kept arrays, by index into `arrays`.
    pub kept: Vec<(usize, Values)>,
    /// The cell each triangle was cut from; filled when cell arrays may be kept.
    pub triangle_cells: Vec<u32>,
    /// The file's own colours of consecutive triangle ranges, first at triangle 0; empty when
    /// the file has none.
    pub parts: Vec<Part>,
}

impl MeshData {
    /// Adds an array the file offers; returns its index.
    pub fn offer(&mut self, info: ArrayInfo) -> usize {
        self.arrays.push(info);
        self.arrays.len() - 1
    }

    /// The kept values of array `index`, if kept.
    pub fn values(&self, index: usize) -> Option<&Values> {
        self.kept.iter().find(|(i, _)| *i == index).map(|(_, v)| v)
    }

    /// The names offered for `assoc`, as a message lists them.
    pub fn names(&self, assoc: Assoc) -> String {
        let names: Vec<&str> = self
            .arrays
            .iter()
            .filter(|a| a.assoc == assoc)
            .map(|a| a.name.as_str())
            .collect();
        if names.is_empty() {
            "none".into()
        } else {
            names.join(", ")
        }
    }
}
