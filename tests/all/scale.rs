//! Robustness at every scale, through the GPU kernels: ambient occlusion and shadows of a lone
//! convex object seen from near and far and translated far from the origin, small triangles far
//! away and huge triangles close up against the f64 reference. Each test prints its failure
//! count before it asserts.

use crate::common::*;
use dcrt::gpu::tracer::Settings;
use dcrt::reference::Reference;
use dcrt::render::Prepared;
use dcrt::scene::ray::Ray;
use dcrt::scene::{Camera, Model};
use dcrt::shading::{Light, Mode, Shading};

type Tri = [[f32; 3]; 3];

/// A lat-long sphere of `radius` at `center`: a convex polyhedron (its vertices are on the
/// sphere), with `n` rings and `2n` segments.
fn sphere(n: u32, radius: f64, center: [f64; 3]) -> Vec<Tri> {
    let v = |i: u32, j: u32| -> [f32; 3] {
        let t = std::f64::consts::PI * f64::from(i) / f64::from(n);
        let p = std::f64::consts::TAU * f64::from(j % (2 * n)) / f64::from(2 * n);
        let d = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
        std::array::from_fn(|a| (center[a] + radius * d[a]) as f32)
    };
    let mut tris = Vec::new();
    for i in 0..n {
        for j in 0..2 * n {
            let (a, b, c, d) = (v(i, j), v(i, j + 1), v(i + 1, j), v(i + 1, j + 1));
            if i > 0 {
                tris.push([a, c, b]);
            }
            if i + 1 < n {
                tris.push([b, c, d]);
            }
        }
    }
    tris
}

/// A camera `distance` from `center` looking at it, with the view angle that frames a sphere of
/// `radius` with a margin.
fn camera_at(center: [f64; 3], radius: f64, distance: f64) -> Camera {
    let dir = [0.3, -1.0, 0.2];
    let l = (dir.iter().map(|c| c * c).sum::<f64>()).sqrt();
    Camera {
        position: std::array::from_fn(|a| center[a] + distance * dir[a] / l),
        focal_point: center,
        view_up: [0.0, 0.0, 1.0],
        view_angle: 2.4 * (radius / distance).asin().to_degrees(),
        parallel_scale: None,
    }
}

fn shade(p: &Prepared, cam: &Camera, size: u32, sh: Shading) -> dcrt::gpu::frame::Frame {
    let s = Settings {
        shading: sh,
        ..Settings::default()
    };
    render(&gpu(), p, cam, size, size, s).0
}

/// (hit pixels, hit pixels whose colour is not `want`) of an AO render of a convex sphere.
fn ao_failures(radius: f64, center: [f64; 3], distance: f64) -> (usize, usize) {
    let p = prepare(Model::from_triangles(sphere(24, radius, center)));
    let sh = Shading {
        mode: Mode::Ao,
        ao_rays: 8,
        ..Shading::default()
    };
    let f = shade(&p, &camera_at(center, radius, distance), 32, sh);
    let hits: Vec<_> = f.pixels.iter().filter(|p| !is_miss(p)).collect();
    let bad = hits.iter().filter(|p| p.rgb != [1.0; 3]).count();
    (hits.len(), bad)
}

/// Camera distances from the centre, in radii, and centres of the object.
const DISTANCES: [f64; 5] = [2.0, 11.0, 101.0, 1001.0, 10001.0];
const CENTERS: [[f64; 3]; 3] = [[0.0; 3], [1e5, -3e4, 2e4], [1e7, 3e6, -2e6]];

/// The sphere's radius at `center`: 2, or large enough that its f32 vertices (spaced by the ulps
/// of the centre's coordinates) still make a convex polyhedron.
fn radius(center: [f64; 3]) -> f64 {
    center.iter().fold(2.0f64, |r, c| r.max(c.abs() * 1e-4))
}

#[test]
fn ao_of_a_convex_object_is_one_at_every_distance_and_place() {
    let mut failures = Vec::new();
    for center in CENTERS {
        let r = radius(center);
        for k in DISTANCES {
            let (hits, bad) = ao_failures(r, center, r * k);
            eprintln!(
                "AO: centre {center:?}, camera {k} radii away: {bad} of {hits} hit pixels below 1"
            );
            assert!(hits > 300, "the sphere fills the view ({hits} pixels)");
            if bad > 0 {
                failures.push((center, k, bad, hits));
            }
        }
    }
    assert!(failures.is_empty(), "AO below 1: {failures:?}");
}

#[test]
fn shadows_of_a_convex_object_lit_from_the_camera_leave_every_hit_pixel_lit() {
    let mut failures = Vec::new();
    for center in CENTERS {
        let r = radius(center);
        for k in [2.0, 101.0, 10001.0] {
            let cam = camera_at(center, r, r * k);
            let p = prepare(Model::from_triangles(sphere(24, r, center)));
            // A directional light travelling along the view: every visible face faces it.
            let f: [f64; 3] = std::array::from_fn(|a| cam.focal_point[a] - cam.position[a]);
            let l = f.iter().map(|c| c * c).sum::<f64>().sqrt();
            let mut lights = [None; 4];
            lights[0] = Some(Light::Directional {
                dir: f.map(|c| (c / l) as f32),
                color: [1.0; 3],
            });
            let sh = Shading {
                mode: Mode::Shadows,
                lights,
                ambient: 0.0,
                ..Shading::default()
            };
            let img = shade(&p, &cam, 32, sh);
            let hits: Vec<_> = img.pixels.iter().filter(|p| !is_miss(p)).collect();
            // Shadowed, a pixel gets the ambient term only (0 here).
            let dark = hits.iter().filter(|p| p.rgb[0] <= 0.0).count();
            eprintln!(
                "shadows: centre {center:?}, {k} radii: {dark} of {} hit pixels dark",
                hits.len()
            );
            if dark > 0 {
                failures.push((center, k, dark));
            }
        }
    }
    assert!(failures.is_empty(), "shadowed pixels: {failures:?}");
}

/// Rays from `origin` towards points spread over the disc of 0.9 `radius` about `center`, as
/// seen from the origin.
fn rays_into_disc(origin: [f64; 3], center: [f64; 3], radius: f64, n: usize) -> Vec<Ray> {
    let f: [f64; 3] = std::array::from_fn(|a| center[a] - origin[a]);
    let d = f.iter().map(|c| c * c).sum::<f64>().sqrt();
    let f = f.map(|c| c / d);
    let r = normalize([f[1], -f[0], 0.0]);
    let u = cross(r, f);
    let side = (n as f64).sqrt().ceil() as usize;
    let mut rays = Vec::new();
    for i in 0..side {
        for j in 0..side {
            let (a, b) = (
                2.0 * (i as f64 + 0.5) / side as f64 - 1.0,
                2.0 * (j as f64 + 0.5) / side as f64 - 1.0,
            );
            if a * a + b * b > 0.81 {
                continue;
            }
            let target: [f64; 3] =
                std::array::from_fn(|k| center[k] + radius * (a * r[k] + b * u[k]));
            let dir: [f64; 3] = std::array::from_fn(|k| target[k] - origin[k]);
            rays.push(Ray {
                origin: origin.map(|c| c as f32),
                dir: normalize(dir).map(|c| c as f32),
                tmax: f32::INFINITY,
            });
        }
    }
    rays
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let l = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    v.map(|c| c / l)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// (rays the reference hits, of those the GPU misses) for `tris` traced along `rays`.
fn misses_against_reference(tris: Vec<Tri>, rays: &[Ray]) -> (usize, usize) {
    let reference = Reference::new(&tris);
    let p = prepare(Model::from_triangles(tris));
    let gpu = gpu();
    let mut tracer = p.tracer(&gpu, Settings::default()).unwrap();
    let got = tracer.trace_camera_rays(rays).unwrap();
    let want = reference.closest_hits(rays);
    let hit = want.iter().filter(|h| h.is_some()).count();
    let missed = want
        .iter()
        .zip(&got)
        .filter(|(w, g)| w.is_some() && g.is_none())
        .count();
    (hit, missed)
}

#[test]
fn small_triangles_far_away_are_hit_as_the_reference_hits_them() {
    // A sphere of radius 1 (edges about 0.2) seen from 3e4, 5e4 and 1e5 away, at the origin and
    // translated.
    let mut failures = Vec::new();
    for center in [[0.0; 3], [1e5, 2e4, -3e4]] {
        for distance in [3e4, 5e4, 1e5] {
            let dir = normalize([0.2, -1.0, 0.3]);
            let origin: [f64; 3] = std::array::from_fn(|a| center[a] + distance * dir[a]);
            let rays = rays_into_disc(origin, center, 1.0, 1200);
            let (hit, missed) = misses_against_reference(sphere(16, 1.0, center), &rays);
            eprintln!("far: centre {center:?}, {distance} away: {missed} of {hit} missed");
            assert!(hit * 10 >= rays.len() * 9, "the reference hits the disc");
            if missed > 0 {
                failures.push((center, distance, missed, hit));
            }
        }
    }
    assert!(failures.is_empty(), "far triangles missed: {failures:?}");
}

/// Two triangles `size` across (2e6 to 2e8) through the origin on a tilted normal, seen from 2
/// units away by rays within 60 degrees of the normal. At 2e8 the plane's offset at the origin,
/// computed from vertices 1e8 away, is below f32's resolution (the shear's z terms, ~1e24, cancel
/// to ~1e16): the kernel resolves it in extended precision (`plane_hit`). Every ray the f64
/// reference hits must hit, as camera rays and as rays leaving a surface (shadow rays, which need
/// the hit proven in front of the origin), at the reference's distance; and rays leaving the
/// plane from the kernel's own hit points, offset as `spawn` offsets them, towards the camera's
/// side (shadow rays to a light there) must never hit it.
#[test]
fn huge_triangles_close_up_are_hit_as_the_reference_hits_them() {
    let mut failures = Vec::new();
    for size in [2e6, 6e6, 2e7, 2e8] {
        let n = normalize([0.3, -0.5, 0.8]);
        let a = normalize(cross(n, [0.0, 0.0, 1.0]));
        let b = cross(n, a);
        let s = size / 2.0;
        let corner = |x: f64, y: f64| -> [f32; 3] {
            std::array::from_fn(|k| (s * (x * a[k] + y * b[k])) as f32)
        };
        let (p, q, r, t) = (
            corner(-1.0, -1.0),
            corner(1.0, -1.0),
            corner(1.0, 1.0),
            corner(-1.0, 1.0),
        );
        let tris = vec![[p, q, r], [p, r, t]];
        let origin: [f64; 3] = std::array::from_fn(|k| 2.0 * n[k] + 0.37 * a[k]);
        let mut rays = Vec::new();
        for i in 0..32 {
            for j in 0..32 {
                let (x, y) = (
                    (i as f64 + 0.5) / 32.0 * 2.0 - 1.0,
                    (j as f64 + 0.5) / 32.0 * 2.0 - 1.0,
                );
                let d: [f64; 3] = std::array::from_fn(|k| -n[k] + 1.5 * (x * a[k] + y * b[k]));
                rays.push(Ray {
                    origin: origin.map(|c| c as f32),
                    dir: normalize(d).map(|c| c as f32),
                    tmax: f32::INFINITY,
                });
            }
        }
        let reference = Reference::new(&tris);
        let want = reference.closest_hits(&rays);
        assert!(
            want.iter().all(Option::is_some),
            "the reference hits every ray"
        );
        let prepared = prepare(Model::from_triangles(tris));
        let gpu = gpu();
        let mut tracer = prepared.tracer(&gpu, Settings::default()).unwrap();
        let camera = tracer.trace_camera_rays(&rays).unwrap();
        let surface = tracer.trace_rays(&rays).unwrap();
        // (missed, off by more than 1e-4 of the distance).
        let wrong = |got: &[Option<dcrt::gpu::rays::RayHit>]| {
            let missed = got.iter().filter(|g| g.is_none()).count();
            let off = got
                .iter()
                .zip(&want)
                .filter_map(|(g, w)| Some((g.as_ref()?.t, w.unwrap().t)))
                .filter(|&(g, w)| (f64::from(g) - w).abs() > 1e-4 * w)
                .count();
            (missed, off)
        };
        let (camera_wrong, surface_wrong) = (wrong(&camera), wrong(&surface));
        // Back towards the camera's side, from each hit, on a spread of directions.
        let leaving: Vec<Ray> = camera
            .iter()
            .zip(&rays)
            .enumerate()
            .filter_map(|(i, (h, ray))| {
                let h = h.as_ref()?;
                let towards = if dot(h.normal, ray.dir) < 0.0 {
                    1.0
                } else {
                    -1.0
                };
                let nl = h.normal.map(|c| c * towards);
                let o = dcrt::mirror::offset::offset_ray(h.point, nl, h.error);
                let tilt = (i as f32 * 0.37).sin() * 0.9;
                let d: [f32; 3] = std::array::from_fn(|k| {
                    nl[k] + tilt * a[k] as f32 + (1.0 - tilt.abs()) * 0.5 * b[k] as f32
                });
                Some(Ray {
                    origin: o,
                    dir: d,
                    tmax: f32::INFINITY,
                })
            })
            .collect();
        let self_hits = tracer
            .trace_rays(&leaving)
            .unwrap()
            .iter()
            .filter(|h| h.is_some())
            .count();
        eprintln!(
            "huge: {size} across, {} rays: (missed, off) camera rays {camera_wrong:?}, surface \
             rays {surface_wrong:?}; {self_hits} of {} rays leaving the plane hit it",
            rays.len(),
            leaving.len()
        );
        assert_eq!(leaving.len(), rays.len());
        if camera_wrong != (0, 0) || surface_wrong != (0, 0) || self_hits > 0 {
            failures.push((size, camera_wrong, surface_wrong, self_hits));
        }
    }
    assert!(failures.is_empty(), "huge triangles: {failures:?}");
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
