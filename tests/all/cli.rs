//! The command line end to end: prepare a block file, render it replicated and through the
//! distributed cache (same PNG), write traces; damaged block files are refused.

use crate::common::*;

const SCENE: &str = "[camera]\nposition = [0, -2.2, 1.8]\nfocal_point = [0, 0, 0]\n\
                     view_up = [0, 0, 1]\nview_angle = 40\n[image]\nwidth = 48\nheight = 40\n\
                     [[mesh]]\ngenerator = \"rm\"\ntriangles = 8000\n";

fn ok(args: &[&dyn AsRef<std::ffi::OsStr>]) -> String {
    let r = dcrt(args);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert!(r.status.success(), "{err}");
    err
}

#[test]
fn prepared_model_renders_the_same_through_the_cache() {
    let d = TempDir::new("cli-dc");
    let scene = d.write("s.toml", SCENE);
    let dcb = d.path("m.dcb");
    ok(&[&"prepare", &scene, &"-o", &dcb]);
    let direct = d.path("direct.png");
    ok(&[&"render", &scene, &"-o", &direct]);
    let rep = d.path("rep.png");
    ok(&[&"render", &dcb, &"-o", &rep]);
    let traces = d.path("traces");
    let dc = d.path("dc.png");
    let log = ok(&[
        &"render",
        &dcb,
        &"-o",
        &dc,
        &"--virtual-ranks",
        &"3",
        &"--rank",
        &"1",
        &"--cache",
        &"1line",
        &"--trace",
        &traces,
    ]);
    assert!(log.contains("rank 1 of 3"), "{log}");
    let a = std::fs::read(&direct).unwrap();
    assert_eq!(
        a,
        std::fs::read(&rep).unwrap(),
        "the .dcb renders like its scene"
    );
    assert_eq!(
        a,
        std::fs::read(&dc).unwrap(),
        "the DC renders like the replicated model"
    );
    // The trace: rounds, then one frame summary that adds up.
    let text = std::fs::read_to_string(traces.join("frame_0000.rank1.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let frame = lines.last().unwrap();
    assert_eq!(frame["type"], "frame");
    let n = |v: &serde_json::Value, k: &str| v[k].as_u64().unwrap();
    assert_eq!(n(frame, "hits") + n(frame, "misses"), n(frame, "lookups"));
    let rounds: Vec<_> = lines.iter().filter(|l| l["type"] == "round").collect();
    assert!(!rounds.is_empty());
    let fetched: u64 = rounds.iter().map(|r| n(r, "fetched_blocks")).sum();
    assert_eq!(fetched, n(frame, "fetched_blocks"));
    assert_eq!(rounds.len() as u64, n(frame, "fault_rounds"));
    // The line per frame gives the fault rounds and their bound as the trace records them;
    // through one line every block but one needs a round of its own.
    let bound = n(frame, "fault_round_bound");
    assert_eq!(bound, n(frame, "distinct_blocks") - 1, "{frame}");
    assert!(bound > 0, "{frame}");
    let said = format!(
        "{} fault rounds (at least {bound})",
        n(frame, "fault_rounds")
    );
    assert!(log.contains(&said), "{said}: {log}");
}

#[test]
fn damaged_block_files_name_block_and_owner() {
    let d = TempDir::new("cli-dcb");
    let scene = d.write("s.toml", SCENE);
    let dcb = d.path("m.dcb");
    ok(&[&"prepare", &scene, &"-o", &dcb]);
    let good = std::fs::read(&dcb).unwrap();
    let data = u64::from_le_bytes(good[32..40].try_into().unwrap()) as usize;
    // Flip a byte in block 1: owned by rank 1 of 3, borrowed by rank 0.
    let mut bad = good.clone();
    bad[data + 8192 + 100] ^= 0x40;
    let corrupt = d.write("corrupt.dcb", &bad);
    let out = d.path("x.png");
    for (rank, needle) in [
        ("1", "block 1 (owner rank 1)"),
        ("0", "block 1 (owner rank 1)"),
    ] {
        let r = dcrt(&[
            &"render",
            &corrupt,
            &"-o",
            &out,
            &"--virtual-ranks",
            &"3",
            &"--rank",
            &rank,
        ]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{err}");
        assert!(err.contains(needle) && err.contains("corrupt.dcb"), "{err}");
        assert!(!out.exists());
    }
    let truncated = d.write("short.dcb", &good[..good.len() / 2]);
    let magic = d.write("magic.dcb", [b"NOTDCRT\0".as_slice(), &good[8..]].concat());
    let mut v = good.clone();
    v[8] = 9;
    let newer = d.write("newer.dcb", &v);
    let mut v = good.clone();
    v[8] = 1;
    let old = d.write("old.dcb", &v);
    // One flipped bit in the metadata's camera (0.0 -> 4.0) would render another view.
    let mut v = good.clone();
    let at = v
        .windows(15)
        .position(|w| w == b"\"focal_point\":[")
        .unwrap()
        + 15;
    assert_eq!(v[at], b'0');
    v[at] ^= 4;
    let flipped = d.write("flipped.dcb", &v);
    for (f, needle) in [
        (truncated, "truncated"),
        (magic, "bad magic"),
        (newer, "newer"),
        (old, "prepare it again"),
        (flipped, "metadata checksum mismatch"),
    ] {
        let r = dcrt(&[&"render", &f, &"-o", &out]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{err}");
        assert!(err.contains(needle), "{err}");
    }
}

#[test]
fn long_renders_say_how_far_they_are() {
    let d = TempDir::new("cli-progress");
    let scene = d.write("s.toml", SCENE);
    let out = d.path("p.png");
    // Every pass reported: 4 samples over one batch, the last pass (the frame done) not.
    let err = ok(&[
        &"render",
        &scene,
        &"-o",
        &out,
        &"--spp",
        &"4",
        &"--progress-every",
        &"0",
    ]);
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.contains("sample passes"))
        .collect();
    assert_eq!(
        lines,
        [
            "  1 of 4 sample passes",
            "  2 of 4 sample passes",
            "  3 of 4 sample passes"
        ]
    );
    // A render shorter than the interval says nothing of the kind.
    let err = ok(&[&"render", &scene, &"-o", &out, &"--spp", &"4"]);
    assert!(!err.contains("sample passes"), "{err}");
    let r = dcrt(&[&"render", &scene, &"-o", &out, &"--progress-every", &"-1"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("--progress-every"),
        "{err}"
    );
}

/// A headless run (no Wayland display: `XDG_RUNTIME_DIR` unset) prints nothing from the window
/// systems that Mesa's device-select layer probes: only dcrt's own lines.
#[test]
fn headless_runs_are_quiet() {
    let d = TempDir::new("cli-quiet");
    let scene = d.write("s.toml", SCENE);
    let out = d.path("o.png");
    for args in [
        vec![
            "render".as_ref(),
            scene.as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
            "--width".as_ref(),
            "16".as_ref(),
            "--height".as_ref(),
            "16".as_ref(),
        ],
        vec!["info".as_ref()],
    ] {
        let r = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"))
            .args(&args)
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("WAYLAND_DISPLAY")
            .env_remove("WAYLAND_SOCKET")
            .env_remove("NODEVICE_SELECT")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(r.status.success(), "{err}");
        assert!(!err.contains("XDG_RUNTIME_DIR"), "{args:?}: {err}");
        for line in err.lines() {
            assert!(
                ["adapter:", "replicated:", "frame 0:"]
                    .iter()
                    .any(|p| line.starts_with(p)),
                "{args:?}: unexpected line on stderr: {line}"
            );
        }
    }
}

/// `--camera FILE.pvcc` renders with ParaView's saved camera: the image is the one of a scene
/// giving the same camera; a parallel projection changes it; a broken camera file is an error
/// naming the file and property, before any output.
#[test]
fn paraview_camera_files() {
    let d = TempDir::new("cli-pvcc");
    let body = "[image]\nwidth = 48\nheight = 40\n[[mesh]]\ngenerator = \"rm\"\ntriangles = 8000\n";
    let pvcc = |parallel: u8| {
        format!(
            r#"<?xml version="1.0"?>
<PVCameraConfiguration description="ParaView camera configuration" version="1.0">
  <Proxy group="views" type="RenderView" id="1" servers="21">
    <Property name="CameraPosition" id="1.CameraPosition" number_of_elements="3">
      <Element index="0" value="0.25"/><Element index="1" value="-2.2"/><Element index="2" value="1.8"/>
    </Property>
    <Property name="CameraFocalPoint" id="1.CameraFocalPoint" number_of_elements="3">
      <Element index="0" value="0"/><Element index="1" value="0"/><Element index="2" value="0"/>
    </Property>
    <Property name="CameraViewUp" id="1.CameraViewUp" number_of_elements="3">
      <Element index="0" value="0"/><Element index="1" value="0"/><Element index="2" value="1"/>
    </Property>
    <Property name="CameraViewAngle" id="1.CameraViewAngle" number_of_elements="1">
      <Element index="0" value="35"/>
    </Property>
    <Property name="CameraParallelScale" id="1.CameraParallelScale" number_of_elements="1">
      <Element index="0" value="0.8"/>
    </Property>
    <Property name="CameraParallelProjection" id="1.CameraParallelProjection" number_of_elements="1">
      <Element index="0" value="{parallel}"/>
    </Property>
  </Proxy>
</PVCameraConfiguration>
"#
        )
    };
    let plain = d.write("plain.toml", body);
    let with_camera = d.write(
        "cam.toml",
        format!(
            "[camera]\nposition = [0.25, -2.2, 1.8]\nfocal_point = [0, 0, 0]\n\
             view_up = [0, 0, 1]\nview_angle = 35\n{body}"
        ),
    );
    let (a, b, c) = (d.path("a.png"), d.path("b.png"), d.path("c.png"));
    ok(&[
        &"render",
        &plain,
        &"-o",
        &a,
        &"--camera",
        &d.write("v.pvcc", pvcc(0)),
    ]);
    ok(&[&"render", &with_camera, &"-o", &b]);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    ok(&[
        &"render",
        &plain,
        &"-o",
        &c,
        &"--camera",
        &d.write("p.pvcc", pvcc(1)),
    ]);
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&c).unwrap());
    let bad = d.write(
        "bad.pvcc",
        pvcc(0).replace("value=\"35\"", "value=\"wide\""),
    );
    let out = d.path("bad.png");
    let r = dcrt(&[&"render", &plain, &"-o", &out, &"--camera", &bad]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success(), "{err}");
    assert!(
        err.contains("bad.pvcc") && err.contains("CameraViewAngle") && err.contains("'wide'"),
        "{err}"
    );
    assert!(!out.exists());
}

/// `bench BENCH --json -q` on an 8,000-triangle `generator` model at 48x40 with `extra`: its
/// report and its stderr (the run must succeed).
fn small_bench(bench: &str, generator: &str, extra: &[&str]) -> (serde_json::Value, String) {
    let mut args = vec![
        "bench",
        bench,
        "--generator",
        generator,
        "--triangles",
        "8000",
        "--width",
        "48",
        "--height",
        "40",
        "--json",
        "-q",
    ];
    args.extend_from_slice(extra);
    let args: Vec<&dyn AsRef<std::ffi::OsStr>> = args.iter().map(|a| a as _).collect();
    let out = dcrt(&args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    (serde_json::from_slice(&out.stdout).unwrap(), err)
}

/// `bench rays` of `small_bench`, one run.
fn small_rays_bench(generator: &str, extra: &[&str]) -> (serde_json::Value, String) {
    small_bench("rays", generator, &[&["--runs", "1"], extra].concat())
}

/// `bench rays --json` keeps the keys scripts read (docs/ARCHITECTURE.md, CLI contract) and adds
/// the traversal's counts, the lane share among them: steps over the iterations lanes ran, a
/// share.
#[test]
fn bench_json_reports_rates_counts_and_lane_share() {
    let (r, _) = small_rays_bench("assembly", &[]);
    assert!(r["adapter"].is_string(), "{r}");
    assert_eq!(
        (r["width"].as_u64(), r["height"].as_u64()),
        (Some(48), Some(40))
    );
    assert!(r["triangles"].as_u64().is_some_and(|t| t > 0), "{r}");
    for k in [
        "bvh_build_ms",
        "trace_ms_median",
        "mrays_per_s",
        "steps_per_ray",
        "nodes_per_node_block",
    ] {
        assert!(row_num(&r, k) > 0.0, "{k}: {r}");
    }
    let lanes = row_num(&r, "lane_use");
    assert!(lanes > 0.0 && lanes < 1.0, "lane_use {lanes}");
    assert_eq!(row_num(&r["rows"][0], "lane_use"), lanes);
}

/// `bench rays --peer embree` (Embree 3 from scripts/setup.sh, the harness compiled by
/// scripts/embree-peer.sh) traces each mode's rays beside dcrt's: the same camera rays with the
/// same hits, as many AO rays (4 a hit), about as many path rays (the bounces' directions are the
/// peer's own), a rate and a ratio per mode; shadows has no peer and says so.
#[test]
fn bench_rays_peer_traces_each_mode_s_rays() {
    let extra = ["--modes", "cast,ao,path,shadows", "--peer", "embree"];
    let (r, err) = small_rays_bench("rm", &extra);
    assert!(err.contains("no peer for shadows rays"), "{err}");
    let rows = r["rows"].as_array().unwrap();
    let dcrt_rays = |mode: &str| {
        let row = rows.iter().find(|x| x["mode"] == mode).unwrap();
        row["rays"].as_u64().unwrap()
    };
    let peers = r["peers"].as_array().unwrap();
    let modes: Vec<&str> = peers.iter().map(|p| p["mode"].as_str().unwrap()).collect();
    assert_eq!(modes, ["cast", "ao", "path"], "{r}");
    assert_eq!(r["peer"]["mode"], "cast", "{r}");
    for p in peers {
        let mode = p["mode"].as_str().unwrap();
        let (mine, theirs) = (dcrt_rays(mode), p["rays"].as_u64().unwrap());
        match mode {
            "cast" => assert_eq!((mine, theirs), (48 * 40, 48 * 40), "{p}"),
            // 4 AO rays a hit: as many as dcrt's but for pixels whose camera ray the two decide
            // differently (hit or miss).
            "ao" => {
                let split = (1.0 - p["hit_miss_agreement"].as_f64().unwrap()) * (48.0 * 40.0);
                assert!(theirs.abs_diff(mine) as f64 <= 4.0 * split.round(), "{p}");
            }
            _ => assert!(
                theirs.abs_diff(mine) * 10 < mine && theirs > 48 * 40 * 2,
                "path rays: dcrt {mine}, peer {theirs}"
            ),
        }
        assert!(p["hit_agreement"].as_f64().unwrap() > 0.99, "{p}");
        let (ratio, rate) = (
            p["ratio"].as_f64().unwrap(),
            p["mrays_per_s"].as_f64().unwrap(),
        );
        assert!(ratio.is_finite() && ratio > 0.0 && rate > 0.0, "{p}");
    }
}

/// `bench dc` of `small_bench` on `rm`, 2-frame orbits.
fn small_dc_bench(extra: &[&str]) -> serde_json::Value {
    small_bench("dc", "rm", &[&["--frames", "2"], extra].concat()).0
}

/// A number a `bench` report or row holds under `k`.
fn row_num(r: &serde_json::Value, k: &str) -> f64 {
    r[k].as_f64().unwrap_or_else(|| panic!("row key {k}: {r}"))
}

/// `bench dc --step`: the report says the step its frames were turned by (the cameras
/// themselves: `bench::dc::tests`).
#[test]
fn dc_bench_reports_its_step() {
    let still = small_dc_bench(&["--caches", "1/8", "--cache-maps", "lru", "--step", "2.5"]);
    assert_eq!(still["step"], 2.5);
}

/// `bench dc` renders each configuration's frames beside replicated frames of its own: its
/// ratio is its warm frame over those (`replicated_frame_ms`), not over an orbit rendered before.
#[test]
fn dc_bench_pairs_each_configuration_with_replicated_frames() {
    let report = small_dc_bench(&["--caches", "1/8,1/2", "--cache-maps", "lru"]);
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3);
    let f = row_num;
    for r in &rows[1..] {
        let ratio = f(r, "frame_ms") / f(r, "replicated_frame_ms");
        assert!(
            (f(r, "frame_over_replicated") - ratio).abs() <= 1e-9 * ratio,
            "{r}"
        );
    }
}

/// `bench dc --json` on a small model: every row keeps its keys, the replicated row is the
/// reference of the ratios, each repeat runs every configuration, and the block counts come from
/// the extra counting frame (the timed frames leave them out).
#[test]
fn dc_bench_reports_ratios_over_its_repeats() {
    let report = small_dc_bench(&[
        "--caches",
        "1/8",
        "--cache-maps",
        "lru,ize",
        "--replicate-blocks",
        "nodes",
        "--repeats",
        "2",
    ]);
    assert_eq!(report["repeats"], 2);
    let rows = report["rows"].as_array().unwrap();
    let configs: Vec<(&str, &str)> = rows
        .iter()
        .map(|r| {
            let map = r["cache_map"].as_str().unwrap_or("-");
            (r["config"].as_str().unwrap(), map)
        })
        .collect();
    assert_eq!(configs, [("replicated", "-"), ("dc", "lru"), ("dc", "ize")]);
    let f = row_num;
    for r in rows {
        for k in ["frame_ms", "first_frame_ms"] {
            assert!(f(r, k) > 0.0, "{k}: {r}");
        }
        assert!(f(r, "rounds_per_frame") >= 1.0, "{r}");
        // Only the cached configurations fetch.
        let fetched = f(r, "fetched_bytes_per_frame");
        if r["config"] == "replicated" {
            assert_eq!(fetched, 0.0, "{r}");
        } else {
            assert!(fetched > 0.0, "a 1/8 cache fetches: {r}");
        }
        let (lo, mid, hi) = (
            f(r, "frame_over_replicated_min"),
            f(r, "frame_over_replicated"),
            f(r, "frame_over_replicated_max"),
        );
        assert!(lo > 0.0 && lo <= mid && mid <= hi, "{r}");
        assert!(
            f(r, "nodes_per_block_entry") >= 1.0,
            "counted in the extra frame: {r}"
        );
        // Every traced ray takes a step; the share of busy lanes is a share.
        assert!(f(r, "steps_per_ray") >= 1.0, "{r}");
        let lanes = f(r, "lane_use");
        assert!(lanes > 0.0 && lanes <= 1.0, "{r}");
    }
    assert_eq!(f(&rows[0], "frame_over_replicated_min"), 1.0);
    assert_eq!(f(&rows[0], "frame_over_replicated_max"), 1.0);
    assert_eq!(f(&rows[0], "replicated_frame_ms"), f(&rows[0], "frame_ms"));
    for r in &rows[1..] {
        assert!(f(r, "distinct_blocks_per_frame") > 0.0, "{r}");
        assert!(f(r, "fetches_per_distinct_block") > 0.0, "{r}");
        assert!(
            f(r, "fault_rounds_per_frame") > 0.0,
            "a 1/8 cache faults: {r}"
        );
        assert!(
            f(r, "fault_round_bound_per_frame") <= f(r, "fault_rounds_per_frame"),
            "no schedule beats the bound: {r}"
        );
    }
    assert_eq!(f(&rows[0], "fault_round_bound_per_frame"), 0.0);
}

/// The switches for measurements are options of the benches, not of `dcrt render`: the render
/// CLI refuses each, naming it (a usage error, exit 2), and `dcrt bench job`, the render path
/// the cluster bench and the figures run, takes each and renders. `--block-counts` reaches the
/// tracer (its counts are in `--stats`, 0 without); `--display-bench` needs mpirun.
#[test]
fn measurement_switches_are_bench_options_not_render_options() {
    let d = TempDir::new("cli-switches");
    let scene = d.write("s.toml", SCENE);
    let png = d.path("s.png");
    let stats = d.path("s.json");
    let switches: [&[&str]; 7] = [
        &["--faults", "never"],
        &["--overlap-batches", "never"],
        &["--block-counts"],
        &["--epsilon", "0.0001"],
        &["--closest-hit-shadows"],
        &["--no-cull"],
        &["--display-bench"],
    ];
    let node_visits = |extra: &[&str]| -> u64 {
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> =
            vec![&"bench", &"job", &scene, &"-o", &png, &"--stats", &stats];
        args.extend(extra.iter().map(|a| a as &dyn AsRef<std::ffi::OsStr>));
        ok(&args);
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        v["frames"][0]["stats"]["node_visits"].as_u64().unwrap()
    };
    for switch in switches {
        let mut render: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"render", &scene, &"-o", &png];
        render.extend(switch.iter().map(|a| a as &dyn AsRef<std::ffi::OsStr>));
        let r = dcrt(&render);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{switch:?}: {err}");
        assert!(
            err.contains(&format!("unexpected argument '{}'", switch[0])),
            "{switch:?}: {err}"
        );
        if switch[0] == "--display-bench" {
            let mut job: Vec<&dyn AsRef<std::ffi::OsStr>> =
                vec![&"bench", &"job", &scene, &"-o", &png];
            job.extend(switch.iter().map(|a| a as &dyn AsRef<std::ffi::OsStr>));
            let r = dcrt(&job);
            let err = String::from_utf8_lossy(&r.stderr);
            assert_eq!(r.status.code(), Some(1), "{err}");
            assert!(err.contains("run it under mpirun"), "{err}");
        } else {
            let _ = std::fs::remove_file(&png);
            let visits = node_visits(switch);
            assert!(png.exists(), "{switch:?}");
            assert_eq!(visits > 0, switch[0] == "--block-counts", "{switch:?}");
        }
    }
}

/// scripts/gpu-bench.sh, the run prepared for a machine with a GPU, works on the driver at hand
/// with tiny scenes: a line per scene, store and mode, the distributed cache's table for both
/// camera steps with a row per cache and mapping, each bench's output kept in OUT; a bench that
/// fails is named and the rest still run; an unknown part is refused before anything runs.
#[test]
fn gpu_bench_script_prints_every_mode_and_the_dc_table() {
    let d = TempDir::new("gpu-bench");
    let out = d.path("out");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/gpu-bench.sh");
    let run = |parts: &str, limit: &str| {
        std::process::Command::new("bash")
            .arg(script)
            .arg(env!("CARGO_BIN_EXE_dcrt"))
            .args(["--runs", "1"])
            .env_remove("ADAPTER")
            .env_remove("MODES")
            .env_remove("NODE_COSTS")
            .envs([
                ("TRIANGLES", "3000"),
                ("SIZE", "24"),
                ("DC_TRIANGLES", "3000"),
                ("DC_SIZES", "24"),
                ("DC_FRAMES", "2"),
                ("PARTS", parts),
                ("LIMIT", limit),
            ])
            .env("OUT", &out)
            .output()
            .unwrap()
    };
    let r = run("rays dc", "200");
    let text = String::from_utf8_lossy(&r.stdout).into_owned();
    assert!(
        r.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert!(text.starts_with("adapter "), "{text}");
    for generator in ["rm", "assembly"] {
        for cost in ["3", "1"] {
            for store in ["texture", "buffer"] {
                for mode in ["cast", "ao", "path"] {
                    let want = [generator, "node", "cost", cost, store, mode];
                    let line = text
                        .lines()
                        .find(|l| l.split_whitespace().take(6).eq(want))
                        .unwrap_or_else(|| panic!("no {want:?} line: {text}"));
                    let rate: f64 = line.split_whitespace().nth(6).unwrap().parse().unwrap();
                    assert!(rate > 0.0 && line.contains("Mrays/s"), "{line}");
                }
            }
        }
        let json = std::fs::read_to_string(out.join(format!("rays-{generator}.json"))).unwrap();
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v["rows"].as_array().unwrap().len(), 12, "{json}");
    }
    for step in ["3", "120"] {
        let table = std::fs::read_to_string(out.join(format!("dc-24-{step}.txt"))).unwrap();
        assert!(
            table.lines().any(|l| l.starts_with("replicated ")),
            "{table}"
        );
        for map in ["ize", "demarle", "lru"] {
            for cache in ["1/8", "1/32"] {
                assert!(
                    table
                        .lines()
                        .any(|l| l.split_whitespace().take(4).eq(["dc", cache, map, "root"])),
                    "no {cache} {map} row for a {step} degree step: {table}"
                );
            }
        }
    }
    // A limit no bench meets: each is named, none stops the others, the script fails.
    let r = run("dc rays", "0.01");
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    for bench in [
        "dc at 24x24, 3 degrees",
        "dc at 24x24, 120 degrees",
        "rays on rm",
        "rays on assembly",
    ] {
        assert!(
            err.contains(&format!("gpu-bench: bench {bench} failed")),
            "{bench}: {err}"
        );
    }
    let r = run("rays frames", "200");
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("unknown part 'frames'"), "{err}");
    assert!(
        r.stdout.is_empty(),
        "ran before refusing: {}",
        String::from_utf8_lossy(&r.stdout)
    );
}
