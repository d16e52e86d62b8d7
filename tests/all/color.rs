//! Colour by data: the albedo of a hit comes from its triangle's attributes through the
//! colormap exactly as the CPU twins compute it; images are bit-identical across ranks, caches
//! and mappings, in every shading mode; a one-line cache finishes; a model without colour data
//! stores and fetches nothing extra.

use crate::common::*;
use dcrt::colormap::Colormap;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::Settings;
use dcrt::mirror::colormap::{colormap, srgb_color};
use dcrt::render::{DcOptions, Prepared};
use dcrt::scene::{Camera, Model, Scene};
use dcrt::shading::{Mode, Shading};

const W: u32 = 48;
const H: u32 = 40;

/// A legacy VTK file: an n x n grid of quads on z = 0 over [0, 1]^2, a point array "x" (the
/// x coordinate), a cell array "id" (the cell's index) and a cell colour array "rgb".
fn grid_vtk(n: usize) -> String {
    let mut s = format!(
        "# vtk DataFile Version 3.0\ngrid\nASCII\nDATASET POLYDATA\nPOINTS {} float\n",
        (n + 1) * (n + 1)
    );
    for j in 0..=n {
        for i in 0..=n {
            s += &format!("{} {} 0\n", i as f32 / n as f32, j as f32 / n as f32);
        }
    }
    s += &format!("POLYGONS {} {}\n", n * n, 5 * n * n);
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            s += &format!("4 {} {} {} {}\n", a, a + 1, a + n + 2, a + n + 1);
        }
    }
    s += &format!(
        "POINT_DATA {}\nSCALARS x float\nLOOKUP_TABLE default\n",
        (n + 1) * (n + 1)
    );
    for _ in 0..=n {
        for i in 0..=n {
            s += &format!("{}\n", i as f32 / n as f32);
        }
    }
    s += &format!(
        "CELL_DATA {}\nSCALARS id int\nLOOKUP_TABLE default\n",
        n * n
    );
    for c in 0..n * n {
        s += &format!("{c}\n");
    }
    s += "COLOR_SCALARS rgb 3\n";
    for c in 0..n * n {
        s += &format!("{} {} 0.25\n", (c % 7) as f32 / 6.0, (c % 5) as f32 / 4.0);
    }
    s
}

const CAMERA: &str = "[camera]\nposition = [0.5, -0.6, 1.2]\nfocal_point = [0.5, 0.5, 0]\n\
                      view_up = [0, 0, 1]\nview_angle = 50\n";

/// A scene of the grid four times over: coloured by point values, cell values, cell colours,
/// and plain (so the model mixes every look, and its attributes are three words a triangle).
fn mixed_scene(d: &TempDir) -> Scene {
    d.write("grid.vtk", grid_vtk(12));
    let text = format!(
        "{CAMERA}[image]\nwidth = {W}\nheight = {H}\n\
         [[mesh]]\nfile = \"grid.vtk\"\ncolor_by = \"x\"\ncolormap = \"rainbow-uniform\"\n\
         [[mesh]]\nfile = \"grid.vtk\"\ncolor_by = \"id\"\ncell = true\ntranslate = [1.1, 0, 0]\n\
         [[mesh]]\nfile = \"grid.vtk\"\ncolor_by = \"rgb\"\ncell = true\ntranslate = [0, 1.1, 0]\n\
         [[mesh]]\nfile = \"grid.vtk\"\ncolor = [0.3, 0.6, 0.2]\ntranslate = [1.1, 1.1, 0]\n"
    );
    let path = d.write("mixed.toml", text);
    Scene::load(&path).unwrap()
}

fn shading(mode: Mode) -> Shading {
    Shading {
        mode,
        spp: if mode == Mode::Cast { 1 } else { 2 },
        max_depth: 2,
        ..Shading::default()
    }
}

#[test]
fn images_are_the_same_through_every_cache() {
    let gpu = gpu();
    let d = TempDir::new("color-dc");
    let scene = mixed_scene(&d);
    let model = scene.load_model().unwrap();
    let camera = scene.camera.unwrap();
    let p = prepare(model);
    assert_eq!(p.blocks.attrs.words, 3);
    assert!(p.blocks.attrs.blocks >= 1);
    let basis = camera.basis(W, H);
    for mode in [Mode::Cast, Mode::Path] {
        let settings = Settings {
            shading: shading(mode),
            ..Settings::default()
        };
        let mut t = p.tracer(&gpu, settings).unwrap();
        let (reference, _) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        let buffer = Settings {
            store: Store::Buffer,
            ..settings
        };
        let (b, _) = p
            .tracer(&gpu, buffer)
            .unwrap()
            .render(&basis, [0.1, 0.2, 0.3])
            .unwrap();
        same_pixels(&reference, &b, &format!("{mode:?} buffer store"));
        for (n, size, map) in [
            (2, "1line", CacheMap::Ize),
            (3, "1/8", CacheMap::Demarle),
            (4, "1line", CacheMap::Demarle),
            (7, "1/2", CacheMap::Ize),
        ] {
            let o = DcOptions {
                ranks: n,
                rank: n - 1,
                cache: CacheSize::parse(size).unwrap(),
                map,
                replicate: Default::default(),
            };
            let mut t = p.tracer_dc(&gpu, settings, &o).unwrap();
            let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
            let what = format!("{mode:?} N={n} cache {size} {map:?}");
            same_pixels(&reference, &frame, &what);
            // Attribute blocks were borrowed and fetched like any block.
            let attr0 = p.blocks.node_blocks + p.blocks.tri_blocks;
            let fetched_attr = t
                .take_trace()
                .rounds
                .iter()
                .flat_map(|r| &r.faults)
                .filter(|f| f.served && f.block >= attr0)
                .count();
            assert!(fetched_attr > 0, "{what}: no attribute block was fetched");
            assert!(stats.fetched_blocks > 0);
        }
    }
}

/// A valley of n x n quads, z = |x - 0.5| over [0, 1]^2, every cell white by a cell colour array
/// "rgb" (or a plain mesh with `plain`): light that bounces off one side hits the other.
fn valley_vtk(n: usize, plain: bool) -> String {
    let mut s = format!(
        "# vtk DataFile Version 3.0\nvalley\nASCII\nDATASET POLYDATA\nPOINTS {} float\n",
        (n + 1) * (n + 1)
    );
    for j in 0..=n {
        for i in 0..=n {
            let x = i as f32 / n as f32;
            s += &format!("{x} {} {}\n", j as f32 / n as f32, (x - 0.5).abs());
        }
    }
    s += &format!("POLYGONS {} {}\n", n * n, 5 * n * n);
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            s += &format!("4 {} {} {} {}\n", a, a + 1, a + n + 2, a + n + 1);
        }
    }
    if !plain {
        s += &format!("CELL_DATA {}\nCOLOR_SCALARS rgb 3\n", n * n);
        s += &"1 1 1\n".repeat(n * n);
    }
    s
}

/// Path tracing with a sun (two rays a pixel in each wave: the sun's and the bounce) in a valley
/// whose bounce rays hit its other side: the albedo kernel must resolve each bounce ray's hit in
/// that ray's wave slot (`wave_slot`), where the gather reads it, so cells white by data render
/// to the bit as a plain white mesh.
#[test]
fn bounce_albedos_by_data_equal_a_plain_colour() {
    let gpu = gpu();
    let d = TempDir::new("color-valley");
    let mut frames = Vec::new();
    for plain in [false, true] {
        d.write("valley.vtk", valley_vtk(16, plain));
        let look = if plain {
            "color = [1, 1, 1]"
        } else {
            "color_by = \"rgb\"\ncell = true"
        };
        let text = format!(
            "[camera]\nposition = [0.5, -0.9, 1.4]\nfocal_point = [0.5, 0.5, 0.1]\n\
             view_up = [0, 0, 1]\nview_angle = 50\n[image]\nwidth = {W}\nheight = {H}\n\
             [[mesh]]\nfile = \"valley.vtk\"\n{look}\n"
        );
        let scene = Scene::load(&d.write("valley.toml", text)).unwrap();
        let model = scene.load_model().unwrap();
        let camera = scene.camera.unwrap();
        let p = prepare(model);
        assert_eq!(
            p.blocks.attrs.blocks > 0,
            !plain,
            "attribute blocks, plain {plain}"
        );
        let settings = Settings {
            shading: Shading {
                sun_dir: Some([0.3, 0.2, -1.0]),
                ..shading(Mode::Path)
            },
            ..Settings::default()
        };
        let mut t = p.tracer(&gpu, settings).unwrap();
        frames.push(t.render(&camera.basis(W, H), [0.1, 0.2, 0.3]).unwrap().0);
    }
    same_pixels(&frames[1], &frames[0], "white by data against plain white");
}

/// Each triangle its own mesh of the colour the CPU twins give its attributes: the albedo kernel
/// must give every cell-coloured pixel exactly that colour.
#[test]
fn cell_colours_are_the_cpu_twins_bit_for_bit() {
    let gpu = gpu();
    let d = TempDir::new("color-cells");
    d.write("grid.vtk", grid_vtk(9));
    let camera = Camera {
        position: [0.5, -0.6, 1.2],
        focal_point: [0.5, 0.5, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 50.0,
        parallel_scale: None,
    };
    for (key, extra) in [
        (
            "id",
            "cell = true\ncolormap = \"viridis\"\nrange = [-3, 150]",
        ),
        ("id", "cell = true"),
        ("rgb", "cell = true"),
    ] {
        let path = d.write(
            "s.toml",
            format!("[[mesh]]\nfile = \"grid.vtk\"\ncolor_by = \"{key}\"\n{extra}\n"),
        );
        let scene = Scene::load(&path).unwrap();
        let model = scene.load_model().unwrap();
        let coloured = prepare(model.clone());
        // The same triangles, one constant-coloured mesh each.
        let attrs = model.attributes.clone().unwrap();
        let look = model.looks[0].clone();
        let colors: Vec<[f32; 3]> = (0..model.triangles.len())
            .map(|t| {
                let w = attrs.data[t * attrs.words as usize];
                match &look {
                    dcrt::scene::color::Look::Scalars {
                        colormap: map,
                        range,
                        ..
                    } => {
                        let scale = dcrt::colormap::scale(range[0], range[1]);
                        colormap(f32::from_bits(w), range[0], scale, map.index())
                    }
                    _ => srgb_color(w),
                }
            })
            .collect();
        let plain = Model {
            mesh_first: (0..model.triangles.len() as u32).collect(),
            colors,
            ..Model::from_triangles(model.triangles.clone())
        };
        let plain = prepare(plain);
        let (a, _) = render(&gpu, &coloured, &camera, W, H, Settings::default());
        let (b, _) = render(&gpu, &plain, &camera, W, H, Settings::default());
        assert!(a.pixels.iter().filter(|p| !is_miss(p)).count() > 400);
        same_pixels(&a, &b, &format!("{key} {extra}"));
    }
}

/// Point data is interpolated at the hit before mapping: on a plane coloured by x (linear, so
/// interpolation is exact), each pixel's colour is the colormap bin of the hit's x, give or take
/// one bin where rounding puts the hit on the other side of a bin's edge.
#[test]
fn point_values_are_interpolated_at_the_hit() {
    let gpu = gpu();
    let d = TempDir::new("color-points");
    d.write("grid.vtk", grid_vtk(6));
    let path = d.write(
        "s.toml",
        "[[mesh]]\nfile = \"grid.vtk\"\ncolor_by = \"x\"\ncolormap = \"grayscale\"\n",
    );
    let scene = Scene::load(&path).unwrap();
    let model = scene.load_model().unwrap();
    let camera = Camera {
        position: [0.5, 0.5, 1.0],
        focal_point: [0.5, 0.5, 0.0],
        view_up: [0.0, 1.0, 0.0],
        view_angle: 60.0,
        parallel_scale: None,
    };
    let coloured = prepare(model.clone());
    let white = prepare(Model {
        colors: vec![[1.0; 3]],
        ..Model::from_triangles(model.triangles.clone())
    });
    let (a, _) = render(&gpu, &coloured, &camera, W, H, Settings::default());
    let (b, _) = render(&gpu, &white, &camera, W, H, Settings::default());
    let hits = reference(&model, &camera, W, H);
    let basis = camera.basis(W, H);
    let (mut exact, mut near, mut total) = (0, 0, 0);
    for (i, h) in hits.iter().enumerate() {
        let Some(h) = h else { continue };
        // The albedo: the coloured pixel over the white one (same shading factor).
        let albedo = a.pixels[i].rgb[0] / b.pixels[i].rgb[0];
        let x = basis.origin[0] as f64 + h.t * basis.dir(i as u32 % W, i as u32 / W)[0];
        let want = dcrt::mirror::colormap::bin(x as f32, 0.0, 256.0);
        let got = (0..256)
            .min_by(|&p, &q| {
                let e = |k: usize| (dcrt::colormap::srgb_to_linear(k as u8) - albedo).abs();
                e(p).total_cmp(&e(q))
            })
            .unwrap();
        total += 1;
        exact += usize::from(got == want);
        near += usize::from(got.abs_diff(want) <= 1);
    }
    assert!(total > 1000, "{total} hits");
    assert_eq!(near, total, "every pixel within a bin of its hit's value");
    assert!(exact * 10 >= total * 9, "{exact} of {total} exact");
}

/// Without colour data nothing extra is stored: no attribute blocks, no attribute kernel, and a
/// distributed-cache frame fetches exactly what it did before (the same blocks).
#[test]
fn no_colour_data_no_attribute_blocks() {
    let d = TempDir::new("color-none");
    d.write("grid.vtk", grid_vtk(4));
    let path = d.write("s.toml", "[[mesh]]\nfile = \"grid.vtk\"\n");
    let model = Scene::load(&path).unwrap().load_model().unwrap();
    assert!(model.attributes.is_none());
    let p: Prepared = prepare(model);
    assert_eq!(p.blocks.attrs.blocks, 0);
    assert_eq!(p.blocks.count(), p.blocks.node_blocks + p.blocks.tri_blocks);
    assert_eq!(Colormap::default(), Colormap::CoolToWarm);
}

/// `--legend` draws a scalar bar per array of values at the image's right edge: the colormap's
/// own 8-bit colours from the range's start (bottom) to its end (top); the rest of the image is
/// untouched. A scene coloured only by direct colours has no legend to draw: an error.
#[test]
fn legend_shows_the_colormap_beside_the_image() {
    let d = TempDir::new("color-legend");
    d.write("grid.vtk", grid_vtk(4));
    let scene = d.write(
        "s.toml",
        format!(
            "{CAMERA}[image]\nwidth = 160\nheight = 120\n[[mesh]]\nfile = \"grid.vtk\"\n\
             color_by = \"x\"\ncolormap = \"viridis\"\n"
        ),
    );
    let (plain, with) = (d.path("plain.png"), d.path("legend.png"));
    for (out, extra) in [(&plain, None), (&with, Some("--legend"))] {
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"render", &scene, &"-o", out];
        if let Some(e) = &extra {
            args.push(e);
        }
        let r = dcrt(&args);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let a = image::open(&plain).unwrap().to_rgb8();
    let b = image::open(&with).unwrap().to_rgb8();
    let (w, h) = b.dimensions();
    // The bar: 3% of the width (6 px at least), 60% of the height, centred, at the right edge
    // less room for the labels (`legend::Legend::draw`).
    let text = (f64::from(h) / 28.0).clamp(8.0, 28.0);
    let bar_w = (f64::from(w) * 0.03).max(6.0) as u32;
    let bar_h = (f64::from(h) * 0.6).max(16.0) as u32;
    let x0 = w - bar_w - (text * 4.5) as u32;
    let top = (h - bar_h) / 2;
    let x = x0 + bar_w / 2;
    let map = Colormap::Viridis.srgb();
    for y in 1..bar_h - 1 {
        let bin = ((bar_h - 1 - y) as usize * 256) / bar_h as usize;
        assert_eq!(b.get_pixel(x, top + y).0, map[bin], "bar row {y}");
    }
    for y in 0..h {
        for x in 0..x0 - 2 {
            assert_eq!(
                a.get_pixel(x, y),
                b.get_pixel(x, y),
                "pixel ({x}, {y}) outside the legend"
            );
        }
    }
    // Colour arrays have no scale to show.
    let rgb = d.write(
        "rgb.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"grid.vtk\"\ncolor_by = \"rgb\"\ncell = true\n"),
    );
    let out = d.path("rgb.png");
    let r = dcrt(&[&"render", &rgb, &"-o", &out, &"--legend"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("--legend: no mesh is coloured by values"),
        "{err}"
    );
    assert!(!out.exists());
}
