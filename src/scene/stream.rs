//! A scene's triangles in pieces: the triangles `Scene::load_model` makes (placed, checked, in
//! primitive-id order, meshes in scene order), handed on a few thousand at a time so that no
//! whole mesh is ever held. The out-of-core prepare reads its input this way
//! (docs/ARCHITECTURE.md, Out-of-core prepare).

use super::generate::Generator;
use super::{Bounds, DEFAULT_COLOR, DEFAULT_GENERATOR_TRIANGLES, Model, Placement, Scene};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Triangles handed to a sink at a time.
const BATCH: usize = 1 << 16;

/// Where a scene's triangles go, in primitive-id order.
pub trait Sink {
    /// A mesh begins, of colour `color`: the triangles that follow are its own.
    fn mesh(&mut self, color: [f32; 3]) -> Result<()>;
    /// The next triangles, placed and finite.
    fn triangles(&mut self, triangles: &[[[f32; 3]; 3]]) -> Result<()>;
    /// The most vertices a mesh file may have: its vertices are all held while its faces are
    /// read.
    fn vertex_limit(&self) -> u64 {
        u64::MAX
    }
}

/// A model in memory is the simplest sink: `Scene::stream` into a `Model` gives
/// `Scene::load_model`'s model.
impl Sink for Model {
    fn mesh(&mut self, color: [f32; 3]) -> Result<()> {
        self.mesh_first.push(self.triangles.len() as u32);
        self.colors.push(color);
        Ok(())
    }

    fn triangles(&mut self, triangles: &[[[f32; 3]; 3]]) -> Result<()> {
        for p in triangles.iter().flatten() {
            self.bounds.grow(*p);
        }
        self.triangles.extend_from_slice(triangles);
        Ok(())
    }
}

/// What `Scene::stream` handed on: triangles in all and their bounds.
#[derive(Clone, Copy, Debug)]
pub struct Streamed {
    pub triangles: u64,
    pub bounds: Bounds,
}

impl Scene {
    /// Hands every triangle of the scene to `sink`, in primitive-id order, with the same checks
    /// and errors as `load_model`; generators and mesh files are read in pieces.
    pub fn stream(&self, sink: &mut dyn Sink) -> Result<Streamed> {
        let dir = self.mesh_dir()?;
        let mut out = Placed {
            sink,
            batch: Vec::with_capacity(BATCH),
            total: 0,
            bounds: Bounds::default(),
        };
        for spec in &self.meshes {
            out.sink.mesh(spec.color.unwrap_or(DEFAULT_COLOR))?;
            let place = Placement::of(spec);
            let first = out.total;
            let origin = if let Some(file) = &spec.file {
                let path = dir.join(file);
                let limit = out.sink.vertex_limit();
                super::stream_mesh_file(&path, limit, &mut |positions, triangles| {
                    out.piece(positions, triangles, &place, &path, first)
                })?;
                path
            } else {
                let name = spec.generator.as_deref().unwrap_or_default();
                let g = Generator::parse(name)
                    .ok_or_else(|| Error::Invalid(format!("unknown generator '{name}'")))?;
                let origin = PathBuf::from(format!("<generator {name}>"));
                g.pieces(
                    spec.triangles.unwrap_or(DEFAULT_GENERATOR_TRIANGLES),
                    spec.seed.unwrap_or(1),
                    &mut |mesh| {
                        mesh.validate(&origin)?;
                        out.piece(&mesh.positions, &mesh.triangles, &place, &origin, first)
                    },
                )?;
                origin
            };
            out.flush()?;
            if out.total == first {
                return Err(Error::format(
                    &origin,
                    None,
                    "the mesh has no triangles (no faces read)",
                ));
            }
        }
        if out.total == 0 {
            return Err(Error::format(
                &self.path,
                None,
                "the scene has no triangles",
            ));
        }
        Ok(Streamed {
            triangles: out.total,
            bounds: out.bounds,
        })
    }
}

/// Places pieces' triangles into batches for the sink.
struct Placed<'s> {
    sink: &'s mut dyn Sink,
    batch: Vec<[[f32; 3]; 3]>,
    total: u64,
    bounds: Bounds,
}

impl Placed<'_> {
    /// `triangles` (indices into `positions`, checked by whoever made them), a piece of the mesh
    /// from `origin` whose triangles are numbered from `first` in the scene (errors number them
    /// within their mesh).
    fn piece(
        &mut self,
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
        place: &Placement,
        origin: &Path,
        first: u64,
    ) -> Result<()> {
        for t in triangles {
            if self.total + 1 >= u64::from(u32::MAX) {
                return Err(Error::format(
                    origin,
                    None,
                    "the scene has more than 2^32-1 triangles",
                ));
            }
            let corners = t.map(|v| positions[v as usize]);
            let tri = place.triangle(corners, origin, self.total - first)?;
            for p in &tri {
                self.bounds.grow(*p);
            }
            self.batch.push(tri);
            self.total += 1;
            if self.batch.len() == BATCH {
                self.flush()?;
            }
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        if !self.batch.is_empty() {
            self.sink.triangles(&self.batch)?;
            self.batch.clear();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Streaming into a model gives `load_model`'s model, generators and files alike, with
    /// placement applied.
    #[test]
    fn streaming_gives_the_loaded_model() {
        let dir = std::env::temp_dir().join(format!("dcrt-stream-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("quad.obj"),
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
        )
        .unwrap();
        let text = "[[mesh]]\ngenerator = \"rm\"\ntriangles = 200000\n\
                    [[mesh]]\nfile = \"quad.obj\"\ncolor = [1, 0, 0]\nscale = 2\n\
                    translate = [0, 0, 3]\n\
                    [[mesh]]\ngenerator = \"assembly\"\ntriangles = 50000\nseed = 4\n";
        let path = dir.join("s.toml");
        std::fs::write(&path, text).unwrap();
        let scene = Scene::load(&path).unwrap();
        let whole = scene.load_model().unwrap();
        let mut streamed = Model::default();
        let s = scene.stream(&mut streamed).unwrap();
        let bits = |m: &Model| -> Vec<u32> {
            m.triangles
                .iter()
                .flatten()
                .flatten()
                .map(|c| c.to_bits())
                .collect()
        };
        assert!(bits(&whole) == bits(&streamed), "triangles differ");
        assert_eq!(whole.mesh_first, streamed.mesh_first);
        assert_eq!(whole.colors, streamed.colors);
        assert_eq!(whole.bounds, streamed.bounds);
        assert_eq!(s.bounds, whole.bounds);
        assert_eq!(s.triangles, whole.triangles.len() as u64);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
