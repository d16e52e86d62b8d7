//! The frame loop: its frames are those of `Tracer::render` on the orbit's cameras, replicated or
//! through the distributed cache; each frame's trace names its frame, role and rank, agrees with
//! the frame's statistics and carries the events its body added; `dcrt render` writes a trace
//! and a `--stats` entry per frame.

use crate::common::*;
use dcrt::dc::{CacheMap, CacheSize};
use dcrt::gpu::frame::{Frame, FrameStats};
use dcrt::gpu::tracer::Settings;
use dcrt::render::DcOptions;
use dcrt::render::frames::{
    FrameBody, FrameCtx, FramePlan, Role, View, run_frames, run_images, summarize,
};
use dcrt::scene::Scene;
use dcrt::scene::generate::Generator;
use dcrt::traces::record::{Event, FrameTrace, Tile};

const W: u32 = 32;
const H: u32 = 24;
const BG: [f32; 3] = [0.1, 0.2, 0.3];

fn bits(f: &Frame) -> &[u8] {
    bytemuck::cast_slice(&f.pixels)
}

/// Keeps each frame, its statistics and its trace; adds one event per frame.
#[derive(Default)]
struct Keep {
    frames: Vec<Frame>,
    stats: Vec<FrameStats>,
    traces: Vec<FrameTrace>,
    current: Option<Frame>,
}

impl FrameBody for Keep {
    fn trace(&mut self, mut ctx: FrameCtx<'_, '_>) -> dcrt::Result<()> {
        self.current = Some(ctx.render_whole(W, H, BG)?);
        Ok(())
    }
    fn finish(
        &mut self,
        frame: u32,
        stats: &FrameStats,
        trace: &mut FrameTrace,
    ) -> dcrt::Result<()> {
        // Any typed event: a tile whose x is the frame, to find it in the file.
        trace.events.push(Event::Tile(Tile {
            x: frame,
            y: 0,
            w: 1,
            h: 1,
            start_ms: 0.0,
            trace_ms: 0.0,
            send_ms: 0.0,
        }));
        self.frames.extend(self.current.take());
        self.stats.push(stats.clone());
        self.traces.push(trace.clone());
        Ok(())
    }
}

#[test]
fn orbit_frames_render_like_the_tracer_and_trace_who_rendered_them() {
    let gpu = gpu();
    let scene = Scene::generated(Generator::Rm, 8000, W, H);
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    let p = prepare(model);
    let n = 3;
    let expected: Vec<Frame> = (0..n)
        .map(|i| {
            let c = camera.orbit(std::f64::consts::TAU * f64::from(i) / f64::from(n));
            let mut t = p.tracer(&gpu, Settings::default()).unwrap();
            t.render(&c.basis(W, H), BG).unwrap().0
        })
        .collect();
    assert_ne!(bits(&expected[0]), bits(&expected[1]), "the camera moves");

    // Replicated, through the closure form.
    let mut t = p.tracer(&gpu, Settings::default()).unwrap();
    let plan = FramePlan {
        frames: n,
        view: View::Orbit(camera),
        role: Role::one_process(&t),
        trace_dir: None,
    };
    assert_eq!(
        plan.role,
        Role {
            name: "single",
            rank: 0,
            ranks: 1
        }
    );
    let mut got = Vec::new();
    // Cloned, not taken: the frame loop writes each frame over the last one's pixels.
    run_images(&mut t, &plan, W, H, BG, &mut |i, f, _| {
        got.push((i, f.clone()));
        Ok(())
    })
    .unwrap();
    assert_eq!(got.len(), n as usize);
    for (i, f) in &got {
        assert_eq!(
            bits(f),
            bits(&expected[*i as usize]),
            "replicated frame {i}"
        );
    }

    // Through the cache, with traces written.
    let dir = TempDir::new("frames-loop");
    let o = DcOptions {
        ranks: 3,
        rank: 1,
        cache: CacheSize::parse("1/8").unwrap(),
        map: CacheMap::Demarle,
        replicate: Default::default(),
    };
    let mut t = p.tracer_dc(&gpu, Settings::default(), &o).unwrap();
    let role = Role::one_process(&t);
    assert_eq!(
        role,
        Role {
            name: "render",
            rank: 1,
            ranks: 3
        }
    );
    let plan = FramePlan {
        frames: n,
        view: View::Orbit(camera),
        role,
        trace_dir: Some(&dir.0),
    };
    let mut keep = Keep::default();
    run_frames(&mut t, &plan, &mut keep).unwrap();
    let (_, lines, _) = t.cache().unwrap();
    assert_eq!(keep.frames.len(), expected.len());
    for (i, image) in expected.iter().enumerate() {
        assert_eq!(bits(&keep.frames[i]), bits(image), "DC frame {i}");
        let s = &keep.traces[i].summary;
        let want = summarize(
            &keep.stats[i],
            Some((lines, CacheMap::Demarle)),
            i as u32,
            role,
        );
        // The frame loop adds when the frame began.
        assert!(s.start_ms.is_some_and(|t| t >= 0.0), "frame {i}: {s:?}");
        let want = dcrt::traces::record::FrameSummary {
            start_ms: s.start_ms,
            ..want
        };
        assert_eq!(s, &want, "frame {i}");
        assert_eq!((s.frame, s.rank, s.ranks), (i as u32, 1, 3));
        assert_eq!(s.fault_rounds as usize, keep.traces[i].rounds.len());
        // The file: the rounds, the body's event, then the frame.
        let path = FrameTrace::file_name(&dir.0, i as u32, 1);
        let text = std::fs::read_to_string(&path).unwrap();
        let recs: Vec<serde_json::Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        let r = s.fault_rounds as usize;
        assert_eq!(recs.len(), r + 2, "{}", path.display());
        assert!(recs[..r].iter().all(|x| x["type"] == "round"));
        assert_eq!(recs[r]["type"], "tile");
        assert_eq!(recs[r]["x"], i);
        assert_eq!(recs[r + 1]["type"], "frame");
        assert_eq!(recs[r + 1]["frame"], i);
        assert_eq!(recs[r + 1]["role"], "render");
        assert_eq!(recs[r + 1]["cache_map"], "demarle");
    }
}

#[test]
fn fixed_view_renders_the_same_camera_every_frame() {
    let gpu = gpu();
    let scene = Scene::generated(Generator::Assembly, 4000, W, H);
    let model = scene.load_model().unwrap();
    let camera = scene.camera_or_default(&model);
    let p = prepare(model);
    let mut t = p.tracer(&gpu, Settings::default()).unwrap();
    let (want, _) = t.render(&camera.basis(W, H), BG).unwrap();
    let plan = FramePlan {
        frames: 2,
        view: View::Fixed(camera),
        role: Role::one_process(&t),
        trace_dir: None,
    };
    let mut keep = Keep::default();
    run_frames(&mut t, &plan, &mut keep).unwrap();
    assert_eq!(keep.frames.len(), 2);
    for f in &keep.frames {
        assert_eq!(bits(f), bits(&want));
    }
}

const SCENE: &str = "[camera]\nposition = [0, -2.2, 1.8]\nfocal_point = [0, 0, 0]\n\
                     view_up = [0, 0, 1]\nview_angle = 40\n[image]\nwidth = 40\nheight = 32\n\
                     [[mesh]]\ngenerator = \"rm\"\ntriangles = 8000\n";

fn lines(path: &std::path::Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn render_writes_a_trace_and_statistics_per_frame() {
    let d = TempDir::new("frames-cli");
    let scene = d.write("s.toml", SCENE);
    for (extra, rank, role, ranks) in [
        (vec![], 0u32, "single", 1u32),
        (
            vec!["--virtual-ranks", "2", "--rank", "1", "--cache", "1/8"],
            1,
            "render",
            2,
        ),
    ] {
        let traces = d.path(&format!("traces-{role}"));
        let stats = d.path(&format!("stats-{role}.json"));
        let out = d.path(&format!("{role}.png"));
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![
            &"render",
            &scene,
            &"-o",
            &out,
            &"--frames",
            &"2",
            &"--trace",
            &traces,
            &"--stats",
            &stats,
        ];
        args.extend(extra.iter().map(|s| s as &dyn AsRef<std::ffi::OsStr>));
        let r = dcrt(&args);
        let err = String::from_utf8_lossy(&r.stderr).to_string();
        assert!(r.status.success(), "{err}");
        let all: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        assert_eq!(
            (all["ranks"].as_u64(), all["width"].as_u64()),
            (Some(1), Some(40))
        );
        let per_frame = all["frames"].as_array().unwrap();
        assert_eq!(per_frame.len(), 2, "{all}");
        for i in 0..2u32 {
            let png = d.path(&format!("{role}_{i:04}.png"));
            assert!(png.exists(), "{}", png.display());
            let line = format!("frame {i}: cast 1 spp, 8080 triangles");
            assert!(err.contains(&line), "{err}");
            assert!(err.contains(&format!("wrote {}", png.display())), "{err}");
            let recs = lines(&FrameTrace::file_name(&traces, i, rank));
            let f = recs.last().unwrap();
            let st = &per_frame[i as usize];
            assert_eq!(st["frame"], i);
            assert_eq!(f["type"], "frame");
            assert_eq!(f["frame"], i);
            assert_eq!(f["role"], role);
            assert_eq!(f["rank"], rank);
            assert_eq!(f["ranks"], ranks);
            assert_eq!(f["rounds"], st["stats"]["rounds"]);
            assert_eq!(f["frame_ms"], st["frame_ms"]);
            if role == "single" {
                assert_eq!(recs.len(), 1);
                assert_eq!(
                    (f["hit_rate"].as_f64(), f["cache_map"].as_str()),
                    (Some(1.0), Some(""))
                );
                assert_eq!(f["lookups"], 0);
            } else {
                assert_eq!(f["cache_map"], "lru", "the default mapping");
                assert_eq!(f["lookups"], st["stats"]["lookups"]);
                assert_eq!(f["fetched_blocks"], st["stats"]["fetched_blocks"]);
            }
        }
        assert_ne!(
            std::fs::read(d.path(&format!("{role}_0000.png"))).unwrap(),
            std::fs::read(d.path(&format!("{role}_0001.png"))).unwrap(),
            "the camera orbits"
        );
    }
}
