//! Outputs are safe: written through a temporary file and renamed into place, never over an
//! input of the same run or over something that is not a regular file, checked before any
//! rendering; on failure or interruption the frames the run finished stay, nothing half done is
//! left, and what was there before stays.

use crate::common::*;
use std::ffi::OsStr;
use std::path::PathBuf;

const SCENE: &str = "[camera]\nposition = [0.3, 0.3, 3]\nfocal_point = [0.3, 0.3, 0]\n\
                     view_up = [0, 1, 0]\nview_angle = 40\n[image]\nwidth = 24\nheight = 16\n\
                     [[mesh]]\nfile = \"tri.obj\"\n";

fn setup(tag: &str) -> (TempDir, PathBuf) {
    let d = TempDir::new(tag);
    d.write("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let s = d.write("s.toml", SCENE);
    (d, s)
}

/// Runs dcrt, expects exit 1 with every `needles` in stderr; returns stderr.
fn refused(args: &[&dyn AsRef<OsStr>], needles: &[&str]) -> String {
    let r = dcrt(args);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert_eq!(r.status.code(), Some(1), "should fail cleanly: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}:\n{err}");
    }
    err
}

#[test]
fn outputs_never_replace_the_run_s_inputs() {
    let (d, s) = setup("out-inputs");
    let before = std::fs::read(&s).unwrap();
    refused(&[&"render", &s, &"-o", &s], &["would replace the input"]);
    refused(&[&"prepare", &s, &"-o", &s], &["would replace the input"]);
    let mesh = d.path("tri.obj");
    refused(
        &[&"prepare", &s, &"-o", &mesh],
        &["tri.obj", "would replace the input"],
    );
    // Through another spelling of the same path.
    let other = d.path(".").join("s.toml");
    refused(
        &[&"render", &s, &"-o", &other],
        &["would replace the input"],
    );
    assert_eq!(std::fs::read(&s).unwrap(), before);
    let dcb = d.path("good.dcb");
    let r = dcrt(&[&"prepare", &s, &"-o", &dcb]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let good = std::fs::read(&dcb).unwrap();
    refused(
        &[&"render", &dcb, &"-o", &dcb],
        &["good.dcb", "would replace the input"],
    );
    let png = d.path("x.png");
    refused(
        &[&"render", &dcb, &"-o", &png, &"--exr", &dcb],
        &["EXR output would replace"],
    );
    // A scene naming the block file: the block file is an input too.
    let named = d.write("named.toml", "model = \"good.dcb\"\n");
    refused(
        &[&"render", &named, &"-o", &dcb],
        &["would replace the input"],
    );
    assert_eq!(std::fs::read(&dcb).unwrap(), good);
    assert!(!png.exists());
}

#[test]
fn non_regular_outputs_are_refused_and_kept() {
    use std::os::unix::fs::FileTypeExt;
    let (d, s) = setup("out-special");
    refused(
        &[&"render", &s, &"-o", &"/dev/full"],
        &["/dev/full", "not a regular file"],
    );
    refused(
        &[&"prepare", &s, &"-o", &"/dev/null"],
        &["a character device"],
    );
    let png = d.path("x.png");
    refused(
        &[&"render", &s, &"-o", &png, &"--exr", &"/dev/null"],
        &["/dev/null"],
    );
    assert!(
        std::fs::metadata("/dev/null")
            .unwrap()
            .file_type()
            .is_char_device()
    );
    assert!(!png.exists());
    let dir = d.path("adir");
    std::fs::create_dir(&dir).unwrap();
    refused(&[&"prepare", &s, &"-o", &dir], &["adir", "a directory"]);
    refused(
        &[&"render", &s, &"-o", &png, &"--stats", &dir],
        &["adir", "a directory"],
    );
    assert!(!png.exists(), "checked before rendering: no PNG");
    assert_eq!(listing(&d.0), ["adir", "s.toml", "tri.obj"]);
    assert!(listing(&dir).is_empty());
}

#[test]
fn png_exr_and_stats_paths_must_differ() {
    let (d, s) = setup("out-same");
    let p = d.path("same.png");
    refused(
        &[&"render", &s, &"-o", &p, &"--exr", &p],
        &["both the PNG and the EXR"],
    );
    refused(
        &[&"render", &s, &"-o", &p, &"--stats", &p],
        &["both the PNG and the statistics"],
    );
    let e = d.path("same.exr");
    refused(
        &[&"render", &s, &"-o", &p, &"--exr", &e, &"--stats", &e],
        &["both the EXR and the statistics"],
    );
    assert!(!p.exists() && !e.exists());
    // A directory no file can be created in (procfs refuses even root): refused before
    // rendering, so the PNG is not written either.
    refused(
        &[&"render", &s, &"-o", &p, &"--exr", &"/proc/x.exr"],
        &["cannot create the EXR"],
    );
    assert!(!p.exists());
}

#[test]
fn a_full_filesystem_fails_the_run_and_keeps_the_old_files() {
    let (d, s) = setup("out-full");
    let png = d.path("out.png");
    std::fs::write(&png, b"old").unwrap();
    let r = on_full_disk(&d.0, 0, &[&"render", &s, &"-o", &png]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("out.png") && !err.contains("wrote"), "{err}");
    assert_eq!(std::fs::read(&png).unwrap(), b"old", "the old PNG stays");
    let r = on_full_disk(&d.0, 0, &[&"render", &s, &"-o", &png, &"--frames", &"3"]);
    assert_eq!(r.status.code(), Some(1));
    let dcb = d.path("m.dcb");
    let r = on_full_disk(&d.0, 0, &[&"prepare", &s, &"-o", &dcb]);
    assert_eq!(
        r.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert_eq!(
        listing(&d.0),
        ["out.png", "s.toml", "tri.obj"],
        "no partial files"
    );
    // Room for a PNG (a few hundred bytes) but not its EXR with every AOV: the frame written
    // before the failure is removed too.
    let exr = d.path("out.exr");
    let big = d.write(
        "big.toml",
        SCENE.replace("width = 24\nheight = 16", "width = 64\nheight = 64"),
    );
    let r = on_full_disk(
        &d.0,
        4,
        &[
            &"render",
            &big,
            &"-o",
            &png,
            &"--frames",
            &"2",
            &"--exr",
            &exr,
            &"--aov",
            &"depth",
            &"--aov",
            &"id",
            &"--aov",
            &"normal",
        ],
    );
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("out_0000.exr"), "{err}");
    assert_eq!(
        listing(&d.0),
        ["big.toml", "out.png", "s.toml", "tri.obj"],
        "{err}"
    );
}

#[test]
fn outputs_are_replaced_whole() {
    let (d, s) = setup("out-ok");
    let png = d.path("out.png");
    std::fs::write(&png, b"old").unwrap();
    let r = dcrt(&[&"render", &s, &"-o", &png, &"--frames", &"2"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert_eq!(std::fs::read(&png).unwrap(), b"old", "frames are numbered");
    for f in ["out_0000.png", "out_0001.png"] {
        assert!(std::fs::read(d.path(f)).unwrap().starts_with(b"\x89PNG"));
    }
    let r = dcrt(&[&"render", &s, &"-o", &png]);
    assert!(r.status.success());
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
    assert_eq!(
        listing(&d.0),
        [
            "out.png",
            "out_0000.png",
            "out_0001.png",
            "s.toml",
            "tri.obj"
        ]
    );
}

/// Starts `cmd` with stderr piped, waits for a stderr line containing `line`, sends it `signal`
/// (`kill -SIG`), and waits for it to end: its status, its stderr, and the time from the signal
/// to its end. Every wait is bounded by `limit`; a command still running then is killed and the
/// test fails.
pub(crate) fn signal_after(
    cmd: std::process::Command,
    line: &str,
    signal: &str,
    limit: std::time::Duration,
) -> (std::process::ExitStatus, String, std::time::Duration) {
    signal_after_to(cmd, line, signal, limit, &|pid| pid)
}

/// `signal_after`, the signal going to the process `target` names given the command's pid (a
/// rank of an mpirun job, say).
pub(crate) fn signal_after_to(
    mut cmd: std::process::Command,
    line: &str,
    signal: &str,
    limit: std::time::Duration,
    target: &dyn Fn(u32) -> u32,
) -> (std::process::ExitStatus, String, std::time::Duration) {
    use std::io::BufRead;
    use std::time::Instant;
    let mut child = cmd
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let err = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in std::io::BufReader::new(err).lines() {
            let Ok(l) = l else { break };
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let mut text = String::new();
    let start = Instant::now();
    loop {
        let left = limit.saturating_sub(start.elapsed());
        match rx.recv_timeout(left) {
            Ok(l) => {
                text.push_str(&l);
                text.push('\n');
                if l.contains(line) {
                    break;
                }
            }
            Err(_) => {
                let _ = child.kill();
                panic!("no line {line:?} within {limit:?}:\n{text}");
            }
        }
    }
    let status = std::process::Command::new("kill")
        .args([format!("-{signal}"), target(child.id()).to_string()])
        .status()
        .unwrap();
    assert!(status.success(), "kill -{signal} failed");
    let sent = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if sent.elapsed() > limit {
            let _ = child.kill();
            panic!("still running {limit:?} after {signal}:\n{text}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let took = sent.elapsed();
    // What the process said before it ended (the pipe closes with it).
    while let Ok(l) = rx.recv_timeout(std::time::Duration::from_secs(2)) {
        text.push_str(&l);
        text.push('\n');
    }
    (status, text, took)
}

/// SIGTERM, SIGINT or SIGHUP part-way through a one-process run: the run keeps every frame it
/// finished (PNG and EXR, each whole) and says so, removes its temporary files, exits with 128 +
/// the signal; a file the run would have overwritten later stays as it was, and files that are
/// not outputs of the run stay.
#[test]
fn an_interrupted_render_keeps_its_finished_frames() {
    for (signal, code) in [("TERM", 143), ("INT", 130), ("HUP", 129)] {
        let (d, s) = setup(&format!("out-sig{signal}"));
        d.write("keep.txt", "mine");
        // An output of a frame the run will not reach.
        d.write("f_0900.png", "old");
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"));
        cmd.arg("render")
            .arg(&s)
            .arg("-o")
            .arg(d.path("f.png"))
            .arg("--exr")
            .arg(d.path("f.exr"))
            .args(["--aov", "depth", "--frames", "1000"]);
        let limit = std::time::Duration::from_secs(60);
        let (status, err, _) = signal_after(cmd, "frame 2:", signal, limit);
        assert_eq!(status.code(), Some(code), "SIG{signal}:\n{err}");
        let left = listing(&d.0);
        let pngs: Vec<&String> = left
            .iter()
            .filter(|f| f.starts_with("f_") && f.ends_with(".png") && *f != "f_0900.png")
            .collect();
        let n = pngs.len();
        assert!(n >= 3, "SIG{signal}: {n} frames kept:\n{err}");
        let said = format!(
            "interrupted by SIG{signal} after frame {}: kept {n} frames in {}/",
            n - 1,
            d.0.display()
        );
        assert!(err.contains(&said), "SIG{signal}: no {said:?} in:\n{err}");
        let mut want: Vec<String> = (0..n)
            .flat_map(|i| [format!("f_{i:04}.exr"), format!("f_{i:04}.png")])
            .chain(["f_0900.png", "keep.txt", "s.toml", "tri.obj"].map(String::from))
            .collect();
        want.sort();
        assert_eq!(left, want, "SIG{signal}: what is left:\n{err}");
        for i in 0..n {
            let png = image::open(d.path(&format!("f_{i:04}.png"))).unwrap();
            assert_eq!((png.width(), png.height()), (24, 16));
            let exr = dcrt::output::read_exr(&d.path(&format!("f_{i:04}.exr"))).unwrap();
            assert!(exr.iter().any(|(c, _)| c == "Z"), "frame {i}: {exr:?}");
        }
        assert_eq!(std::fs::read(d.path("f_0900.png")).unwrap(), b"old");
        assert_eq!(std::fs::read(d.path("keep.txt")).unwrap(), b"mine");
    }
}

/// SIGTERM to a render blocked writing to a stderr that nobody reads (a full pipe; a pager the
/// user paused) still ends it, with 143, its finished frames whole and no temporary file: the
/// interruption's message may wait on stderr, the exit does not. The output path is made long so
/// that a few dozen frame lines fill the pipe.
#[test]
fn an_interrupted_render_ends_though_nobody_reads_its_stderr() {
    use std::io::BufRead;
    use std::time::{Duration, Instant};
    let (d, s) = setup("out-sig-full-stderr");
    let mut dir = d.0.clone();
    for i in 0..14 {
        dir.push(format!("{i:02}{}", "d".repeat(198)));
    }
    std::fs::create_dir_all(&dir).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"))
        .arg("render")
        .arg(&s)
        .arg("-o")
        .arg(dir.join("f.png"))
        .args(["--frames", "100000"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    while !line.starts_with("frame 2:") {
        line.clear();
        assert!(err.read_line(&mut line).unwrap() > 0, "no frame 2");
    }
    // From here nobody reads: wait until a thread of the render waits in a pipe write (the
    // kernel's wait channel), stderr being the only pipe it writes.
    let tasks = format!("/proc/{}/task", child.id());
    let blocked = || {
        std::fs::read_dir(&tasks).unwrap().any(|t| {
            let wchan = std::fs::read_to_string(t.unwrap().path().join("wchan"));
            wchan.is_ok_and(|w| w.contains("pipe_write"))
        })
    };
    let limit = Instant::now() + Duration::from_secs(120);
    while !blocked() {
        assert!(
            Instant::now() < limit,
            "the render never blocked on its stderr"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let pid = child.id().to_string();
    let sent = std::process::Command::new("kill")
        .args(["-TERM", &pid])
        .status();
    assert!(sent.unwrap().success());
    let limit = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > limit {
            let _ = child.kill();
            panic!("a render blocked on stderr outlived SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(status.code(), Some(143));
    let left = listing(&dir);
    assert!(left.len() >= 3, "{} frames kept", left.len());
    for (i, f) in left.iter().enumerate() {
        assert_eq!(f, &format!("f_{i:04}.png"), "what is left: {left:?}");
        let png = image::open(dir.join(f)).unwrap();
        assert_eq!((png.width(), png.height()), (24, 16));
    }
}

/// The EXR contract read back against values known in closed form: the scene's one triangle
/// (0,0,0) (1,0,0) (0,1,0) seen straight down from 3 units above (0.3, 0.3): a pixel whose ray
/// clearly hits it has `Z` = the distance along the normalized ray, `id` 0 and a unit `N` along
/// z; one that clearly misses has `Z` = +inf, `id` 0xFFFFFFFF and `N` zero. The EXR's colour is
/// linear and ignores `--exposure`; the PNG is sRGB of the colour times 2^exposure.
#[test]
fn exr_channels_hold_known_depths_ids_and_normals() {
    use dcrt::output::{ExrSamples, read_exr};
    let (d, s) = setup("out-exr-contract");
    let (w, h) = (24usize, 16usize);
    let mut runs = Vec::new();
    for (tag, exposure) in [("e0", "0"), ("e1", "1")] {
        let (png, exr) = (d.path(&format!("{tag}.png")), d.path(&format!("{tag}.exr")));
        let r = dcrt(&[
            &"render",
            &s,
            &"-o",
            &png,
            &"--exr",
            &exr,
            &"--aov",
            &"depth,id,normal",
            &"--exposure",
            &exposure,
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let channels: std::collections::BTreeMap<String, ExrSamples> =
            read_exr(&exr).unwrap().into_iter().collect();
        runs.push((image::open(&png).unwrap().to_rgb8(), channels));
    }
    let f32s = |c: &std::collections::BTreeMap<String, ExrSamples>, name: &str| match &c[name] {
        ExrSamples::F32(v) => v.clone(),
        other => panic!("{name}: {other:?}"),
    };
    let (_, c) = &runs[0];
    let (z, nx, ny, nz) = (f32s(c, "Z"), f32s(c, "N.X"), f32s(c, "N.Y"), f32s(c, "N.Z"));
    let ExrSamples::U32(id) = &c["id"] else {
        panic!("id is not u32")
    };
    let th = (20f64).to_radians().tan();
    let (mut hits, mut misses) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let sx = 2.0 * (x as f64 + 0.5) / w as f64 - 1.0;
            let sy = 1.0 - 2.0 * (y as f64 + 0.5) / h as f64;
            // The ray's direction before normalizing has z = -1: it meets z = 0 at t = 3 |v|.
            let v = [sx * th * w as f64 / h as f64, sy * th, -1.0];
            let (px, py) = (0.3 + 3.0 * v[0], 0.3 + 3.0 * v[1]);
            let inside = px.min(py).min(1.0 - px - py);
            if inside > 0.02 {
                hits += 1;
                let t = 3.0 * (v[0] * v[0] + v[1] * v[1] + 1.0).sqrt();
                assert!(
                    (f64::from(z[i]) - t).abs() < 1e-5 * t,
                    "pixel {i}: Z {} not {t}",
                    z[i]
                );
                assert_eq!(id[i], 0, "pixel {i}");
                assert!(nx[i].abs() < 1e-6 && ny[i].abs() < 1e-6, "pixel {i}");
                assert!((nz[i].abs() - 1.0).abs() < 1e-6, "pixel {i}: N.Z {}", nz[i]);
            } else if inside < -0.02 {
                misses += 1;
                assert!(z[i].is_infinite() && z[i] > 0.0, "pixel {i}: Z {}", z[i]);
                assert_eq!(id[i], u32::MAX, "pixel {i}");
                assert_eq!([nx[i], ny[i], nz[i]], [0.0; 3], "pixel {i}");
            }
        }
    }
    assert!(
        hits > 20 && misses > 20,
        "{hits} hits, {misses} misses checked"
    );
    // Exposure: the EXR's colour is the same, the PNG is sRGB of twice it.
    let (png1, c1) = &runs[1];
    for name in ["R", "G", "B"] {
        assert_eq!(
            f32s(c, name),
            f32s(c1, name),
            "{name} depends on --exposure"
        );
    }
    let srgb = |c: f32| -> u8 {
        let c = f64::from(c).clamp(0.0, 1.0);
        let s = if c <= 0.0031308 {
            12.92 * c
        } else {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0 + 0.5) as u8
    };
    let (r, g, b) = (f32s(c, "R"), f32s(c, "G"), f32s(c, "B"));
    for (i, p) in png1.pixels().enumerate() {
        let want = [srgb(2.0 * r[i]), srgb(2.0 * g[i]), srgb(2.0 * b[i])];
        assert_eq!(p.0, want, "pixel {i} of the PNG at exposure 1");
    }
}
