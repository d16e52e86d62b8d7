//! `dcrt prepare` within a memory budget: a tiny `--memory` makes the out-of-core path run
//! (several parts, a top tree), and its block file is a valid tree over the same triangles that
//! renders the same hit in every pixel as the one built in memory; bad budgets, full disks, bad
//! input found late and interruptions leave no block file and no temporary files.

use crate::common::*;
use dcrt::blocks::Blocks;
use dcrt::blocks::file::DcbFile;
use dcrt::bvh::{Child, Node, WIDTH};
use dcrt::output::{ExrSamples, read_exr};
use std::ffi::OsStr;
use std::path::Path;

const CAMERA: &str = "[camera]\nposition = [0.2, -2.4, 1.6]\nfocal_point = [0, 0, 0]\n\
                      view_up = [0, 0, 1]\nview_angle = 38\n[image]\nwidth = 56\nheight = 44\n";

/// A model of two meshes: an rm surface and a quad placed above it, with its own colour.
fn scene(d: &TempDir, triangles: u32, quad: &str) -> std::path::PathBuf {
    d.write("quad.obj", quad);
    d.write(
        "s.toml",
        format!(
            "{CAMERA}[[mesh]]\ngenerator = \"rm\"\ntriangles = {triangles}\n\
             [[mesh]]\nfile = \"quad.obj\"\ncolor = [0.9, 0.2, 0.1]\nscale = 0.5\n\
             translate = [0, 0, 0.4]\n"
        ),
    )
}

const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";

fn run(args: &[&dyn AsRef<OsStr>]) -> (bool, String) {
    let r = dcrt(args);
    (
        r.status.success(),
        String::from_utf8_lossy(&r.stderr).to_string(),
    )
}

fn ok(args: &[&dyn AsRef<OsStr>]) -> String {
    let (good, err) = run(args);
    assert!(good, "{err}");
    err
}

/// The parts count from `prepare`'s line, `None` when built in memory; the largest part is
/// checked against the most a part may have.
fn parts(log: &str) -> Option<usize> {
    let at = log.find("out of core in ")?;
    let words: Vec<&str> = log[at + 15..].split([' ', ';']).collect();
    let number = |after: &str| -> u64 {
        let i = words.iter().position(|w| *w == after).unwrap();
        words[i + 1].parse().unwrap()
    };
    let (largest, most) = (number("largest"), number("most"));
    assert!(
        largest <= most,
        "a part of {largest} triangles, more than {most}: {log}"
    );
    words[0].parse().ok()
}

/// Walks the tree of `b`: every triangle reached once, in depth-first order (a node's leaves,
/// then its inner children), inside every box above it; returns the primitive id of each
/// triangle in walk order.
fn walk(b: &Blocks) -> Vec<u32> {
    type Box3 = ([f32; 3], [f32; 3]);
    fn grow(all: &mut Box3, (lo, hi): Box3) {
        for a in 0..3 {
            all.0[a] = all.0[a].min(lo[a]);
            all.1[a] = all.1[a].max(hi[a]);
        }
    }
    fn inside((lo, hi): Box3, (l, h): Box3) -> bool {
        (0..3).all(|a| lo[a] <= l[a] && h[a] <= hi[a])
    }
    fn below(b: &Blocks, i: u32, ids: &mut Vec<u32>, next: &mut u32) -> Box3 {
        let n = b.node(i);
        let mut all = ([f32::MAX; 3], [f32::MIN; 3]);
        for s in 0..WIDTH {
            if let Child::Leaf { first, count } = n.child(s) {
                assert_eq!(first, *next, "node {i} slot {s}: triangles depth-first");
                for t in first..first + count {
                    let (tri, id) = b.triangle(t);
                    ids.push(id);
                    let lo =
                        std::array::from_fn(|a| tri.iter().map(|p| p[a]).fold(f32::MAX, f32::min));
                    let hi =
                        std::array::from_fn(|a| tri.iter().map(|p| p[a]).fold(f32::MIN, f32::max));
                    assert!(
                        inside(n.child_box(s), (lo, hi)),
                        "node {i} slot {s}: triangle {t} outside"
                    );
                    grow(&mut all, (lo, hi));
                }
                *next += count;
            }
        }
        for s in 0..WIDTH {
            if let Child::Inner(c) = n.child(s) {
                assert!(c > i, "node {i}: children after parents");
                let got = below(b, c, ids, next);
                assert!(
                    inside(n.child_box(s), got),
                    "node {i} slot {s}: a box misses its subtree"
                );
                grow(&mut all, got);
            }
        }
        all
    }
    let mut ids = Vec::new();
    below(b, 0, &mut ids, &mut 0);
    ids
}

/// Each primitive id's triangle in `b`.
fn by_id(b: &Blocks, n: usize) -> Vec<[[f32; 3]; 3]> {
    let mut out = vec![[[f32::NAN; 3]; 3]; n];
    for t in 0..n as u32 {
        let (tri, id) = b.triangle(t);
        out[id as usize] = tri;
    }
    out
}

#[test]
fn out_of_core_prepare_makes_the_same_model_as_in_memory() {
    let d = TempDir::new("prep-ooc");
    let s = scene(&d, 60_000, QUAD);
    let whole = d.path("whole.dcb");
    let log = ok(&[&"prepare", &s, &"-o", &whole]);
    assert_eq!(parts(&log), None, "built in memory: {log}");
    let ooc = d.path("ooc.dcb");
    let log = ok(&[&"prepare", &s, &"-o", &ooc, &"--memory", &"16MiB"]);
    let n = parts(&log).unwrap_or_else(|| panic!("not out of core: {log}"));
    assert!(n >= 3, "{n} parts: {log}");
    assert_eq!(
        listing(&d.0),
        ["ooc.dcb", "quad.obj", "s.toml", "whole.dcb"]
    );

    // Both files pass every structural check; the same triangles under the same ids, the same
    // mesh table, bounds and view.
    let (fa, fb) = (DcbFile::open(&whole).unwrap(), DcbFile::open(&ooc).unwrap());
    let (a, b) = (fa.read_all(1).unwrap(), fb.read_all(1).unwrap());
    let count = fa.meta.triangles as usize;
    assert_eq!(fb.meta.triangles as usize, count);
    assert_eq!(fa.meta.mesh_first, fb.meta.mesh_first);
    assert_eq!(fa.meta.colors, fb.meta.colors);
    assert_eq!(fa.meta.camera, fb.meta.camera);
    assert_eq!(
        (fa.meta.bounds_min, fa.meta.bounds_max),
        (fb.meta.bounds_min, fb.meta.bounds_max)
    );
    assert_eq!(fa.meta.mesh_first, [0, count as u32 - 2]);
    // Parts' nodes after their heads start blocks, after padding that no node reaches.
    let padding = (0..fb.meta.nodes as u32).filter(|&i| b.node(i) == Node::PADDING);
    assert!(
        padding.count() > 0,
        "no part's nodes were moved to a block's start"
    );
    let ids = walk(&b);
    let mut sorted = ids.clone();
    sorted.sort_unstable();
    assert!(
        sorted.iter().copied().eq(0..count as u32),
        "every triangle once"
    );
    let bits = |v: Vec<[[f32; 3]; 3]>| -> Vec<u32> {
        v.iter().flatten().flatten().map(|c| c.to_bits()).collect()
    };
    assert!(
        bits(by_id(&a, count)) == bits(by_id(&b, count)),
        "the same triangles"
    );

    // The same hit in every pixel, replicated and through a distributed cache.
    let render = |dcb: &Path, name: &str, extra: &[&dyn AsRef<OsStr>]| -> Vec<u32> {
        let exr = d.path(&format!("{name}.exr"));
        let png = d.path(&format!("{name}.png"));
        let mut args: Vec<&dyn AsRef<OsStr>> = vec![
            &"render", &dcb, &"-o", &png, &"--exr", &exr, &"--aov", &"id",
        ];
        args.extend_from_slice(extra);
        ok(&args);
        let channels = read_exr(&exr).unwrap();
        match &channels.iter().find(|(n, _)| n == "id").unwrap().1 {
            ExrSamples::U32(v) => v.clone(),
            other => panic!("id channel {other:?}"),
        }
    };
    let ia = render(&whole, "a", &[]);
    let ib = render(&ooc, "b", &[]);
    let hits = ia.iter().filter(|&&i| i != u32::MAX).count();
    assert!(
        hits > ia.len() / 4,
        "the camera sees the model: {hits} hits"
    );
    let quad = count as u32 - 2..count as u32;
    assert!(ia.iter().any(|i| quad.contains(i)), "the quad is seen");
    assert_eq!(ia, ib, "the same hit in every pixel");
    let dc: [&dyn AsRef<OsStr>; 6] = [
        &"--virtual-ranks",
        &"3",
        &"--rank",
        &"2",
        &"--cache",
        &"1/8",
    ];
    assert_eq!(render(&ooc, "c", &dc), ib, "the same through the cache");
}

/// Inputs a spatial cut cannot separate: 30,000 copies of one triangle (cut by order) and a
/// dense cluster beside a few far triangles (its cells cut again over its own centres) make valid
/// trees over every triangle out of core.
#[test]
fn inseparable_and_clustered_inputs_make_valid_trees() {
    let d = TempDir::new("prep-degenerate");
    let mut copies = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    copies += &"f 1 2 3\n".repeat(30_000);
    d.write("copies.obj", copies);
    let mut cluster = String::new();
    let mut rng = Rng(5);
    for i in 0..40_000 {
        let far = i % 1000 == 0;
        let s = if far { 100.0 } else { 1e-3 };
        let c = [0; 3].map(|_| rng.range(-s, s));
        for k in 0..3 {
            let p = [0; 3]
                .map(|a| c[a] + rng.range(0.0, s * 1e-2) + if a == k { s * 1e-2 } else { 0.0 });
            cluster += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        cluster += &format!("f {} {} {}\n", 3 * i + 1, 3 * i + 2, 3 * i + 3);
    }
    d.write("cluster.obj", cluster);
    for mesh in ["copies.obj", "cluster.obj"] {
        let s = d.write("s.toml", format!("[[mesh]]\nfile = \"{mesh}\"\n"));
        let dcb = d.path("m.dcb");
        let log = ok(&[&"prepare", &s, &"-o", &dcb, &"--memory", &"16MiB"]);
        let n = parts(&log).unwrap_or_else(|| panic!("{mesh}: not out of core: {log}"));
        assert!(n >= 3, "{mesh}: {n} parts");
        let f = DcbFile::open(&dcb).unwrap();
        let b = f.read_all(1).unwrap();
        let mut ids = walk(&b);
        ids.sort_unstable();
        let count = f.meta.triangles as u32;
        assert!(ids.into_iter().eq(0..count), "{mesh}: every triangle once");
    }
}

#[test]
fn a_bad_memory_budget_is_refused_before_any_work() {
    let d = TempDir::new("prep-budget");
    let s = scene(&d, 2_000, QUAD);
    let dcb = d.path("m.dcb");
    for (value, want) in [
        ("4GB", "4GiB"),
        ("0", "binary unit"),
        ("abc", "binary unit"),
        ("1KiB", "at least"),
        ("4096TiB", "this machine has"),
    ] {
        let (good, err) = run(&[&"prepare", &s, &"-o", &dcb, &"--memory", &value]);
        assert!(!good, "--memory {value} accepted");
        assert!(
            err.contains("--memory") && err.contains(want),
            "{value}: {err}"
        );
    }
    assert_eq!(listing(&d.0), ["quad.obj", "s.toml"]);
}

#[test]
fn a_full_disk_leaves_no_block_file_and_no_temporary_files() {
    let d = TempDir::new("prep-full");
    let s = scene(&d, 60_000, QUAD);
    let dcb = d.path("m.dcb");
    std::fs::write(&dcb, b"old").unwrap();
    // Room for some of the spilled triangles (2 MiB in all), then for the parts but not the
    // block file (2.6 MiB).
    for kib in [1024, 2300] {
        let r = on_full_disk(
            &d.0,
            kib,
            &[&"prepare", &s, &"-o", &dcb, &"--memory", &"16MiB"],
        );
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{err}");
        assert!(
            err.contains("m.dcb") && err.contains("No space left on device"),
            "{err}"
        );
        assert_eq!(std::fs::read(&dcb).unwrap(), b"old", "the old file stays");
        assert_eq!(listing(&d.0), ["m.dcb", "quad.obj", "s.toml"], "{err}");
    }
}

#[test]
fn bad_input_found_late_leaves_nothing() {
    let d = TempDir::new("prep-late");
    // The rm surface is spilled before the OBJ is read; its fifth face is wrong.
    let bad = format!("{QUAD}f 1 2 3\nf 2 3 4\nf 1 3 4\nf 1 2 9\n");
    let s = scene(&d, 60_000, &bad);
    let dcb = d.path("m.dcb");
    let (good, err) = run(&[&"prepare", &s, &"-o", &dcb, &"--memory", &"16MiB"]);
    assert!(!good);
    assert!(
        err.contains("quad.obj") && err.contains("line 9") && err.contains("out of range"),
        "{err}"
    );
    assert_eq!(listing(&d.0), ["quad.obj", "s.toml"]);

    // A binary PLY read in pieces, its face 150000 of 178802 wrong: most of it has been read
    // and spilled when the error is found.
    let n = 300u32;
    let mut ply = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
         property float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        n * n,
        2 * (n - 1) * (n - 1)
    )
    .into_bytes();
    for i in 0..n * n {
        for c in [(i % n) as f32, (i / n) as f32, 0.0] {
            ply.extend_from_slice(&c.to_le_bytes());
        }
    }
    let mut face = 0;
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let v = y * n + x;
            for t in [[v, v + 1, v + n + 1], [v, v + n + 1, v + n]] {
                let t = if face == 150_000 {
                    [v, v + 1, n * n]
                } else {
                    t
                };
                ply.push(3);
                for i in t {
                    ply.extend_from_slice(&(i as i32).to_le_bytes());
                }
                face += 1;
            }
        }
    }
    d.write("grid.ply", &ply);
    let s = d.write("p.toml", format!("{CAMERA}[[mesh]]\nfile = \"grid.ply\"\n"));
    let (good, err) = run(&[&"prepare", &s, &"-o", &dcb, &"--memory", &"16MiB"]);
    assert!(!good);
    assert!(
        err.contains("grid.ply: face 150000") && err.contains("out of range"),
        "{err}"
    );
    assert_eq!(listing(&d.0), ["grid.ply", "p.toml", "quad.obj", "s.toml"]);
}

#[test]
fn an_interrupted_prepare_removes_its_temporary_files() {
    let d = TempDir::new("prep-int");
    let s = scene(&d, 1_500_000, QUAD);
    let dcb = d.path("m.dcb");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"))
        .args([
            "prepare".as_ref(),
            s.as_os_str(),
            "-o".as_ref(),
            dcb.as_os_str(),
            "--memory".as_ref(),
            "16MiB".as_ref(),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Interrupted once its temporary directory exists.
    let t = std::time::Instant::now();
    while !listing(&d.0).iter().any(|n| n.ends_with(".parts")) {
        assert!(
            t.elapsed().as_secs() < 60,
            "no temporary directory appeared"
        );
        assert!(
            child.try_wait().unwrap().is_none(),
            "finished before it could be interrupted"
        );
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let pid = child.id().to_string();
    std::process::Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(err.contains("interrupted by SIGTERM"), "{err}");
    assert_eq!(listing(&d.0), ["quad.obj", "s.toml"]);
}

/// A PLY grid of `n` x `n` quads with a point property `value`.
fn coloured_grid(d: &TempDir, n: usize) -> std::path::PathBuf {
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty float value\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        (n + 1) * (n + 1),
        n * n
    );
    for j in 0..=n {
        for i in 0..=n {
            ply += &format!("{i} {j} 0 {}\n", i + j);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let v = j * (n + 1) + i;
            ply += &format!("4 {v} {} {} {}\n", v + 1, v + n + 2, v + n + 1);
        }
    }
    d.write("grid.ply", ply);
    d.write(
        "s.toml",
        "[[mesh]]\nfile = \"grid.ply\"\ncolor_by = \"value\"\n",
    )
}

#[test]
fn colours_by_data_are_built_in_memory_or_refused_never_dropped() {
    // 2 x 180^2 = 64,800 triangles: more than a 16 MiB budget builds in memory, and out of core
    // the attribute blocks would be lost.
    let d = TempDir::new("prep-colour");
    let s = coloured_grid(&d, 180);
    let dcb = d.path("m.dcb");
    let (good, err) = run(&[&"prepare", &s, &"-o", &dcb, &"--memory", &"16MiB"]);
    assert!(!good, "a coloured model was prepared out of core: {err}");
    assert!(
        err.contains("mesh 1 is coloured by data") && err.contains("raise --memory"),
        "{err}"
    );
    assert_eq!(listing(&d.0), ["grid.ply", "s.toml"]);
    let log = ok(&[&"prepare", &s, &"-o", &dcb, &"--memory", &"64MiB"]);
    assert!(
        log.contains("attribute blocks") && log.contains("in memory"),
        "{log}"
    );
    let f = DcbFile::open(&dcb).unwrap();
    assert!(f.meta.attrs.blocks > 0, "no attribute blocks");
}
