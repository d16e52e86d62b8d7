//! Procedural stand-ins for the two massive models of Ize, Brownlee & Hansen (EGPGV 2011): a
//! Richtmyer-Meshkov mixing-layer isosurface ([`rm`]) and an occluded CAD assembly in the manner
//! of the Boeing 777 ([`assembly`]). Both take a target triangle count and a seed, are
//! deterministic for the pair, and scale from thousands to hundreds of millions of triangles.

pub mod assembly;
pub mod rm;

pub use assembly::{assembly, assembly_pieces};
pub use rm::{rm, rm_pieces};

use crate::error::Result;
use crate::scene::mesh::Mesh;

/// A named procedural model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Generator {
    /// The crumpled isosurface of a synthetic Richtmyer-Meshkov mixing layer (see [`rm`]).
    Rm,
    /// A closed fuselage shell full of structural and system parts (see [`assembly`]).
    Assembly,
}

/// A camera: where it is, what it looks at, which way is up, and the vertical field of view in
/// degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub position: [f64; 3],
    pub focal_point: [f64; 3],
    pub view_up: [f64; 3],
    pub view_angle: f64,
}

impl Generator {
    /// Every generator, in the order they are listed to the user.
    pub const ALL: [Generator; 2] = [Generator::Rm, Generator::Assembly];
    /// The names scene files use.
    pub const NAMES: [&'static str; 2] = ["rm", "assembly"];

    /// The generator called `name` (case-insensitive; `rm`, `richtmyer-meshkov`, `assembly`,
    /// `boeing`), if any.
    pub fn parse(name: &str) -> Option<Generator> {
        match name.trim().to_ascii_lowercase().as_str() {
            "rm" | "richtmyer-meshkov" | "richtmyer_meshkov" => Some(Generator::Rm),
            "assembly" | "boeing" | "cad" => Some(Generator::Assembly),
            _ => None,
        }
    }

    /// The canonical name, which [`Generator::parse`] accepts.
    pub fn name(&self) -> &'static str {
        match self {
            Generator::Rm => "rm",
            Generator::Assembly => "assembly",
        }
    }

    /// A mesh of about `triangles` triangles (within a few percent above 10,000), the same for
    /// the same `(triangles, seed)`.
    pub fn generate(&self, triangles: u64, seed: u64) -> Mesh {
        match self {
            Generator::Rm => rm(triangles, seed),
            Generator::Assembly => assembly(triangles, seed),
        }
    }

    /// The same model as `generate`, handed to `piece` in pieces that are meshes of their own,
    /// in order (their triangles, in order, are `generate`'s), never holding the whole model. An
    /// error of `piece` stops the generator and is returned.
    pub fn pieces(
        &self,
        triangles: u64,
        seed: u64,
        piece: &mut dyn FnMut(&Mesh) -> Result<()>,
    ) -> Result<()> {
        match self {
            Generator::Rm => rm_pieces(triangles, seed, piece),
            Generator::Assembly => assembly_pieces(triangles, seed, piece),
        }
    }

    /// A camera that shows the whole model: the RM surface from above at an angle, the fuselage
    /// obliquely from outside.
    pub fn default_view(&self) -> View {
        match self {
            Generator::Rm => View {
                position: [0.0, -2.2, 1.8],
                focal_point: [0.0, -0.2, -0.05],
                view_up: [0.0, 0.0, 1.0],
                view_angle: 40.0,
            },
            Generator::Assembly => View {
                position: [3.4, -4.6, 2.3],
                focal_point: [0.0, 0.0, 0.0],
                view_up: [0.0, 0.0, 1.0],
                view_angle: 26.0,
            },
        }
    }
}

/// SplitMix64 (Steele, Lea & Flood): a tiny, fast, well-mixed generator; enough for placing
/// parts and drawing field parameters, and identical on every platform.
#[derive(Clone, Debug)]
pub(crate) struct SplitMix64(u64);

impl SplitMix64 {
    pub(crate) fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    pub(crate) fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in 0..n (n > 0).
    pub(crate) fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.next_u64()) * u128::from(n)) >> 64) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_are_near_the_target() {
        for g in Generator::ALL {
            for target in [10_000u64, 100_000, 1_000_000] {
                let m = g.generate(target, 1);
                m.validate(std::path::Path::new(g.name())).unwrap();
                let r = m.triangle_count() as f64 / target as f64;
                assert!(
                    (0.75..=1.25).contains(&r),
                    "{} at {target}: ratio {r}",
                    g.name()
                );
            }
        }
    }

    /// The pieces, in order, hold the whole model's triangles corner for corner; the larger
    /// targets come in several pieces.
    #[test]
    fn pieces_are_the_model_in_order() {
        for g in Generator::ALL {
            for target in [5_000u64, 300_000] {
                let whole = g.generate(target, 3);
                let bits = |c: [[f32; 3]; 3]| c.map(|p| p.map(f32::to_bits));
                let want: Vec<_> = (0..whole.triangle_count())
                    .map(|i| bits(whole.corners(i)))
                    .collect();
                let (mut got, mut pieces) = (Vec::new(), 0);
                g.pieces(target, 3, &mut |m| {
                    m.validate(std::path::Path::new(g.name()))?;
                    got.extend((0..m.triangle_count()).map(|i| bits(m.corners(i))));
                    pieces += 1;
                    Ok(())
                })
                .unwrap();
                assert!(got == want, "{} at {target}: pieces differ", g.name());
                if target >= 300_000 {
                    assert!(pieces > 4, "{} at {target}: {pieces} pieces", g.name());
                }
            }
        }
    }

    #[test]
    fn parse_and_name_round_trip() {
        for g in Generator::ALL {
            assert_eq!(Generator::parse(g.name()), Some(g));
        }
        assert_eq!(Generator::parse("RM"), Some(Generator::Rm));
        assert_eq!(Generator::parse("Boeing"), Some(Generator::Assembly));
        assert_eq!(Generator::parse("bunny"), None);
    }

    #[test]
    fn default_views_are_sane() {
        for g in Generator::ALL {
            let v = g.default_view();
            let d: Vec<f64> = (0..3).map(|i| v.focal_point[i] - v.position[i]).collect();
            let len = d.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!(len > 1.0, "{}: camera too close", g.name());
            assert!(v.view_angle > 5.0 && v.view_angle < 90.0);
            // view_up is not parallel to the view direction
            let c = [
                d[1] * v.view_up[2] - d[2] * v.view_up[1],
                d[2] * v.view_up[0] - d[0] * v.view_up[2],
                d[0] * v.view_up[1] - d[1] * v.view_up[0],
            ];
            assert!(c.iter().map(|c| c * c).sum::<f64>().sqrt() > 0.1 * len);
        }
    }

    #[test]
    fn generate_dispatches() {
        for g in Generator::ALL {
            let m = g.generate(10_000, 1);
            assert!(m.triangle_count() > 5_000, "{}", g.name());
            m.validate(std::path::Path::new(g.name())).unwrap();
        }
    }

    #[test]
    fn rng_is_deterministic_and_uniform_enough() {
        let mut a = SplitMix64::new(7);
        let mut b = SplitMix64::new(7);
        let mut sum = 0.0;
        for _ in 0..10_000 {
            let x = a.unit();
            assert_eq!(x, b.unit());
            assert!((0.0..1.0).contains(&x));
            sum += x;
        }
        assert!((sum / 10_000.0 - 0.5).abs() < 0.02);
        assert!((0..1000).all(|_| a.below(7) < 7));
    }
}
