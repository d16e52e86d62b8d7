// TEMPORARY stub until the generators land.
use crate::scene::mesh::Mesh;
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Generator {
    Rm,
    Assembly,
}
pub struct View {
    pub position: [f64; 3],
    pub focal_point: [f64; 3],
    pub view_up: [f64; 3],
    pub view_angle: f64,
}
impl Generator {
    pub const NAMES: &'static [&'static str] = &["rm", "assembly"];
    pub fn parse(n: &str) -> Option<Generator> {
        match n {
            "rm" => Some(Generator::Rm),
            "assembly" => Some(Generator::Assembly),
            _ => None,
        }
    }
    pub fn name(&self) -> &'static str {
        match self {
            Generator::Rm => "rm",
            Generator::Assembly => "assembly",
        }
    }
    pub fn generate(&self, triangles: u64, _seed: u64) -> Mesh {
        // a grid of bumps
        let n = ((triangles as f64 / 2.0).sqrt() as u32).max(1);
        let mut m = Mesh::default();
        for j in 0..=n {
            for i in 0..=n {
                let x = i as f32 / n as f32 * 2.0 - 1.0;
                let y = j as f32 / n as f32 * 2.0 - 1.0;
                m.positions
                    .push([x, y, 0.2 * (5.0 * x).sin() * (4.0 * y).cos()]);
            }
        }
        for j in 0..n {
            for i in 0..n {
                let a = j * (n + 1) + i;
                m.triangles.push([a, a + 1, a + n + 2]);
                m.triangles.push([a, a + n + 2, a + n + 1]);
            }
        }
        m
    }
    pub fn default_view(&self) -> View {
        View {
            position: [0.0, -2.2, 1.8],
            focal_point: [0.0; 3],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 40.0,
        }
    }
}
