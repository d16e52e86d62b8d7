//! The budgeted traversal rounds: a tiny step budget gives the same image as a large one (no result
//! is ever truncated), every ray ends done, and a view of nothing is all misses.

use crate::common::*;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::frame::FrameStats;
use dcrt::gpu::layout::status;
use dcrt::gpu::shaders::Store;
use dcrt::gpu::tracer::{MAX_STEP_BUDGET, Settings};
use dcrt::render::DcOptions;
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Model, Scene};
use dcrt::shading::{Mode, Shading};

fn rm() -> (Model, Camera) {
    let scene = Scene::generated(Generator::Rm, 30_000, 96, 96);
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    (model, camera)
}

#[test]
fn small_step_budget_resumes_rays_to_the_same_image() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let big = Settings::default();
    let (a, sa) = render(&gpu, &prepared, &camera, 96, 96, big);
    // A budget of 5 iterations is far below what a ray needs (tens of steps), so rays must be
    // suspended and resumed many times.
    let small = Settings {
        step_budget: 5,
        max_batch_rays: 64 * 48,
        ..Settings::default()
    };
    let mut tracer = prepared.tracer(&gpu, small).unwrap();
    let (b, sb) = tracer
        .render(&camera.basis(96, 96), [0.1, 0.2, 0.3])
        .unwrap();
    assert!(
        sa.max_live_rounds <= 2,
        "the default budget finishes at once"
    );
    let max_steps = sb.steps as f64 / sb.rays as f64;
    assert!(
        sb.max_live_rounds > 4,
        "budget 5 needs many rounds, took {} (mean steps {max_steps})",
        sb.max_live_rounds
    );
    assert!(sb.batches > 1, "several batches");
    assert_eq!(sa.steps, sb.steps, "the same traversal, only cut in pieces");
    assert_same_pixels(&a, &b, "budget 5 against the default budget");
    // The last batch's rays all finished (none left suspended or overflowed); in cast mode a ray
    // that ends in the first round is shaded there.
    let rays = tracer.read_rays(tracer.params().batch_rays).unwrap();
    let ended = [status::DONE, status::OUTSIDE, status::SHADED];
    let bad = rays.iter().position(|r| !ended.contains(&r.status));
    assert_eq!(rays.len() as u32, tracer.params().batch_rays);
    assert!(
        bad.is_none(),
        "ray {bad:?} not finished: {:?}",
        bad.map(|i| rays[i])
    );
    assert!(rays.iter().any(|r| r.steps > 5 * 4));
}

/// In cast mode a batch's first round writes the pixel of every ray that ends in it and the shade
/// kernel the others': over several jittered samples (summed in place), the two give the same
/// bits. With a budget of one step almost every ray is left to the shade kernel.
#[test]
fn cast_pixels_of_the_first_round_equal_the_shade_kernel_s() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let shading = Shading {
        mode: Mode::Cast,
        spp: 3,
        ..Shading::default()
    };
    let at = |step_budget| {
        let s = Settings {
            step_budget,
            shading,
            ..Settings::default()
        };
        let mut tracer = prepared.tracer(&gpu, s).unwrap();
        let (frame, _) = tracer
            .render(&camera.basis(96, 96), [0.1, 0.2, 0.3])
            .unwrap();
        let rays = tracer.read_rays(tracer.params().batch_rays).unwrap();
        let shaded = rays.iter().filter(|r| r.status == status::SHADED).count();
        (frame, shaded as f64 / rays.len() as f64)
    };
    let (first, in_first) = at(Settings::default().step_budget);
    let (later, in_later) = at(1);
    assert!(
        in_first > 0.99,
        "{in_first} of the rays shaded in the first round"
    );
    assert!(
        in_later < 0.5,
        "{in_later} of the rays shaded in the first round at budget 1"
    );
    assert_same_pixels(&first, &later, "shaded in the first round against by shade");
}

/// A wave of secondary rays is made by its first traversal round or by the `spawn` kernel (a
/// path's later waves): both make the same rays. Path tracing with a sun (two rays a bounce) and
/// ambient occlusion, every wave made each way, give the same bits and trace as many rays (a
/// maker that traced stale slots as well need not change the bits).
#[test]
fn a_wave_made_by_its_first_round_equals_a_spawned_one() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    // The default path shading has a sun: a sun ray and a bounce a wave.
    for mode in [Mode::Path, Mode::Ao] {
        let shading = Shading {
            mode,
            spp: 2,
            max_depth: 3,
            ao_rays: 4,
            ..Shading::default()
        };
        assert!(shading.fan() > 1, "{mode:?}: several rays a wave");
        let frame = |spawned_waves_from| {
            let s = Settings {
                shading,
                spawned_waves_from,
                ..Settings::default()
            };
            render(&gpu, &prepared, &camera, 48, 48, s)
        };
        let (spawned, stats) = frame(0);
        assert!(stats.secondary_rays > 0, "{mode:?}: secondary rays");
        for from in [1, u32::MAX] {
            let what = format!("{mode:?}, waves spawned from {from}");
            let (f, s) = frame(from);
            assert_same_pixels(&spawned, &f, &what);
            assert_eq!(
                s.secondary_rays, stats.secondary_rays,
                "{what}: secondary rays"
            );
        }
    }
}

/// A path's later waves made from `spawn`'s list (its first round makes the listed rays) against
/// waves made in every slot, through a 1/8 cache and with a budget of a few steps: listed rays
/// that suspend at a fault or run out of steps in their first round resume from the state that
/// round stored, and give the same bits as the replicated frame.
#[test]
fn spawned_waves_resume_through_the_cache_to_the_same_bits() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let shading = Shading {
        mode: Mode::Path,
        spp: 1,
        max_depth: 3,
        ..Shading::default()
    };
    let basis = camera.basis(32, 32);
    let frame = |spawned_waves_from, step_budget, cached: bool| {
        let s = Settings {
            shading,
            spawned_waves_from,
            step_budget,
            ..Settings::default()
        };
        let mut t = if cached {
            let o = DcOptions {
                ranks: 4,
                rank: 1,
                cache: CacheSize::parse("1/8").unwrap(),
                map: CacheMap::Lru,
                replicate: Default::default(),
            };
            prepared.tracer_dc(&gpu, s, &o).unwrap()
        } else {
            prepared.tracer(&gpu, s).unwrap()
        };
        t.render(&basis, [0.1, 0.2, 0.3]).unwrap()
    };
    let (every_slot, rs) = frame(u32::MAX, Settings::default().step_budget, false);
    assert!(rs.secondary_rays > 0, "secondary rays");
    for (from, budget, cached) in [(1, 6, false), (1, 4096, true), (0, 6, true)] {
        let what = format!("waves spawned from {from}, budget {budget}, cached {cached}");
        let (f, s) = frame(from, budget, cached);
        assert_same_pixels(&every_slot, &f, &what);
        assert_eq!(
            s.secondary_rays, rs.secondary_rays,
            "{what}: secondary rays"
        );
        if cached {
            assert!(s.fault_rounds > 0, "{what}: the cache faulted");
        } else {
            assert!(s.max_live_rounds > 2, "{what}: rays resumed over rounds");
        }
    }
}

/// A frame's `steps` is the sum of its rays' own: the traversal kernel's per-workgroup sum of its
/// invocations' counts (`wg_counts`) loses none.
#[test]
fn frame_steps_are_the_sum_of_every_ray_s_steps() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let mut tracer = prepared.tracer(&gpu, Settings::default()).unwrap();
    let (_, stats) = tracer
        .render(&camera.basis(96, 96), [0.1, 0.2, 0.3])
        .unwrap();
    assert_eq!(stats.batches, 1, "one batch, whose rays read back");
    let rays = tracer.read_rays(tracer.params().batch_rays).unwrap();
    let own: u64 = rays.iter().map(|r| u64::from(r.steps)).sum();
    assert!(own > 96 * 96, "every ray took steps");
    assert_eq!(stats.steps, own);
}

#[test]
fn batches_in_bands_give_the_same_image() {
    // 384x48 pixels (48 x 6 tiles) in batches of 16 tiles would be stripes 48 times wider than
    // tall: they are traced as 4x4-tile patches in bands 4 tiles wide, every other band upward,
    // and each pixel lands where one batch of the whole image puts it.
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let (a, sa) = render(&gpu, &prepared, &camera, 384, 48, Settings::default());
    let banded = Settings {
        max_batch_rays: 64 * 16,
        ..Settings::default()
    };
    let mut tracer = prepared.tracer(&gpu, banded).unwrap();
    let (b, sb) = tracer
        .render(&camera.basis(384, 48), [0.1, 0.2, 0.3])
        .unwrap();
    assert_eq!(sa.batches, 1);
    assert_eq!(sb.batches, 18);
    assert_eq!(tracer.params().band_tiles, 4, "bands, not rows");
    assert_eq!(sa.steps, sb.steps);
    assert_same_pixels(&a, &b, "banded batches against one batch");
}

#[test]
fn step_budget_is_bounded() {
    let gpu = gpu();
    let (model, _) = rm();
    let prepared = prepare(model);
    for bad in [0, MAX_STEP_BUDGET + 1] {
        let s = Settings {
            step_budget: bad,
            ..Settings::default()
        };
        let err = prepared.tracer(&gpu, s).err().expect("refused");
        assert!(err.to_string().contains("step budget"), "{err}");
    }
}

#[test]
fn looking_away_misses_everything() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let away = Camera {
        focal_point: [
            2.0 * camera.position[0] - camera.focal_point[0],
            2.0 * camera.position[1] - camera.focal_point[1],
            2.0 * camera.position[2] - camera.focal_point[2],
        ],
        ..camera
    };
    let (frame, stats) = render(&gpu, &prepared, &away, 70, 50, Settings::default());
    assert_eq!(frame.pixels.len(), 70 * 50);
    for p in &frame.pixels {
        assert!(is_miss(p));
        assert_eq!(p.depth, f32::INFINITY);
        assert_eq!(p.rgb, [0.1, 0.2, 0.3]);
        assert_eq!(p.normal, [0.0; 3]);
    }
    assert!(
        stats.tri_tests == 0,
        "no triangle is behind the camera's back"
    );
}

#[test]
fn degenerate_triangles_are_never_hit() {
    let gpu = gpu();
    // Zero-area triangles (collinear, repeated vertices) right in front of the camera, and one
    // real triangle behind them.
    let tris = vec![
        [[-1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [0.0, 0.0, 0.0]],
        [[-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [1.0, 0.0, -1.0]],
        [[0.2, 0.0, 0.2], [0.2, 0.0, 0.2], [0.2, 0.0, 0.2]],
        [[-1.0, 0.5, -1.0], [1.0, 0.5, -1.0], [0.0, 0.5, 1.0]],
    ];
    let prepared = prepare(Model::from_triangles(tris));
    let camera = Camera {
        position: [0.0, -3.0, 0.0],
        focal_point: [0.0, 0.0, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 60.0,
        parallel_scale: None,
    };
    let (frame, _) = render(&gpu, &prepared, &camera, 64, 64, Settings::default());
    let hits: Vec<u32> = frame
        .pixels
        .iter()
        .filter(|p| !is_miss(p))
        .map(|p| p.id)
        .collect();
    assert!(hits.len() > 100, "the real triangle is seen");
    assert!(
        hits.iter().all(|&id| id == 3),
        "only the real triangle is hit"
    );
}

#[test]
fn buffer_and_texture_stores_give_the_same_image() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let frames: Vec<_> = Store::ALL
        .iter()
        .map(|&store| {
            let s = Settings {
                store,
                ..Settings::default()
            };
            render(&gpu, &prepared, &camera, 80, 60, s).0
        })
        .collect();
    assert!(frames[0].pixels.iter().any(|p| !is_miss(p)));
    for (p, q) in frames[0].pixels.iter().zip(&frames[1].pixels) {
        assert_eq!(bytemuck::bytes_of(p), bytemuck::bytes_of(q));
    }
}

/// Any cut of the image into rectangles (odd sizes, not multiples of the 8x8 tile, some smaller
/// than one tile) gives the same pixels as one whole-image render: what the cluster relies on.
#[test]
fn rectangles_tile_the_image_exactly() {
    use dcrt::gpu::frame::Rect;
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let (w, h) = (61, 45);
    let (whole, _) = render(&gpu, &prepared, &camera, w, h, Settings::default());
    let mut tracer = prepared.tracer(&gpu, Settings::default()).unwrap();
    let basis = camera.basis(w, h);
    let mut stats = tracer.begin_frame();
    let mut pieced = vec![None; (w * h) as usize];
    let (xs, ys) = ([0, 5, 13, 40, 61], [0, 1, 9, 30, 45]);
    for yi in 0..4 {
        for xi in 0..4 {
            let rect = Rect {
                x: xs[xi],
                y: ys[yi],
                w: xs[xi + 1] - xs[xi],
                h: ys[yi + 1] - ys[yi],
            };
            let px = tracer
                .render_rect(&basis, [0.1, 0.2, 0.3], rect, &mut stats)
                .unwrap();
            assert_eq!(px.len(), rect.pixels());
            for (i, p) in px.into_iter().enumerate() {
                let (x, y) = (rect.x + i as u32 % rect.w, rect.y + i as u32 / rect.w);
                let slot = &mut pieced[(y * w + x) as usize];
                assert!(slot.is_none(), "pixel ({x}, {y}) rendered twice");
                *slot = Some(p);
            }
        }
    }
    tracer.end_frame(&mut stats).unwrap();
    assert_eq!(stats.rays, u64::from(w * h));
    for (i, (p, q)) in whole.pixels.iter().zip(&pieced).enumerate() {
        let q = q.unwrap_or_else(|| panic!("pixel {i} never rendered"));
        assert_eq!(bytemuck::bytes_of(p), bytemuck::bytes_of(&q), "pixel {i}");
    }
    let outside = Rect {
        x: 60,
        y: 0,
        w: 2,
        h: 1,
    };
    assert!(
        tracer
            .render_rect(&basis, [0.0; 3], outside, &mut stats)
            .is_err()
    );
}

/// Node visits, block entries and lane steps are counted only when asked
/// (`Settings::block_counts`, and `Tracer::set_block_counts` on a tracer already built): the
/// same image and steps either way, the counts 0 without, and with them every visit's count
/// consistent.
#[test]
fn block_entries_are_counted_only_when_asked() {
    let gpu = gpu();
    let (model, camera) = rm();
    let prepared = prepare(model);
    let (a, plain) = render(&gpu, &prepared, &camera, 96, 96, Settings::default());
    let counting = Settings {
        block_counts: true,
        ..Settings::default()
    };
    let (b, counted) = render(&gpu, &prepared, &camera, 96, 96, counting);
    let counts = |s: &FrameStats| (s.node_visits, s.block_entries, s.tri_block_entries);
    assert_eq!(counts(&plain), (0, 0, 0), "no counts unless asked");
    assert_eq!(plain.lane_steps, 0);
    // A subgroup's lanes run as many iterations as its longest ray: at least every ray's own,
    // at most all of its rays' together on every lane.
    let (lanes, steps) = (counted.lane_steps, counted.steps);
    let (min_size, max_size) = (gpu.info.subgroup_min_size, gpu.info.subgroup_max_size);
    assert!(
        steps > 0 && steps < lanes && lanes <= steps * u64::from(max_size),
        "{steps} steps, {lanes} lane steps, subgroups of {min_size}..={max_size}"
    );
    if min_size == max_size {
        assert_eq!(lanes % u64::from(min_size), 0, "{lanes} lane steps");
    }
    let (visits, entries, tri_entries) = counts(&counted);
    assert!(
        entries > 0 && visits >= entries,
        "{visits} visits, {entries} block entries"
    );
    assert!(
        tri_entries > 0 && tri_entries <= counted.tri_tests,
        "{tri_entries} triangle block entries, {} tests",
        counted.tri_tests
    );
    assert_eq!(plain.steps, counted.steps, "the same traversal");
    for (i, (p, q)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        assert_eq!(bytemuck::bytes_of(p), bytemuck::bytes_of(q), "pixel {i}");
    }
    let mut tracer = prepared.tracer(&gpu, Settings::default()).unwrap();
    tracer.set_block_counts(true);
    let (_, switched) = tracer
        .render(&camera.basis(96, 96), [0.1, 0.2, 0.3])
        .unwrap();
    assert_eq!(counts(&switched), counts(&counted));
    tracer.set_block_counts(false);
    let (_, off) = tracer
        .render(&camera.basis(96, 96), [0.1, 0.2, 0.3])
        .unwrap();
    assert_eq!(counts(&off), (0, 0, 0));
}
