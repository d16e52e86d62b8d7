//! Every CPU twin in `dcrt::mirror` against its WGSL function, run on the GPU through the
//! `mirror` kernel: integer functions bit for bit, float ones within the precision WGSL allows.

use crate::common::*;
use dcrt::blocks::ranks::Ranks;
use dcrt::bvh::Node;
use dcrt::dc::{CacheMap, cache_line};
use dcrt::gpu::layout::{MirrorCase, Params, flags};
use dcrt::gpu::probe::run_mirror;
use dcrt::mirror::colormap::{bin, colormap, srgb_color};
use dcrt::mirror::offset::offset_ray_with;
use dcrt::mirror::sampling::{cosine_dir, hash, sample2, sample2_patch};
use dcrt::mirror::tiles::{TILE, Tiling, tile_pixel};
use dcrt::shading::Sampler;

/// Test inputs: coordinates, normals and samples.
trait Cases {
    fn unit(&mut self) -> f32;
    fn coord(&mut self) -> f32;
    fn normal(&mut self) -> [f32; 3];
}

impl Cases for Rng {
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Log-uniform magnitude over 1e-8..1e8 with a random sign, or an exact small value.
    fn coord(&mut self) -> f32 {
        match self.next() % 8 {
            0 => 0.0,
            1 => 0.02 * (self.unit() - 0.5),
            _ => {
                let m = 10f32.powf(16.0 * self.unit() - 8.0);
                if self.next().is_multiple_of(2) { m } else { -m }
            }
        }
    }
    fn normal(&mut self) -> [f32; 3] {
        loop {
            let v = [0; 3].map(|_| 2.0 * self.unit() - 1.0);
            let l = v.iter().map(|c| c * c).sum::<f32>().sqrt();
            if l > 0.1 && l <= 1.0 {
                return v.map(|c| c / l);
            }
        }
    }
}

fn cases(n: usize) -> Vec<MirrorCase> {
    let mut m = Rng(42);
    (0..n)
        .map(|_| {
            let n3 = m.normal();
            // Offset distances from zero to far beyond the coordinates' ulps.
            let d = match m.next() % 4 {
                0 => 0.0,
                _ => 10f32.powf(16.0 * m.unit() - 9.0),
            };
            MirrorCase {
                p: [m.coord(), m.coord(), m.coord(), d],
                n: [n3[0], n3[1], n3[2], 0.0],
                u: [m.unit(), m.unit(), 0.0, 0.0],
                words: [
                    m.next() as u32,
                    m.next() as u32,
                    (m.next() % 64) as u32,
                    m.next() as u32,
                ],
                node: [0; 16],
                c: [0.0; 4],
            }
        })
        .collect()
}

fn params() -> Params {
    Params {
        seed: 0xdead_beef,
        // sample2_patch's row length: the case's pixels are any u32.
        width: 1000,
        // A rectangle 3 x 30 tiles in bands 2 wide: the slots run into the second band, which
        // goes bottom to top.
        first_tile: 5,
        tiles_x: 3,
        rect_h: 30 * TILE - 3,
        band_tiles: 2,
        ..Params::default()
    }
}

#[test]
fn integer_twins_match_the_gpu_bit_for_bit() {
    let gpu = gpu();
    let mut cases = cases(4096);
    // Small sample indices too (the first samples of a render), and the top of the range.
    for (i, c) in cases.iter_mut().enumerate().take(1024) {
        c.words[3] = if i < 768 {
            i as u32
        } else {
            u32::MAX - i as u32
        };
    }
    for (sampler, flag) in [
        (Sampler::Sobol, 0),
        (Sampler::Independent, flags::SAMPLER_INDEPENDENT),
    ] {
        let p = Params {
            flags: flag | flags::JITTER,
            ..params()
        };
        let out = run_mirror(&gpu, &p, &cases, &[]).unwrap();
        assert_eq!(out.len(), cases.len());
        for (i, (c, r)) in cases.iter().zip(&out).enumerate() {
            assert_eq!(r.words[0], hash(c.words[0]), "hash, case {i}");
            let s = sample2(sampler, p.seed, c.words[1], c.words[2], c.words[3]);
            assert_eq!(
                [r.sample[0].to_bits(), r.sample[1].to_bits()],
                s.map(f32::to_bits),
                "sample2 {sampler:?}, case {i}"
            );
            let s = sample2_patch(sampler, p.seed, c.words[1], p.width, c.words[2], c.words[3]);
            assert_eq!(
                [r.patched[0].to_bits(), r.patched[1].to_bits()],
                s.map(f32::to_bits),
                "sample2_patch {sampler:?}, case {i}"
            );
            let tiling = Tiling {
                tiles_x: p.tiles_x,
                tiles_y: p.rect_h.div_ceil(TILE),
                band: p.band_tiles,
            };
            let t = tile_pixel(p.first_tile, tiling, i as u32);
            assert_eq!((r.words[1], r.words[2]), t, "tile_pixel, slot {i}");
        }
    }
}

#[test]
fn cache_line_matches_the_gpu_for_both_mappings() {
    let gpu = gpu();
    let cases = cases(4096);
    for (map, code) in [
        (CacheMap::Ize, 0),
        (CacheMap::Demarle, 1),
        (CacheMap::Lru, 1),
    ] {
        for (n, rank, lines) in [(1, 0, 7), (3, 1, 64), (8, 5, 1000), (5, 4, 1)] {
            let p = Params {
                dc_ranks: n,
                dc_rank: rank,
                dc_lines: lines,
                dc_map: code,
                ..params()
            };
            let out = run_mirror(&gpu, &p, &cases, &[]).unwrap();
            let ranks = Ranks::new(n, rank).unwrap();
            for (c, r) in cases.iter().zip(&out) {
                // Blocks the rank owns never reach the cache; the formula is checked for all.
                let k = c.words[0] >> 2;
                let want = cache_line(map, ranks, lines, k);
                assert_eq!(
                    r.words[3], want,
                    "cache_line({k}) {map:?} n{n} r{rank} l{lines}"
                );
            }
        }
    }
}

#[test]
fn offset_ray_matches_the_gpu_bit_for_bit() {
    // One multiply and one add (or one fused multiply-add, where the GPU compiler contracts
    // them), then a step of one float: exact in IEEE f32 on both sides.
    let gpu = gpu();
    let cases = cases(4096);
    let out = run_mirror(&gpu, &params(), &cases, &[]).unwrap();
    for (i, (c, r)) in cases.iter().zip(&out).enumerate() {
        let (p, d) = ([c.p[0], c.p[1], c.p[2]], c.p[3]);
        let n = [c.n[0], c.n[1], c.n[2]];
        let gpu: [u32; 3] = std::array::from_fn(|a| r.offset[a].to_bits());
        let plain = offset_ray_with(p, n, d, false).map(f32::to_bits);
        let fused = offset_ray_with(p, n, d, true).map(f32::to_bits);
        assert!(
            gpu == plain || gpu == fused,
            "offset_ray({p:?}, {n:?}, {d}), case {i}: GPU {gpu:?}, CPU {plain:?} or {fused:?}"
        );
    }
}

/// Quantized child boxes decode on the GPU exactly as `Node::child_box` decodes them, and contain
/// the exact boxes they were made from: traversal is conservative at every scale. Nodes of four
/// boxes around centres log-uniform over 1e-8..1e8 with random signs, extents from zero (flat)
/// to far beyond the centre's magnitude.
#[test]
fn child_box_matches_the_gpu_and_contains_the_box() {
    let gpu = gpu();
    let mut m = Rng(7);
    let mut cases = Vec::new();
    let mut exact = Vec::new();
    for _ in 0..1024 {
        let centre = [0; 3].map(|_| m.coord());
        let boxes: Vec<([f32; 3], [f32; 3])> = (0..4)
            .map(|_| {
                let mut lo = [0.0; 3];
                let mut hi = [0.0; 3];
                for a in 0..3 {
                    let scale = centre[a].abs().max(1e-30) * 10f32.powf(6.0 * m.unit() - 5.0);
                    let c = centre[a] + scale * (m.unit() - 0.5);
                    let e = if m.next().is_multiple_of(5) {
                        0.0
                    } else {
                        scale * m.unit()
                    };
                    (lo[a], hi[a]) = (c - e, c + e);
                }
                (lo, hi)
            })
            .collect();
        let node = Node::quantized(&boxes);
        let words: &[u32] = bytemuck::cast_slice(std::slice::from_ref(&node));
        for (s, b) in boxes.iter().enumerate() {
            cases.push(MirrorCase {
                words: [0, 0, 0, s as u32],
                node: words.try_into().unwrap(),
                ..MirrorCase::default()
            });
            exact.push((node, s, *b));
        }
    }
    let out = run_mirror(&gpu, &params(), &cases, &[]).unwrap();
    for ((node, s, (lo, hi)), r) in exact.iter().zip(&out) {
        let (clo, chi) = node.child_box(*s);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&r.lo[..3]),
            bits(&clo),
            "lower bounds, slot {s} of {node:?}"
        );
        assert_eq!(
            bits(&r.hi[..3]),
            bits(&chi),
            "upper bounds, slot {s} of {node:?}"
        );
        for a in 0..3 {
            assert!(
                clo[a] <= lo[a] && hi[a] <= chi[a],
                "slot {s} axis {a}: {lo:?}..{hi:?} outside {clo:?}..{chi:?}"
            );
        }
    }
}

#[test]
fn cosine_dir_matches_the_gpu_within_float_precision() {
    let gpu = gpu();
    let cases = cases(4096);
    let out = run_mirror(&gpu, &params(), &cases, &[]).unwrap();
    let mut worst = 0.0f32;
    for (c, r) in cases.iter().zip(&out) {
        let cpu = cosine_dir([c.n[0], c.n[1], c.n[2]], [c.u[0], c.u[1]]);
        for (c, g) in cpu.iter().zip(r.dir) {
            worst = worst.max((c - g).abs());
        }
    }
    // WGSL's sin, cos and sqrt are not correctly rounded; 1e-5 is a few hundred ulps of a unit
    // vector and far below any visible difference.
    assert!(worst < 1e-5, "largest difference {worst}");
}

#[test]
fn cosine_dir_on_the_gpu_has_the_cosine_moments() {
    // For directions distributed as cos(theta) / pi about n: E[cos] = 2/3, E[cos^2] = 1/2,
    // and no direction below the surface. 4096 uniform samples: the means' standard errors
    // are about 0.004; 0.02 is five of them.
    let gpu = gpu();
    let cases = cases(4096);
    let out = run_mirror(&gpu, &params(), &cases, &[]).unwrap();
    let cos: Vec<f64> = cases
        .iter()
        .zip(&out)
        .map(|(c, r)| (0..3).map(|a| f64::from(c.n[a] * r.dir[a])).sum())
        .collect();
    let m1 = cos.iter().sum::<f64>() / cos.len() as f64;
    let m2 = cos.iter().map(|c| c * c).sum::<f64>() / cos.len() as f64;
    eprintln!("cosine moments: E[cos] {m1:.4}, E[cos^2] {m2:.4}");
    assert!((m1 - 2.0 / 3.0).abs() < 0.02, "E[cos] = {m1}");
    assert!((m2 - 0.5).abs() < 0.02, "E[cos^2] = {m2}");
    assert!(
        cos.iter().all(|&c| c >= -1e-6),
        "a direction below the surface"
    );
}

/// Scalars map to the same colormap bin on the GPU as on the CPU, bit for bit: values at and
/// beside every bin boundary of ranges from tiny to huge, outside the range, infinite and NaN;
/// and packed sRGB colours decode alike.
#[test]
fn colormap_matches_the_gpu_bit_for_bit() {
    let gpu = gpu();
    let mut m = Rng(11);
    let mut cases = cases(6144);
    for (i, c) in cases.iter_mut().enumerate() {
        let lo = match i % 4 {
            0 => 0.0,
            1 => -1e5 * m.unit(),
            2 => 101325.0,
            _ => m.coord(),
        };
        let width = 10f32.powf(12.0 * m.unit() - 6.0);
        let scale = dcrt::colormap::scale(lo, lo + width);
        // On a boundary k / 256 of the range, one float either side, or anywhere.
        let k = (m.next() % 258) as f32 - 1.0;
        let on = lo + k * width / 256.0;
        let s = match m.next() % 8 {
            0 => on,
            1 => f32::from_bits(on.to_bits().wrapping_add(1)),
            2 => f32::from_bits(on.to_bits().wrapping_sub(1)),
            3 => [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, lo][i % 4],
            _ => lo + width * (1.4 * m.unit() - 0.2),
        };
        c.c = [s, lo, scale, 0.0];
    }
    let out = run_mirror(&gpu, &params(), &cases, &[]).unwrap();
    let mut bins = std::collections::BTreeSet::new();
    for (i, (c, r)) in cases.iter().zip(&out).enumerate() {
        let [s, lo, scale, _] = c.c;
        let cpu = colormap(s, lo, scale, c.words[2] % 4);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&r.color[..3]),
            bits(&cpu),
            "colormap({s}, {lo}, {scale}, {}), case {i}",
            c.words[2] % 4
        );
        assert_eq!(
            bits(&r.rgb[..3]),
            bits(&srgb_color(c.words[0])),
            "srgb_color({:#x}), case {i}",
            c.words[0]
        );
        bins.insert(bin(s, lo, scale));
    }
    // The cases reach every bin, the first and the last included.
    assert_eq!(bins.len(), 256, "bins reached: {}", bins.len());
}

/// `dot_difference(n, v, o)` (shared/compensated.wgsl), the extended-precision plane distance of
/// the triangle test, against the exact value: within its documented bound, u |exact| + 2^-38
/// sum |n_k| (|v_k| + |o_k|), where plain f32 is off by far more. Points on planes through o's
/// neighbourhood seen from far and near (1e-6..1e9 away), the cancellation of a huge triangle
/// seen close up.
#[test]
fn dot_difference_on_the_gpu_is_within_its_bound_of_the_exact_value() {
    let gpu = gpu();
    let mut m = Rng(7);
    let mut cases = Vec::new();
    for _ in 0..4096 {
        let n = m.normal();
        let t1 = normalize3(cross3(n, m.normal()));
        let t2 = normalize3(cross3(n, t1));
        let (n, t1, t2) = (n.map(f64::from), t1.map(f64::from), t2.map(f64::from));
        let o: [f32; 3] = [0; 3].map(|_| m.coord());
        let reach = 10f64.powf(15.0 * f64::from(m.unit()) - 6.0);
        let height = 10f64.powf(8.0 * f64::from(m.unit()) - 6.0) * f64::from(o[0].abs() + 1.0);
        let (a, b) = (f64::from(m.unit()) - 0.5, f64::from(m.unit()) - 0.5);
        let v: [f32; 3] = std::array::from_fn(|k| {
            (f64::from(o[k]) + height * n[k] + reach * (a * t1[k] + b * t2[k])) as f32
        });
        cases.push(MirrorCase {
            p: [v[0], v[1], v[2], 0.0],
            n: [n[0] as f32, n[1] as f32, n[2] as f32, 0.0],
            u: [o[0], o[1], o[2], 0.0],
            ..MirrorCase::default()
        });
    }
    let out = run_mirror(&gpu, &params(), &cases, &[]).unwrap();
    let (mut bad, mut plain_bad) = (0, 0);
    for (i, (c, r)) in cases.iter().zip(&out).enumerate() {
        let exact: f64 = (0..3)
            .map(|k| f64::from(c.n[k]) * (f64::from(c.p[k]) - f64::from(c.u[k])))
            .sum();
        let mag: f64 = (0..3)
            .map(|k| f64::from(c.n[k].abs()) * (f64::from(c.p[k].abs()) + f64::from(c.u[k].abs())))
            .sum();
        let bound = exact.abs() * 2f64.powi(-24) + mag * 2f64.powi(-38) + 1e-36;
        let got = f64::from(r.sample[2]);
        if (got - exact).abs() > bound {
            bad += 1;
            if bad <= 5 {
                eprintln!("case {i}: {c:?}: got {got:e}, exact {exact:e}, bound {bound:e}");
            }
        }
        let plain: f32 = (0..3).map(|k| c.n[k] * (c.p[k] - c.u[k])).sum();
        plain_bad += usize::from((f64::from(plain) - exact).abs() > bound);
    }
    eprintln!(
        "dot_difference: {bad} of {} beyond the bound (plain f32: {plain_bad})",
        cases.len()
    );
    assert!(
        plain_bad > cases.len() / 4,
        "the cases need extended precision"
    );
    assert_eq!(bad, 0, "dot_difference beyond its bound");
}

fn cross3(a: [f32; 3], b: [f32; 3]) -> [f64; 3] {
    let (a, b) = (a.map(f64::from), b.map(f64::from));
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize3(v: [f64; 3]) -> [f32; 3] {
    let l = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    v.map(|c| (c / l) as f32)
}

#[test]
fn block_rows_read_back_from_every_texel_row_of_their_table() {
    // The trace loop's block-row table is a texture of row_table::WIDTH blocks a texel row:
    // two full rows and part of a third, every entry distinct.
    let gpu = gpu();
    let n = 2 * dcrt::gpu::row_table::WIDTH as usize + 100;
    let table: Vec<u32> = (0..n as u32)
        .map(|k| k.wrapping_mul(2_654_435_761) ^ 0x5a5a)
        .collect();
    let out = run_mirror(&gpu, &params(), &cases(n), &table).unwrap();
    for (k, r) in out.iter().enumerate() {
        assert_eq!(r.row[0], table[k], "block {k}");
    }
}
