//! CPU reference for the `shadows` and `ao` modes at one sample per pixel (pixel centres): the
//! f64 reference tracer for visibility, and the GPU's own sampler, offset and hemisphere mapping
//! (`crate::mirror`), so GPU and CPU shoot the same secondary rays up to float rounding.

use crate::mirror::offset::{offset_distance, offset_ray};
use crate::mirror::sampling::{cosine_dir, sample2_patch};
use crate::reference::{Ray, Reference};
use crate::scene::{CameraBasis, Model};
use crate::shading::{Light, Mode, Offset, Shading};
use rayon::prelude::*;

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Linear RGB of every pixel, row-major; `None` when the mode is not `shadows` or `ao`.
pub fn reference_image(
    reference: &Reference,
    model: &Model,
    basis: &CameraBasis,
    shading: &Shading,
    background: [f32; 3],
) -> Option<Vec<[f32; 3]>> {
    if !matches!(shading.mode, Mode::Shadows | Mode::Ao) {
        return None;
    }
    let (w, h) = (basis.width, basis.height);
    let lights = shading.effective_lights(basis.key_light());
    let sample = shading.first_sample;
    let px: Vec<[f32; 3]> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (o, d) = basis.pixel_ray(x, y);
            let ray = Ray {
                origin: o.map(|c| c as f32),
                dir: d.map(|c| c as f32),
                tmax: f32::INFINITY,
            };
            let Some(hit) = reference.closest_hit(&ray) else {
                return background;
            };
            // The hit point from barycentrics in f64, rounded to f32 (half an ulp of error),
            // offset past that error as the GPU offsets past its own bound.
            let tri = model.triangles[hit.prim as usize];
            let b = [1.0 - hit.u - hit.v, hit.u, hit.v];
            let exact: [f64; 3] =
                std::array::from_fn(|a| (0..3).map(|k| b[k] * f64::from(tri[k][a])).sum::<f64>());
            let p = exact.map(|c| c as f32);
            let err = p.map(|c| c.abs() * f32::EPSILON);
            let mut n = hit.normal.map(|c| c as f32);
            if dot(n, ray.dir) > 0.0 {
                n = n.map(|c| -c);
            }
            let o = match shading.offset {
                Offset::Bound => offset_ray(p, n, offset_distance(n, err)),
                Offset::Epsilon(e) => std::array::from_fn(|a| p[a] + e * n[a]),
            };
            let visible = |dir: [f32; 3], tmax: f32| {
                !reference.any_hit(&Ray {
                    origin: o,
                    dir,
                    tmax,
                })
            };
            if shading.mode == Mode::Ao {
                let n_rays = shading.ao_rays;
                let open = (0..n_rays)
                    .filter(|&k| {
                        let u = sample2_patch(
                            shading.sampler,
                            shading.seed,
                            i,
                            w,
                            1,
                            sample * n_rays + k,
                        );
                        visible(cosine_dir(n, u), shading.ao_distance)
                    })
                    .count();
                return [open as f32 / n_rays as f32; 3];
            }
            let albedo = model.colors[model.mesh_of(hit.prim)];
            let mut c = albedo.map(|a| a * shading.ambient);
            for l in &lights {
                let (dir, tmax, scale) = match *l {
                    Light::Directional { dir, color } => {
                        let len = dot(dir, dir).sqrt();
                        (dir.map(|v| -v / len), f32::INFINITY, color)
                    }
                    Light::Point { pos, color } => {
                        let v: [f32; 3] = std::array::from_fn(|a| pos[a] - p[a]);
                        let len = dot(v, v).sqrt();
                        (v.map(|c| c / len), len, color.map(|c| c / (len * len)))
                    }
                };
                let cos = dot(dir, n);
                if cos > 0.0 && visible(dir, tmax) {
                    for a in 0..3 {
                        c[a] += albedo[a] * scale[a] * cos;
                    }
                }
            }
            c
        })
        .collect();
    Some(px)
}
