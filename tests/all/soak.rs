//! Long sessions: a few hundred frames of an orbit, replicated and through a distributed cache,
//! keep every GPU object count flat (wgpu's counters: exact, so any object made a frame and not
//! freed fails) and the resident memory bounded (a leak of host memory, as the half a megabyte a
//! frame that once went unnoticed, fails). `dcrt bench soak` measures the same over thousands.

use crate::common::*;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::tracer::Settings;
use dcrt::render::frames::{FramePlan, Role, View, run_images};
use dcrt::render::memory::resident;
use dcrt::render::{DcOptions, Prepared};
use dcrt::scene::generate::Generator;
use dcrt::scene::{Camera, Scene};

const FRAMES: u32 = 300;
/// Frames before the counts are taken: the cache fills, spare lanes are made, the allocator
/// settles.
const WARM: u32 = 30;

fn rm(triangles: u64) -> (Prepared, Camera) {
    let scene = Scene::generated(Generator::Rm, triangles, 32, 32);
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    (prepare(model), camera)
}

/// Renders `FRAMES` frames of an orbit with a fresh tracer; returns the GPU object counts and
/// the resident bytes after frame `WARM` and after the last.
fn soak(
    gpu: &dcrt::gpu::Gpu,
    p: &Prepared,
    camera: Camera,
    dc: Option<&DcOptions>,
) -> [(dcrt::gpu::Live, u64); 2] {
    let mut tracer = p.tracer_with(gpu, Settings::default(), dc).unwrap();
    let plan = FramePlan {
        frames: FRAMES,
        view: View::Orbit(camera),
        role: Role::one_process(&tracer),
        trace_dir: None,
    };
    let mut taken = Vec::new();
    run_images(
        &mut tracer,
        &plan,
        32,
        32,
        [0.1, 0.2, 0.3],
        &mut |i, frame, _| {
            assert_eq!(frame.pixels.len(), 32 * 32);
            if i == WARM || i + 1 == FRAMES {
                taken.push((gpu.live(), resident().expect("/proc/self/status").0));
            }
            Ok(())
        },
    )
    .unwrap();
    [taken[0], taken[1]]
}

#[test]
fn long_sessions_keep_gpu_objects_and_memory_flat() {
    let gpu = gpu();
    let (p, camera) = rm(20_000);
    let cached = DcOptions {
        ranks: 4,
        rank: 1,
        cache: CacheSize::parse("1/8").unwrap(),
        map: CacheMap::Ize,
        replicate: Default::default(),
    };
    for (what, dc) in [
        ("replicated", None),
        ("cache 1/8 as rank 1 of 4", Some(&cached)),
    ] {
        let [(live0, rss0), (live1, rss1)] = soak(&gpu, &p, camera, dc);
        eprintln!("{what}: {live1:?}; RSS {rss0} -> {rss1} bytes");
        assert!(
            live1.buffers > 0 && live1.pipelines > 0,
            "{what}: counters off: {live1:?}"
        );
        assert_eq!(
            live0, live1,
            "{what}: GPU objects grew between frames {WARM} and {FRAMES}"
        );
        // 270 frames: a leak of 64 KiB a frame is 17 MiB; allocator noise measured under 1 MiB.
        let grew = rss1.saturating_sub(rss0);
        assert!(
            grew < 16 << 20,
            "{what}: resident memory grew {grew} bytes over {} frames",
            FRAMES - WARM - 1
        );
    }
}
