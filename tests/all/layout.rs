//! Host and WGSL structs agree: every member's offset and every struct's size against naga's
//! layout of the composed kernels (no GPU needed), and the layout probe, which reads every member
//! of every struct the host writes back through a shader, using the same accessors as the
//! kernels, and compares it word by word.

use crate::common::*;
use dcrt::colormap::Colormap;
use dcrt::gpu::layout::{
    Counter, FaultHeader, Light, MeshInfo, MirrorCase, MirrorResult, Params, Path, Pixel, RayState,
    ShadeParams, Stats,
};
use dcrt::gpu::shaders::wgsl_struct;
use dcrt::gpu::tracer::Settings;
use dcrt::scene::Model;
use dcrt::scene::color::Look;
use std::mem::{offset_of, size_of};

fn words<T: bytemuck::Pod>(v: &T) -> Vec<u32> {
    bytemuck::cast_slice(bytemuck::bytes_of(v)).to_vec()
}

#[test]
fn every_member_reads_back_through_the_shader() {
    let gpu = gpu();
    // Enough triangles for several node and triangle blocks.
    let tris: Vec<_> = (0..3000)
        .map(|i| {
            let x = i as f32 * 0.01;
            [[x, 0.0, 0.0], [x + 0.005, 1.0, 0.5], [x, 0.25 + x, 1.0]]
        })
        .collect();
    let mut model = Model::from_triangles(tris);
    model.mesh_first = vec![0, 1000, 2500];
    model.colors = vec![[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]];
    // Every look, so that each MeshInfo member holds something.
    model.looks = vec![
        Look::Constant,
        Look::Scalars {
            array: "p".into(),
            colormap: Colormap::Viridis,
            range: [-2.5, 7.5],
            cell: false,
        },
        Look::Colors {
            array: "rgb".into(),
            cell: true,
        },
    ];
    let prepared = prepare(model);
    let mut tracer = prepared.tracer(&gpu, Settings::default()).unwrap();
    let nodes = prepared.bvh.nodes.len() as u32;
    let tris = prepared.bvh.triangles.len() as u32;
    assert!(prepared.blocks.node_blocks > 1 && prepared.blocks.tri_blocks > 1);

    // Distinct values in every member that the accessors do not depend on.
    let base = tracer.params();
    let f = |k: u32| -> [f32; 4] { std::array::from_fn(|i| (k * 4 + i as u32) as f32 + 0.5) };
    let params = Params {
        origin: f(1),
        forward: f(2),
        right: f(3),
        up: f(4),
        background: f(5),
        width: 101,
        height: 102,
        tiles_x: 103,
        first_tile: 104,
        batch_rays: 105,
        step_budget: 106,
        stack_size: 107,
        rect_x: 108,
        rect_y: 109,
        rect_w: 110,
        rect_h: 111,
        pad0: nodes,
        pad1: tris,
        sample: 112,
        seed: 113,
        flags: 114,
        spp: 115,
        // A replicated tracer's `locate` reads none of these: they can take any value.
        dc_ranks: 116,
        dc_rank: 117,
        dc_lines: 118,
        dc_map: 119,
        dc_cache_row: 120,
        dc_root_row: 121,
        dc_fault_cap: 122,
        dc_defer: 123,
        opaque_zero: 124,
        attr_block0: 125,
        albedo_stride: 126,
        band_tiles: 127,
        lane: 128,
        ..base
    };
    let g = |k: u32| -> [f32; 4] { std::array::from_fn(|i| (k * 4 + i as u32) as f32 + 0.25) };
    let shading = ShadeParams {
        sky: g(1),
        sun_dir: g(2),
        sun: g(3),
        mode: 201,
        fan: 202,
        ao_rays: 203,
        ao_distance: 204.5,
        max_depth: 205,
        rr_depth: 206,
        light_count: 207,
        offset_mode: 208,
        epsilon: 209.5,
        ambient: 210.5,
        any_hit: 211,
        pad: 212,
        lights: std::array::from_fn(|i| Light {
            pos: g(10 + 2 * i as u32),
            color: g(11 + 2 * i as u32),
        }),
    };
    let rays = [
        RayState {
            origin: [1.5, 2.5, 3.5],
            t: 4.5,
            dir: [5.5, 6.5, 7.5],
            hit: 8,
            sp: 10,
            status: 11,
            steps: 12,
            cur_index: 13,
            cur_count: 14,
            prim: 15,
            normal: [16.5, 17.5, 18.5],
            wait_block: 19,
            flags: 20,
            hit_point: [21.5, 22.5, 23.5],
            hit_error: 24.5,
            b1: 25.5,
            b2: 26.5,
            skip: 27,
            pad: [28, 29],
        },
        RayState {
            origin: [-1.0, -2.0, -3.0],
            t: 1e30,
            dir: [0.25, 0.125, 0.0625],
            hit: u32::MAX,
            sp: 78,
            status: 79,
            steps: 80,
            cur_index: 81,
            cur_count: u32::MAX,
            prim: 83,
            normal: [-0.5, 0.25, 1e-3],
            wait_block: u32::MAX,
            flags: 86,
            hit_point: [-87.0, 88.0, -89.0],
            hit_error: 1e-7,
            b1: 0.25,
            b2: 0.5,
            skip: u32::MAX,
            pad: [90, 91],
        },
    ];
    let out = tracer.probe(params, &rays, &shading).unwrap();
    let mut expect = words(&params);
    for n in &prepared.bvh.nodes {
        expect.extend(words(n));
    }
    for t in 0..tris {
        let (tri, id) = prepared.blocks.triangle(t);
        assert_eq!(tri, prepared.bvh.triangles[t as usize]);
        expect.extend(bytemuck::cast_slice::<_, u32>(&tri));
        expect.push(id);
    }
    for r in &rays {
        expect.extend(words(r));
    }
    for m in prepared.meshes().infos() {
        expect.extend(words(&m));
    }
    expect.extend(words(&shading));
    assert_eq!(out.len(), expect.len());
    for (i, (a, b)) in out.iter().zip(&expect).enumerate() {
        assert_eq!(a, b, "word {i} differs");
    }
}

/// Checks a host struct against the WGSL struct of the same layout: equal sizes, and each WGSL
/// member (named in the list) at the host offset given; every WGSL member must be listed.
macro_rules! same_layout {
    ($host:ty, $wgsl:literal, { $($m:literal => $f:ident $(+ $k:literal)?),* $(,)? }) => {{
        let w = wgsl_struct($wgsl);
        let listed = [$($m),*];
        $(
            assert_eq!(
                w.offset($m) as usize,
                offset_of!($host, $f) $(+ $k)?,
                "{}.{}: WGSL offset against host {}.{}",
                $wgsl, $m, stringify!($host), stringify!($f)
            );
        )*
        for (m, _) in w.members {
            assert!(listed.contains(m), "WGSL {}.{} has no host counterpart", $wgsl, m);
        }
        w
    }};
}

#[test]
fn host_structs_match_naga_layouts() {
    let sized = |w: &dcrt::gpu::shaders::StructInfo, host: usize| {
        assert_eq!(w.size as usize, host, "size of WGSL {}", w.name);
    };
    let w = same_layout!(Params, "Params", {
        "origin" => origin, "forward" => forward, "right" => right, "up" => up,
        "background" => background, "width" => width, "height" => height,
        "tiles_x" => tiles_x, "first_tile" => first_tile, "batch_rays" => batch_rays,
        "step_budget" => step_budget, "stack_size" => stack_size, "mesh_count" => mesh_count,
        "node_blocks" => node_blocks, "dc_ranks" => dc_ranks, "dc_rank" => dc_rank,
        "dc_lines" => dc_lines, "dc_map" => dc_map, "dc_cache_row" => dc_cache_row,
        "dc_root_row" => dc_root_row, "dc_fault_cap" => dc_fault_cap, "rect_x" => rect_x,
        "rect_y" => rect_y, "rect_w" => rect_w, "rect_h" => rect_h, "pad0" => pad0,
        "pad1" => pad1, "dc_defer" => dc_defer, "opaque_zero" => opaque_zero, "sample" => sample, "seed" => seed,
        "flags" => flags, "spp" => spp, "attr_block0" => attr_block0,
        "albedo_stride" => albedo_stride, "band_tiles" => band_tiles, "lane" => lane,
    });
    sized(w, size_of::<Params>());
    let w = same_layout!(RayState, "RayState", {
        "ox" => origin, "oy" => origin + 4, "oz" => origin + 8, "t" => t,
        "dx" => dir, "dy" => dir + 4, "dz" => dir + 8, "hit" => hit,
        "sp" => sp, "status" => status, "steps" => steps, "cur_index" => cur_index,
        "cur_count" => cur_count, "prim" => prim, "nx" => normal, "ny" => normal + 4,
        "nz" => normal + 8, "wait_block" => wait_block, "flags" => flags,
        "hx" => hit_point, "hy" => hit_point + 4, "hz" => hit_point + 8, "herr" => hit_error,
        "b1" => b1, "b2" => b2, "skip" => skip, "pad0" => pad, "pad1" => pad + 4,
    });
    sized(w, size_of::<RayState>());
    let w = same_layout!(MeshInfo, "MeshInfo", {
        "color" => color, "first_prim" => first_prim, "look" => look, "point" => point,
        "map" => map, "lo" => lo, "scale" => scale, "pad0" => pad, "pad1" => pad + 4,
    });
    sized(w, size_of::<MeshInfo>());
    let w = same_layout!(Pixel, "Pixel", {
        "r" => rgb, "g" => rgb + 4, "b" => rgb + 8, "depth_bits" => depth, "id" => id,
        "nx" => normal, "ny" => normal + 4, "nz" => normal + 8,
    });
    sized(w, size_of::<Pixel>());
    let w = same_layout!(Counter, "Counter", {
        "count" => count, "x" => dispatch, "y" => dispatch + 4, "z" => dispatch + 8,
    });
    sized(w, size_of::<Counter>());
    let w = same_layout!(Stats, "Stats", {
        "steps" => steps, "tri_tests" => tri_tests, "overflows" => overflows,
        "suspended" => suspended, "started" => started, "hits" => hits, "misses" => misses,
        "node_visits" => node_visits, "block_entries" => block_entries,
        "tri_block_entries" => tri_block_entries, "subgroup_steps" => subgroup_steps,
        "subgroup_size" => subgroup_size, "closest_hits" => closest_hits, "pad" => pad,
    });
    sized(w, size_of::<Stats>());
    // The fault list follows the header.
    let w = same_layout!(FaultHeader, "Faults", {
        "count" => count, "dropped" => dropped, "pad0" => pad, "pad1" => pad + 4,
        "blocks" => pad + 8,
    });
    assert_eq!(w.offset("blocks") as usize, size_of::<FaultHeader>());
    let w = same_layout!(Light, "Light", { "pos" => pos, "color" => color });
    sized(w, size_of::<Light>());
    let w = same_layout!(ShadeParams, "ShadeParams", {
        "sky" => sky, "sun_dir" => sun_dir, "sun" => sun, "mode" => mode, "fan" => fan,
        "ao_rays" => ao_rays, "ao_distance" => ao_distance, "max_depth" => max_depth,
        "rr_depth" => rr_depth, "light_count" => light_count, "offset_mode" => offset_mode,
        "epsilon" => epsilon, "ambient" => ambient, "any_hit" => any_hit, "pad1" => pad,
        "lights" => lights,
    });
    // The size pins the light array's length (MAX_LIGHTS on both sides).
    sized(w, size_of::<ShadeParams>());
    let w = same_layout!(Path, "Path", {
        "pos" => pos, "alive" => alive, "n" => n, "depth" => depth, "albedo" => albedo,
        "pixel" => pixel, "tp" => tp, "err" => err, "l" => l, "tri" => tri,
    });
    sized(w, size_of::<Path>());
    let w = same_layout!(MirrorCase, "MirrorCase", {
        "p" => p, "n" => n, "u" => u, "words" => words, "node" => node, "c" => c,
    });
    sized(w, size_of::<MirrorCase>());
    let w = same_layout!(MirrorResult, "MirrorResult", {
        "offset" => offset, "dir" => dir, "sample" => sample, "words" => words, "lo" => lo,
        "hi" => hi, "color" => color, "rgb" => rgb, "row" => row, "patched" => patched,
    });
    sized(w, size_of::<MirrorResult>());
}
