//! The GPU against the independent f64 CPU reference: hit/miss on at least 99.99% of pixels,
//! primitive id on at least 99.9%, depth within 1e-5 relative and normals where ids agree.

use crate::common::*;
use dcrt::blocks::Format;
use dcrt::bvh::Build;
use dcrt::gpu::frame::FrameStats;
use dcrt::gpu::tracer::Settings;
use dcrt::render::Prepared;
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Model, Scene};

const W: u32 = 256;
const H: u32 = 256;

fn check(name: &str, model: Model, camera: Camera) -> FrameStats {
    check_built(name, model, camera, Build::default())
}

/// `check` on a tree built as `build` says; the frame's statistics.
fn check_built(name: &str, model: Model, camera: Camera, build: Build) -> FrameStats {
    let gpu = gpu();
    let prepared = Prepared::from_model(model, build, Format::default(), 0.0).unwrap();
    let (frame, stats) = render(&gpu, &prepared, &camera, W, H, Settings::default());
    let reference = reference(&prepared.model, &camera, W, H);
    let n = frame.pixels.len();
    let (mut hitmiss_bad, mut id_bad, mut both_hit) = (0usize, 0usize, 0usize);
    let mut worst_depth = 0.0f64;
    for (p, r) in frame.pixels.iter().zip(&reference) {
        match r {
            None => hitmiss_bad += usize::from(!is_miss(p)),
            Some(h) if is_miss(p) => {
                let _ = h;
                hitmiss_bad += 1
            }
            Some(h) => {
                both_hit += 1;
                if p.id != h.prim {
                    id_bad += 1;
                    continue;
                }
                let rel = (f64::from(p.depth) - h.t).abs() / h.t;
                worst_depth = worst_depth.max(rel);
                let dn: f64 = (0..3)
                    .map(|a| (f64::from(p.normal[a]) - h.normal[a]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                assert!(
                    dn < 1e-4,
                    "{name}: normal differs by {dn} at prim {}",
                    h.prim
                );
            }
        }
    }
    eprintln!(
        "{name}: {n} pixels, {both_hit} hit in both, hit/miss differ {hitmiss_bad}, \
         id differs {id_bad}, worst relative depth error {worst_depth:.2e}"
    );
    assert!(both_hit > n / 10, "{name}: the view should see the model");
    assert!(
        hitmiss_bad as f64 <= n as f64 * 1e-4,
        "{name}: hit/miss differ on {hitmiss_bad}"
    );
    assert!(
        id_bad as f64 <= n as f64 * 1e-3,
        "{name}: ids differ on {id_bad}"
    );
    assert!(worst_depth <= 1e-5, "{name}: depth error {worst_depth}");
    stats
}

#[test]
fn loaded_meshes_match_the_reference() {
    let scene = scene("bumpy.toml");
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    check("bumpy", model, camera);
}

fn generated(g: Generator, triangles: u64) -> (Model, Camera) {
    let scene = Scene::generated(g, triangles, W, H);
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    (model, camera)
}

/// Also with a tree of smaller leaves (`--bvh-node-cost 1`), which takes fewer steps.
#[test]
fn rm_matches_the_reference() {
    let (m, c) = generated(Generator::Rm, 60_000);
    let default = check("rm", m.clone(), c);
    let small = Build {
        node_cost: 1.0,
        ..Build::default()
    };
    let smaller = check_built("rm, node cost 1", m, c, small);
    assert_eq!(smaller.rays, default.rays);
    assert!(
        smaller.steps * 20 < default.steps * 19,
        "steps {} against {} at the default node cost",
        smaller.steps,
        default.steps
    );
}

#[test]
fn assembly_matches_the_reference() {
    let (m, c) = generated(Generator::Assembly, 60_000);
    check("assembly", m, c);
}

#[test]
fn assembly_interior_matches_the_reference() {
    // From inside the shell the parts are visible: the occluded geometry is traced right too.
    let (m, _) = generated(Generator::Assembly, 60_000);
    let camera = Camera {
        position: [-1.5, 0.05, 0.05],
        focal_point: [1.0, 0.0, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 70.0,
        parallel_scale: None,
    };
    check("assembly inside", m, camera);
}

#[test]
fn parallel_projection_matches_the_reference() {
    // ParaView's parallel projection (a .pvcc with CameraParallelProjection 1): rays along the
    // view from the image plane. The depth is measured from that plane.
    let scene = scene("bumpy.toml");
    let model = scene.load_model().unwrap();
    let camera = Camera {
        parallel_scale: Some(1.6),
        ..scene.camera_or_default(&model)
    };
    check("bumpy parallel", model, camera);
}

#[test]
fn visualization_examples_match_the_reference() {
    // The shipped STL, legacy VTK, glTF and VTK XML examples, through their scenes.
    for name in ["formats.toml", "isosurface.toml"] {
        let scene = scene(name);
        let model = scene.load_model().unwrap();
        let camera = scene.camera_or_default(&model);
        check(name, model, camera);
    }
}
