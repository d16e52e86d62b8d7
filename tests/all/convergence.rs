//! Per-pixel convergence of the samplers on the GPU (docs/ARCHITECTURE.md, Shading): each
//! pixel's error against a reference rendered with the other sampler falls about 2x for every
//! 4x samples, in path mode with several bounces and in AO with several samples per pixel; and
//! an analytic case with interreflection, a sphere cavity lit through an opening.

use crate::common::*;
use dcrt::gpu::tracer::Settings;
use dcrt::render::Prepared;
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Model, Scene};
use dcrt::shading::{Mode, Sampler, Shading};

const LADDER: [u32; 4] = [16, 64, 256, 1024];
const REFERENCE_SPP: u32 = 1024;

fn mean_image(p: &Prepared, cam: &Camera, w: u32, h: u32, sh: Shading) -> Vec<f64> {
    let s = Settings {
        shading: sh,
        ..Settings::default()
    };
    let (f, _) = render(&gpu(), p, cam, w, h, s);
    f.pixels.iter().map(|p| f64::from(p.rgb[0])).collect()
}

fn rmse(a: &[f64], b: &[f64]) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (s / a.len() as f64).sqrt()
}

fn other(s: Sampler) -> Sampler {
    match s {
        Sampler::Sobol => Sampler::Independent,
        Sampler::Independent => Sampler::Sobol,
    }
}

/// Each pixel's RMSE at the ladder's spp against a reference rendered with the other sampler,
/// the reference's own noise taken out: the reference is the mean of two renders of
/// `REFERENCE_SPP` with different seeds, whose difference measures that noise.
fn ladder(sampler: Sampler, p: &Prepared, cam: &Camera, w: u32, h: u32, base: Shading) -> Vec<f64> {
    let reference_sh = Shading {
        sampler: other(sampler),
        spp: REFERENCE_SPP,
        ..base
    };
    let a = mean_image(
        p,
        cam,
        w,
        h,
        Shading {
            seed: 1000,
            ..reference_sh
        },
    );
    let b = mean_image(
        p,
        cam,
        w,
        h,
        Shading {
            seed: 1001,
            ..reference_sh
        },
    );
    let reference: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
    // Var(mean of two) = Var(a - b) / 4.
    let noise2 = rmse(&a, &b).powi(2) / 4.0;
    // Progressively: samples done..spp added to the mean of samples 0..done.
    let (mut errs, mut mean, mut done) = (Vec::new(), vec![0.0; reference.len()], 0u32);
    for spp in LADDER {
        let sh = Shading {
            sampler,
            first_sample: done,
            spp: spp - done,
            seed: 7,
            ..base
        };
        let more = mean_image(p, cam, w, h, sh);
        for (m, v) in mean.iter_mut().zip(more) {
            *m = (*m * f64::from(done) + v * f64::from(spp - done)) / f64::from(spp);
        }
        done = spp;
        let e2 = rmse(&mean, &reference).powi(2);
        errs.push((e2 - noise2).max(0.0).sqrt());
    }
    let shown: Vec<String> = errs.iter().map(|e| format!("{e:.5}")).collect();
    eprintln!(
        "{:?} {sampler:?}: reference noise {:.5}, RMSE at {LADDER:?} spp: {}",
        base.mode,
        noise2.sqrt(),
        shown.join(" ")
    );
    errs
}

/// Every 4x spp divides the error by at least 1.6 (independent samples: 2; a plateau: ~1).
fn check(sampler: Sampler, e: &[f64]) {
    assert!(e[0] > 0.0, "{sampler:?}: the image has noise to lose");
    for k in 1..e.len() {
        let ratio = e[k - 1] / e[k];
        assert!(
            ratio >= 1.6,
            "{sampler:?}: RMSE {:.5} at {} spp, {:.5} at {}: fell {ratio:.2}x for 4x samples",
            e[k - 1],
            LADDER[k - 1],
            e[k],
            LADDER[k]
        );
    }
}

/// A small rm isosurface with folds (occlusion, interreflection), white albedo 0.8.
fn rm_scene(w: u32, h: u32) -> (Prepared, Camera) {
    let scene = Scene::generated(Generator::Rm, 20_000, w, h);
    let mut model = scene.load_model().unwrap();
    model.colors.iter_mut().for_each(|c| *c = [0.8; 3]);
    let cam = scene.camera_or_default(&model);
    (prepare(model), cam)
}

fn path_converges(sampler: Sampler) {
    let (w, h) = (16, 16);
    let (p, cam) = rm_scene(w, h);
    let base = Shading {
        mode: Mode::Path,
        sky: [1.0; 3],
        sun: [0.0; 3],
        max_depth: 3,
        ..Shading::default()
    };
    check(sampler, &ladder(sampler, &p, &cam, w, h, base));
}

fn ao_converges(sampler: Sampler) {
    let (w, h) = (16, 16);
    let (p, cam) = rm_scene(w, h);
    let base = Shading {
        mode: Mode::Ao,
        ao_rays: 2,
        ao_distance: 0.5,
        ..Shading::default()
    };
    check(sampler, &ladder(sampler, &p, &cam, w, h, base));
}

#[test]
fn path_tracing_converges_per_pixel_sobol() {
    path_converges(Sampler::Sobol);
}

#[test]
fn path_tracing_converges_per_pixel_independent() {
    path_converges(Sampler::Independent);
}

#[test]
fn ambient_occlusion_converges_per_pixel_sobol() {
    ao_converges(Sampler::Sobol);
}

#[test]
fn ambient_occlusion_converges_per_pixel_independent() {
    ao_converges(Sampler::Independent);
}

/// A lat-long sphere of radius 1 at the origin without the cap of polar angle below `cap`
/// (the opening, towards +z).
fn open_sphere(rings: u32, segs: u32, cap_rings: u32) -> Model {
    let v = |i: u32, j: u32| -> [f32; 3] {
        let t = std::f32::consts::PI * i as f32 / rings as f32;
        let p = std::f32::consts::TAU * (j % segs) as f32 / segs as f32;
        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
    };
    let mut tris = Vec::new();
    for i in cap_rings..rings {
        for j in 0..segs {
            let (a, b, c, d) = (v(i, j), v(i, j + 1), v(i + 1, j), v(i + 1, j + 1));
            tris.push([a, c, b]);
            if i + 1 < rings {
                tris.push([b, c, d]);
            }
        }
    }
    Model::from_triangles(tris)
}

#[test]
fn sphere_cavity_matches_its_geometric_series() {
    // Inside a sphere, a cosine-weighted ray from any point of the surface lands uniformly on
    // its area; so a ray escapes through the opening with probability f, its share of the
    // sphere's area, whatever the bounce. Seen through the opening, every point inside has
    // radiance a f S (1 + r + ... + r^(D-1)), r = a (1 - f), for albedo a, sky S, D bounces.
    let (rings, segs, cap) = (64, 128, 16);
    let mut m = open_sphere(rings, segs, cap);
    let a = 0.7;
    m.colors = vec![[a as f32; 3]];
    // The opening's share of the area of the (inscribed) polygonal sphere, from its triangles.
    let area = |t: &[[f32; 3]; 3]| {
        let u: [f64; 3] = std::array::from_fn(|k| f64::from(t[1][k] - t[0][k]));
        let v: [f64; 3] = std::array::from_fn(|k| f64::from(t[2][k] - t[0][k]));
        let c = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
    };
    let closed = open_sphere(rings, segs, 0);
    let whole: f64 = closed.triangles.iter().map(area).sum();
    let kept: f64 = m.triangles.iter().map(area).sum();
    let f = 1.0 - kept / whole;
    let p = prepare(m);
    // On the axis, looking in through the opening (polar angle pi/4): only the inside shows.
    let cam = Camera {
        position: [0.0, 0.0, 3.0],
        focal_point: [0.0, 0.0, 0.0],
        view_up: [0.0, 1.0, 0.0],
        view_angle: 12.0,
        parallel_scale: None,
    };
    let (w, h, depth) = (16, 16, 4);
    let r = a * (1.0 - f);
    let want = a * f * (0..depth).map(|k| r.powi(k as i32)).sum::<f64>();
    for sampler in [Sampler::Sobol, Sampler::Independent] {
        let image = |spp| {
            let sh = Shading {
                mode: Mode::Path,
                sampler,
                spp,
                sky: [1.0; 3],
                sun: [0.0; 3],
                max_depth: depth,
                ..Shading::default()
            };
            let s = Settings {
                shading: sh,
                ..Settings::default()
            };
            let (frame, _) = render(&gpu(), &p, &cam, w, h, s);
            assert!(
                frame.pixels.iter().all(|p| !is_miss(p)),
                "every pixel sees the inside"
            );
            frame
                .pixels
                .iter()
                .map(|p| f64::from(p.rgb[0]))
                .collect::<Vec<f64>>()
        };
        let (coarse, fine) = (image(16), image(256));
        let n = fine.len() as f64;
        let mean = fine.iter().sum::<f64>() / n;
        let sd = (fine.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let (e16, e256) = (
            rmse(&coarse, &vec![want; coarse.len()]),
            rmse(&fine, &vec![want; fine.len()]),
        );
        eprintln!(
            "cavity {sampler:?}: opening {f:.4} of the area, want {want:.5}, mean {mean:.5} \
             ({:+.3}%, standard error {:.3}%), per-pixel RMSE {e16:.5} at 16 spp, {e256:.5} at \
             256",
            100.0 * (mean / want - 1.0),
            100.0 * sd / n.sqrt() / want
        );
        // The polygonal sphere is not exactly a sphere: 0.3% for that, and 4 standard errors.
        assert!(
            (mean - want).abs() < 0.003 * want + 4.0 * sd / n.sqrt(),
            "{sampler:?}: mean {mean}, analytic {want}"
        );
        // 16x the samples: each pixel's error falls 4x for independent samples.
        assert!(
            e16 / e256 >= 3.2,
            "{sampler:?}: per-pixel RMSE {e16:.5} at 16 spp, {e256:.5} at 256"
        );
    }
}
