//! Shading modes: furnace, lone convex object under AO, GPU against the CPU reference for
//! shadows and AO, distributed cache against replicated for every mode, determinism, and the
//! `cast` image unchanged by culling.

use crate::common::*;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::frame::Frame;
use dcrt::gpu::tracer::Settings;
use dcrt::reference::Reference;
use dcrt::reference::shade::reference_image;
use dcrt::render::{DcOptions, Prepared};
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Model, Scene};
use dcrt::shading::{Light, Mode, Sampler, Shading};

/// A closed lat-long sphere of radius about 1 at the origin; `bump` > 0 makes it non-convex.
fn sphere(rings: u32, segs: u32, bump: f32) -> Model {
    let r = |t: f32, p: f32| 1.0 + bump * (5.0 * t).sin() * (4.0 * p).cos();
    let v = |i: u32, j: u32| -> [f32; 3] {
        if i == 0 {
            return [0.0, 0.0, r(0.0, 0.0)];
        }
        if i == rings {
            return [0.0, 0.0, -r(std::f32::consts::PI, 0.0)];
        }
        let t = std::f32::consts::PI * i as f32 / rings as f32;
        let p = std::f32::consts::TAU * (j % segs) as f32 / segs as f32;
        let k = r(t, p);
        [k * t.sin() * p.cos(), k * t.sin() * p.sin(), k * t.cos()]
    };
    let mut tris = Vec::new();
    for i in 0..rings {
        for j in 0..segs {
            let (a, b, c, d) = (v(i, j), v(i, j + 1), v(i + 1, j), v(i + 1, j + 1));
            if i > 0 {
                tris.push([a, c, b]);
            }
            if i + 1 < rings {
                tris.push([b, c, d]);
            }
        }
    }
    Model::from_triangles(tris)
}

fn camera() -> Camera {
    Camera {
        position: [0.3, -4.0, 1.0],
        focal_point: [0.0, 0.0, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 40.0,
        parallel_scale: None,
    }
}

fn shaded(p: &Prepared, cam: &Camera, w: u32, h: u32, sh: Shading) -> Frame {
    let gpu = gpu();
    let s = Settings {
        shading: sh,
        ..Settings::default()
    };
    render(&gpu, p, cam, w, h, s).0
}

fn bits(f: &Frame) -> Vec<u8> {
    bytemuck::cast_slice(&f.pixels).to_vec()
}

/// `m` in one grey `albedo`, path traced under a sky of radiance 1 and no sun, 32x32.
fn under_white_sky(mut m: Model, albedo: f32, spp: u32, max_depth: u32) -> Frame {
    m.colors = vec![[albedo; 3]];
    let sh = Shading {
        mode: Mode::Path,
        spp,
        sky: [1.0; 3],
        sun: [0.0; 3],
        max_depth,
        ..Shading::default()
    };
    shaded(&prepare(m), &camera(), 32, 32, sh)
}

#[test]
fn furnace_converges_to_one() {
    // Albedo 1 under a sky of radiance 1 and no sun: every path carries throughput 1 until it
    // escapes, so every pixel (object or sky) is 1. A path that self-intersects (bad offset)
    // or is cut at the depth limit darkens its pixel.
    let f = under_white_sky(sphere(48, 96, 0.12), 1.0, 8, 64);
    let hits = f.pixels.iter().filter(|p| !is_miss(p)).count();
    assert!(
        hits > 200,
        "the object fills part of the view ({hits} pixels)"
    );
    let mean: f64 = f
        .pixels
        .iter()
        .flat_map(|p| p.rgb)
        .map(f64::from)
        .sum::<f64>()
        / (3 * f.pixels.len()) as f64;
    let off = f
        .pixels
        .iter()
        .filter(|p| p.rgb.iter().any(|c| (c - 1.0).abs() > 1e-4))
        .count();
    eprintln!(
        "furnace: mean {mean}, {off} of {} pixels off 1 by > 1e-4",
        f.pixels.len()
    );
    assert!(
        (mean - 1.0).abs() < 1e-3,
        "mean radiance {mean}, expected 1 within 1e-3"
    );
    assert!(
        off * 100 <= f.pixels.len(),
        "{off} pixels differ from 1 by more than 1e-4"
    );
}

/// The furnace with albedo 1 cannot tell whether the albedo is applied at each bounce. A convex
/// object of albedo 0.5 under a sky of 1: every bounce leaves it for the sky, so each of its
/// pixels is 0.5 and each sky pixel 1 (a bounce that applied the albedo twice, or not at all,
/// or sent rays into the surface would show). How bounce directions are distributed is checked
/// by the cavity test (convergence), whose answer depends on it.
#[test]
fn convex_object_of_albedo_one_half_under_a_white_sky_is_one_half() {
    // One sample at each pixel's centre: with several, jittered, an edge pixel mixes the
    // object and the sky.
    let f = under_white_sky(sphere(24, 48, 0.0), 0.5, 1, 8);
    let (mut hits, mut worst) = (0, 0f32);
    for px in &f.pixels {
        let want = if is_miss(px) { 1.0 } else { 0.5 };
        hits += usize::from(!is_miss(px));
        for c in px.rgb {
            worst = worst.max((c - want).abs());
        }
    }
    assert!(
        hits > 100,
        "the object fills part of the view ({hits} pixels)"
    );
    assert!(worst < 1e-4, "a pixel is off its value by {worst}");
}

#[test]
fn ao_of_a_lone_convex_object_is_one() {
    let p = prepare(sphere(24, 48, 0.0));
    let sh = Shading {
        mode: Mode::Ao,
        ..Shading::default()
    };
    let f = shaded(&p, &camera(), 32, 32, sh);
    let hit: Vec<_> = f.pixels.iter().filter(|p| !is_miss(p)).collect();
    assert!(hit.len() > 100);
    for px in hit {
        assert_eq!(px.rgb, [1.0; 3], "prim {}: AO of a convex object", px.id);
    }
}

/// A path from a lone convex object under a sky and a sun: every bounce ray leaves to the sky and
/// every sun ray towards the lit side is unoccluded, so a pixel is its albedo times the sky plus
/// the sun's Lambert term, whatever the sampler drew. It reads each pixel's sun ray and bounce ray
/// from the wave's ray slots (`wave_slot`): a pixel given another slot's rays is wrong.
#[test]
fn path_of_a_lone_convex_object_is_its_albedo_under_sky_and_sun() {
    let p = prepare(sphere(24, 48, 0.0));
    let travel = [-1.0f32, 0.2, -0.1];
    let len = travel.iter().map(|c| c * c).sum::<f32>().sqrt();
    let to_sun = travel.map(|c| -c / len);
    let sh = Shading {
        mode: Mode::Path,
        sun_dir: Some(travel),
        ..Shading::default()
    };
    let f = shaded(&p, &camera(), 32, 32, sh);
    let albedo = p.model.colors[0];
    let (mut lit, mut shaded_side) = (0, 0);
    for px in f.pixels.iter().filter(|p| !is_miss(p)) {
        let cos = (0..3).map(|a| px.normal[a] * to_sun[a]).sum::<f32>();
        let want: [f32; 3] = std::array::from_fn(|a| {
            albedo[a] * sh.sky[a] + albedo[a] / std::f32::consts::PI * sh.sun[a] * cos.max(0.0)
        });
        for a in 0..3 {
            assert!(
                (px.rgb[a] - want[a]).abs() <= 1e-3 * want[a].max(1e-3),
                "prim {}: {:?} against {want:?} (cos to the sun {cos})",
                px.id,
                px.rgb
            );
        }
        // Pixels near the terminator may go either way by rounding: count the clear ones.
        lit += usize::from(cos > 0.05);
        shaded_side += usize::from(cos < -0.05);
    }
    assert!(
        lit > 50 && shaded_side > 50,
        "{lit} lit, {shaded_side} unlit pixels"
    );
}

/// A path goes on only from a hit, so a wave follows only rays that found one
/// (`Stats::closest_hits`). Every bounce off a convex object leaves it: at a depth limit of 8
/// one wave is traced, in the rounds it takes at a limit of 1, with the same image. A view of
/// the sky alone traces no wave at all, in path tracing or ambient occlusion: the rounds of its
/// camera rays, as in cast mode.
#[test]
fn path_waves_follow_only_rays_that_found_a_hit() {
    let gpu = gpu();
    let p = prepare(sphere(24, 48, 0.0));
    let path = |max_depth| Settings {
        shading: Shading {
            mode: Mode::Path,
            max_depth,
            ..Shading::default()
        },
        ..Settings::default()
    };
    let (one, s1) = render(&gpu, &p, &camera(), 32, 32, path(1));
    let (eight, s8) = render(&gpu, &p, &camera(), 32, 32, path(8));
    assert_same_pixels(&one, &eight, "depth limit 1 against 8");
    assert!(s1.secondary_rays > 0, "the object's paths trace a wave");
    assert_eq!(s8.secondary_rays, s1.secondary_rays, "secondary rays");
    assert_eq!(s8.rounds, s1.rounds, "rounds at depth limits 8 and 1");
    let away = Camera {
        focal_point: [0.3, -8.0, 1.0],
        ..camera()
    };
    let (_, cast) = render(&gpu, &p, &away, 32, 32, Settings::default());
    let ao = Settings {
        shading: Shading {
            mode: Mode::Ao,
            ..Shading::default()
        },
        ..Settings::default()
    };
    for (what, settings) in [("path", path(8)), ("ao", ao)] {
        let (sky, s) = render(&gpu, &p, &away, 32, 32, settings);
        assert!(
            sky.pixels.iter().all(is_miss),
            "{what}: the view holds only sky"
        );
        assert_eq!(s.secondary_rays, 0, "{what}: secondary rays from the sky");
        assert_eq!(
            s.rounds, cast.rounds,
            "{what}: rounds of a view of sky against cast"
        );
    }
}

/// GPU against the CPU reference for one mode on a small rm isosurface.
fn against_reference(sh: Shading) {
    let (w, h) = (48, 40);
    let scene = Scene::generated(Generator::Rm, 20_000, w, h);
    let model = scene.load_model().unwrap();
    let cam = scene.camera_or_default(&model);
    let p = prepare(model);
    let f = shaded(&p, &cam, w, h, sh);
    let reference = Reference::new(&p.model.triangles);
    let bg = [0.1, 0.2, 0.3];
    let cpu = reference_image(&reference, &p.model, &cam.basis(w, h), &sh, bg).unwrap();
    let (mut worst, mut sum, mut far) = (0.0f32, 0.0f64, 0usize);
    for (g, c) in f.pixels.iter().zip(&cpu) {
        let d = (0..3).map(|a| (g.rgb[a] - c[a]).abs()).fold(0.0, f32::max);
        worst = worst.max(d);
        sum += f64::from(d);
        // One AO ray of 36 flipping by rounding moves a pixel by 1/36.
        far += usize::from(d > 0.06);
    }
    let n = cpu.len();
    let mean = sum / n as f64;
    eprintln!(
        "{:?}: mean |gpu - cpu| {mean:.2e}, worst {worst:.3}, {far} of {n} pixels off by > 0.06",
        sh.mode
    );
    assert!(mean < 5e-3, "mean difference {mean}");
    assert!(far * 100 <= n, "{far} pixels differ by more than 0.06");
    let lit = f.pixels.iter().filter(|p| !is_miss(p)).count();
    assert!(lit > n / 4, "the view sees the model");
    // Pixels the reference shows occluded (AO below 0.8; shadows: nothing but the ambient
    // term): there must be many, and the GPU must agree on nearly all of them.
    // (A shadowed pixel gets less than it would if every light it faces were visible.)
    let basis = cam.basis(w, h);
    let lights = sh.effective_lights(basis.key_light());
    let unoccluded = |i: usize, g: &dcrt::gpu::layout::Pixel| -> f64 {
        let d = basis.dir(i as u32 % w, i as u32 / w);
        let n = g.normal.map(f64::from);
        let s = if (0..3).map(|a| n[a] * d[a]).sum::<f64>() > 0.0 {
            -1.0
        } else {
            1.0
        };
        let at: [f64; 3] =
            std::array::from_fn(|a| f64::from(basis.origin[a]) + f64::from(g.depth) * d[a]);
        let albedo = f64::from(p.model.colors[p.model.mesh_of(g.id)][0]);
        let mut e = f64::from(sh.ambient);
        for l in &lights {
            let (to, scale) = match *l {
                Light::Directional { dir, color } => (dir.map(|c| -f64::from(c)), color[0]),
                Light::Point { pos, color } => {
                    let v: [f64; 3] = std::array::from_fn(|a| f64::from(pos[a]) - at[a]);
                    let l2 = v.iter().map(|c| c * c).sum::<f64>();
                    (v, color[0] / l2 as f32)
                }
            };
            let len = to.iter().map(|c| c * c).sum::<f64>().sqrt();
            let cos = s * (0..3).map(|a| n[a] * to[a]).sum::<f64>() / len;
            if cos > 0.0 {
                e += f64::from(scale) * cos;
            }
        }
        albedo * e
    };
    let occluded: Vec<(&dcrt::gpu::layout::Pixel, &[f32; 3])> = f
        .pixels
        .iter()
        .zip(&cpu)
        .enumerate()
        .filter(|(i, (g, c))| {
            !is_miss(g)
                && match sh.mode {
                    Mode::Ao => c[0] < 0.8,
                    _ => f64::from(c[0]) < unoccluded(*i, g) - 0.02,
                }
        })
        .map(|(_, pair)| pair)
        .collect();
    let agree = occluded
        .iter()
        .filter(|(g, c)| (g.rgb[0] - c[0]).abs() < 0.06)
        .count();
    eprintln!(
        "{:?}: {} of {lit} hit pixels occluded in the reference, the GPU agrees on {agree}",
        sh.mode,
        occluded.len()
    );
    assert!(occluded.len() * 30 >= lit, "the reference shows occlusion");
    assert!(
        agree * 100 >= occluded.len() * 97,
        "the GPU disagrees on occluded pixels"
    );
}

#[test]
fn convex_object_under_a_sun_is_lambertian() {
    // Albedo 0.6 under a sun alone (no sky): every path ends after its first sun ray, since a
    // bounce off a convex object escapes to a black sky. Each hit pixel is exactly
    // albedo / pi * irradiance * cos(normal, sun), 0 facing away; a ray that self-shadows (bad
    // offset) makes a lit pixel 0.
    let mut m = sphere(48, 96, 0.0);
    m.colors = vec![[0.6; 3]];
    let p = prepare(m);
    let to_sun = {
        let d = [-0.3f32, -0.8, 0.5];
        let l = d.iter().map(|c| c * c).sum::<f32>().sqrt();
        d.map(|c| c / l)
    };
    let sh = Shading {
        mode: Mode::Path,
        spp: 1,
        sky: [0.0; 3],
        sun: [2.0; 3],
        sun_dir: Some(to_sun.map(|c| -c)),
        ..Shading::default()
    };
    let cam = camera();
    let f = shaded(&p, &cam, 32, 32, sh);
    let mut lit = 0;
    let mut bad = Vec::new();
    for px in f.pixels.iter().filter(|p| !is_miss(p)) {
        // The outward normal: for a visible point of a convex object centred at the origin, it
        // faces the camera's side of the centre.
        let out = (0..3)
            .map(|a| f64::from(px.normal[a]) * cam.position[a])
            .sum::<f64>()
            > 0.0;
        let n = if out {
            px.normal
        } else {
            px.normal.map(|c| -c)
        };
        let cos: f32 = (0..3).map(|a| n[a] * to_sun[a]).sum();
        let want = if cos > 0.0 {
            0.6 / std::f32::consts::PI * 2.0 * cos
        } else {
            0.0
        };
        lit += usize::from(want > 0.0);
        if (px.rgb[0] - want).abs() > 1e-4 + 1e-4 * want {
            bad.push((px.id, px.rgb[0], want));
        }
    }
    eprintln!(
        "sun: {lit} lit pixels, {} off the analytic value",
        bad.len()
    );
    assert!(lit > 100, "the sun lights part of the view");
    assert!(
        bad.is_empty(),
        "{} pixels off: {:?}",
        bad.len(),
        &bad[..bad.len().min(8)]
    );
}

#[test]
fn ao_matches_the_cpu_reference() {
    against_reference(Shading {
        mode: Mode::Ao,
        ao_rays: 36,
        ao_distance: 0.3,
        seed: 5,
        ..Shading::default()
    });
}

#[test]
fn shadows_match_the_cpu_reference() {
    let mut sh = Shading {
        mode: Mode::Shadows,
        ..Shading::default()
    };
    // Low, so that the isosurface's folds cast shadows.
    sh.add_light(Light::Directional {
        dir: [0.9, 0.6, -0.35],
        color: [0.8, 0.8, 0.7],
    })
    .unwrap();
    sh.add_light(Light::Point {
        pos: [0.4, -0.4, 0.9],
        color: [0.3, 0.2, 0.2],
    })
    .unwrap();
    against_reference(sh);
}

#[test]
fn every_mode_is_bit_identical_through_the_distributed_cache() {
    let gpu = gpu();
    let (w, h) = (24, 24);
    let scene = Scene::generated(Generator::Assembly, 20_000, w, h);
    let model = scene.load_model().unwrap();
    let cam = scene.camera_or_default(&model);
    let p = prepare(model);
    let basis = cam.basis(w, h);
    for mode in [Mode::Cast, Mode::Shadows, Mode::Ao, Mode::Path] {
        let sh = Shading {
            mode,
            spp: 2,
            ao_rays: 8,
            max_depth: 3,
            ..Shading::default()
        };
        let s = Settings {
            shading: sh,
            ..Settings::default()
        };
        let mut t = p.tracer(&gpu, s).unwrap();
        let (replicated, rs) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        let o = DcOptions {
            ranks: 4,
            rank: 1,
            cache: CacheSize::parse("1/8").unwrap(),
            map: CacheMap::Ize,
            replicate: Default::default(),
        };
        let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
        let (dc, ds) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        eprintln!(
            "{mode:?}: {} secondary rays, {} blocks fetched, {} fault rounds",
            ds.secondary_rays, ds.fetched_blocks, ds.fault_rounds
        );
        assert_eq!(rs.secondary_rays, ds.secondary_rays, "{mode:?}");
        if mode != Mode::Cast {
            assert!(ds.secondary_rays > 0, "{mode:?} shoots secondary rays");
        }
        assert!(ds.fetched_blocks > 0, "{mode:?}: a cold cache fetches");
        assert!(bits(&replicated) == bits(&dc), "{mode:?}: DC image differs");
    }
}

#[test]
fn same_seed_same_bits_other_seed_other_image() {
    let scene = Scene::generated(Generator::Rm, 20_000, 24, 24);
    let model = scene.load_model().unwrap();
    let cam = scene.camera_or_default(&model);
    let p = prepare(model);
    for mode in [Mode::Ao, Mode::Path] {
        let sh = Shading {
            mode,
            spp: 2,
            ao_rays: 4,
            seed: 1,
            ..Shading::default()
        };
        let a = shaded(&p, &cam, 24, 24, sh);
        let b = shaded(&p, &cam, 24, 24, sh);
        assert!(bits(&a) == bits(&b), "{mode:?}: same seed, different bits");
        let c = shaded(&p, &cam, 24, 24, Shading { seed: 2, ..sh });
        assert!(
            bits(&a) != bits(&c),
            "{mode:?}: the seed changes the samples"
        );
        let independent = Shading {
            sampler: Sampler::Independent,
            ..sh
        };
        let d = shaded(&p, &cam, 24, 24, independent);
        assert!(
            bits(&a) != bits(&d),
            "{mode:?}: the sampler changes the samples"
        );
        let e = shaded(&p, &cam, 24, 24, independent);
        assert!(
            bits(&d) == bits(&e),
            "{mode:?}: independent, different bits"
        );
    }
}

#[test]
fn culling_and_any_hit_change_costs_not_images() {
    // The sphere fills part of the view: many primary rays miss its box.
    let p = prepare(sphere(24, 48, 0.15));
    let cam = camera();
    let gpu = gpu();
    for mode in [Mode::Cast, Mode::Ao] {
        let sh = Shading {
            mode,
            ao_rays: 8,
            ..Shading::default()
        };
        let run = |sh: Shading| {
            let s = Settings {
                shading: sh,
                ..Settings::default()
            };
            render(&gpu, &p, &cam, 32, 32, s)
        };
        let (a, sa) = run(sh);
        let (b, sb) = run(Shading { cull: false, ..sh });
        assert!(bits(&a) == bits(&b), "{mode:?}: culling changed the image");
        assert!(
            sa.traced_rays < sb.traced_rays,
            "{mode:?}: culling skips rays"
        );
        if mode == Mode::Ao {
            let (c, sc) = run(Shading {
                any_hit: false,
                ..sh
            });
            let rgb = |f: &Frame| f.pixels.iter().map(|p| p.rgb).collect::<Vec<_>>();
            assert_eq!(rgb(&a), rgb(&c), "any-hit changed the occlusion");
            assert!(sa.steps < sc.steps, "any-hit rays take fewer steps");
        }
    }
}

#[test]
fn bad_shading_input_is_a_clear_error() {
    let dir = TempDir::new("shading-bad");
    let ply = repo().join("scenes/meshes/bumpy.ply");
    let out = dir.path("o.png");
    let scene = |extra: &str| {
        dir.write(
            "s.toml",
            format!("[[mesh]]\nfile = {:?}\n{extra}", ply.display().to_string()),
        )
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["--mode".into(), "foo".into()], "invalid value 'foo'"),
        (vec!["--spp".into(), "0".into()], "--spp must be 1..="),
        (vec!["--ao-rays".into(), "0".into()], "--ao-rays must be"),
        (
            vec!["--sampler".into(), "halton".into()],
            "invalid value 'halton'",
        ),
        (
            vec!["--exposure".into(), "nan".into()],
            "--exposure must be finite",
        ),
    ];
    let good = scene("");
    for (args, want) in cases {
        let mut a: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"render", &good, &"-o", &out];
        a.extend(args.iter().map(|s| s as &dyn AsRef<std::ffi::OsStr>));
        let o = dcrt(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} should fail");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    let scenes = [
        (
            "[[light]]\ntype = \"point\"\ndirection = [0.0, 0.0, 1.0]\n",
            "light 1: a point light needs `position`",
        ),
        (
            "[[light]]\ntype = \"directional\"\ndirection = [0.0, 0.0, 0.0]\n",
            "light 1: direction must be finite and non-zero",
        ),
        ("[[light]]\ntype = \"spot\"\n", "unknown variant `spot`"),
        ("[render]\nmode = \"raster\"\n", "unknown variant `raster`"),
        ("[render]\nspp = 0\n", "spp must be 1..="),
        (
            "[render]\nsampler = \"halton\"\n",
            "unknown variant `halton`",
        ),
    ];
    for (text, want) in scenes {
        let s = scene(text);
        let o = dcrt(&[&"render", &s, &"-o", &out]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{text} should fail");
        assert!(err.contains(want), "{text}: {err}");
        assert!(!err.contains("panicked"), "{text}: {err}");
    }
    assert!(!exists(&out), "no image is written on bad input");
}
