//! `dcrt bench view`: the live view as its user meets it. `dcrt view` runs as a child process
//! (replicated, or as one rank of virtual ranks through a cache) and this process drives it over
//! the WebSocket as the page does: at rest, the camera stepped a few degrees at a time, the
//! latency from each change to the first full frame of it delivered here, beside the time the
//! view's tracer took for that frame; dragging, interactive cameras 60 times a second and the
//! frames a second that come back; the encoder's share of each. With `--minutes`, a long session
//! of steady dragging instead, and the child's resident memory over it.

use super::{ReportArgs, Table, emit};
use anyhow::{Context, Result, bail};
use clap::Args;
use dcrt::view::camera::CameraJson;
use serde::Serialize;
use serde_json::{Value, json};
use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The longest wait for a frame before the bench gives up.
const WAIT: Duration = Duration::from_secs(300);

#[derive(Args)]
pub struct ViewArgs {
    /// Scene file or block file (.dcb); without it a generated scene (--generator,
    /// --triangles).
    scene: Option<PathBuf>,
    #[arg(long, default_value = "rm")]
    generator: String,
    #[arg(long, default_value_t = 1_000_000)]
    triangles: u64,
    /// Frame sizes, comma separated (WIDTHxHEIGHT).
    #[arg(long, value_delimiter = ',', default_value = "512x512,1920x1080")]
    sizes: Vec<String>,
    /// Caches, comma separated: `none` (replicated) or a size as `dcrt view --cache` takes it,
    /// as rank 0 of --virtual-ranks.
    #[arg(long, value_delimiter = ',', default_value = "none,1/8")]
    caches: Vec<String>,
    #[arg(long, default_value_t = 8)]
    virtual_ranks: u32,
    /// Camera changes at rest, each --degrees about the focal point from the last.
    #[arg(long, default_value_t = 20)]
    steps: u32,
    #[arg(long, default_value_t = 3.0)]
    degrees: f64,
    /// Seconds of dragging (interactive cameras at 60 a second, 1 degree each).
    #[arg(long, default_value_t = 10.0)]
    drag_seconds: f64,
    /// A session of steady dragging this long instead (the first size and cache only): the
    /// view's resident memory every 10 s.
    #[arg(long)]
    minutes: Option<f64>,
    #[command(flatten)]
    report: ReportArgs,
}

/// The figures of one size and cache.
#[derive(Serialize)]
struct Run {
    size: String,
    cache: String,
    /// At rest: latency from a camera change to its first full frame here, ms.
    latency_median_ms: f64,
    latency_p95_ms: f64,
    /// The view's own time for those frames (the frame loop's, as `dcrt bench` times a frame).
    frame_median_ms: f64,
    /// The target: 1.5 times the frame plus 30 ms.
    target_ms: f64,
    encode_median_ms: f64,
    jpeg_kib: f64,
    fault_rounds: f64,
    fetched_mib: f64,
    /// Dragging: frames a second delivered, their median size, the latency of each from the
    /// camera it shows, and the encoder's share of the frame interval.
    drag_fps: f64,
    drag_pixels: f64,
    drag_latency_median_ms: f64,
    drag_encode_share: f64,
    /// The view's resident memory after the run, MiB.
    rss_mib: f64,
}

#[derive(Serialize)]
struct Soak {
    size: String,
    cache: String,
    minutes: f64,
    frames: u64,
    /// (seconds, resident MiB) every 10 s.
    rss: Vec<(f64, f64)>,
}

pub fn bench(a: &ViewArgs) -> Result<()> {
    let sizes: Vec<(u32, u32)> = a
        .sizes
        .iter()
        .map(|s| parse_size(s))
        .collect::<Result<_>>()?;
    if sizes.is_empty() || a.caches.is_empty() {
        bail!("--sizes and --caches need at least one value each");
    }
    if a.steps == 0 || a.drag_seconds.is_nan() || a.drag_seconds <= 0.0 || !a.degrees.is_finite() {
        bail!("--steps, --drag-seconds and --degrees must be positive");
    }
    let dir = std::env::temp_dir().join(format!("dcrt-bench-view-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
    let scene = match &a.scene {
        Some(s) => s.clone(),
        None => {
            let p = dir.join("scene.toml");
            std::fs::write(
                &p,
                format!(
                    "[image]\nwidth = 512\nheight = 512\n[[mesh]]\ngenerator = \"{}\"\ntriangles = {}\n",
                    a.generator, a.triangles
                ),
            )?;
            p
        }
    };
    let result = if let Some(minutes) = a.minutes {
        soak(a, &scene, sizes[0], &a.caches[0], minutes).and_then(|s| {
            emit(a.report.json, &s, |s| {
                println!(
                    "view soak, {} cache {}: {} frames in {:.1} min",
                    s.size, s.cache, s.frames, s.minutes
                );
                for (t, m) in &s.rss {
                    println!("  {t:7.0} s  {m:8.1} MiB");
                }
            })
        })
    } else {
        let mut runs = Vec::new();
        for cache in &a.caches {
            for &size in &sizes {
                runs.push(one(a, &scene, size, cache)?);
            }
        }
        emit(a.report.json, &runs, print)
    };
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once('x')
        .with_context(|| format!("--sizes: {s:?} is not WIDTHxHEIGHT"))?;
    Ok((
        w.trim()
            .parse()
            .with_context(|| format!("--sizes: {s:?}"))?,
        h.trim()
            .parse()
            .with_context(|| format!("--sizes: {s:?}"))?,
    ))
}

fn print(runs: &Vec<Run>) {
    let t = Table(&[
        ("size", -10),
        ("cache", -6),
        ("latency", 8),
        ("p95", 8),
        ("frame", 8),
        ("target", 8),
        ("encode", 7),
        ("KiB", 6),
        ("rounds", 6),
        ("MiB", 6),
        ("drag fps", 8),
        ("drag px", 8),
        ("drag lat", 8),
        ("enc share", 9),
        ("RSS MiB", 8),
    ]);
    t.header();
    for r in runs {
        t.row(&[
            r.size.clone(),
            r.cache.clone(),
            format!("{:.1}", r.latency_median_ms),
            format!("{:.1}", r.latency_p95_ms),
            format!("{:.1}", r.frame_median_ms),
            format!("{:.1}", r.target_ms),
            format!("{:.1}", r.encode_median_ms),
            format!("{:.0}", r.jpeg_kib),
            format!("{:.1}", r.fault_rounds),
            format!("{:.2}", r.fetched_mib),
            format!("{:.1}", r.drag_fps),
            format!("{:.0}", r.drag_pixels),
            format!("{:.1}", r.drag_latency_median_ms),
            format!("{:.3}", r.drag_encode_share),
            format!("{:.0}", r.rss_mib),
        ]);
    }
    println!(
        "latency, p95, frame, target, encode in ms (median); target = 1.5 x frame + 30; rounds \
         and MiB: fault rounds and MiB fetched a frame at rest; drag: frames a second while \
         dragging, their median pixels and latency, encode time over the frame interval"
    );
}

/// A running `dcrt view`, ended on drop.
struct Running {
    child: Child,
    ws: Socket,
}

type Socket = tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>;

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts the view of `scene` at `size` with `cache` and connects to it.
fn start(a: &ViewArgs, scene: &Path, (w, h): (u32, u32), cache: &str) -> Result<Running> {
    let exe = std::env::current_exe()?;
    let mut cmd = Command::new(exe);
    cmd.arg("view").arg(scene).args([
        "--port",
        "0",
        "--width",
        &w.to_string(),
        "--height",
        &h.to_string(),
    ]);
    if cache != "none" {
        cmd.args([
            "--virtual-ranks",
            &a.virtual_ranks.to_string(),
            "--cache",
            cache,
        ]);
    }
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("starting dcrt view")?;
    let err = child.stderr.take().context("the view's stderr")?;
    let mut lines = BufReader::new(err).lines();
    let mut said = Vec::new();
    let port = loop {
        let Some(line) = lines.next() else {
            let _ = child.wait();
            bail!(
                "dcrt view {} ended before it listened, saying:\n{}",
                scene.display(),
                said.join("\n")
            );
        };
        let line = line?;
        said.push(line.clone());
        if let Some(rest) = line.strip_prefix("view: listening on ") {
            break rest
                .rsplit(':')
                .next()
                .and_then(|p| p.parse::<u16>().ok())
                .context("the view's port")?;
        }
    };
    // The rest of its stderr, drained so that it never blocks.
    std::thread::spawn(move || for _ in lines {});
    let (mut ws, _) = tungstenite::connect(format!("ws://127.0.0.1:{port}/ws"))
        .context("the view's WebSocket")?;
    if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_mut() {
        s.set_read_timeout(Some(WAIT))?;
    }
    Ok(Running { child, ws })
}

/// The next frame on the socket: its description (the JPEG is dropped), when it arrived.
fn next_frame(ws: &mut Socket) -> Result<(Value, Instant)> {
    let mut info = None;
    loop {
        match ws.read()? {
            tungstenite::Message::Text(t) => {
                let v: Value = serde_json::from_str(&t)?;
                if let Some(e) = v.get("error") {
                    bail!("the view refused a message: {e}");
                }
                info = Some(v);
            }
            tungstenite::Message::Binary(_) => {
                if let Some(i) = info.take() {
                    return Ok((i, Instant::now()));
                }
            }
            _ => {}
        }
    }
}

fn send_camera(ws: &mut Socket, c: &dcrt::scene::Camera, interactive: bool) -> Result<()> {
    let m = json!({ "camera": CameraJson::of(c), "interactive": interactive });
    ws.send(tungstenite::Message::text(m.to_string()))?;
    Ok(())
}

fn median(v: &mut [f64]) -> f64 {
    percentile(v, 0.5)
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn num(v: &Value, k: &str) -> f64 {
    v[k].as_f64().unwrap_or(f64::NAN)
}

fn rss_mib(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.split_whitespace().next()?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

/// The first finished frame after the start, and the home camera it shows; the last seq.
fn settle(ws: &mut Socket) -> Result<(dcrt::scene::Camera, u64)> {
    loop {
        let (info, _) = next_frame(ws)?;
        if info["full"] == true && info["samples"] == info["spp"] {
            let c: CameraJson = serde_json::from_value(info["camera"].clone())?;
            return Ok((c.camera()?, info["seq"].as_u64().unwrap_or(0)));
        }
    }
}

fn one(a: &ViewArgs, scene: &Path, size: (u32, u32), cache: &str) -> Result<Run> {
    dcrt::report!("bench view: {}x{} cache {cache}", size.0, size.1);
    let mut v = start(a, scene, size, cache)?;
    let (home, mut seq) = settle(&mut v.ws)?;
    // At rest: a camera a step further each time, and its first full frame.
    let (mut lat, mut frame, mut enc, mut kib, mut rounds, mut mib) =
        (vec![], vec![], vec![], vec![], vec![], vec![]);
    for i in 1..=a.steps {
        let c = home.orbit((a.degrees * f64::from(i)).to_radians());
        let sent = Instant::now();
        send_camera(&mut v.ws, &c, false)?;
        seq += 1;
        loop {
            let (info, at) = next_frame(&mut v.ws)?;
            if info["seq"].as_u64() >= Some(seq) && info["full"] == true {
                lat.push((at - sent).as_secs_f64() * 1e3);
                frame.push(num(&info, "frame_ms"));
                enc.push(num(&info, "encode_ms"));
                kib.push(num(&info, "jpeg_bytes") / 1024.0);
                rounds.push(num(&info, "fault_rounds"));
                mib.push(num(&info, "fetched_mib"));
                break;
            }
        }
    }
    // Dragging: interactive cameras at 60 a second, a degree each, for the drag's seconds.
    let drag = drag(
        &mut v.ws,
        &home,
        &mut seq,
        Duration::from_secs_f64(a.drag_seconds),
    )?;
    let frame_median = median(&mut frame);
    Ok(Run {
        size: format!("{}x{}", size.0, size.1),
        cache: cache.to_string(),
        latency_median_ms: median(&mut lat),
        latency_p95_ms: percentile(&mut lat, 0.95),
        frame_median_ms: frame_median,
        target_ms: 1.5 * frame_median + 30.0,
        encode_median_ms: median(&mut enc),
        jpeg_kib: median(&mut kib),
        fault_rounds: mean(&rounds),
        fetched_mib: mean(&mib),
        drag_fps: drag.fps,
        drag_pixels: drag.pixels,
        drag_latency_median_ms: drag.latency,
        drag_encode_share: drag.encode_share,
        rss_mib: rss_mib(v.child.id()),
    })
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

struct Drag {
    fps: f64,
    pixels: f64,
    latency: f64,
    encode_share: f64,
    frames: u64,
}

/// Interactive cameras every 1/60 s for `length`, turning a degree each; the frames that come.
fn drag(
    ws: &mut Socket,
    home: &dcrt::scene::Camera,
    seq: &mut u64,
    length: Duration,
) -> Result<Drag> {
    if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_mut() {
        s.set_read_timeout(Some(Duration::from_millis(2)))?;
    }
    let start = Instant::now();
    let period = Duration::from_secs_f64(1.0 / 60.0);
    let mut sent_at: std::collections::BTreeMap<u64, Instant> = Default::default();
    let (mut n, mut next_send) = (0u64, start);
    let (mut pixels, mut lat, mut enc) = (vec![], vec![], vec![]);
    let mut info: Option<Value> = None;
    let first_seq = *seq + 1;
    let mut frames = 0u64;
    while start.elapsed() < length {
        if Instant::now() >= next_send {
            n += 1;
            let c = home.orbit(((n % 360) as f64).to_radians());
            send_camera(ws, &c, true)?;
            *seq += 1;
            sent_at.insert(*seq, Instant::now());
            next_send += period;
        }
        match ws.read() {
            Ok(tungstenite::Message::Text(t)) => info = Some(serde_json::from_str(&t)?),
            Ok(tungstenite::Message::Binary(_)) => {
                if let Some(i) = info.take()
                    && i["seq"].as_u64().is_some_and(|s| s >= first_seq)
                {
                    frames += 1;
                    pixels.push(num(&i, "width") * num(&i, "height"));
                    enc.push(num(&i, "encode_ms"));
                    if let Some(t) = i["seq"].as_u64().and_then(|s| sent_at.get(&s)) {
                        lat.push(t.elapsed().as_secs_f64() * 1e3);
                    }
                }
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e.into()),
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_mut() {
        s.set_read_timeout(Some(WAIT))?;
    }
    let fps = frames as f64 / seconds;
    let encode = mean(&enc);
    Ok(Drag {
        fps,
        pixels: median(&mut pixels),
        latency: median(&mut lat),
        encode_share: if fps > 0.0 {
            encode / (1e3 / fps)
        } else {
            f64::NAN
        },
        frames,
    })
}

fn soak(a: &ViewArgs, scene: &Path, size: (u32, u32), cache: &str, minutes: f64) -> Result<Soak> {
    let mut v = start(a, scene, size, cache)?;
    let (home, mut seq) = settle(&mut v.ws)?;
    let pid = v.child.id();
    let start = Instant::now();
    let mut rss = vec![(0.0, rss_mib(pid))];
    let mut frames = 0;
    while start.elapsed().as_secs_f64() < minutes * 60.0 {
        let d = drag(&mut v.ws, &home, &mut seq, Duration::from_secs(10))?;
        frames += d.frames;
        rss.push((start.elapsed().as_secs_f64(), rss_mib(pid)));
        dcrt::report!(
            "bench view: {:.0} s, {frames} frames, {:.1} MiB",
            start.elapsed().as_secs_f64(),
            rss.last().map_or(0.0, |r| r.1)
        );
    }
    Ok(Soak {
        size: format!("{}x{}", size.0, size.1),
        cache: cache.to_string(),
        minutes,
        frames,
        rss,
    })
}
