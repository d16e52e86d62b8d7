//! `dcrt view` (docs/ARCHITECTURE.md, Live view) through its protocol, without a browser: the
//! camera's round trip, the still frame equal to `dcrt render`'s to the pixel, refinement up to
//! the requested samples, malformed requests refused without harm, the token off loopback, a
//! signal ending it, all of it under mpirun with a distributed cache too; and the page in a
//! headless Chromium (tests/view_browser.py), from one process and from mpirun's display rank.

use crate::common::{TempDir, dcrt};
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// How long a test waits for the view to listen, or for an answer: bounds, not expectations.
const START: Duration = Duration::from_secs(120);
const ANSWER: Duration = Duration::from_secs(90);

const SCENE: &str =
    "[image]\nwidth = 64\nheight = 48\n[[mesh]]\ngenerator = \"rm\"\ntriangles = 8000\n";

/// A running `dcrt view`, killed on drop.
struct View {
    child: Child,
    port: u16,
    url: String,
    /// The lines of stderr after the URL.
    stderr: mpsc::Receiver<String>,
}

impl View {
    fn start(scene: &Path, args: &[&str]) -> View {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_dcrt"));
        cmd.arg("view").arg(scene).args(["--port", "0"]).args(args);
        View::spawn(cmd)
    }

    /// `mpirun -n k dcrt view ...` under `timeout` (which passes a SIGTERM on to mpirun, and
    /// mpirun to every rank).
    fn mpirun(k: u32, scene: &Path, args: &[&str]) -> View {
        let mut cmd = Command::new("timeout");
        cmd.args([
            "-k",
            "5",
            "600",
            "mpirun",
            "--oversubscribe",
            "-n",
            &k.to_string(),
        ])
        .arg(env!("CARGO_BIN_EXE_dcrt"))
        .arg("view")
        .arg(scene)
        .args(["--port", "0", "--timeout", "60"])
        .args(args)
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1");
        View::spawn(cmd)
    }

    fn spawn(mut cmd: Command) -> View {
        let mut child = cmd
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, rx) = mpsc::channel();
        let err = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let (mut port, mut seen) = (None, Vec::new());
        loop {
            let line = match rx.recv_timeout(START) {
                Ok(l) => l,
                Err(_) => {
                    let _ = child.kill();
                    let _ = child.wait();
                    panic!("dcrt view printed no URL: {seen:#?}");
                }
            };
            if let Some(rest) = line.strip_prefix("view: listening on ") {
                port = rest.rsplit(':').next().and_then(|p| p.parse().ok());
            }
            if let Some(rest) = line.strip_prefix("view: open ") {
                let url = rest.split_whitespace().next().unwrap().to_string();
                return View {
                    child,
                    port: port.expect("the port before the URL"),
                    url,
                    stderr: rx,
                };
            }
            seen.push(line);
        }
    }

    fn token(&self) -> Option<String> {
        self.url.split("token=").nth(1).map(str::to_string)
    }

    /// A request to 127.0.0.1 at the view's port: (status, body).
    fn request(&self, method: &str, path: &str, body: &[u8]) -> (u16, Vec<u8>) {
        http(self.port, method, path, body)
    }

    fn get_json(&self, path: &str) -> serde_json::Value {
        let (status, body) = self.request("GET", path, b"");
        assert_eq!(status, 200, "{path}: {}", String::from_utf8_lossy(&body));
        serde_json::from_slice(&body).unwrap()
    }

    fn post_camera(&self, camera: &serde_json::Value) -> u64 {
        let (status, body) = self.request("POST", "/camera", camera.to_string().as_bytes());
        assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
        let v: serde_json::Value = serde_json::from_slice(&body).unwrap();
        v["seq"].as_u64().unwrap()
    }

    fn frame(&self, after: u64) -> image::RgbImage {
        let (status, body) = self.request("GET", &format!("/frame.png?after={after}"), b"");
        assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
        image::load_from_memory_with_format(&body, image::ImageFormat::Png)
            .unwrap()
            .to_rgb8()
    }
}

impl Drop for View {
    /// SIGTERM first, so that `timeout` passes it on to an mpirun; then SIGKILL.
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .arg(self.child.id().to_string())
            .status();
        if wait_bounded(&mut self.child, Duration::from_secs(20)).is_none() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// One HTTP/1.1 request with `Connection: close`: (status, body).
fn http(port: u16, method: &str, path: &str, body: &[u8]) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(ANSWER)).unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    // A server may answer before it has read the body (413 on the Content-Length alone) and close:
    // the rest of the body then meets a closed socket, and the answer is still there to be read.
    let closed =
        |e: &std::io::Error| matches!(e.kind(), ErrorKind::BrokenPipe | ErrorKind::ConnectionReset);
    let early = match s.write_all(body) {
        Err(e) if closed(&e) => true,
        r => {
            r.unwrap();
            false
        }
    };
    let mut all = Vec::new();
    match s.read_to_end(&mut all) {
        Err(e) if early && closed(&e) => {}
        r => {
            r.unwrap();
        }
    }
    let end = all
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("an HTTP head");
    let head = String::from_utf8_lossy(&all[..end]).to_string();
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    let mut body = all[end + 4..].to_vec();
    if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        body = dechunk(&body);
    }
    (status, body)
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let nl = b.windows(2).position(|w| w == b"\r\n").unwrap();
        let n = usize::from_str_radix(std::str::from_utf8(&b[..nl]).unwrap().trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[nl + 2..nl + 2 + n]);
        b = &b[nl + 2 + n + 2..];
    }
}

/// A ParaView camera file of the camera JSON `c`.
fn pvcc(c: &serde_json::Value) -> String {
    let prop = |name: &str, v: &serde_json::Value| {
        let values: Vec<f64> = match v.as_array() {
            Some(a) => a.iter().map(|x| x.as_f64().unwrap()).collect(),
            None => vec![v.as_f64().unwrap()],
        };
        let elements: String = values
            .iter()
            .enumerate()
            .map(|(i, x)| format!("<Element index=\"{i}\" value=\"{x:?}\"/>"))
            .collect();
        format!(
            "<Property name=\"{name}\" id=\"1.{name}\" number_of_elements=\"{}\">{elements}</Property>\n",
            values.len()
        )
    };
    format!(
        "<?xml version=\"1.0\"?>\n<PVCameraConfiguration description=\"ParaView camera \
         configuration\" version=\"1.0\">\n<Proxy group=\"views\" type=\"RenderView\" id=\"1\" \
         servers=\"21\">\n{}{}{}{}</Proxy>\n</PVCameraConfiguration>\n",
        prop("CameraPosition", &c["position"]),
        prop("CameraFocalPoint", &c["focal_point"]),
        prop("CameraViewUp", &c["view_up"]),
        prop("CameraViewAngle", &c["view_angle"]),
    )
}

/// `dcrt render` of `scene` with the camera JSON `c` and `args`: its PNG.
fn render(d: &TempDir, scene: &Path, c: &serde_json::Value, args: &[&str]) -> image::RgbImage {
    let cam = d.write("camera.pvcc", pvcc(c));
    let out = d.path("render.png");
    let mut all: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![
        &"render",
        &scene,
        &"-o",
        &out,
        &"--camera",
        &cam,
        &"--quiet",
    ];
    for a in args {
        all.push(a);
    }
    let r = dcrt(&all);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    image::open(&out).unwrap().to_rgb8()
}

fn scene(d: &TempDir) -> PathBuf {
    d.write("scene.toml", SCENE)
}

/// A camera other than the scene's: turned and moved.
fn moved(c: &serde_json::Value) -> serde_json::Value {
    let mut m = c.clone();
    m["position"] = serde_json::json!([0.7, -2.1, 1.3]);
    m["focal_point"] = serde_json::json!([0.05, 0.02, -0.03]);
    m["view_angle"] = serde_json::json!(33.5);
    m
}

fn assert_same(a: &image::RgbImage, b: &image::RgbImage, what: &str) {
    assert_eq!(a.dimensions(), b.dimensions(), "{what}: sizes");
    let differ = a.pixels().zip(b.pixels()).filter(|(x, y)| x != y).count();
    assert_eq!(
        differ, 0,
        "{what}: {differ} pixels differ from dcrt render's"
    );
}

/// The camera posted is the camera read back, to the bit, and its still frame is, pixel for
/// pixel, the image `dcrt render` writes for that camera.
#[test]
fn camera_round_trip_and_still_frame_equal_render() {
    let d = TempDir::new("view-cast");
    let scene = scene(&d);
    let v = View::start(&scene, &[]);
    let first = v.get_json("/camera");
    for key in [
        "position",
        "focal_point",
        "view_up",
        "view_angle",
        "parallel_projection",
    ] {
        assert!(first.get(key).is_some(), "GET /camera lacks {key}: {first}");
    }
    let c = moved(&first);
    let seq = v.post_camera(&c);
    assert!(seq >= 1);
    let back = v.get_json("/camera");
    for key in ["position", "focal_point", "view_up", "view_angle"] {
        assert_eq!(back[key], c[key], "{key}");
    }
    let frame = v.frame(seq);
    assert_same(&frame, &render(&d, &scene, &c, &[]), "cast");
    // A frame of the first camera differs: the test sees the camera.
    assert_ne!(frame, render(&d, &scene, &first, &[]));
    let stats = v.get_json("/stats");
    assert!(stats["frames"].as_u64().unwrap() >= 1, "{stats}");
    assert_eq!(stats["seq"].as_u64(), Some(seq), "{stats}");
}

/// In `ao` the still frame refines, sample pass by sample pass, to the requested spp; the
/// finished frame is `dcrt render --mode ao --spp 3`'s to the pixel.
#[test]
fn ao_refines_to_the_requested_spp_and_equals_render() {
    let d = TempDir::new("view-ao");
    let scene = scene(&d);
    let shade = ["--mode", "ao", "--spp", "3", "--ao-rays", "6"];
    let v = View::start(&scene, &shade);
    let c = moved(&v.get_json("/camera"));
    let seq = v.post_camera(&c);
    let frame = v.frame(seq);
    let stats = v.get_json("/stats");
    assert_eq!(stats["seq"].as_u64(), Some(seq), "{stats}");
    assert_eq!(stats["spp_reached"].as_u64(), Some(3), "{stats}");
    assert_eq!(stats["last"]["samples"].as_u64(), Some(3), "{stats}");
    assert_same(&frame, &render(&d, &scene, &c, &shade), "ao 3 spp");
    // The settings change the frame: 1 spp of the same camera is another image.
    let (status, body) = v.request("POST", "/settings", br#"{"spp": 1}"#);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    let seq: u64 = serde_json::from_slice::<serde_json::Value>(&body).unwrap()["seq"]
        .as_u64()
        .unwrap();
    let one = v.frame(seq);
    let shade1 = ["--mode", "ao", "--spp", "1", "--ao-rays", "6"];
    assert_same(&one, &render(&d, &scene, &c, &shade1), "ao 1 spp");
    assert_ne!(one, frame);
}

/// Malformed or wrong messages get 400 (too large: 413) with what is wrong, and the session goes
/// on: the next good camera still gets its frame.
#[test]
fn malformed_requests_are_refused_and_the_session_goes_on() {
    let d = TempDir::new("view-bad");
    let scene = scene(&d);
    let v = View::start(&scene, &[]);
    let c = moved(&v.get_json("/camera"));
    let (status, body) = v.request("POST", "/camera", b"{\"position\": [1, 2");
    assert_eq!(status, 400);
    assert!(String::from_utf8_lossy(&body).contains("camera"));
    let mut same = c.clone();
    same["focal_point"] = same["position"].clone();
    let (status, body) = v.request("POST", "/camera", same.to_string().as_bytes());
    assert_eq!(status, 400);
    assert!(
        String::from_utf8_lossy(&body).contains("same point"),
        "{}",
        String::from_utf8_lossy(&body)
    );
    let mut extra = c.clone();
    extra["zoom"] = serde_json::json!(2);
    assert_eq!(
        v.request("POST", "/camera", extra.to_string().as_bytes()).0,
        400
    );
    let huge = vec![b' '; 1 << 20];
    assert_eq!(v.request("POST", "/camera", &huge).0, 413);
    let (status, body) = v.request("POST", "/settings", br#"{"spp": 0}"#);
    assert_eq!(status, 400);
    assert!(String::from_utf8_lossy(&body).contains("spp"));
    assert_eq!(v.request("POST", "/settings", br#"{"mode": "x"}"#).0, 400);
    assert_eq!(v.request("GET", "/frame.png?after=x", b"").0, 400);
    // The camera is unchanged by the refusals, and the session still works.
    let seq = v.post_camera(&c);
    assert_eq!(v.get_json("/camera")["position"], c["position"]);
    assert_same(
        &v.frame(seq),
        &render(&d, &scene, &c, &[]),
        "after refusals",
    );
}

/// Bound off loopback the view needs its token: the URL carries it, a request without it (or
/// with a wrong one) gets 403, with it 200.
#[test]
fn off_loopback_every_request_needs_the_token() {
    let d = TempDir::new("view-token");
    let scene = scene(&d);
    let v = View::start(&scene, &["--bind", "0.0.0.0"]);
    let token = v.token().expect("a token in the URL");
    assert!(token.len() >= 32, "{token}");
    for path in ["/", "/camera", "/stats", "/frame.png"] {
        assert_eq!(v.request("GET", path, b"").0, 403, "{path}");
        assert_eq!(
            v.request("GET", &format!("{path}?token=wrong"), b"").0,
            403,
            "{path}"
        );
    }
    assert_eq!(v.request("POST", "/camera", b"{}").0, 403);
    assert_eq!(
        v.request("GET", &format!("/camera?token={token}"), b"").0,
        200
    );
    let (status, page) = v.request("GET", &format!("/?token={token}"), b"");
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&page).contains("<title>dcrt view</title>"));
    // On loopback there is no token.
    let local = View::start(&scene, &[]);
    assert_eq!(local.token(), None, "{}", local.url);
    assert_eq!(local.request("GET", "/camera", b"").0, 200);
}

/// SIGTERM and SIGINT end the view, with 128 + the signal's number, while it serves.
#[test]
fn signals_end_the_view() {
    let d = TempDir::new("view-signal");
    let scene = scene(&d);
    for (signal, code) in [("TERM", 143), ("INT", 130)] {
        let mut v = View::start(&scene, &[]);
        v.get_json("/camera");
        let ok = Command::new("kill")
            .arg(format!("-{signal}"))
            .arg(v.child.id().to_string())
            .status()
            .unwrap();
        assert!(ok.success());
        let status = wait_bounded(&mut v.child, ANSWER).expect("the view ended on the signal");
        assert_eq!(status.code(), Some(code), "SIG{signal}");
        let said: Vec<String> = v.stderr.try_iter().collect();
        assert!(
            said.iter().any(|l| l.contains(&format!("SIG{signal}"))),
            "{said:?}"
        );
    }
}

fn wait_bounded(child: &mut Child, limit: Duration) -> Option<std::process::ExitStatus> {
    let start = std::time::Instant::now();
    while start.elapsed() < limit {
        if let Some(s) = child.try_wait().unwrap() {
            return Some(s);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    None
}

/// The page in a headless Chromium (tests/view_browser.py, selenium in the venv
/// scripts/setup.sh makes): it loads, shows a frame, a left drag turns the camera (GET /camera
/// sees it) and a frame of the new camera arrives. Skipped, saying so, only where the browser is
/// not installed; with it but without the venv it fails.
#[test]
fn the_page_shows_frames_and_turns_the_camera_under_the_mouse() {
    let d = TempDir::new("view-browser");
    let scene = scene(&d);
    in_browser(Browser::Chromium, || View::start(&scene, &[]));
}

/// The same page served by the display rank of `mpirun -n 4` with a distributed cache.
#[test]
fn the_page_under_mpirun_shows_frames_and_turns_the_camera() {
    let d = TempDir::new("view-browser-mpirun");
    let scene = scene(&d);
    in_browser(Browser::Chromium, || {
        View::mpirun(4, &scene, &["--cache", "1/2"])
    });
}

/// The same page in a headless Firefox (Debian's firefox-esr, geckodriver from crates.io).
#[test]
fn the_page_in_firefox_shows_frames_and_turns_the_camera() {
    let d = TempDir::new("view-browser-firefox");
    let scene = scene(&d);
    in_browser(Browser::Firefox, || View::start(&scene, &[]));
}

#[derive(Clone, Copy)]
enum Browser {
    Chromium,
    Firefox,
}

/// Runs tests/view_browser.py in `browser` against the view `start` starts, where the browser
/// is installed.
fn in_browser(browser: Browser, start: impl FnOnce() -> View) {
    let which = |name: &str| {
        std::env::var_os("PATH").and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|d| d.join(name))
                .find(|p| p.is_file())
        })
    };
    let (kind, exe, driver, packages) = match browser {
        Browser::Chromium => (
            "chromium",
            "chromium",
            "chromedriver",
            "Debian's chromium and chromium-driver",
        ),
        Browser::Firefox => (
            "firefox",
            "firefox-esr",
            "geckodriver",
            "Debian's firefox-esr and geckodriver with cargo install",
        ),
    };
    let (Some(exe), Some(driver)) = (which(exe), which(driver)) else {
        eprintln!(
            "SKIPPED: {kind} or its driver is not installed (scripts/setup.sh installs {packages})"
        );
        return;
    };
    let python = crate::common::repo().join(".view-venv/bin/python");
    assert!(
        python.is_file(),
        "{} is missing: run scripts/setup.sh (it makes the venv with selenium)",
        python.display()
    );
    let v = start();
    let mut child = Command::new(&python)
        .arg(crate::common::repo().join("tests/view_browser.py"))
        .arg(&v.url)
        .arg(kind)
        .arg(&driver)
        .arg(&exe)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = wait_bounded(&mut child, Duration::from_secs(240));
    if status.is_none() {
        let _ = child.kill();
    }
    let out = child.wait_with_output().unwrap();
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(status.is_some(), "the browser test did not end: {said}");
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains(&format!("view_browser: ok: {kind}")),
        "{said}"
    );
}

type Socket = tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>;

fn socket(port: u16) -> Socket {
    let (mut ws, _) = tungstenite::connect(format!("ws://127.0.0.1:{port}/ws")).unwrap();
    if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_mut() {
        s.set_read_timeout(Some(ANSWER)).unwrap();
    }
    ws
}

/// The next message on `ws` that is a frame (its description and JPEG) or an error.
enum Got {
    Frame(serde_json::Value, Vec<u8>),
    Error(String),
}

fn next(ws: &mut Socket) -> Got {
    let mut info = None;
    loop {
        match ws.read().expect("a message within the bound") {
            tungstenite::Message::Text(t) => {
                let v: serde_json::Value = serde_json::from_str(&t).unwrap();
                if let Some(e) = v.get("error") {
                    return Got::Error(e.as_str().unwrap().to_string());
                }
                info = Some(v);
            }
            tungstenite::Message::Binary(b) => {
                let info = info.take().expect("a frame's description before its JPEG");
                return Got::Frame(info, b.to_vec());
            }
            _ => {}
        }
    }
}

/// Frames on `ws` until one of wish `seq` with every sample: its description and JPEG.
fn finished_frame(ws: &mut Socket, seq: u64) -> (serde_json::Value, Vec<u8>) {
    loop {
        if let Got::Frame(info, jpeg) = next(ws)
            && info["seq"].as_u64() == Some(seq)
            && info["full"] == true
            && info["samples"] == info["spp"]
        {
            return (info, jpeg);
        }
    }
}

/// Several pages at once: each gets the frames; one steers over its WebSocket and the others see
/// its camera's frames; a malformed message is answered with an error and the socket goes on; a
/// page that leaves harms nobody.
#[test]
fn websocket_clients_steer_and_watch() {
    let d = TempDir::new("view-ws");
    let scene = scene(&d);
    let v = View::start(&scene, &[]);
    let (mut steer, mut watch) = (socket(v.port), socket(v.port));
    let (info, jpeg) = finished_frame(&mut watch, 0);
    assert_eq!(
        (info["width"].as_u64(), info["height"].as_u64()),
        (Some(64), Some(48))
    );
    let img = image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg).unwrap();
    assert_eq!((img.width(), img.height()), (64, 48));
    // The JPEG is the still frame, within JPEG's loss.
    let png = v.frame(0);
    let diff: f64 = img
        .to_rgb8()
        .as_raw()
        .iter()
        .zip(png.as_raw())
        .map(|(a, b)| f64::from(a.abs_diff(*b)))
        .sum::<f64>()
        / png.as_raw().len() as f64;
    assert!(
        diff < 6.0,
        "the JPEG differs from the frame by {diff} a channel"
    );
    steer
        .send(tungstenite::Message::text("{\"camera\": [1, 2"))
        .unwrap();
    loop {
        if let Got::Error(e) = next(&mut steer) {
            assert!(e.contains("not a view message"), "{e}");
            break;
        }
    }
    let c = moved(&v.get_json("/camera"));
    let m = serde_json::json!({ "camera": c, "interactive": false });
    steer
        .send(tungstenite::Message::text(m.to_string()))
        .unwrap();
    let (seen, _) = finished_frame(&mut watch, 1);
    assert_eq!(seen["camera"]["position"], c["position"]);
    finished_frame(&mut steer, 1);
    assert_eq!(v.get_json("/camera")["position"], c["position"]);
    // The watcher leaves; the steering page and the API go on.
    drop(watch);
    let set = serde_json::json!({ "settings": { "mode": "shadows" } });
    steer
        .send(tungstenite::Message::text(set.to_string()))
        .unwrap();
    let (info, _) = finished_frame(&mut steer, 2);
    assert_eq!(info["mode"], "shadows");
    assert_same(
        &v.frame(2),
        &render(&d, &scene, &c, &["--mode", "shadows"]),
        "shadows after a settings message",
    );
}

/// Through a distributed cache of virtual ranks the still frame is still `dcrt render`'s with the
/// same cache options, and the statistics count the cache's work.
#[test]
fn distributed_cache_still_frame_equals_render() {
    let d = TempDir::new("view-dc");
    let scene = scene(&d);
    let dc = ["--virtual-ranks", "3", "--rank", "1", "--cache", "4lines"];
    let v = View::start(&scene, &dc);
    let c = moved(&v.get_json("/camera"));
    let seq = v.post_camera(&c);
    assert_same(
        &v.frame(seq),
        &render(&d, &scene, &c, &dc),
        "3 virtual ranks",
    );
    let stats = v.get_json("/stats");
    assert!(stats["fault_rounds"].as_u64().unwrap() > 0, "{stats}");
    assert!(stats["fetched_mib"].as_f64().unwrap() > 0.0, "{stats}");
    let rate = stats["hit_rate"].as_f64().unwrap();
    assert!(rate > 0.0 && rate < 1.0, "{stats}");
}

/// Under mpirun (4 ranks: display, balancer, 2 render ranks with a distributed cache of 1/2):
/// the still frame of a posted camera, refined over 3 sample passes, is `dcrt render`'s in one
/// process; the statistics name both render ranks, whose parts cover the frame, and count the
/// cache's fetches; a frame while moving comes at reduced size; SIGTERM to mpirun ends every
/// rank.
#[test]
fn under_mpirun_the_display_rank_serves_frames_equal_to_render() {
    let d = TempDir::new("view-mpirun");
    let scene = scene(&d);
    let mut v = View::mpirun(4, &scene, &["--cache", "1/2", "--mode", "ao", "--spp", "3"]);
    let first = v.get_json("/camera");
    let c = moved(&first);
    let seq = v.post_camera(&c);
    let frame = v.frame(seq);
    assert_same(
        &frame,
        &render(&d, &scene, &c, &["--mode", "ao", "--spp", "3"]),
        "mpirun, ao, 3 passes",
    );
    let stats = v.get_json("/stats");
    assert_eq!(stats["spp_reached"].as_u64(), Some(3), "{stats}");
    assert_eq!(stats["render_ranks"].as_u64(), Some(2), "{stats}");
    let ranks = stats["last"]["ranks"].as_array().unwrap();
    let ids: Vec<u64> = ranks.iter().map(|r| r["rank"].as_u64().unwrap()).collect();
    assert_eq!(ids, [2, 3], "{stats}");
    let pixels: u64 = ranks.iter().map(|r| r["pixels"].as_u64().unwrap()).sum();
    assert_eq!(pixels, 64 * 48, "{stats}");
    assert!(stats["fetched_mib"].as_f64().unwrap() > 0.0, "{stats}");
    // A moving camera over the WebSocket: a reduced frame of it.
    let mut ws = socket(v.port);
    let turned = serde_json::json!({"camera": moved(&c), "interactive": true});
    ws.send(tungstenite::Message::text(turned.to_string()))
        .unwrap();
    let moving = loop {
        if let Got::Frame(i, _) = next(&mut ws)
            && i["seq"].as_u64().unwrap() > seq
        {
            break i;
        }
    };
    assert_eq!(moving["full"], false, "{moving}");
    assert!(moving["width"].as_u64().unwrap() <= 64, "{moving}");
    drop(ws);
    // SIGTERM to mpirun (through timeout): every rank ends.
    let ok = Command::new("kill")
        .arg(v.child.id().to_string())
        .status()
        .unwrap();
    assert!(ok.success());
    let status = wait_bounded(&mut v.child, ANSWER);
    assert!(status.is_some(), "mpirun did not end on SIGTERM");
}

/// Under mpirun a render rank that dies or stops while the view makes its first frame ends the
/// whole job, as in a render: killed, mpirun ends it; stopped (SIGSTOP), the display names it
/// after `--timeout` s of silence.
#[test]
fn under_mpirun_a_dying_or_stopped_render_rank_ends_the_view() {
    let d = TempDir::new("view-mpirun-fail");
    let scene = scene(&d);
    for (how, named) in [("kill@3", "rank 3"), ("stop@3", "rank 3 (render)")] {
        let start = std::time::Instant::now();
        let out = Command::new("timeout")
            .args(["-k", "5", "120", "mpirun", "--oversubscribe", "-n", "4"])
            .arg(env!("CARGO_BIN_EXE_dcrt"))
            .arg("view")
            .arg(&scene)
            .args(["--port", "0", "--cache", "1/2", "--timeout", "5"])
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .env("DCRT_TEST_FAIL", how)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let code = out.status.code();
        // `timeout` would stop it at 120 s; mpirun's own exit for a killed rank is 137 too.
        assert!(
            code != Some(0) && start.elapsed().as_secs() < 115,
            "{how}: the job did not end by itself (exit {code:?}):\n{err}"
        );
        assert!(err.contains(named), "{how}: no {named:?} in:\n{err}");
    }
}

/// `dcrt bench view` drives a view and reports what it measured: every camera change got its
/// frame (the latency includes that frame's time), frames came while dragging, the encoder ran;
/// a bad size and a missing scene are refused, naming them.
#[test]
fn bench_view_measures_a_view_and_refuses_bad_input() {
    let d = TempDir::new("view-bench");
    let scene = scene(&d);
    let out = Command::new(env!("CARGO_BIN_EXE_dcrt"))
        .args(["bench", "view"])
        .arg(&scene)
        .args([
            "--sizes",
            "32x24",
            "--caches",
            "none,4lines",
            "--virtual-ranks",
            "3",
        ])
        .args(["--steps", "3", "--drag-seconds", "1", "--json", "--quiet"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let runs: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let runs = runs.as_array().unwrap();
    assert_eq!(runs.len(), 2, "{runs:?}");
    for r in runs {
        let f = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
        assert!(f("frame_median_ms") > 0.0, "{r}");
        assert!(f("latency_median_ms") >= f("frame_median_ms"), "{r}");
        assert!(f("drag_fps") > 0.0 && f("drag_pixels") > 0.0, "{r}");
        assert!(f("encode_median_ms") > 0.0 && f("jpeg_kib") > 0.0, "{r}");
    }
    assert_eq!(runs[0]["fault_rounds"], 0.0, "replicated");
    assert!(
        runs[1]["fault_rounds"].as_f64().unwrap() > 0.0,
        "{}",
        runs[1]
    );
    let bad = dcrt(&[&"bench", &"view", &"--sizes", &"32y24"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("\"32y24\" is not WIDTHxHEIGHT"));
    let missing = d.path("missing.toml");
    let bad = dcrt(&[&"bench", &"view", &missing, &"--sizes", &"32x24"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success());
    assert!(
        err.contains("missing.toml ended before it listened") && err.contains("No such file"),
        "{err}"
    );
}
