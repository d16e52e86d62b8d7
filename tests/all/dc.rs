//! The distributed cache: the image (and id AOV) is bit-identical to the replicated one for any
//! number of ranks, cache size and mapping; even a single-line cache finishes; a frame's trace
//! adds up.

use crate::common::*;
use dcrt::dc::{CacheMap, CacheSize, Replicate};
use dcrt::gpu::frame::{Frame, Rect};
use dcrt::gpu::layout::Pixel;
use dcrt::gpu::scheduler::{Next, RectSource};
use dcrt::gpu::tracer::{FaultMode, OverlapMode, Settings};
use dcrt::render::frames::{Role, summarize};
use dcrt::render::{DcOptions, Prepared};
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Scene};
use glam::DVec3;

const W: u32 = 40;
const H: u32 = 32;

fn model(g: Generator, triangles: u64) -> (Prepared, Camera) {
    let scene = Scene::generated(g, triangles, W, H);
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    (prepare(model), camera)
}

/// rm 20k seen at 128x96, more pixels than the small batches and caches of the tests below
/// hold: the model, the view and its replicated frame.
fn rm_128x96(gpu: &dcrt::gpu::Gpu) -> (Prepared, dcrt::scene::CameraBasis, Frame) {
    let (w, h) = (128, 96);
    let (p, camera) = model(Generator::Rm, 20_000);
    let (reference, _) = render(gpu, &p, &camera, w, h, Settings::default());
    (p, camera.basis(w, h), reference)
}

/// rm 20k with the camera moved right by most of the view's half-width: the model fills the left
/// part of a `w` x `h` frame, the right part sees nothing.
fn rm_on_the_left(w: u32, h: u32) -> (Prepared, Camera) {
    let (p, mut camera) = model(Generator::Rm, 20_000);
    let right = glam::Vec3::from(camera.basis(w, h).right)
        .as_dvec3()
        .normalize();
    let (pos, focus) = (
        DVec3::from(camera.position),
        DVec3::from(camera.focal_point),
    );
    let half_width =
        pos.distance(focus) * (camera.view_angle.to_radians() / 2.0).tan() * f64::from(w)
            / f64::from(h);
    let shift = 0.8 * half_width * right;
    camera.position = (pos + shift).to_array();
    camera.focal_point = (focus + shift).to_array();
    (p, camera)
}

fn sweep(g: Generator) {
    let gpu = gpu();
    let (p, camera) = model(g, 20_000);
    let basis = camera.basis(W, H);
    let (reference, _) = render(&gpu, &p, &camera, W, H, Settings::default());
    assert!(reference.pixels.iter().any(|px| !is_miss(px)));
    let sizes = ["1line", "1/32", "1/8", "1/2", "1/1"];
    // Cache lines the GPU marked as used, over the fault rounds of the whole sweep.
    let mut used_lines = 0u64;
    let mut kept_lines = 0u64;
    let mut fetched_ahead = 0u64;
    for n in [1u32, 2, 3, 4, 7] {
        for size in sizes {
            for map in [CacheMap::Ize, CacheMap::Demarle, CacheMap::Lru] {
                // Rank 0 of an even count (it holds the root at row 0 of its resident blocks,
                // beside its own), a middle rank of an odd one.
                let rank = if n % 2 == 0 { 0 } else { n / 2 };
                let o = DcOptions {
                    ranks: n,
                    rank,
                    cache: CacheSize::parse(size).unwrap(),
                    map,
                    replicate: Default::default(),
                };
                let t0 = std::time::Instant::now();
                let mut t = p.tracer_dc(&gpu, Settings::default(), &o).unwrap();
                let t1 = t0.elapsed();
                let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                let what = format!("{g:?} N={n} rank {rank} cache {size} {map:?}");
                eprintln!(
                    "{what}: setup {t1:?} frame {:.3}s rounds {} fetched {}",
                    stats.seconds, stats.rounds, stats.fetched_blocks
                );
                same_pixels(&reference, &frame, &what);
                let mut trace = t.take_trace();
                if size == "1/1" && n > 1 {
                    // Suspending at every fault, a ray visits the blocks it would replicated, so
                    // the same view again, every block cached, fetches nothing and looks up the
                    // same blocks: counted by the host from the lines the GPU used and the
                    // faults, not only from what was fetched. With every node block replicated
                    // the traversal kernel marks the lines it used when a ray stops, not as it goes.
                    let never = Settings {
                        faults: FaultMode::Never,
                        ..Settings::default()
                    };
                    for replicate in [Replicate::Root, Replicate::Nodes] {
                        let o = DcOptions { replicate, ..o };
                        let mut t = p.tracer_dc(&gpu, never, &o).unwrap();
                        let (_, cold) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                        let (again, warm) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                        let what = format!("{what} {replicate:?}");
                        same_pixels(&reference, &again, &what);
                        assert_eq!(warm.fetched_blocks, 0, "{what}");
                        assert!(warm.distinct_blocks > 0, "{what}");
                        assert_eq!(warm.distinct_blocks, cold.distinct_blocks, "{what}");
                    }
                }
                let cache = t.cache().map(|(_, lines, map)| (lines, map));
                trace.summary = summarize(&stats, cache, 0, Role::one_process(&t));
                let s = &trace.summary;
                // No schedule takes fewer fault rounds than the cache allows the frame's blocks;
                // through one line, every block but one already there needs a round of its own.
                assert_eq!(s.fault_round_bound, stats.fault_round_bound, "{what}");
                assert!(
                    stats.fault_rounds >= stats.fault_round_bound,
                    "{what}: {stats:?}"
                );
                if size == "1line" {
                    let all_but_one = stats.distinct_blocks.saturating_sub(1);
                    assert_eq!(u64::from(stats.fault_round_bound), all_but_one, "{what}");
                }
                // A fetched block was missed first and found in its line afterwards.
                if s.fetched_blocks > 0 {
                    assert!(s.misses > 0 && s.hits > 0, "{what}: {s:?}");
                }
                // A round fetches the faults it serves and, with Lru, blocks ahead of them.
                let served: u64 = trace
                    .rounds
                    .iter()
                    .map(|r| (r.faults.iter().filter(|f| f.served).count() + r.ahead.len()) as u64)
                    .sum();
                assert_eq!(s.fetched_blocks, served, "{what}");
                assert_eq!(stats.fetched_blocks, served, "{what}");
                let ahead: Vec<u32> = trace.rounds.iter().flat_map(|r| r.ahead.clone()).collect();
                if map != CacheMap::Lru {
                    assert!(ahead.is_empty(), "{what}");
                }
                fetched_ahead += ahead.len() as u64;
                // A cold frame fetches only borrowed blocks it looks up. Not every one: a ray
                // sets an absent block's subtree aside, and a hit found meanwhile may cull it.
                let fetched: std::collections::BTreeSet<u32> = trace
                    .rounds
                    .iter()
                    .flat_map(|r| r.faults.iter().filter(|f| f.served).map(|f| f.block))
                    .collect();
                assert!(stats.distinct_blocks >= fetched.len() as u64, "{what}");
                if n > 1 {
                    assert!(!fetched.is_empty(), "{what}");
                }
                // Any line will do for Lru: while the blocks it fetches fit, none is fetched twice.
                let lines = t.cache().map_or(0, |(_, l, _)| l);
                let all: std::collections::BTreeSet<u32> =
                    fetched.iter().chain(&ahead).copied().collect();
                if map == CacheMap::Lru && all.len() <= lines as usize {
                    assert_eq!(stats.fetched_blocks, all.len() as u64, "{what}");
                }
                for &k in &ahead {
                    assert!(k != 0 && k % n != rank, "{what}: {k} is on the rank");
                }
                if n > 1 {
                    assert!(s.lookups > 0, "{what}: borrowed blocks are looked up");
                    assert!(s.fetched_blocks > 0, "{what}: a cold cache fetches");
                }
                for r in &trace.rounds {
                    assert!(
                        r.fetched_blocks >= 1,
                        "{what}: every fault round loads a block"
                    );
                    assert!(r.used_lines <= lines, "{what}");
                    // Only rays still live keep a line, each its last triangle block's.
                    assert!(r.kept_lines <= r.used_lines.min(r.live), "{what}: {r:?}");
                    used_lines += u64::from(r.used_lines);
                    kept_lines += u64::from(r.kept_lines);
                    for f in r.faults.iter() {
                        assert_ne!(f.owner, rank, "{what}: a rank never fetches its own block");
                    }
                }
            }
        }
    }
    // Resumed rays find the blocks the rounds before them fetched: the GPU marks those lines
    // (Lru's recency).
    assert!(used_lines > 0, "no round found a block in a cache line");
    assert!(kept_lines > 0, "no ray still live kept a line");
    // Lru fetched children of faulted node blocks ahead of their rays, and the images stayed.
    assert!(fetched_ahead > 0, "no block was fetched ahead");
}

#[test]
fn rm_dc_images_match_replicated() {
    sweep(Generator::Rm);
}

#[test]
fn assembly_dc_images_match_replicated() {
    sweep(Generator::Assembly);
}

#[test]
fn batches_shrink_to_the_blocks_a_cache_holds_and_images_stay_the_same() {
    // 128x96 pixels of rm need far more blocks than a 1/32 cache holds: after the first frame
    // shows it, frames are traced in batches of at least 4096 pixels (64 tiles) that come
    // closest to fitting, with the same image.
    let gpu = gpu();
    let (p, basis, reference) = rm_128x96(&gpu);
    let (w, h) = (basis.width, basis.height);
    for map in [CacheMap::Ize, CacheMap::Lru] {
        let o = DcOptions {
            ranks: 4,
            rank: 1,
            cache: CacheSize::parse("1/32").unwrap(),
            map,
            replicate: Default::default(),
        };
        let mut t = p.tracer_dc(&gpu, Settings::default(), &o).unwrap();
        let lines = t.cache().map_or(0, |(_, l, _)| l);
        let (first, s1) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        let (second, s2) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        let what = format!("{map:?}");
        eprintln!(
            "{what}: lines {lines}, distinct {} {}, batches {} {}, fetched {} {}, rounds {} {}",
            s1.distinct_blocks,
            s2.distinct_blocks,
            s1.batches,
            s2.batches,
            s1.fetched_blocks,
            s2.fetched_blocks,
            s1.fault_rounds,
            s2.fault_rounds
        );
        assert!(
            s1.distinct_blocks > u64::from(lines),
            "{what}: the test needs a small cache"
        );
        assert_eq!(
            s1.distinct_blocks, s2.distinct_blocks,
            "{what}: the same view"
        );
        assert_eq!(s1.batches, 1, "{what}");
        let fit = (s1.rays * u64::from(lines) / s1.distinct_blocks).max(4096);
        let tiles = u64::from(w.div_ceil(8) * h.div_ceil(8));
        let want = tiles.div_ceil(fit / 64);
        assert_eq!(u64::from(s2.batches), want, "{what}");
        assert!(s2.batches > 1, "{what}");
        same_pixels(&reference, &first, &what);
        same_pixels(&reference, &second, &what);
    }
}

#[test]
fn stores_split_over_several_textures_give_the_same_image() {
    // An adapter bounds the bytes of one texture (lavapipe: 2 GiB), so a larger store spans up to
    // four. Here the bound is set small enough that a small model's store spans three or four,
    // replicated and with a cache whose lines fall in the last parts, and the image is the same.
    let gpu = gpu();
    let (p, camera) = model(Generator::Rm, 20_000);
    let basis = camera.basis(W, H);
    let (reference, _) = render(&gpu, &p, &camera, W, H, Settings::default());
    let caches = [
        None,
        Some(("1/2", CacheMap::Ize)),
        Some(("1/8", CacheMap::Lru)),
    ];
    for cache in caches {
        let o = cache.map(|(size, map)| DcOptions {
            ranks: 3,
            rank: 1,
            cache: CacheSize::parse(size).unwrap(),
            map,
            replicate: Default::default(),
        });
        let tracer = |s: Settings| match &o {
            Some(o) => p.tracer_dc(&gpu, s, o).unwrap(),
            None => p.tracer(&gpu, s).unwrap(),
        };
        let whole = tracer(Settings::default());
        assert_eq!(whole.store_parts(), 1);
        let rows = whole.store_rows();
        drop(whole);
        // A third of the rows a texture: three or four textures (layers hold whole rows).
        let split = Settings {
            max_texture_bytes: Some(u64::from(rows.div_ceil(3)) * 8192),
            ..Settings::default()
        };
        let mut t = tracer(split);
        let what = format!("{cache:?}, {rows} rows");
        assert!((3..=4).contains(&t.store_parts()), "{what}");
        let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        if o.is_some() {
            assert!(stats.fetched_blocks > 0, "{what}: lines are written");
        }
        same_pixels(&reference, &frame, &what);
    }
}

#[test]
fn faults_count_to_the_tiles_whose_rays_listed_them() {
    // The model seen in the left part of a 128x96 frame (the camera moved right by most of the
    // view's half-width), batches of two tile rows across it, a short cache and the nodes
    // replicated: a ray faults only on the triangle blocks of leaves it enters. The GPU names the
    // ray that listed each fault, so the faults go to the tiles of the left part, none to the
    // tile columns whose pixels all miss the model, though every batch spans both.
    let gpu = gpu();
    let (w, h) = (128, 96);
    let (p, camera) = rm_on_the_left(w, h);
    let (reference, _) = render(&gpu, &p, &camera, w, h, Settings::default());
    let tiles_x = w.div_ceil(8) as usize;
    // Tile columns whose every pixel misses the model.
    let empty_column = |tx: usize| {
        (0..h as usize)
            .all(|y| (tx * 8..tx * 8 + 8).all(|x| is_miss(&reference.pixels[y * w as usize + x])))
    };
    let empty: Vec<usize> = (0..tiles_x).filter(|&tx| empty_column(tx)).collect();
    assert!(
        empty.len() >= 3 && empty.len() < tiles_x - 3,
        "empty tile columns {empty:?}"
    );
    let o = DcOptions {
        ranks: 4,
        rank: 1,
        cache: CacheSize::parse("1/32").unwrap(),
        map: CacheMap::Lru,
        replicate: Replicate::Nodes,
    };
    let s = Settings {
        max_batch_rays: 2048,
        ..Settings::default()
    };
    let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
    assert!(t.tile_faults().is_none());
    for f in 0..2 {
        let (frame, _) = t.render(&camera.basis(w, h), [0.1, 0.2, 0.3]).unwrap();
        same_pixels(&reference, &frame, &format!("frame {f}"));
    }
    let (rect, faults) = t
        .tile_faults()
        .expect("a frame in batches sized to the cache");
    assert_eq!(rect, Rect::whole(w, h));
    assert_eq!(faults.len(), tiles_x * h.div_ceil(8) as usize);
    let column = |tx: usize| -> f64 { faults.iter().skip(tx).step_by(tiles_x).sum() };
    let in_empty: f64 = empty.iter().map(|&tx| column(tx)).sum();
    let total: f64 = faults.iter().sum();
    assert!(total > 0.0, "no faults counted");
    assert_eq!(
        in_empty, 0.0,
        "faults in empty columns {empty:?}: {faults:?}"
    );
}

#[test]
fn spare_lanes_sized_to_the_batches_trace_the_same_image() {
    // With the default batch size and a 1/32 cache, batches are fitted far below a lane's size:
    // the spare lanes are made that small (smaller than the frame), as many as fit in the memory
    // of two full lanes, and batches run in them, overlapping; the image stays the replicated one
    // in every frame. From the fourth frame on batches are sized by the last frame's faults: one
    // over the right half, which sees nothing, would take all its 320 tiles but takes no more
    // than the 128 its spare lane holds (a batch past its lane is refused with an error).
    let gpu = gpu();
    let (w, h) = (256, 160);
    let (p, camera) = rm_on_the_left(w, h);
    let (reference, _) = render(&gpu, &p, &camera, w, h, Settings::default());
    let basis = camera.basis(w, h);
    let o = DcOptions {
        ranks: 4,
        rank: 1,
        cache: CacheSize::parse("1/32").unwrap(),
        map: CacheMap::Lru,
        replicate: Default::default(),
    };
    let mut t = p.tracer_dc(&gpu, Settings::default(), &o).unwrap();
    let mut shared = 0;
    for f in 0..4 {
        let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        same_pixels(&reference, &frame, &format!("frame {f}"));
        // The first frame, before its blocks are counted, is one batch.
        assert!(
            f == 0 || stats.batches > 1,
            "frame {f}: {} batches",
            stats.batches
        );
        shared += stats.shared_rounds;
    }
    let lanes = t.lane_rays();
    assert!(lanes.len() > 3, "{lanes:?}");
    assert!(lanes[1..].iter().all(|&r| r < lanes[0]), "{lanes:?}");
    assert!(
        lanes[1] < w * h,
        "{lanes:?}: the spare lanes do not hold the frame"
    );
    assert!(shared > 0);
}

#[test]
fn batches_overlap_where_their_tails_meet() {
    // Small batches (32 tiles, two rows of a 128x96 frame): with a cache, the next batch starts
    // while the last rays of those in flight still wait for blocks, and their rounds are
    // shared. The images are those of the replicated model, the same with overlapping off, and
    // a one-line cache still finishes. From the third frame on, a short cache's batches are
    // sized by the last frame's faults per tile.
    let gpu = gpu();
    let (p, basis, reference) = rm_128x96(&gpu);
    let caches = [
        ("1/1", CacheMap::Ize),
        ("1/1", CacheMap::Lru),
        ("1/8", CacheMap::Demarle),
        ("1/8", CacheMap::Lru),
        ("1line", CacheMap::Lru),
    ];
    let mut short_shared = 0;
    for (size, map) in caches {
        let o = DcOptions {
            ranks: 4,
            rank: 1,
            cache: CacheSize::parse(size).unwrap(),
            map,
            replicate: Default::default(),
        };
        let frames = |overlap_batches| {
            let s = Settings {
                max_batch_rays: 2048,
                overlap_batches: if overlap_batches {
                    OverlapMode::Always
                } else {
                    OverlapMode::Never
                },
                ..Settings::default()
            };
            let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
            [0, 1, 2].map(|f| {
                let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                let what = format!("{size} {map:?} overlap {overlap_batches} frame {f}");
                same_pixels(&reference, &frame, &what);
                assert!(stats.batches > 1, "{what}");
                stats
            })
        };
        let (on, off) = (frames(true), frames(false));
        let what = format!(
            "{size} {map:?}: fault rounds {} {} (shared {} {}), without overlapping {} {}",
            on[0].fault_rounds,
            on[1].fault_rounds,
            on[0].shared_rounds,
            on[1].shared_rounds,
            off[0].fault_rounds,
            off[1].fault_rounds
        );
        eprintln!("{what}");
        assert!(off.iter().all(|s| s.shared_rounds == 0), "{what}");
        if size == "1/1" {
            // The cache holds every borrowed block: batches overlap from the first frame, and
            // with nothing evicted the rounds do not depend on the order faults arrive in.
            assert!(on[0].shared_rounds > 0, "{what}");
            assert!(on[0].fault_rounds < off[0].fault_rounds, "{what}");
            // By default only an associative cache overlaps batches.
            let s = Settings {
                max_batch_rays: 2048,
                ..Settings::default()
            };
            let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
            let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
            same_pixels(&reference, &frame, &what);
            assert_eq!(stats.shared_rounds > 0, map == CacheMap::Lru, "{what}");
        }
        if size == "1/8" {
            // Once a frame has sized the batches to the cache (the rounds vary with the order
            // the GPU lists faults in, which sets what is evicted).
            short_shared += on[1].shared_rounds;
        }
    }
    assert!(short_shared > 0, "batches overlap with a short cache");
}

/// Rectangles handed out one at a time, their pixels put together into a frame.
struct Tiles {
    rects: Vec<Rect>,
    frame: Frame,
}

impl RectSource for Tiles {
    fn next(&mut self, _busy: bool) -> dcrt::Result<Next> {
        Ok(self.rects.pop().map_or(Next::End, Next::Rect))
    }

    fn done(&mut self, r: Rect, pixels: Vec<Pixel>) -> dcrt::Result<()> {
        for (i, p) in pixels.into_iter().enumerate() {
            let (x, y) = (r.x + i as u32 % r.w, r.y + i as u32 / r.w);
            self.frame.pixels[(y * self.frame.width + x) as usize] = p;
        }
        Ok(())
    }
}

#[test]
fn tiles_from_a_source_share_rounds() {
    // A cluster rank's tiles come one at a time: with an lru cache the next starts while the last
    // rays of those in flight still wait for blocks. The frame is the replicated one, and
    // rounds were shared (deterministic here: the cache holds every block, nothing is evicted).
    let gpu = gpu();
    let (p, basis, reference) = rm_128x96(&gpu);
    let (w, h) = (basis.width, basis.height);
    let o = DcOptions {
        ranks: 4,
        rank: 1,
        cache: CacheSize::parse("1/1").unwrap(),
        map: CacheMap::Lru,
        replicate: Default::default(),
    };
    for overlap_batches in [OverlapMode::Auto, OverlapMode::Never] {
        let s = Settings {
            overlap_batches,
            ..Settings::default()
        };
        let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
        let mut stats = t.begin_frame();
        let rects = (0..h / 16)
            .flat_map(|y| {
                (0..w / 16).map(move |x| Rect {
                    x: x * 16,
                    y: y * 16,
                    w: 16,
                    h: 16,
                })
            })
            .collect();
        let blank = Frame {
            width: w,
            height: h,
            pixels: vec![Pixel::default(); (w * h) as usize],
        };
        let mut tiles = Tiles {
            rects,
            frame: blank,
        };
        t.render_rects(&basis, [0.1, 0.2, 0.3], &mut tiles, &mut stats)
            .unwrap();
        t.end_frame(&mut stats).unwrap();
        let what = format!("{overlap_batches:?}: {} shared rounds", stats.shared_rounds);
        eprintln!("{what}");
        same_pixels(&reference, &tiles.frame, &what);
        assert_eq!(stats.batches, 48, "{what}");
        assert_eq!(
            stats.shared_rounds > 0,
            overlap_batches == OverlapMode::Auto,
            "{what}"
        );
    }
}

/// The most blocks on a path from the root to a triangle: the node blocks it passes through, then
/// the leaf's triangle blocks.
fn block_chain(b: &dcrt::blocks::Blocks) -> u32 {
    use dcrt::bvh::{Child, WIDTH};
    let (npb, tpb) = (b.format.nodes_per_block(), b.format.tris_per_block());
    let mut stack = vec![(0u32, 1u32)];
    let mut most = 0;
    while let Some((i, d)) = stack.pop() {
        let n = b.node(i);
        for s in 0..WIDTH {
            match n.child(s) {
                Child::Inner(c) => stack.push((c, d + u32::from(c / npb != i / npb))),
                Child::Leaf { first, count } => {
                    most = most.max(d + (first + count - 1) / tpb - first / tpb + 1);
                }
                Child::Empty => {}
            }
        }
    }
    most
}

#[test]
fn a_rays_faults_go_out_together() {
    // With a cache that holds the model, a ray sets aside what an absent block holds and goes on
    // with the rest: the first round asks for more blocks than when rays suspend at their first
    // fault, a cold frame takes no more fault rounds than the longest chain of blocks on a path
    // through the tree, and the image is the same.
    let gpu = gpu();
    let (w, h) = (128, 96);
    for g in [Generator::Rm, Generator::Assembly] {
        let (p, camera) = model(g, 300_000);
        let basis = camera.basis(w, h);
        let (reference, _) = render(&gpu, &p, &camera, w, h, Settings::default());
        let chain = block_chain(&p.blocks);
        for map in [CacheMap::Ize, CacheMap::Lru] {
            let o = DcOptions {
                ranks: 7,
                rank: 3,
                cache: CacheSize::parse("1/1").unwrap(),
                map,
                replicate: Default::default(),
            };
            let run = |faults| {
                let s = Settings {
                    faults,
                    ..Settings::default()
                };
                let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
                let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                same_pixels(&reference, &frame, &format!("{g:?} {map:?}"));
                let first = t.take_trace().rounds[0].faults.len();
                (stats.fault_rounds, first)
            };
            let ((on, first_on), (off, first_off)) = (run(FaultMode::Fit), run(FaultMode::Never));
            let what = format!(
                "{g:?} {map:?}: chain {chain}; fault rounds {on}, first round's faults \
                 {first_on}; suspending at faults: {off}, {first_off}"
            );
            eprintln!("{what}");
            assert!((1..=chain).contains(&on), "{what}");
            assert!(first_on > first_off, "{what}");
        }
    }
}

#[test]
fn equally_near_hits_do_not_depend_on_the_order_blocks_arrive() {
    // 3,000 copies of one triangle (one coincident group, spread over many triangle blocks)
    // in front of a plane: every ray that hits them hits all at the same distance. A ray that
    // sets absent blocks aside meets the copies in another order than a replicated one; the
    // lowest index wins either way, so the id AOV is the same.
    let gpu = gpu();
    let mut tris = vec![[[-1.0f32, 0.0, -1.0], [1.0, 0.0, -1.0], [0.0, 0.0, 1.0]]; 3000];
    tris.push([[-4.0, 2.0, -4.0], [4.0, 2.0, -4.0], [0.0, 2.0, 4.0]]);
    let p = prepare(dcrt::scene::Model::from_triangles(tris));
    let camera = Camera {
        position: [0.0, -3.0, 0.0],
        focal_point: [0.0, 0.0, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 60.0,
        parallel_scale: None,
    };
    let basis = camera.basis(W, H);
    let (reference, _) = render(&gpu, &p, &camera, W, H, Settings::default());
    assert!(
        reference
            .pixels
            .iter()
            .any(|px| !is_miss(px) && px.id < 3000)
    );
    for (ranks, size) in [(2, "1/1"), (5, "1/2"), (7, "1line")] {
        let o = DcOptions {
            ranks,
            rank: 1,
            cache: CacheSize::parse(size).unwrap(),
            map: CacheMap::Lru,
            replicate: Default::default(),
        };
        let s = Settings {
            faults: FaultMode::Always,
            ..Settings::default()
        };
        let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
        let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        same_pixels(&reference, &frame, &format!("{ranks} ranks, {size}"));
        assert!(
            stats.fetched_blocks > 0,
            "{ranks} ranks, {size}: blocks were absent"
        );
    }
}

#[test]
fn replicated_node_blocks_leave_only_triangle_blocks_to_fault() {
    // With every node block on every rank, a ray walks the whole tree without a fault and waits
    // only for triangle blocks: the image stays the same for every rank count, cache and
    // mapping (a single line still finishes), no node block is ever fetched, and a cold frame
    // takes fewer fault rounds than with the root alone replicated.
    let gpu = gpu();
    let (p, camera) = model(Generator::Rm, 20_000);
    let basis = camera.basis(W, H);
    let (reference, _) = render(&gpu, &p, &camera, W, H, Settings::default());
    let node_blocks = p.blocks.node_blocks;
    assert!(
        node_blocks > 4,
        "the test needs a tree of several node blocks"
    );
    for n in [2u32, 7] {
        for size in ["1line", "1/8", "1/1"] {
            for map in [CacheMap::Ize, CacheMap::Demarle, CacheMap::Lru] {
                let rank = n - 1;
                let o = |replicate| DcOptions {
                    ranks: n,
                    rank,
                    cache: CacheSize::parse(size).unwrap(),
                    map,
                    replicate,
                };
                let what = format!("N={n} rank {rank} cache {size} {map:?}");
                let never = Settings {
                    faults: FaultMode::Never,
                    ..Settings::default()
                };
                let mut t = p.tracer_dc(&gpu, never, &o(Replicate::Nodes)).unwrap();
                let (frame, stats) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                same_pixels(&reference, &frame, &what);
                let fetched: Vec<u32> = t
                    .take_trace()
                    .rounds
                    .iter()
                    .flat_map(|r| r.faults.iter().map(|f| f.block))
                    .collect();
                assert!(!fetched.is_empty(), "{what}: triangle blocks are borrowed");
                assert!(
                    fetched.iter().all(|&k| k >= node_blocks),
                    "{what}: a node block faulted: {fetched:?}"
                );
                let mut root = p.tracer_dc(&gpu, never, &o(Replicate::Root)).unwrap();
                let (_, root_stats) = root.render(&basis, [0.1, 0.2, 0.3]).unwrap();
                assert!(
                    stats.fault_rounds < root_stats.fault_rounds,
                    "{what}: {} fault rounds with the nodes replicated, {} with the root",
                    stats.fault_rounds,
                    root_stats.fault_rounds
                );
            }
        }
    }
}

/// The rounds do not depend on how many threads the driver spreads the workgroups over: a block
/// is served by its least requester's batch and ray slot (ties by block), not by which ray of
/// which thread listed it first. With one llvmpipe thread and with two, every frame of an orbit
/// takes the same fault rounds and fetches the same blocks (before, two threads served `rm`
/// 3M's cold frame at 1/32 in 55 rounds and one thread in 36).
#[test]
fn fault_rounds_do_not_depend_on_the_driver_s_threads() {
    let dir = TempDir::new("dc-threads");
    let scene = dir.write(
        "rm.toml",
        "[image]\nwidth = 192\nheight = 128\n\n[[mesh]]\ngenerator = \"rm\"\ntriangles = 60000\n",
    );
    for replicate in ["root", "nodes"] {
        let run = |threads: &str| -> Vec<(u64, u64)> {
            let stats = dir.path(&format!("stats-{replicate}-{threads}.json"));
            let out = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"))
                .args(["render"])
                .arg(&scene)
                .arg("-o")
                .arg(dir.path("f.png"))
                .args(["--virtual-ranks", "8", "--rank", "0", "--cache", "1/32"])
                .args(["--cache-map", "lru", "--replicate-blocks", replicate])
                .args(["--frames", "3", "--stats"])
                .arg(&stats)
                .env("LP_NUM_THREADS", threads)
                .output()
                .unwrap();
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            let all: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
            let frames = all["frames"].as_array().unwrap();
            frames
                .iter()
                .map(|f| {
                    let s = &f["stats"];
                    (
                        s["fault_rounds"].as_u64().unwrap(),
                        s["fetched_blocks"].as_u64().unwrap(),
                    )
                })
                .collect()
        };
        let one = run("1");
        assert_eq!(one.len(), 3);
        assert!(
            one.iter().all(|&(r, _)| r > 20),
            "{replicate}: a short cache: {one:?}"
        );
        assert_eq!(one, run("2"), "{replicate}: one thread, then two");
    }
}

#[test]
fn rounds_that_drop_faults_finish_with_the_same_image() {
    // A fault list of three blocks: nearly every round lists more faults than that, drops the
    // rest, and its rays ask again next round. A block requested past the list is never listed
    // again unless the next round clears every block's request word (the requesters kernel
    // clears only the listed ones): the frame would never finish.
    let gpu = gpu();
    let (p, basis, reference) = rm_128x96(&gpu);
    for (size, replicate) in [("1/8", Replicate::Nodes), ("1/2", Replicate::Root)] {
        let o = DcOptions {
            ranks: 4,
            rank: 1,
            cache: CacheSize::parse(size).unwrap(),
            map: CacheMap::Lru,
            replicate,
        };
        let s = Settings {
            fault_cap: 3,
            ..Settings::default()
        };
        let mut t = p.tracer_dc(&gpu, s, &o).unwrap();
        for frame_no in 0..2 {
            let what = format!("{size} {replicate:?}, frame {frame_no}");
            let (frame, _) = t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
            same_pixels(&reference, &frame, &what);
            let rounds = t.take_trace().rounds;
            let dropped = rounds.iter().filter(|r| r.dropped > 0).count();
            assert!(dropped > 0, "{what}: no round dropped faults");
            assert!(rounds.iter().all(|r| r.faults.len() <= 3), "{what}");
        }
    }
}

#[test]
fn every_listed_fault_counts_the_ray_that_waits_for_it() {
    // The ray that lists a block adds itself to its line's waiters on the GPU (`cache_line` in
    // shaders/shared/dc.wgsl, built for the mapping: DC_MAP), and the host reads the count at
    // its own `dc::cache_line` of the block: each mapping's kernel must compute the host's line.
    let gpu = gpu();
    let (p, basis, _) = rm_128x96(&gpu);
    for map in [CacheMap::Ize, CacheMap::Demarle, CacheMap::Lru] {
        let o = DcOptions {
            ranks: 4,
            rank: 1,
            cache: CacheSize::parse("1/8").unwrap(),
            map,
            replicate: Replicate::Root,
        };
        let mut t = p.tracer_dc(&gpu, Settings::default(), &o).unwrap();
        t.render(&basis, [0.1, 0.2, 0.3]).unwrap();
        let rounds = t.take_trace().rounds;
        let faults: Vec<_> = rounds.iter().flat_map(|r| &r.faults).collect();
        assert!(faults.len() > 10, "{map:?}: {} faults", faults.len());
        let unwaited: Vec<u32> = faults
            .iter()
            .filter(|f| f.waiting == 0)
            .map(|f| f.block)
            .collect();
        assert!(
            unwaited.is_empty(),
            "{map:?}: no waiter counted for blocks {unwaited:?}"
        );
    }
}
