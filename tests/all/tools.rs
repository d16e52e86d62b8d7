//! The trace tools: `dcrt trace summary` adds up what the frame records say, bad directories
//! are refused with the file and line, and a cluster run's Perfetto timeline has a process per
//! rank with spans of every kind. The `cluster_` tests run mpirun (one at a time, see
//! .config/nextest.toml).

use crate::common::*;
use dcrt::traces::read::Traces;
use dcrt::traces::summary::RunSummary;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

const SCENE: &str = "[camera]\nposition = [0, -2.2, 1.8]\nfocal_point = [0, 0, 0]\n\
                     view_up = [0, 0, 1]\nview_angle = 40\n[image]\nwidth = 48\nheight = 40\n\
                     [[mesh]]\ngenerator = \"rm\"\ntriangles = 8000\n";

fn ok(args: &[&dyn AsRef<std::ffi::OsStr>]) -> String {
    let r = dcrt(args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    String::from_utf8_lossy(&r.stdout).to_string()
}

/// `dcrt trace summary DIR` fails with one `error:` line containing every piece of `want`.
fn refused(dir: &Path, want: &[&str]) {
    let r = dcrt(&[&"trace", &"summary", &dir]);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert!(!r.status.success(), "accepted {}: {err}", dir.display());
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.starts_with("error: "), "{err}");
    for w in want {
        assert!(err.contains(w), "{err} does not name {w}");
    }
}

fn lines(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Three frames as virtual rank 1 of 3 with a small cache: rounds that fault in every frame.
fn one_process_traces(d: &TempDir) -> std::path::PathBuf {
    let scene = d.write("s.toml", SCENE);
    let traces = d.path("traces");
    let r = dcrt(&[
        &"render",
        &scene,
        &"-o",
        &d.path("o.png"),
        &"--frames",
        &"3",
        &"--virtual-ranks",
        &"3",
        &"--rank",
        &"1",
        &"--cache",
        &"4lines",
        &"--trace",
        &traces,
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    traces
}

#[test]
fn summary_totals_are_the_frame_records() {
    let d = TempDir::new("tools-sum");
    let traces = one_process_traces(&d);
    let json: Value = serde_json::from_str(&ok(&[&"trace", &"summary", &traces, &"--json"]))
        .expect("--json prints one object");
    let mut frames = Vec::new();
    let mut faults = 0u64;
    for f in 0..3 {
        let recs = lines(&traces.join(format!("frame_{f:04}.rank1.jsonl")));
        faults += recs
            .iter()
            .filter(|r| r["type"] == "round")
            .map(|r| r["faults"].as_array().unwrap().len() as u64)
            .sum::<u64>();
        let last = recs.last().unwrap().clone();
        assert_eq!(last["type"], "frame");
        assert_eq!(last["version"], 1);
        frames.push(last);
    }
    assert_eq!(json["rows"].as_array().unwrap().len(), 3);
    let t = &json["totals"];
    for k in [
        "rounds",
        "fault_rounds",
        "fault_round_bound",
        "lookups",
        "hits",
        "fetched_blocks",
        "fetched_bytes",
    ] {
        let want: u64 = frames.iter().map(|f| f[k].as_u64().unwrap()).sum();
        assert_eq!(t[k].as_u64().unwrap(), want, "{k}");
    }
    assert!(
        t["fetched_blocks"].as_u64().unwrap() > 0,
        "the cache fetched"
    );
    for k in ["frame_ms", "trace_ms", "fetch_ms", "upload_ms", "shade_ms"] {
        let want: f64 = frames.iter().map(|f| f[k].as_f64().unwrap()).sum();
        assert!((t[k].as_f64().unwrap() - want).abs() < 1e-9, "{k}");
    }
    assert_eq!(t["faults"].as_u64().unwrap(), faults);
    // Four lines for more of the frames' blocks: a bound above 0 that no frame beat.
    let bound = t["fault_round_bound"].as_u64().unwrap();
    assert!(
        bound > 0 && bound <= t["fault_rounds"].as_u64().unwrap(),
        "{t}"
    );
    for f in &frames {
        let (bound, rounds) = (f["fault_round_bound"].as_u64(), f["fault_rounds"].as_u64());
        assert!(bound.unwrap() <= rounds.unwrap(), "{f}");
    }
    let (hits, lookups) = (t["hits"].as_f64().unwrap(), t["lookups"].as_f64().unwrap());
    assert_eq!(t["hit_rate"].as_f64().unwrap(), hits / lookups);
    // The table prints the same totals.
    let table = ok(&[&"trace", &"summary", &traces]);
    let all = table.lines().last().unwrap();
    assert!(all.trim_start().starts_with("all"), "{table}");
    assert!(all.contains(&format!(" {} ", t["fault_rounds"])), "{table}");
    // One process renders, so every timeline process is rank 1's and the plot is drawn.
    let t = Traces::read(&traces).unwrap();
    assert_eq!(RunSummary::of(&t).ranks, [1]);
    ok(&[&"trace", &"plot", &traces, &"-o", &d.path("p.png")]);
    let png = image::open(d.path("p.png")).unwrap();
    assert!(png.width() > 100 && png.height() > 100);
}

/// Writes a copy of `src` into a new directory `name` under `d`, with `edit` applied to the
/// lines of `file`.
fn damaged(
    d: &TempDir,
    src: &Path,
    name: &str,
    file: &str,
    edit: impl Fn(&mut Vec<String>),
) -> std::path::PathBuf {
    let out = d.path(name);
    std::fs::create_dir_all(&out).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let p = e.unwrap().path();
        let target = out.join(p.file_name().unwrap());
        std::fs::copy(&p, &target).unwrap();
    }
    let p = out.join(file);
    let mut l: Vec<String> = std::fs::read_to_string(&p)
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect();
    edit(&mut l);
    std::fs::write(&p, l.join("\n") + "\n").unwrap();
    out
}

#[test]
fn bad_trace_directories_name_the_file_and_line() {
    let d = TempDir::new("tools-bad");
    let traces = one_process_traces(&d);
    let f1 = "frame_0001.rank1.jsonl";
    let n = lines(&traces.join(f1)).len();
    assert!(n >= 2, "frame 1 has rounds");

    refused(&d.path("missing"), &["missing"]);
    std::fs::create_dir_all(d.path("empty")).unwrap();
    refused(&d.path("empty"), &["empty", "no trace files"]);

    // A line cut short, as a killed writer leaves it.
    let cut = damaged(&d, &traces, "cut", f1, |l| {
        let k = l.len() - 1;
        let half = l[k].len() / 2;
        l[k].truncate(half);
    });
    refused(&cut, &[f1, &format!("line {n}"), "truncated"]);
    // The frame record missing altogether.
    let short = damaged(&d, &traces, "short", f1, |l| {
        l.pop();
    });
    refused(&short, &[f1, &format!("line {}", n - 1), "frame record"]);
    // A round lost from the middle.
    let lost = damaged(&d, &traces, "lost", f1, |l| {
        l.remove(0);
    });
    refused(&lost, &[f1, &format!("line {}", n - 1), "fault rounds"]);
    // A line of some other JSON Lines file.
    let foreign = damaged(&d, &traces, "foreign", f1, |l| {
        l.insert(0, r#"{"level":"info","msg":"hello"}"#.into())
    });
    refused(&foreign, &[f1, "line 1", "not a trace record"]);
    let unknown = damaged(&d, &traces, "unknown", f1, |l| {
        l.insert(1, r#"{"type":"span","name":"x"}"#.into())
    });
    refused(&unknown, &[f1, "line 2", "unknown record type"]);
    // A round record without its fields.
    let field = damaged(&d, &traces, "field", f1, |l| {
        l[0] = r#"{"type":"round","batch":0}"#.into()
    });
    refused(&field, &[f1, "line 1", "bad round record"]);
    // A file of another run beside these.
    let mixed = damaged(&d, &traces, "mixed", f1, |l| {
        let k = l.len() - 1;
        let mut v: Value = serde_json::from_str(&l[k]).unwrap();
        v["run"] = "another-run".into();
        l[k] = v.to_string();
    });
    refused(
        &mixed,
        &[f1, &format!("line {n}"), "different runs", "another-run"],
    );
    // A newer schema than this build reads.
    let newer = damaged(&d, &traces, "newer", f1, |l| {
        let k = l.len() - 1;
        let mut v: Value = serde_json::from_str(&l[k]).unwrap();
        v["version"] = 99.into();
        l[k] = v.to_string();
    });
    refused(&newer, &[f1, "version 99"]);
    // Version 0 files (no version, no run) are still read.
    let old = damaged(&d, &traces, "old", f1, |_| {});
    for f in 0..3 {
        let p = old.join(format!("frame_{f:04}.rank1.jsonl"));
        let mut l = lines(&p);
        let last = l.last_mut().unwrap().as_object_mut().unwrap();
        last.remove("version");
        last.remove("run");
        let text: Vec<String> = l.iter().map(Value::to_string).collect();
        std::fs::write(&p, text.join("\n") + "\n").unwrap();
    }
    assert_eq!(RunSummary::of(&Traces::read(&old).unwrap()).version, 0);
}

fn mpirun_traces(k: u32, frames: u32, d: &TempDir) -> std::path::PathBuf {
    let scene = d.write(
        "rm.toml",
        "[image]\nwidth = 72\nheight = 56\n\n[[mesh]]\ngenerator = \"rm\"\ntriangles = 20000\n",
    );
    let dcb = d.path("rm.dcb");
    ok(&[&"prepare", &scene, &"-o", &dcb]);
    let traces = d.path("traces");
    let out = Command::new("timeout")
        .args(["-k", "5", "120", "mpirun", "--oversubscribe", "-n"])
        .arg(k.to_string())
        .arg(env!("CARGO_BIN_EXE_dcrt"))
        .arg("render")
        .arg(&dcb)
        .arg("-o")
        .arg(d.path("t.png"))
        .arg("--trace")
        .arg(&traces)
        .args(["--cache", "1/8", "--tile", "32", "--min-tile", "8"])
        .args(["--frames", &frames.to_string()])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .output()
        .expect("mpirun (apt install openmpi-bin)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    traces
}

#[test]
fn cluster_perfetto_has_a_process_per_rank_and_every_kind_of_span() {
    let d = TempDir::new("tools-perfetto");
    let traces = mpirun_traces(4, 2, &d);
    let out = d.path("p.json");
    ok(&[&"trace", &"perfetto", &traces, &"-o", &out]);
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let ev = v["traceEvents"].as_array().unwrap();
    let names: BTreeMap<u64, String> = ev
        .iter()
        .filter(|e| e["ph"] == "M" && e["name"] == "process_name")
        .map(|e| {
            (
                e["pid"].as_u64().unwrap(),
                e["args"]["name"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    let want: BTreeMap<u64, String> = [
        (1, "display (rank 0)"),
        (2, "balancer (rank 1)"),
        (3, "render 0 (rank 2)"),
        (4, "render 1 (rank 3)"),
    ]
    .into_iter()
    .map(|(p, n)| (p, n.to_owned()))
    .collect();
    assert_eq!(names, want);
    let track = |pid: u64, tid: u64| -> String {
        ev.iter()
            .find(|e| e["name"] == "thread_name" && e["pid"] == pid && e["tid"] == tid)
            .map(|e| e["args"]["name"].as_str().unwrap().to_owned())
            .unwrap_or_default()
    };
    // Which kinds of span each process has, by track name.
    let mut kinds: BTreeMap<u64, BTreeSet<String>> = BTreeMap::new();
    for e in ev.iter().filter(|e| e["ph"] == "X") {
        let (pid, tid) = (e["pid"].as_u64().unwrap(), e["tid"].as_u64().unwrap());
        assert!(e["ts"].as_f64().unwrap() >= 0.0 && e["dur"].as_f64().unwrap() >= 0.0);
        kinds.entry(pid).or_default().insert(track(pid, tid));
    }
    let set = |k: &[&str]| k.iter().map(|s| s.to_string()).collect::<BTreeSet<_>>();
    assert!(kinds[&1].is_superset(&set(&["frames", "display copies"])));
    assert!(kinds[&2].contains("frames"));
    for pid in [3, 4] {
        let k = &kinds[&pid];
        assert!(
            k.is_superset(&set(&[
                "frames",
                "GPU rounds",
                "fetches",
                "uploads",
                "tiles"
            ])),
            "{pid}: {k:?}"
        );
    }
    // Rounds carry their own times: each is placed at its submission, in order, inside one of
    // its rank's frames.
    for pid in [3u64, 4] {
        let spans = |prefix: &str| -> Vec<(f64, f64, &Value)> {
            ev.iter()
                .filter(|e| e["ph"] == "X" && e["pid"] == pid)
                .filter(|e| e["name"].as_str().unwrap().starts_with(prefix))
                .map(|e| (e["ts"].as_f64().unwrap(), e["dur"].as_f64().unwrap(), e))
                .collect()
        };
        let (frames, rounds) = (spans("frame "), spans("round "));
        assert!(!rounds.is_empty(), "{pid}: no rounds");
        let mut last = f64::MIN;
        for &(ts, dur, e) in &rounds {
            assert_eq!(
                e["args"]["placed"], "at its submission, until its readback",
                "{pid}: {e}"
            );
            assert!(ts >= last, "{pid}: rounds out of order at {e}");
            last = ts;
            // Microseconds; 1 ms of slack for rounding and the tiles' own clock reads.
            assert!(
                frames
                    .iter()
                    .any(|&(f, d, _)| ts >= f - 1e3 && ts + dur <= f + d + 1e3),
                "{pid}: round outside every frame: {e}"
            );
        }
    }
    assert!(ev.iter().any(|e| e["ph"] == "i" && e["pid"] == 2), "grants");
    for c in ["hit rate", "live rays", "bytes in flight"] {
        assert!(
            ev.iter().any(|e| e["ph"] == "C" && e["name"] == c),
            "counter {c}"
        );
    }
    // Every flow starts at a render rank and ends at the other one, its blocks' owner.
    let starts: Vec<&Value> = ev.iter().filter(|e| e["ph"] == "s").collect();
    assert!(!starts.is_empty(), "flows from faults to owners");
    for s in starts {
        let end = ev
            .iter()
            .find(|e| e["ph"] == "f" && e["id"] == s["id"])
            .expect("the flow's end");
        assert_ne!(end["pid"], s["pid"]);
        assert!([3, 4].contains(&end["pid"].as_u64().unwrap()));
    }
    // The ranks share one clock: a rank traces its first tile after the balancer granted it
    // (a render rank sets up its GPU before it asks, so its own clock would start hundreds of
    // ms late), and the display completes the frame after the tiles were traced. The margin is
    // for ranks leaving the start-up barrier at slightly different times.
    let t = Traces::read(&traces).unwrap();
    let complete = t.get(0, 0).unwrap().displays[0].complete_ms;
    for r in [2, 3] {
        let tiles = &t.get(0, r).unwrap().tiles;
        let granted = t
            .get(0, 1)
            .unwrap()
            .grants
            .iter()
            .filter(|g| g.rank == r)
            .map(|g| g.t_ms)
            .reduce(f64::min)
            .unwrap();
        let first = tiles.iter().map(|t| t.start_ms).reduce(f64::min).unwrap();
        assert!(
            first >= granted - 20.0,
            "rank {r}: tile at {first} ms, granted at {granted} ms"
        );
        for tile in tiles {
            assert!(tile.start_ms + tile.trace_ms <= complete + 20.0, "rank {r}");
        }
    }
}

/// The simulator replays a 4-rank run at 4 ranks: every frame, with the measured interval beside
/// the predicted one. At 6 ranks on a rank per node with the work per pixel as traced it predicts
/// shorter frames than its own replay; on this machine's 2 cores (the default), longer ones
/// (docs/ARCHITECTURE.md, Traces). How close a prediction comes to a measured run is a timing,
/// so it is measured by scripts/simulate-validate.sh, not asserted here.
#[test]
fn cluster_simulate_predicts_its_own_run() {
    let d = TempDir::new("tools-sim");
    let traces = mpirun_traces(4, 8, &d);
    let run = |k: &str, extra: &[&str]| -> Value {
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> =
            vec![&"simulate", &traces, &"--ranks", &k, &"--json"];
        for e in extra {
            args.push(e);
        }
        serde_json::from_str(&ok(&args)).unwrap()
    };
    let own = run("4", &[]);
    let (p, m) = (
        own["mean_frame_ms"].as_f64().unwrap(),
        own["measured_mean_frame_ms"].as_f64().unwrap(),
    );
    assert!(
        p.is_finite() && p > 0.0 && m.is_finite() && m > 0.0,
        "predicted {p} ms, measured {m} ms"
    );
    // How close the replay comes to the run is a timing (scripts/simulate-validate.sh); that
    // the same traces give the same prediction is not.
    eprintln!("own replay: predicted {p:.1} ms a frame, measured {m:.1} ms");
    assert_eq!(
        run("4", &[]),
        own,
        "a second replay of the same traces differs"
    );
    assert_eq!(own["frames"].as_array().unwrap().len(), 8);
    assert_eq!(own["sharing_stretch"].as_f64(), Some(1.0));
    let nodes = run("6", &["--work-exponent", "0", "--ranks-per-node", "1"]);
    let more = nodes["mean_frame_ms"].as_f64().unwrap();
    assert!(
        more < p,
        "6 ranks on their own nodes {more} ms, 4 ranks {p} ms"
    );
    let shared = run("6", &[]);
    assert!(shared["sharing"]["rounds"].as_u64().unwrap() > 0);
    assert!(
        shared["work_stretch"].as_f64().unwrap() > 1.0,
        "a cached run"
    );
    assert!(
        shared["mean_frame_ms"].as_f64().unwrap() > more,
        "sharing 2 cores costs more than a node each"
    );
    assert!(shared["measured_mean_frame_ms"].is_null());
}

/// `bench figures` on a tiny configuration: traced mpirun jobs (3 ranks, replicated and a 1/2
/// cache, both models), their replays to 60 nodes, memory per node and one display job. The
/// JSON holds one point per configuration and source, every rate finite and positive; the
/// three PNGs decode at their sizes.
#[test]
fn cluster_bench_figures_draws_runs_simulations_and_the_chapters_numbers() {
    let d = TempDir::new("tools-figures");
    let out = d.path("figs");
    let r = Command::new("timeout")
        .args(["-k", "5", "120"])
        .arg(env!("CARGO_BIN_EXE_dcrt"))
        .args(["bench", "figures"])
        .arg(&out)
        .args(["--triangles", "2000", "--width", "32", "--height", "32"])
        .args([
            "--frames", "3", "--ranks", "3", "--caches", "1/2", "--runs", "1",
        ])
        .args([
            "--copy-threads",
            "1",
            "--display-frames",
            "4",
            "--display-ranks",
            "3",
        ])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .output()
        .expect("mpirun (apt install openmpi-bin)");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("figures.json")).unwrap()).unwrap();
    let six = v["figure6"].as_array().unwrap();
    let count = |model: &str, cache: &str, source: &str| {
        six.iter()
            .filter(|p| p["model"] == model && p["cache"] == cache && p["source"] == source)
            .count()
    };
    for model in ["rm", "assembly"] {
        for cache in ["replicated", "1/2"] {
            assert_eq!(count(model, cache, "run"), 1, "{model} {cache}");
            assert_eq!(count(model, cache, "simulated"), 6, "{model} {cache}");
        }
        assert_eq!(count(model, "replicated", "chapter"), 1);
        assert_eq!(count(model, "1/8", "chapter"), 1);
    }
    for p in six {
        let fps = p["fps"].as_f64().unwrap();
        assert!(fps.is_finite() && fps > 0.0, "{p}");
    }
    // A run at 3 ranks is 1 render rank + the display's node; its replay at the same ranks is
    // the simulator's own-run prediction.
    for p in six.iter().filter(|p| p["source"] == "run") {
        assert_eq!(
            (p["nodes"].as_u64(), p["ranks"].as_u64()),
            (Some(2), Some(3))
        );
        let own = six
            .iter()
            .find(|q| {
                q["source"] == "simulated"
                    && q["model"] == p["model"]
                    && q["cache"] == p["cache"]
                    && q["nodes"] == 2
            })
            .unwrap();
        assert!(p["predicted_fps"].as_f64().unwrap() > 0.0, "{p}");
        assert_eq!(p["runs"].as_array().unwrap().len(), 1, "{p}");
        assert_eq!(p["runs"][0], p["fps"]);
        assert!(own["fps"].as_f64().unwrap() > 0.0, "{own}");
    }
    // With a render rank per node, 59 render nodes are faster than 1.
    for model in ["rm", "assembly"] {
        let at = |nodes: u64| {
            six.iter()
                .find(|p| {
                    p["source"] == "simulated"
                        && p["model"] == model
                        && p["cache"] == "replicated"
                        && p["nodes"] == nodes
                })
                .unwrap()["fps"]
                .as_f64()
                .unwrap()
        };
        assert!(
            at(60) > at(2),
            "{model}: {} fps at 60 nodes, {} at 2",
            at(60),
            at(2)
        );
    }
    // Memory per node: the whole model replicated; with the cache, an owner's share and the
    // cache's 1/2, falling with the nodes; the runs' ranks allocated what the model says.
    let seven = v["figure7"].as_array().unwrap();
    let mem = |cache: &str, source: &str, nodes: u64| {
        seven
            .iter()
            .find(|p| p["cache"] == cache && p["source"] == source && p["nodes"] == nodes)
            .unwrap_or_else(|| panic!("{cache} {source} {nodes}"))["fraction"]
            .as_f64()
            .unwrap()
    };
    assert_eq!(
        seven.iter().filter(|p| p["source"] == "model").count(),
        2 * 59
    );
    assert_eq!(mem("replicated", "model", 60), 1.0);
    assert_eq!(
        mem("1/2", "model", 2),
        1.0,
        "one render rank owns all, no cache"
    );
    assert!(
        mem("1/2", "model", 3) >= 1.0,
        "half owned, half cached, and the root"
    );
    let far = mem("1/2", "model", 60);
    assert!((0.5..mem("1/2", "model", 3)).contains(&far), "{far}");
    assert_eq!(mem("1/2", "run", 2), mem("1/2", "model", 2));
    let eight = v["figure8"].as_array().unwrap();
    let runs: Vec<&Value> = eight.iter().filter(|p| p["source"] == "run").collect();
    assert_eq!(runs.len(), 1);
    assert_eq!(runs[0]["copy_threads"], 1);
    assert!(runs[0]["fps"].as_f64().unwrap() > 0.0);
    assert_eq!(eight.iter().filter(|p| p["source"] == "chapter").count(), 7);
    for (name, w) in [
        ("figure6.png", 1400),
        ("figure7.png", 840),
        ("figure8.png", 840),
    ] {
        let img = image::open(out.join(name)).unwrap();
        assert_eq!((img.width(), img.height()), (w, 640), "{name}");
    }
}

/// A 5-rank run's picture names every panel, axis, rank and phase, and its axes end at the
/// traces' maxima: rounds, MiB fetched, cache lines, and the colour bar at the most faults of a
/// line in a frame (every render rank's lines summed).
#[test]
fn cluster_plot_names_everything_and_ends_axes_at_the_maxima() {
    use crate::plot::{TITLES, largest, numbers, panel, svg_texts};
    let d = TempDir::new("tools-plot");
    let traces = mpirun_traces(5, 3, &d);
    let svg = d.path("p.svg");
    ok(&[&"trace", &"plot", &traces, &"-o", &svg]);
    let texts = svg_texts(&svg);
    let has = |w: &str| texts.iter().any(|t| t.text == w);
    let mut want: Vec<&str> = vec![
        "frame",
        "rounds",
        "fetched (MiB)",
        "hit rate (hits / lookups)",
        "share of time",
        "rank",
        "cache line",
        "faults",
        "rank 2",
        "rank 3",
        "rank 4",
    ];
    want.extend(dcrt::traces::plot::PHASES);
    want.extend(&TITLES[..4]);
    for w in want {
        assert!(has(w), "no text {w}");
    }
    assert!(
        !has("rank 0") && !has("rank 1"),
        "display and balancer trace no rounds"
    );
    let heading = &texts[0].text;
    assert!(
        heading.ends_with("traces"),
        "the directory's name: {heading}"
    );
    assert!(
        texts[1].text.starts_with(
            "5 ranks (display: rank 0, balancer: rank 1, render: ranks 2-4); 3 frames"
        ),
        "{}",
        texts[1].text
    );
    let t = Traces::read(&traces).unwrap();
    let render: Vec<&dcrt::traces::read::RankFrame> = t
        .files
        .iter()
        .filter(|f| f.frame.role == "render")
        .collect();
    let most = |v: &dyn Fn(&dcrt::traces::read::RankFrame) -> f64| {
        render.iter().map(|f| v(f)).fold(0.0, f64::max)
    };
    let rounds = most(&|f| f64::from(f.frame.rounds));
    assert_eq!(largest(&numbers(&panel(&texts, 0), "end")), rounds);
    let mib = most(&|f| f.frame.fetched_bytes as f64 / (1024.0 * 1024.0));
    let drawn = largest(&numbers(&panel(&texts, 1), "end"));
    assert!(
        mib > 0.0 && (drawn - mib).abs() <= 0.01 * mib,
        "{drawn} MiB, not {mib}"
    );
    let lines = render[0].frame.cache_lines;
    assert!(
        texts[2]
            .text
            .contains(&format!("cache: {lines} lines per render rank"))
    );
    let heat = panel(&texts, 4);
    assert_eq!(largest(&numbers(&heat, "end")), f64::from(lines));
    let mut cells: BTreeMap<(u32, u32), u64> = BTreeMap::new();
    for f in &render {
        for r in &f.rounds {
            for x in &r.faults {
                *cells.entry((f.frame.frame, x.line)).or_default() += 1;
            }
        }
    }
    let max = cells.values().copied().max().unwrap();
    assert_eq!(
        largest(&numbers(&heat, "start")),
        max as f64,
        "the colour bar"
    );
}
