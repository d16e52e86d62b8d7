//! Layout probe: every member of every struct the host writes for the GPU is read back through a
//! shader, using the same accessors as the kernels, and compared word by word.

use crate::common::*;
use dcrt::gpu::layout::{Light, MeshInfo, Params, RayState, ShadeParams};
use dcrt::gpu::tracer::Settings;
use dcrt::scene::Model;

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
            node: 9,
            sp: 10,
            status: 11,
            steps: 12,
            cur_index: 13,
            cur_count: 14,
            prim: 15,
            normal: [16.5, 17.5, 18.5],
            wait_block: 19,
            flags: 20,
        },
        RayState {
            origin: [-1.0, -2.0, -3.0],
            t: 1e30,
            dir: [0.25, 0.125, 0.0625],
            hit: u32::MAX,
            node: 77,
            sp: 78,
            status: 79,
            steps: 80,
            cur_index: 81,
            cur_count: u32::MAX,
            prim: 83,
            normal: [-0.5, 0.25, 1e-3],
            wait_block: u32::MAX,
            flags: 86,
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
    for (c, &first) in prepared.model.colors.iter().zip(&prepared.model.mesh_first) {
        expect.extend(words(&MeshInfo {
            color: [c[0], c[1], c[2], 1.0],
            first_prim: first,
            pad: [0; 3],
        }));
    }
    expect.extend(words(&shading));
    assert_eq!(out.len(), expect.len());
    for (i, (a, b)) in out.iter().zip(&expect).enumerate() {
        assert_eq!(a, b, "word {i} differs");
    }
}
