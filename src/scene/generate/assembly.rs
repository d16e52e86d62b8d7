//! A stand-in for the Boeing 777 CAD model: a closed fuselage skin with a dense, fully occluded
//! interior of structure (frames, stringers, floor, seats, bins, cargo containers) and systems
//! (pipe and wire bundles with clamps, ducts, equipment boxes with connectors, tanks, brackets and
//! fasteners). From outside only the skin, a few percent of the triangles, is visible.
//!
//! The fuselage is a capsule along x: a cylinder of radius 0.5 over x in [-1.5, 1.5] capped by
//! hemispheres, so x in [-2, 2]. Every part lies strictly inside it: its oriented bounding box
//! fits in the capsule of radius [`PART_RADIUS`] around the same axis.
//!
//! The parts are laid out first, sequentially with a seeded generator (cheap: a few numbers per
//! part), until their exact triangle counts reach the target; then the parts are tessellated in
//! groups of about equal triangle counts, a few groups in parallel at a time, and appended to the
//! mesh in order (or handed on as pieces, `assembly_pieces`).

use super::SplitMix64;
use crate::error::Result;
use crate::scene::mesh::Mesh;
use rayon::prelude::*;
use std::f64::consts::{PI, TAU};

/// Radius of the fuselage skin.
pub const RADIUS: f64 = 0.5;
/// Half the length of its cylindrical part (the caps add RADIUS at each end).
pub const HALF_BODY: f64 = 1.5;
/// Parts stay within this distance of the axis segment, well inside the tessellated skin (whose
/// inscribed radius is at least 0.48).
pub const PART_RADIUS: f64 = 0.46;
/// Share of the target spent on the skin.
const SHELL_SHARE: f64 = 0.025;
/// At most this share of the budget goes to the regular structure; systems fill the rest.
const STRUCTURE_SHARE: f64 = 0.5;
const FLOOR_Z: f64 = -0.12;

/// A closed fuselage full of parts with about `triangles` triangles (within a few percent for
/// targets above ~10,000), deterministic for `(triangles, seed)`. The skin comes first: its
/// vertices and triangles precede every part's.
pub fn assembly(triangles: u64, seed: u64) -> Mesh {
    let built = build(triangles, seed);
    debug_assert!(built.shell_triangles < built.mesh.triangle_count());
    debug_assert!(built.shell_vertices < built.mesh.positions.len());
    built.mesh
}

/// The same model as [`assembly`], handed to `piece` in pieces that are meshes of their own: the
/// skin, then groups of parts, in order; the pieces' triangles, in order, are `assembly`'s. Only
/// a few groups are tessellated at a time, so no whole model is held. An error of `piece` stops
/// the tessellation and is returned.
pub fn assembly_pieces(
    triangles: u64,
    seed: u64,
    piece: &mut dyn FnMut(&Mesh) -> Result<()>,
) -> Result<()> {
    Plan::new(triangles, seed).pieces(piece)
}

struct Built {
    mesh: Mesh,
    shell_vertices: usize,
    shell_triangles: usize,
}

fn build(triangles: u64, seed: u64) -> Built {
    let plan = Plan::new(triangles, seed);
    let (v, t) = plan.totals();
    let mut mesh = Mesh {
        positions: Vec::with_capacity(v),
        triangles: Vec::with_capacity(t),
    };
    let appended = plan.pieces(&mut |piece| {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(&piece.positions);
        let tris = piece.triangles.iter().map(|t| t.map(|i| base + i));
        mesh.triangles.extend(tris);
        Ok(())
    });
    assert!(appended.is_ok(), "{appended:?}");
    Built {
        mesh,
        shell_vertices: plan.shell.vertices(),
        shell_triangles: plan.shell.triangles(),
    }
}

/// The skin and the parts laid out, cut into groups of parts with about equal triangle counts
/// (the pieces that are tessellated in parallel).
struct Plan {
    shell: Shell,
    parts: Vec<Part>,
    /// Group g holds parts `groups[g]..groups[g + 1]`.
    groups: Vec<usize>,
}

impl Plan {
    fn new(triangles: u64, seed: u64) -> Plan {
        let target = triangles.max(1000) as f64;
        let shell = Shell::for_target(target);
        let budget = (target - shell.triangles() as f64).max(0.0) as u64;
        let parts = layout(budget, target, seed);
        let mut triangle_start = Vec::with_capacity(parts.len() + 1);
        let (mut v, mut t) = (shell.vertices() as u64, shell.triangles() as u64);
        for p in &parts {
            triangle_start.push(t);
            let (pv, pt) = p.counts();
            v += pv as u64;
            t += pt as u64;
        }
        assert!(
            v <= u64::from(u32::MAX),
            "too many vertices for 32-bit indices"
        );
        let st = shell.triangles() as u64;
        let count = (parts.len() / 64).clamp(1, 4096);
        let mut groups = vec![0usize];
        for g in 1..count {
            let goal = st + (t - st) * g as u64 / count as u64;
            let at = triangle_start
                .partition_point(|&s| s < goal)
                .min(parts.len());
            if at > *groups.last().unwrap_or(&0) {
                groups.push(at);
            }
        }
        groups.push(parts.len());
        Plan {
            shell,
            parts,
            groups,
        }
    }

    /// Vertices and triangles in all.
    fn totals(&self) -> (usize, usize) {
        let (v, t) = self.parts.iter().map(Part::counts).fold(
            (self.shell.vertices(), self.shell.triangles()),
            |(v, t), (pv, pt)| (v + pv, t + pt),
        );
        (v, t)
    }

    /// Group `g` tessellated as a mesh of its own.
    fn group(&self, g: usize) -> Mesh {
        let parts = &self.parts[self.groups[g]..self.groups[g + 1]];
        let (nv, nt) = parts
            .iter()
            .map(Part::counts)
            .fold((0, 0), |(v, t), (pv, pt)| (v + pv, t + pt));
        let mut m = Mesh {
            positions: vec![[0.0; 3]; nv],
            triangles: vec![[0; 3]; nt],
        };
        let (mut vo, mut to) = (0, 0);
        for part in parts {
            let (pv, pt) = part.counts();
            let (p, q) = (&mut m.positions[vo..vo + pv], &mut m.triangles[to..to + pt]);
            part.write(p, q, vo as u32);
            vo += pv;
            to += pt;
        }
        m
    }

    /// The skin, then the groups in order, a few tessellated in parallel at a time.
    fn pieces(&self, piece: &mut dyn FnMut(&Mesh) -> Result<()>) -> Result<()> {
        let mut skin = Mesh {
            positions: vec![[0.0; 3]; self.shell.vertices()],
            triangles: vec![[0; 3]; self.shell.triangles()],
        };
        self.shell.write(&mut skin.positions, &mut skin.triangles);
        piece(&skin)?;
        drop(skin);
        let window = 2 * rayon::current_num_threads().max(1);
        let groups: Vec<usize> = (0..self.groups.len() - 1).collect();
        for batch in groups.chunks(window) {
            let meshes: Vec<Mesh> = batch.par_iter().map(|&g| self.group(g)).collect();
            for m in &meshes {
                piece(m)?;
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// The skin

/// A capsule tessellated as `seg` meridians by a list of rings (x, radius) between two poles.
struct Shell {
    seg: usize,
    rings: Vec<(f64, f64)>,
}

impl Shell {
    fn for_target(target: f64) -> Self {
        // ~2.9 seg^2 triangles with square-ish quads.
        let seg = ((SHELL_SHARE * target / 2.9).sqrt().round() as usize).clamp(16, 16_384);
        let cap = (seg / 4).max(4);
        let body = ((seg as f64 * 2.0 * HALF_BODY / (TAU * RADIUS)).round() as usize).max(1);
        let mut rings = Vec::with_capacity(2 * cap + body);
        let lat = |i: usize| (PI / 2.0) * i as f64 / cap as f64;
        for i in 1..=cap {
            rings.push((-HALF_BODY - RADIUS * lat(i).cos(), RADIUS * lat(i).sin()));
        }
        for a in 1..=body {
            rings.push((
                -HALF_BODY + 2.0 * HALF_BODY * a as f64 / body as f64,
                RADIUS,
            ));
        }
        for i in (1..cap).rev() {
            rings.push((HALF_BODY + RADIUS * lat(i).cos(), RADIUS * lat(i).sin()));
        }
        Shell { seg, rings }
    }

    fn vertices(&self) -> usize {
        2 + self.seg * self.rings.len()
    }

    fn triangles(&self) -> usize {
        2 * self.seg * self.rings.len()
    }

    fn write(&self, pos: &mut [[f32; 3]], tris: &mut [[u32; 3]]) {
        let seg = self.seg;
        let last = self.rings.len() - 1;
        pos[0] = [(-HALF_BODY - RADIUS) as f32, 0.0, 0.0];
        for (r, &(x, rad)) in self.rings.iter().enumerate() {
            for s in 0..seg {
                let phi = TAU * s as f64 / seg as f64;
                pos[1 + r * seg + s] =
                    [x as f32, (rad * phi.cos()) as f32, (rad * phi.sin()) as f32];
            }
        }
        pos[1 + self.rings.len() * seg] = [(HALF_BODY + RADIUS) as f32, 0.0, 0.0];
        let v = |r: usize, s: usize| (1 + r * seg + s % seg) as u32;
        let north = (1 + self.rings.len() * seg) as u32;
        let mut t = 0;
        for s in 0..seg {
            tris[t] = [0, v(0, s + 1), v(0, s)];
            tris[t + 1] = [north, v(last, s), v(last, s + 1)];
            t += 2;
        }
        for r in 0..last {
            for s in 0..seg {
                tris[t] = [v(r, s), v(r, s + 1), v(r + 1, s + 1)];
                tris[t + 1] = [v(r, s), v(r + 1, s + 1), v(r + 1, s)];
                t += 2;
            }
        }
        debug_assert_eq!(t, tris.len());
    }
}

// ---------------------------------------------------------------------------------------------
// Parts

#[derive(Clone, Copy, Debug)]
enum Shape {
    /// The cube [-1, 1]^3, each face a sub x sub grid.
    Box { sub: u32 },
    /// Radius 1 along local x over [-1, 1], seg around, rings bands along, capped.
    Cylinder { seg: u32, rings: u32 },
    /// The unit sphere, seg meridians, seg / 2 bands from pole (local +z) to pole.
    Sphere { seg: u32 },
}

/// A shape placed by a right-handed orthonormal frame and scaled by `half` along its axes.
#[derive(Clone, Copy, Debug)]
struct Part {
    shape: Shape,
    center: [f64; 3],
    axes: [[f64; 3]; 3],
    half: [f64; 3],
}

const X: [f64; 3] = [1.0, 0.0, 0.0];
const Y: [f64; 3] = [0.0, 1.0, 0.0];
const Z: [f64; 3] = [0.0, 0.0, 1.0];
const IDENTITY: [[f64; 3]; 3] = [X, Y, Z];

/// The frame whose first axis is x and the others turned by `angle` about it.
fn about_x(angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    [X, [0.0, c, s], [0.0, -s, c]]
}

fn sphere_bands(seg: u32) -> u32 {
    (seg / 2).max(2)
}

impl Part {
    fn counts(&self) -> (usize, usize) {
        match self.shape {
            Shape::Box { sub } => {
                let s = sub as usize;
                (6 * (s + 1) * (s + 1), 12 * s * s)
            }
            Shape::Cylinder { seg, rings } => {
                let (s, r) = (seg as usize, rings as usize);
                (s * (r + 1) + 2, 2 * s * (r + 1))
            }
            Shape::Sphere { seg } => {
                let (s, m) = (seg as usize, sphere_bands(seg) as usize);
                (2 + (m - 1) * s, 2 * s * (m - 1))
            }
        }
    }

    fn point(&self, l: [f64; 3]) -> [f64; 3] {
        let mut p = self.center;
        for (a, (&li, &hi)) in self.axes.iter().zip(l.iter().zip(&self.half)) {
            for d in 0..3 {
                p[d] += li * hi * a[d];
            }
        }
        p
    }

    /// Whether the part's bounding box, and so the part, is inside the parts' capsule.
    fn inside(&self) -> bool {
        (0..8).all(|c| {
            let l = [
                if c & 1 == 0 { -1.0 } else { 1.0 },
                if c & 2 == 0 { -1.0 } else { 1.0 },
                if c & 4 == 0 { -1.0 } else { 1.0 },
            ];
            capsule_distance(self.point(l)) < PART_RADIUS
        })
    }

    fn write(&self, pos: &mut [[f32; 3]], tris: &mut [[u32; 3]], base: u32) {
        let mut nv = 0usize;
        let mut put = |pos: &mut [[f32; 3]], l: [f64; 3]| {
            let p = self.point(l);
            pos[nv] = [p[0] as f32, p[1] as f32, p[2] as f32];
            nv += 1;
        };
        let mut nt = 0usize;
        let mut tri = |tris: &mut [[u32; 3]], a: usize, b: usize, c: usize| {
            tris[nt] = [base + a as u32, base + b as u32, base + c as u32];
            nt += 1;
        };
        match self.shape {
            Shape::Box { sub } => {
                let s = sub as usize;
                // (normal, u, v) with u x v = normal.
                let faces: [([f64; 3], [f64; 3], [f64; 3]); 6] = [
                    (X, Y, Z),
                    ([-1.0, 0.0, 0.0], Z, Y),
                    (Y, Z, X),
                    ([0.0, -1.0, 0.0], X, Z),
                    (Z, X, Y),
                    ([0.0, 0.0, -1.0], Y, X),
                ];
                for (f, (n, u, v)) in faces.iter().enumerate() {
                    let first = f * (s + 1) * (s + 1);
                    for b in 0..=s {
                        for a in 0..=s {
                            let (ua, vb) = (
                                2.0 * a as f64 / s as f64 - 1.0,
                                2.0 * b as f64 / s as f64 - 1.0,
                            );
                            put(
                                pos,
                                [
                                    n[0] + ua * u[0] + vb * v[0],
                                    n[1] + ua * u[1] + vb * v[1],
                                    n[2] + ua * u[2] + vb * v[2],
                                ],
                            );
                        }
                    }
                    let g = |a: usize, b: usize| first + b * (s + 1) + a;
                    for b in 0..s {
                        for a in 0..s {
                            tri(tris, g(a, b), g(a + 1, b), g(a + 1, b + 1));
                            tri(tris, g(a, b), g(a + 1, b + 1), g(a, b + 1));
                        }
                    }
                }
            }
            Shape::Cylinder { seg, rings } => {
                let (s, r) = (seg as usize, rings as usize);
                for a in 0..=r {
                    let x = 2.0 * a as f64 / r as f64 - 1.0;
                    for k in 0..s {
                        let phi = TAU * k as f64 / s as f64;
                        put(pos, [x, phi.cos(), phi.sin()]);
                    }
                }
                let (south, north) = (s * (r + 1), s * (r + 1) + 1);
                put(pos, [-1.0, 0.0, 0.0]);
                put(pos, [1.0, 0.0, 0.0]);
                let v = |a: usize, k: usize| a * s + k % s;
                for a in 0..r {
                    for k in 0..s {
                        tri(tris, v(a, k), v(a, k + 1), v(a + 1, k + 1));
                        tri(tris, v(a, k), v(a + 1, k + 1), v(a + 1, k));
                    }
                }
                for k in 0..s {
                    tri(tris, south, v(0, k + 1), v(0, k));
                    tri(tris, north, v(r, k), v(r, k + 1));
                }
            }
            Shape::Sphere { seg } => {
                let (s, m) = (seg as usize, sphere_bands(seg) as usize);
                put(pos, [0.0, 0.0, 1.0]);
                for l in 1..m {
                    let theta = PI * l as f64 / m as f64;
                    for k in 0..s {
                        let phi = TAU * k as f64 / s as f64;
                        put(
                            pos,
                            [
                                theta.sin() * phi.cos(),
                                theta.sin() * phi.sin(),
                                theta.cos(),
                            ],
                        );
                    }
                }
                put(pos, [0.0, 0.0, -1.0]);
                let south = 1 + (m - 1) * s;
                let v = |l: usize, k: usize| 1 + (l - 1) * s + k % s;
                for k in 0..s {
                    tri(tris, 0, v(1, k), v(1, k + 1));
                    tri(tris, south, v(m - 1, k + 1), v(m - 1, k));
                }
                for l in 1..m - 1 {
                    for k in 0..s {
                        tri(tris, v(l, k), v(l + 1, k), v(l + 1, k + 1));
                        tri(tris, v(l, k), v(l + 1, k + 1), v(l, k + 1));
                    }
                }
            }
        }
        debug_assert_eq!((nv, nt), (pos.len(), tris.len()));
    }
}

/// Distance from the fuselage axis segment x in [-HALF_BODY, HALF_BODY].
fn capsule_distance(p: [f64; 3]) -> f64 {
    let dx = (p[0].abs() - HALF_BODY).max(0.0);
    (dx * dx + p[1] * p[1] + p[2] * p[2]).sqrt()
}

// ---------------------------------------------------------------------------------------------
// Layout

/// Collects parts, counting triangles, and stops taking them once the budget is reached.
struct Layout {
    parts: Vec<Part>,
    triangles: u64,
    budget: u64,
    rng: SplitMix64,
    /// Tessellation level: 1 at 10k triangles, ~4 at 100M.
    q: f64,
}

impl Layout {
    fn full(&self) -> bool {
        self.triangles >= self.budget
    }

    /// Adds the part if it is inside the fuselage (and the budget is not spent).
    fn add(&mut self, part: Part) -> bool {
        if self.full() || !part.inside() {
            return false;
        }
        self.triangles += part.counts().1 as u64;
        self.parts.push(part);
        true
    }

    fn boxed(&mut self, center: [f64; 3], axes: [[f64; 3]; 3], half: [f64; 3], sub: u32) -> bool {
        self.add(Part {
            shape: Shape::Box { sub: sub.max(1) },
            center,
            axes,
            half,
        })
    }

    /// A cylinder of `radius` along `axes[0]`, `half_length` each side of `center`.
    fn cylinder(
        &mut self,
        center: [f64; 3],
        axes: [[f64; 3]; 3],
        half_length: f64,
        radius: f64,
        seg_base: f64,
    ) -> bool {
        let seg = (seg_base * self.q).round().max(6.0) as u32;
        // Bands about as long as the facets are wide, a few at least for long parts.
        let facet = TAU * radius / f64::from(seg);
        let rings =
            ((2.0 * half_length / facet / 4.0).round() as u32).clamp(1, (16.0 * self.q) as u32);
        self.add(Part {
            shape: Shape::Cylinder { seg, rings },
            center,
            axes,
            half: [half_length, radius, radius],
        })
    }

    fn sphere(
        &mut self,
        center: [f64; 3],
        axes: [[f64; 3]; 3],
        half: [f64; 3],
        seg_base: f64,
    ) -> bool {
        let seg = (seg_base * self.q).round().max(8.0) as u32;
        self.add(Part {
            shape: Shape::Sphere { seg },
            center,
            axes,
            half,
        })
    }

    fn r(&mut self, lo: f64, hi: f64) -> f64 {
        self.rng.range(lo, hi)
    }
}

fn layout(budget: u64, target: f64, seed: u64) -> Vec<Part> {
    let q = (target / 1e4).powf(0.15).clamp(1.0, 8.0);
    // The regular structure at a scale that fits its share of the budget.
    let mut scale = 1.0;
    let mut parts = Vec::new();
    let mut triangles = 0;
    for _ in 0..6 {
        let mut l = Layout {
            parts: Vec::new(),
            triangles: 0,
            budget: u64::MAX,
            rng: SplitMix64::new(seed ^ 0x7374_7275_6374),
            q,
        };
        structure(&mut l, scale);
        parts = l.parts;
        triangles = l.triangles;
        let share = STRUCTURE_SHARE * budget as f64;
        if triangles as f64 <= share || scale < 0.02 {
            break;
        }
        scale *= 0.95 * share / triangles as f64;
    }
    let mut l = Layout {
        parts,
        triangles,
        budget,
        rng: SplitMix64::new(seed ^ 0x7379_7374_656d),
        q,
    };
    let mut idle = 0;
    while !l.full() && idle < 1000 {
        let before = l.triangles;
        system(&mut l);
        idle = if l.triangles == before { idle + 1 } else { 0 };
    }
    l.parts
}

/// Frames, stringers, floor, seats, bins and cargo containers; `scale` thins their counts.
fn structure(l: &mut Layout, scale: f64) {
    let q = l.q;
    let count = |full: f64, min: usize| ((full * scale).round() as usize).max(min);
    let sub = (q / 2.0).round().max(1.0) as u32;

    // Frames: rings of curved-beam segments at regular stations, smaller ones in the caps.
    let frames = count(56.0, 3);
    let bay = 2.0 * HALF_BODY / frames as f64;
    let frame_segments = (24.0 * q.sqrt()).round() as usize;
    let mut stations: Vec<(f64, f64)> = (0..frames)
        .map(|f| (-HALF_BODY + (f as f64 + 0.5) * bay, 0.44))
        .collect();
    for m in 1..=count(3.0, 1) {
        let dx = 0.11 * m as f64;
        let r = (0.44f64.powi(2) - dx * dx).sqrt();
        stations.push((-HALF_BODY - dx, r));
        stations.push((HALF_BODY + dx, r));
    }
    for &(x, r) in &stations {
        let half_chord = PI * r / frame_segments as f64 * 1.02;
        for s in 0..frame_segments {
            let phi = TAU * (s as f64 + 0.5) / frame_segments as f64;
            let axes = about_x(phi);
            let c = [x, r * phi.cos(), r * phi.sin()];
            l.boxed(
                c,
                [axes[0], axes[1], axes[2]],
                [0.006, 0.014, half_chord],
                sub,
            );
        }
    }

    // Stringers along the cylindrical part, just inside the frames.
    let stringers = count(40.0, 4);
    for s in 0..stringers {
        let phi = TAU * (s as f64 + 0.25) / stringers as f64;
        let c = [0.0, 0.42 * phi.cos(), 0.42 * phi.sin()];
        l.cylinder(c, about_x(phi), HALF_BODY - 0.02, 0.006, 5.0);
    }

    // Floor: a beam at each frame, a panel over each bay, posts below.
    let half_width = (0.44f64 * 0.44 - FLOOR_Z * FLOOR_Z).sqrt() - 0.03;
    for f in 0..frames {
        let x = -HALF_BODY + (f as f64 + 0.5) * bay;
        l.boxed(
            [x, 0.0, FLOOR_Z - 0.02],
            IDENTITY,
            [0.007, half_width, 0.018],
            sub,
        );
        l.boxed(
            [x + bay / 2.0, 0.0, FLOOR_Z + 0.002],
            IDENTITY,
            [bay / 2.0 - 0.002, half_width, 0.003],
            sub,
        );
        for side in [-1.0, 1.0] {
            let c = [x, side * 0.2, FLOOR_Z - 0.14];
            l.cylinder([c[0], c[1], c[2]], [Z, X, Y], 0.1, 0.006, 5.0);
        }
    }

    // Seats: rows of 3-4-3 over the cabin, each a pan, a back, two legs and an armrest.
    let rows = count(30.0, 2);
    let pitch = 2.6 / rows as f64;
    let seat_y: Vec<f64> = [
        -0.30, -0.24, -0.18, -0.09, -0.03, 0.03, 0.09, 0.18, 0.24, 0.30,
    ]
    .to_vec();
    let seats = count(10.0, 2).min(10);
    for row in 0..rows {
        let x = -1.3 + (row as f64 + 0.5) * pitch;
        for &y in seat_y.iter().take(seats) {
            let z = FLOOR_Z + 0.07;
            l.boxed([x, y, z], IDENTITY, [0.025, 0.027, 0.006], 1);
            l.boxed(
                [x + 0.026, y, z + 0.045],
                IDENTITY,
                [0.005, 0.027, 0.045],
                sub,
            );
            for dy in [-0.02, 0.02] {
                l.boxed(
                    [x, y + dy, FLOOR_Z + 0.035],
                    IDENTITY,
                    [0.003, 0.003, 0.032],
                    1,
                );
            }
            l.cylinder([x, y + 0.028, z + 0.02], IDENTITY, 0.022, 0.003, 5.0);
        }
    }

    // Overhead bins over each bay on both sides.
    for f in 0..frames {
        let x = -HALF_BODY + (f as f64 + 0.5) * bay + bay / 2.0;
        for side in [-1.0, 1.0] {
            l.boxed(
                [x, side * 0.3, 0.2],
                about_x(side * 0.3),
                [bay / 2.0 - 0.004, 0.05, 0.04],
                sub,
            );
        }
    }

    // Cargo containers in the lower lobe.
    let containers = count(22.0, 1);
    let step = 2.4 / containers as f64;
    for c in 0..containers {
        let x = -1.2 + (c as f64 + 0.5) * step;
        let h = [step / 2.0 - 0.01, 0.11, 0.075];
        l.boxed([x, 0.0, -0.31], IDENTITY, h, sub);
    }
}

/// One random cluster of system parts.
fn system(l: &mut Layout) {
    let kind = l.rng.below(100);
    let x = l.r(-1.95, 1.95);
    match kind {
        0..=29 => pipe_bundle(l, x),
        30..=49 => equipment(l, x),
        50..=59 => tank(l, x),
        60..=84 => brackets(l, x),
        _ => duct(l, x),
    }
}

/// A point at angle `phi` (from +y towards +z) and distance `r` from the axis.
fn polar(x: f64, phi: f64, r: f64) -> [f64; 3] {
    [x, r * phi.cos(), r * phi.sin()]
}

/// Parallel pipes in segments along x, with a clamp every so often.
fn pipe_bundle(l: &mut Layout, x: f64) {
    // Crown, lower lobe or sidewalls.
    let phi = match l.rng.below(3) {
        0 => l.r(0.35, 0.65) * PI,
        1 => l.r(1.25, 1.75) * PI,
        _ => {
            if l.rng.below(2) == 0 {
                l.r(-0.15, 0.15) * PI
            } else {
                l.r(0.85, 1.15) * PI
            }
        }
    };
    let r = l.r(0.3, 0.39);
    let pipes = 1 + l.rng.below(6) as usize;
    let radius = l.r(0.003, 0.011);
    let length = l.r(0.15, 1.4);
    let segments = ((length / 0.2).ceil() as usize).max(1);
    let seg_len = length / segments as f64;
    let axes = about_x(phi);
    let centre = polar(0.0, phi, r);
    for p in 0..pipes {
        let (du, dv) = ((p % 3) as f64 - 1.0, (p / 3) as f64);
        let off = [
            0.0,
            centre[1] + 2.6 * radius * (du * axes[2][1] + dv * axes[1][1]),
            centre[2] + 2.6 * radius * (du * axes[2][2] + dv * axes[1][2]),
        ];
        for s in 0..segments {
            let cx = x + (s as f64 + 0.5) * seg_len - length / 2.0;
            l.cylinder(
                [cx, off[1], off[2]],
                axes,
                seg_len / 2.0 - 0.002,
                radius,
                4.0,
            );
        }
    }
    for s in 0..=segments {
        let cx = x + s as f64 * seg_len - length / 2.0;
        let w = 1.6 * radius * 3.0;
        l.boxed(
            [cx, centre[1], centre[2]],
            axes,
            [0.004, 2.0 * radius + 0.004, w + 0.004],
            1,
        );
        let foot = [
            cx,
            centre[1] + (2.0 * radius + 0.01) * axes[1][1],
            centre[2] + (2.0 * radius + 0.01) * axes[1][2],
        ];
        l.boxed(foot, axes, [0.008, 0.006, 0.012], 1);
    }
}

/// A box with connectors on top and mounting brackets.
fn equipment(l: &mut Layout, x: f64) {
    let sub = (l.q * 0.75).round().max(1.0) as u32;
    let half = [l.r(0.02, 0.07), l.r(0.02, 0.06), l.r(0.015, 0.05)];
    let (y, z) = match l.rng.below(3) {
        0 => (l.r(-0.25, 0.25), l.r(-0.32, -0.2)),
        1 => (l.r(-0.2, 0.2), l.r(0.26, 0.36)),
        _ => (l.r(-0.35, 0.35), l.r(-0.1, 0.15)),
    };
    let axes = about_x(l.r(-0.3, 0.3));
    let c = [x, y, z];
    if !l.boxed(c, axes, half, sub) {
        return;
    }
    let connectors = 2 + l.rng.below(5) as usize;
    for k in 0..connectors {
        let u = -half[0] * 0.8 + 1.6 * half[0] * (k as f64 + 0.5) / connectors as f64;
        let r = l.r(0.003, 0.008);
        let len = l.r(0.006, 0.02);
        let along = half[2] + len;
        let p = [
            c[0] + u,
            c[1] + along * axes[2][1],
            c[2] + along * axes[2][2],
        ];
        l.cylinder(p, [axes[2], axes[0], axes[1]], len, r, 4.0);
    }
    for side in [-1.0, 1.0] {
        let p = [
            c[0] + side * (half[0] + 0.006),
            c[1],
            c[2] - half[2] * axes[2][2],
        ];
        l.boxed(p, axes, [0.005, half[1] * 0.8, 0.004], 1);
    }
}

/// A spherical or capsule-shaped tank on a saddle.
fn tank(l: &mut Layout, x: f64) {
    let r = l.r(0.03, 0.08);
    let (y, z) = (l.r(-0.2, 0.2), l.r(-0.34, -0.18));
    if l.rng.below(2) == 0 {
        l.sphere([x, y, z], IDENTITY, [r, r, r], 10.0);
    } else {
        let half = l.r(0.05, 0.15);
        if l.cylinder([x, y, z], IDENTITY, half, r, 8.0) {
            for side in [-1.0, 1.0] {
                l.sphere([x + side * half, y, z], IDENTITY, [r * 0.6, r, r], 10.0);
            }
        }
    }
    l.boxed(
        [x, y, z - r - 0.006],
        IDENTITY,
        [r * 0.8, r * 0.7, 0.006],
        1,
    );
}

/// L-brackets with bolts at a frame.
fn brackets(l: &mut Layout, x: f64) {
    let count = 1 + l.rng.below(4) as usize;
    let phi0 = l.r(0.0, TAU);
    for b in 0..count {
        let phi = phi0 + 0.08 * b as f64;
        let axes = about_x(phi);
        let r = l.r(0.38, 0.42);
        let c = polar(x, phi, r);
        let (w, h) = (l.r(0.008, 0.02), l.r(0.01, 0.03));
        if !l.boxed(c, axes, [0.003, h, w], 1) {
            continue;
        }
        let foot = polar(x + 0.01, phi, r - h + 0.003);
        l.boxed(foot, axes, [0.01, 0.003, w], 1);
        for k in [-0.5, 0.5] {
            let bolt = polar(x, phi + k * w / r, r + h * 0.4);
            l.cylinder(bolt, axes, 0.006, 0.002, 3.0);
        }
    }
}

/// A large duct along x with elbows at its ends.
fn duct(l: &mut Layout, x: f64) {
    let phi = l.r(0.3, 0.7) * PI;
    let radius = l.r(0.015, 0.035);
    let r = l.r(0.3, 0.4 - radius);
    let half = l.r(0.1, 0.5);
    let c = polar(x, phi, r);
    if l.cylinder(c, about_x(phi), half, radius, 8.0) {
        for side in [-1.0, 1.0] {
            let e = [c[0] + side * half, c[1], c[2]];
            l.sphere(e, IDENTITY, [radius; 3], 8.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;
    use std::path::Path;

    #[test]
    fn deterministic_per_seed() {
        let (a, b, c) = (
            assembly(50_000, 5),
            assembly(50_000, 5),
            assembly(50_000, 6),
        );
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
        assert!(a.positions != c.positions || a.triangles != c.triangles);
    }

    fn signed_volume(m: &Mesh, tris: std::ops::Range<usize>) -> f64 {
        tris.map(|i| {
            let c = m.corners(i).map(|p| p.map(f64::from));
            (c[0][0] * (c[1][1] * c[2][2] - c[1][2] * c[2][1])
                - c[0][1] * (c[1][0] * c[2][2] - c[1][2] * c[2][0])
                + c[0][2] * (c[1][0] * c[2][1] - c[1][1] * c[2][0]))
                / 6.0
        })
        .sum()
    }

    #[test]
    fn shell_is_closed_and_faces_out() {
        for target in [10_000, 300_000] {
            let b = build(target, 2);
            let m = &b.mesh;
            let mut edges = HashMap::new();
            for t in &m.triangles[..b.shell_triangles] {
                for k in 0..3 {
                    assert!((t[k] as usize) < b.shell_vertices);
                    *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
                }
            }
            for (&(a, c), &n) in &edges {
                assert_eq!(n, 1, "shell edge {a}-{c} repeated");
                assert_eq!(edges.get(&(c, a)), Some(&1), "shell edge {a}-{c} open");
            }
            let capsule = PI * RADIUS * RADIUS * 2.0 * HALF_BODY + 4.0 / 3.0 * PI * RADIUS.powi(3);
            let v = signed_volume(m, 0..b.shell_triangles);
            assert!(v > 0.95 * capsule && v <= capsule, "{v} vs {capsule}");
            let share = b.shell_triangles as f64 / m.triangle_count() as f64;
            assert!(share < 0.1, "shell share {share}");
            if target >= 100_000 {
                assert!(share > 0.01 && share < 0.05, "shell share {share}");
            }
        }
    }

    #[test]
    fn parts_stay_strictly_inside() {
        let b = build(200_000, 3);
        let m = &b.mesh;
        m.validate(Path::new("assembly")).unwrap();
        for (i, p) in m.positions.iter().enumerate() {
            let q = p.map(f64::from);
            assert!(
                q[0].abs() <= HALF_BODY + RADIUS && q[1].abs() <= RADIUS && q[2].abs() <= RADIUS
            );
            let d = capsule_distance(q);
            if i < b.shell_vertices {
                assert!((d - RADIUS).abs() < 1e-6, "shell vertex {i} at {d}");
            } else {
                assert!(d < PART_RADIUS + 1e-6, "part vertex {i} at {d}: {p:?}");
            }
        }
        // The tessellated skin's inscribed capsule still clears the parts.
        let seg = Shell::for_target(200_000.0).seg as f64;
        assert!(PART_RADIUS < RADIUS * (PI / seg).cos() * (PI / 16.0).cos());
        // Most triangles are inside.
        assert!(b.shell_triangles * 10 < m.triangle_count());
    }

    #[test]
    fn no_repeated_indices_or_degenerate_triangles() {
        let m = assembly(100_000, 4);
        for i in 0..m.triangle_count() {
            let t = m.triangles[i];
            assert!(
                t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
                "triangle {i}: {t:?}"
            );
            let c = m.corners(i).map(|p| p.map(f64::from));
            let e1 = [c[1][0] - c[0][0], c[1][1] - c[0][1], c[1][2] - c[0][2]];
            let e2 = [c[2][0] - c[0][0], c[2][1] - c[0][1], c[2][2] - c[0][2]];
            let n = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            assert!(n.iter().any(|&x| x != 0.0), "triangle {i} has no area");
        }
    }

    /// Each shape is a closed surface facing out: its signed volume is positive and close to the
    /// solid's.
    #[test]
    fn shapes_face_out() {
        let axes = about_x(0.7);
        let half = [0.3, 0.2, 0.1];
        let cases = [
            (Shape::Box { sub: 3 }, 8.0 * 0.3 * 0.2 * 0.1),
            (Shape::Cylinder { seg: 48, rings: 3 }, PI * 0.2 * 0.1 * 0.6),
            (Shape::Sphere { seg: 48 }, 4.0 / 3.0 * PI * 0.3 * 0.2 * 0.1),
        ];
        for (shape, exact) in cases {
            let part = Part {
                shape,
                center: [0.1, -0.2, 0.05],
                axes,
                half,
            };
            let (nv, nt) = part.counts();
            let mut m = Mesh {
                positions: vec![[0.0; 3]; nv],
                triangles: vec![[0; 3]; nt],
            };
            part.write(&mut m.positions, &mut m.triangles, 0);
            m.validate(Path::new("part")).unwrap();
            let v = signed_volume(&m, 0..nt);
            assert!((v / exact - 1.0).abs() < 0.02, "{shape:?}: {v} vs {exact}");
        }
    }

    #[test]
    fn detail_and_count_grow_with_target() {
        let small = layout(20_000, 20_000.0, 1);
        let large = layout(2_000_000, 2_000_000.0, 1);
        assert!(large.len() > 10 * small.len());
        let mean =
            |p: &[Part]| p.iter().map(|p| p.counts().1).sum::<usize>() as f64 / p.len() as f64;
        assert!(mean(&large) > 1.5 * mean(&small));
    }
}
