//! An indexed triangle mesh as loaders and generators produce it, before the BVH reorders and
//! unshares it.

use crate::error::{Error, Result};
use std::path::Path;

/// Where a mesh read in pieces goes: the vertices read so far (every one a triangle may use),
/// and the next triangles, in order.
pub type Piece<'p> = dyn FnMut(&[[f32; 3]], &[[u32; 3]]) -> Result<()> + 'p;

/// Triangles in input order: triangle `i` of the mesh is `triangles[i]`, indices into `positions`.
/// Polygons are fan-triangulated in order by the loaders, so primitive ids follow file order.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Checks that every coordinate is finite and every index is in range; `origin` names the
    /// file or generator in the error.
    pub fn validate(&self, origin: &Path) -> Result<()> {
        for (i, p) in self.positions.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(Error::format(
                    origin,
                    Some(format!("vertex {i}")),
                    format!("coordinate is not finite: {p:?}"),
                ));
            }
        }
        let n = self.positions.len() as u64;
        for (i, t) in self.triangles.iter().enumerate() {
            if let Some(bad) = t.iter().find(|&&v| u64::from(v) >= n) {
                return Err(Error::format(
                    origin,
                    Some(format!("triangle {i}")),
                    format!("vertex index {bad} out of range ({n} vertices)"),
                ));
            }
        }
        Ok(())
    }

    /// The three corners of triangle `i`.
    pub fn corners(&self, i: usize) -> [[f32; 3]; 3] {
        let t = self.triangles[i];
        [
            self.positions[t[0] as usize],
            self.positions[t[1] as usize],
            self.positions[t[2] as usize],
        ]
    }
}
