//! `dcrt trace plot`: the SVG's text names every panel, axis, rank and phase; the axes end at the
//! traces' maxima; one rank, one frame, no faults, many ranks and many frames draw; the format
//! comes from the name or `--format`, a contradiction is refused, and a failure writes nothing.
//! The cluster run's picture is checked in `tools::cluster_plot_*` (mpirun).

use crate::common::*;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// A `<text>` element of an SVG: where it is anchored, how, and what it says.
#[derive(Clone, Debug)]
pub struct SvgText {
    pub x: f64,
    pub y: f64,
    pub anchor: String,
    pub text: String,
}

/// Every `<text>` of the SVG at `path`, in document order.
pub fn svg_texts(path: &Path) -> Vec<SvgText> {
    use quick_xml::events::Event;
    let xml = std::fs::read_to_string(path).unwrap();
    let mut r = quick_xml::Reader::from_str(&xml);
    let mut out = Vec::new();
    let mut open: Option<SvgText> = None;
    loop {
        match r.read_event().expect("the SVG parses") {
            Event::Start(e) if e.name().as_ref() == "text" => {
                let attr = |k: &str| -> String {
                    e.attributes()
                        .map(|a| a.unwrap())
                        .find(|a| a.key.as_ref() == k)
                        .map(|a| a.value.to_string())
                        .unwrap_or_default()
                };
                open = Some(SvgText {
                    x: attr("x").parse().unwrap(),
                    y: attr("y").parse().unwrap(),
                    anchor: attr("text-anchor"),
                    text: String::new(),
                });
            }
            Event::Text(t) => {
                if let Some(o) = open.as_mut() {
                    o.text.push_str(&t.xml10_content());
                }
            }
            Event::GeneralRef(g) => {
                if let Some(o) = open.as_mut() {
                    let name = g.xml10_content().to_string();
                    o.text.push_str(match name.as_str() {
                        "amp" => "&",
                        "lt" => "<",
                        "gt" => ">",
                        "quot" => "\"",
                        "apos" => "'",
                        _ => panic!("entity {name}"),
                    });
                }
            }
            Event::End(e) if e.name().as_ref() == "text" => {
                let mut t = open.take().unwrap();
                t.text = t.text.trim().to_string();
                out.push(t);
            }
            Event::Eof => break,
            _ => {}
        }
    }
    out
}

/// The panel titles of a trace plot, top to bottom (the heat map's is a prefix).
pub const TITLES: [&str; 5] = [
    "Rounds per frame",
    "Blocks fetched per frame",
    "Cache hit rate per frame",
    "Share of each phase in a rank's time (all frames)",
    "Cache-line faults per frame",
];

/// The texts of panel `i` (of `TITLES`): below its title, above the next one.
pub fn panel(texts: &[SvgText], i: usize) -> Vec<SvgText> {
    let y = |t: &str| {
        texts
            .iter()
            .find(|x| x.text.starts_with(t))
            .unwrap_or_else(|| panic!("no title {t}"))
            .y
    };
    let top = y(TITLES[i]);
    let bottom = TITLES.get(i + 1).map_or(f64::MAX, |t| y(t));
    texts
        .iter()
        .filter(|t| t.y > top && t.y < bottom)
        .cloned()
        .collect()
}

/// The numbers of a panel's labels anchored `anchor` ("end": the y axis's ticks, "middle": the
/// x axis's, "start": a colour bar's).
pub fn numbers(texts: &[SvgText], anchor: &str) -> Vec<f64> {
    texts
        .iter()
        .filter(|t| t.anchor == anchor)
        .filter_map(|t| t.text.parse().ok())
        .collect()
}

pub fn largest(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::MIN, f64::max)
}

/// `dcrt trace plot ARGS...`, which must succeed.
fn plot(args: &[&dyn AsRef<std::ffi::OsStr>]) {
    let mut all: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"trace", &"plot"];
    all.extend_from_slice(args);
    let r = dcrt(&all);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

/// A trace directory made up: `ranks` render ranks (2..) of a cluster of `ranks + 2`, `frames`
/// frames, `lines` cache lines; rank r faults on `faults(frame, r)` lines in one round each.
fn synthetic(
    d: &TempDir,
    name: &str,
    ranks: u32,
    frames: u32,
    lines: u32,
    faults: impl Fn(u32, u32) -> Vec<u32>,
) -> PathBuf {
    let dir = d.path(name);
    std::fs::create_dir_all(&dir).unwrap();
    let world = ranks + 2;
    for f in 0..frames {
        for rank in 0..world {
            let role = match rank {
                0 => "display",
                1 => "balancer",
                _ => "render",
            };
            let lines_hit = if role == "render" {
                faults(f, rank)
            } else {
                Vec::new()
            };
            let mut records: Vec<Value> = Vec::new();
            if !lines_hit.is_empty() {
                let fs: Vec<Value> = lines_hit
                    .iter()
                    .map(|&l| {
                        json!({"block": l, "owner": 2, "line": l, "evicted": null, "waiting": 1,
                               "served": true})
                    })
                    .collect();
                records.push(json!({"type": "round", "batch": 0, "round": 0, "live": 0,
                    "faults": fs, "dropped": 0, "fetched_blocks": lines_hit.len(),
                    "fetched_bytes": 8192 * lines_hit.len(), "fetch_us": 10.0,
                    "upload_us": 5.0, "source": "test"}));
            }
            let n = lines_hit.len() as u64;
            let fault_rounds = u32::from(n > 0);
            let lookups = if role == "render" { 100 + n } else { 0 };
            records.push(json!({"type": "frame", "version": 1, "run": "made-up",
                "frame": f, "role": role, "rank": rank, "ranks": world,
                "cache_lines": if role == "render" { lines } else { 0 },
                "cache_map": "ize", "rounds": 1 + fault_rounds, "fault_rounds": fault_rounds,
                "lookups": lookups, "hits": 100, "misses": n,
                "hit_rate": if lookups > 0 { 100.0 / lookups as f64 } else { 1.0 },
                "fetched_blocks": n, "fetched_bytes": 8192 * n, "frame_ms": 10.0,
                "trace_ms": 4.0, "fetch_ms": 1.0, "upload_ms": 1.0, "shade_ms": 2.0}));
            let text: Vec<String> = records.iter().map(Value::to_string).collect();
            std::fs::write(
                dir.join(format!("frame_{f:04}.rank{rank}.jsonl")),
                text.join("\n") + "\n",
            )
            .unwrap();
        }
    }
    dir
}

#[test]
fn plot_axes_end_at_the_traces_maxima() {
    let d = TempDir::new("plot-max");
    // Rank 2 faults on line 5 in every frame and on line (f + 1) in frame f; rank 3 on line 5
    // twice in frame 2. Faults at (frame 2, line 5): 1 + 2 = 3, the most of any cell.
    let dir = synthetic(&d, "made-up", 2, 4, 16, |f, r| {
        if r == 2 {
            vec![5, f + 1]
        } else if f == 2 {
            vec![5, 5]
        } else {
            Vec::new()
        }
    });
    let svg = d.path("p.svg");
    plot(&[&dir, &"-o", &svg]);
    let texts = svg_texts(&svg);
    // Rounds: 2 at most (one fault round and the last); MiB: 2 blocks of 8 KiB.
    assert_eq!(largest(&numbers(&panel(&texts, 0), "end")), 2.0);
    let mib = largest(&numbers(&panel(&texts, 1), "end"));
    let want = 2.0 * 8192.0 / (1024.0 * 1024.0);
    assert!((mib - want).abs() <= 0.01 * want, "{mib} MiB, not {want}");
    assert_eq!(largest(&numbers(&panel(&texts, 2), "end")), 1.0);
    let heat = panel(&texts, 4);
    assert_eq!(largest(&numbers(&heat, "end")), 16.0, "cache lines");
    assert_eq!(largest(&numbers(&heat, "start")), 3.0, "the colour bar");
    // Frames across, 0 to 3, in every frame panel.
    for i in [0, 1, 2, 4] {
        let x = numbers(&panel(&texts, i), "middle");
        assert_eq!((x.first(), x.last()), (Some(&0.0), Some(&3.0)), "panel {i}");
    }
    let heading = &texts[0].text;
    assert!(heading.contains("made-up"), "{heading}");
    assert!(texts.iter().any(|t| t.text.contains("cache: 16 lines")));
    assert!(texts.iter().any(|t| t.text.contains("mapping ize")));
}

#[test]
fn plot_draws_one_rank_one_frame_no_faults() {
    let d = TempDir::new("plot-small");
    let none = synthetic(&d, "none", 1, 1, 8, |_, _| Vec::new());
    let svg = d.path("none.svg");
    plot(&[&none, &"-o", &svg]);
    let texts = svg_texts(&svg);
    assert!(texts.iter().any(|t| t.text == "rank 2"));
    assert!(texts.iter().any(|t| t.text.contains("(no faults)")));
    assert_eq!(numbers(&panel(&texts, 0), "middle"), [0.0], "one frame");
    assert_eq!(
        largest(&numbers(&panel(&texts, 0), "end")),
        1.0,
        "one round"
    );
    plot(&[&none, &"-o", &d.path("none.png")]);
    let png = image::open(d.path("none.png")).unwrap();
    assert!(png.width() >= 1000 && png.height() >= 1000);
    // No cache at all: the heat map says why it is empty.
    let replicated = synthetic(&d, "replicated", 1, 2, 0, |_, _| Vec::new());
    plot(&[&replicated, &"-o", &svg]);
    assert!(
        svg_texts(&svg)
            .iter()
            .any(|t| t.text.contains("no cache: nothing faults"))
    );
}

#[test]
fn plot_bins_and_wraps_for_many_ranks_lines_and_frames() {
    let d = TempDir::new("plot-many");
    // 24 render ranks on 5000 lines: the legend wraps, the lines are binned.
    let many = synthetic(&d, "ranks", 24, 2, 5000, |f, r| {
        vec![(f * 97 + r * 13) % 5000]
    });
    let svg = d.path("ranks.svg");
    plot(&[&many, &"-o", &svg]);
    let texts = svg_texts(&svg);
    let keys: Vec<&SvgText> = texts
        .iter()
        .filter(|t| t.text.starts_with("rank ") && t.anchor == "start")
        .collect();
    assert_eq!(keys.len(), 24, "every rank in the legend");
    let rows: std::collections::BTreeSet<i64> = keys.iter().map(|t| t.y as i64).collect();
    assert!(rows.len() > 1, "the legend wraps: {rows:?}");
    let width: f64 = std::fs::read_to_string(&svg)
        .unwrap()
        .split("width=\"")
        .nth(1)
        .and_then(|s| s.split('"').next())
        .unwrap()
        .parse()
        .unwrap();
    assert!(keys.iter().all(|t| t.x < width), "inside the picture");
    assert!(texts.iter().any(|t| t.text.contains("a cell is 1 frame x")));
    // 1500 frames of one rank: more frames than the heat map has pixels across.
    let long = synthetic(&d, "frames", 1, 1500, 4, |f, _| vec![f % 4]);
    plot(&[&long, &"-o", &svg]);
    let texts = svg_texts(&svg);
    assert!(
        texts
            .iter()
            .any(|t| t.text.ends_with("a cell is 2 frames x 1 line")),
        "{:?}",
        texts.iter().find(|t| t.text.starts_with(TITLES[4]))
    );
    assert_eq!(largest(&numbers(&panel(&texts, 0), "middle")), 1499.0);
}

#[test]
fn plot_format_from_the_name_or_the_flag() {
    let d = TempDir::new("plot-format");
    let dir = synthetic(&d, "t", 2, 2, 8, |f, _| vec![f]);
    let out = d.path("out");
    std::fs::create_dir_all(&out).unwrap();
    // An explicit format for a name without one.
    plot(&[&dir, &"-o", &out.join("plot.figure"), &"--format", &"svg"]);
    let head = std::fs::read_to_string(out.join("plot.figure")).unwrap();
    assert!(head.starts_with("<svg"), "{}", &head[..40.min(head.len())]);
    plot(&[&dir, &"-o", &out.join("p.PNG"), &"--format", &"png"]);
    assert!(image::open(out.join("p.PNG")).is_ok());
    let refused = |args: &[&dyn AsRef<std::ffi::OsStr>], want: &[&str]| {
        let mut all: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"trace", &"plot"];
        all.extend_from_slice(args);
        let r = dcrt(&all);
        let err = String::from_utf8_lossy(&r.stderr).to_string();
        assert!(!r.status.success(), "accepted: {err}");
        assert!(!err.contains("panicked"), "{err}");
        for w in want {
            assert!(err.contains(w), "{err} does not say {w}");
        }
    };
    refused(
        &[&dir, &"-o", &out.join("x.svg"), &"--format", &"png"],
        &["x.svg", "--format png", ".svg"],
    );
    refused(
        &[&dir, &"-o", &out.join("x.gif")],
        &["x.gif", "png or .svg"],
    );
    refused(
        &[&dir, &"-o", &out.join("x.png"), &"--format", &"jpg"],
        &["jpg", "png or svg"],
    );
    // A bad directory: its error as `trace summary` gives it, and nothing written.
    refused(
        &[&d.path("missing"), &"-o", &out.join("y.png")],
        &["missing"],
    );
    // No font for the text: refused, and nothing written.
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"))
        .args(["trace", "plot"])
        .arg(&dir)
        .arg("-o")
        .arg(out.join("z.png"))
        .env("DCRT_FONT", d.path("no-such-font.ttf"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && err.contains("DCRT_FONT"), "{err}");
    assert_eq!(listing(&out), ["p.PNG", "plot.figure"]);
}
