//! What a chunk of the marching makes: its triangles and vertices, with references to the next
//! chunk's first plane tagged until the chunks are joined.

use crate::scene::mesh::Mesh;

/// Marks a vertex index that belongs to the next chunk's first plane.
pub(super) const TAG: u32 = 1 << 31;
#[derive(Default)]
pub(super) struct ChunkOut {
    pub(super) positions: Vec<[f32; 3]>,
    pub(super) triangles: Vec<[u32; 3]>,
    /// Vertices on the first plane (numbered first, in scan order).
    pub(super) first_plane: u32,
    /// The vertices on the next chunk's first plane, which it owns, in its numbering: tagged
    /// index `TAG | i` is `far[i]`.
    pub(super) far: Vec<[f32; 3]>,
    pub(super) count: u64,
}

impl ChunkOut {
    /// The chunk's triangles as a mesh of their own: its vertices, then its copies of the next
    /// chunk's.
    pub(super) fn piece(mut self) -> Mesh {
        let own = self.positions.len() as u32;
        for t in &mut self.triangles {
            for v in t {
                if *v & TAG != 0 {
                    *v = own + (*v & !TAG);
                }
            }
        }
        self.positions.extend_from_slice(&self.far);
        Mesh {
            positions: self.positions,
            triangles: self.triangles,
        }
    }
}
