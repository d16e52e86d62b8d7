//! Chrome Trace Event JSON (opens in Perfetto and chrome://tracing): one process per rank named
//! by its role, a track per kind of span, counters, and flows from a fault round to the ranks
//! that own its blocks.
//!
//! Times: cluster traces count milliseconds from one barrier on every rank (docs/ARCHITECTURE.md,
//! Traces), so the ranks line up. Frames, rounds, tiles, grants and the display's frames carry
//! times: a round spans its submission to its readback (`start_ms`, `wait_ms`), its fetch and
//! upload follow. Traces of older builds have no round or frame times: their rounds are laid out
//! in recorded order from the frame's start, each as its mean GPU time (the frame's `trace_ms`
//! over its rounds), and frames without tiles end to end by `frame_ms`.

use super::read::{RankFrame, Traces};
use serde_json::{Value, json};

/// Thread ids of the tracks within a rank's process.
const FRAMES: u32 = 1;
const ROUNDS: u32 = 2;
const FETCHES: u32 = 3;
const UPLOADS: u32 = 4;
const TILES: u32 = 5;
const COPIES: u32 = 6;
const GRANTS: u32 = 7;
/// Blocks served to rank r are drawn on track `SERVED + r` of the owner.
const SERVED: u32 = 100;

const TRACKS: &[(u32, &str)] = &[
    (FRAMES, "frames"),
    (ROUNDS, "GPU rounds"),
    (FETCHES, "fetches"),
    (UPLOADS, "uploads"),
    (TILES, "tiles"),
    (COPIES, "display copies"),
    (GRANTS, "grants"),
];

fn pid(rank: u32) -> u32 {
    rank + 1
}

/// The first render rank of a world of `k` (docs/ARCHITECTURE.md, Cluster).
fn first_render(k: u32) -> u32 {
    if k <= 2 { 1 } else { 2 }
}

/// The process name: the role, render ranks with their index among render ranks.
pub fn process_name(f: &RankFrame) -> String {
    let s = &f.frame;
    match s.role.as_str() {
        // Cluster render ranks trace tiles; a one-process render as virtual rank R does not.
        "render" if !f.tiles.is_empty() && s.rank >= first_render(s.ranks) => {
            format!("render {}", s.rank - first_render(s.ranks))
        }
        "render" => format!("render {}", s.rank),
        r => r.to_string(),
    }
}

fn us(ms: f64) -> f64 {
    ms * 1000.0
}

fn span(name: String, rank: u32, tid: u32, start_ms: f64, dur_ms: f64, args: Value) -> Value {
    json!({"name": name, "ph": "X", "pid": pid(rank), "tid": tid,
           "ts": us(start_ms), "dur": us(dur_ms.max(0.0)), "args": args})
}

fn counter(name: &str, rank: u32, t_ms: f64, value: f64) -> Value {
    json!({"name": name, "ph": "C", "pid": pid(rank), "ts": us(t_ms), "args": {name: value}})
}

/// The whole timeline as one JSON object.
pub fn timeline(t: &Traces) -> Value {
    let mut ev = Vec::new();
    let mut flow = 0u64;
    for rank in t.ranks() {
        let first = t.files.iter().find(|f| f.frame.rank == rank).expect("rank");
        ev.push(json!({"name": "process_name", "ph": "M", "pid": pid(rank),
                       "args": {"name": format!("{} (rank {rank})", process_name(first))}}));
        ev.push(
            json!({"name": "process_sort_index", "ph": "M", "pid": pid(rank),
                       "args": {"sort_index": rank}}),
        );
        for (tid, name) in TRACKS {
            ev.push(
                json!({"name": "thread_name", "ph": "M", "pid": pid(rank), "tid": tid,
                           "args": {"name": name}}),
            );
        }
        // Frames without times follow each other.
        let mut cursor = 0.0;
        for f in t.files.iter().filter(|f| f.frame.rank == rank) {
            let s = &f.frame;
            let (start, end) = frame_extent(f).unwrap_or_else(|| {
                let at = s.start_ms.unwrap_or(cursor);
                (at, at + s.frame_ms)
            });
            cursor = end;
            let args = json!({"rounds": s.rounds, "fault_rounds": s.fault_rounds,
                              "hit_rate": s.hit_rate, "fetched_blocks": s.fetched_blocks,
                              "fetched_bytes": s.fetched_bytes, "frame_ms": s.frame_ms});
            ev.push(span(
                format!("frame {}", s.frame),
                rank,
                FRAMES,
                start,
                end - start,
                args,
            ));
            if s.lookups > 0 {
                ev.push(counter("hit rate", rank, end, s.hit_rate));
            }
            for tile in &f.tiles {
                let a = json!({"x": tile.x, "y": tile.y, "w": tile.w, "h": tile.h,
                               "trace_ms": tile.trace_ms, "send_ms": tile.send_ms});
                ev.push(span(
                    format!("tile {}x{} at ({}, {})", tile.w, tile.h, tile.x, tile.y),
                    rank,
                    TILES,
                    tile.start_ms,
                    tile.trace_ms + tile.send_ms,
                    a,
                ));
            }
            for g in &f.grants {
                ev.push(
                    json!({"name": format!("{} grant to rank {}", g.kind, g.rank),
                               "ph": "i", "s": "t", "pid": pid(rank), "tid": GRANTS,
                               "ts": us(g.t_ms),
                               "args": {"x": g.x, "y": g.y, "w": g.w, "h": g.h}}),
                );
            }
            for d in &f.displays {
                ev.push(span(
                    format!("frame {} copies", s.frame),
                    rank,
                    COPIES,
                    d.first_message_ms,
                    d.complete_ms - d.first_message_ms,
                    json!({"messages": d.messages, "bytes": d.bytes, "pixels": d.pixels,
                           "copy_wait_ms": d.copy_wait_ms, "copy_threads": d.copy_threads}),
                ));
            }
            let gpu_ms = s.trace_ms / f64::from(s.rounds.max(1));
            let mut at = start;
            for r in &f.rounds {
                let (placed, dur) = match (r.start_ms, r.wait_ms) {
                    (Some(t), Some(w)) => {
                        at = t;
                        ("at its submission, until its readback", w)
                    }
                    _ => ("in recorded order (no start time)", gpu_ms),
                };
                let a = json!({"batch": r.batch, "round": r.round, "live": r.live,
                               "faults": r.faults.len(), "dropped": r.dropped,
                               "gpu_ms": r.gpu_ms, "placed": placed});
                ev.push(span(
                    format!("round {}.{}", r.batch, r.round),
                    rank,
                    ROUNDS,
                    at,
                    dur,
                    a,
                ));
                ev.push(counter("live rays", rank, at, f64::from(r.live)));
                at += dur;
                let fetch_ms = r.fetch_us / 1000.0;
                ev.push(span(
                    format!("fetch {} blocks", r.fetched_blocks),
                    rank,
                    FETCHES,
                    at,
                    fetch_ms,
                    json!({"blocks": r.fetched_blocks, "bytes": r.fetched_bytes,
                           "source": r.source}),
                ));
                ev.push(counter("bytes in flight", rank, at, r.fetched_bytes as f64));
                ev.push(counter("bytes in flight", rank, at + fetch_ms, 0.0));
                if r.source == "mpi" {
                    let mut owners: Vec<u32> = r.faults.iter().map(|x| x.owner).collect();
                    owners.sort_unstable();
                    owners.dedup();
                    for o in owners {
                        let owner = first_render(s.ranks) + o;
                        if owner == rank || t.get(s.frame, owner).is_none() {
                            continue;
                        }
                        flow += 1;
                        let blocks = r.faults.iter().filter(|x| x.owner == o).count();
                        ev.push(
                            json!({"name": "fault", "cat": "fetch", "ph": "s", "id": flow,
                                       "pid": pid(rank), "tid": FETCHES, "ts": us(at)}),
                        );
                        ev.push(span(
                            format!("serve {blocks} blocks to rank {rank}"),
                            owner,
                            SERVED + rank,
                            at,
                            fetch_ms,
                            json!({"blocks": blocks}),
                        ));
                        ev.push(
                            json!({"name": "fault", "cat": "fetch", "ph": "f", "bp": "e",
                                       "id": flow, "pid": pid(owner), "tid": SERVED + rank,
                                       "ts": us(at)}),
                        );
                    }
                }
                at += fetch_ms;
                let upload_ms = r.upload_us / 1000.0;
                ev.push(span(
                    format!("upload {} blocks", r.fetched_blocks),
                    rank,
                    UPLOADS,
                    at,
                    upload_ms,
                    json!({"blocks": r.fetched_blocks}),
                ));
                at += upload_ms;
            }
        }
        for other in t.ranks() {
            ev.push(json!({"name": "thread_name", "ph": "M", "pid": pid(rank),
                           "tid": SERVED + other,
                           "args": {"name": format!("served to rank {other}")}}));
        }
    }
    json!({"traceEvents": ev, "displayTimeUnit": "ms",
           "otherData": {"dir": t.dir.display().to_string(),
                         "run": t.files[0].frame.run}})
}

/// When the frame ran at its rank, from the records that carry times.
fn frame_extent(f: &RankFrame) -> Option<(f64, f64)> {
    let mut spans: Vec<(f64, f64)> = f
        .tiles
        .iter()
        .map(|t| (t.start_ms, t.start_ms + t.trace_ms + t.send_ms))
        .collect();
    spans.extend(
        f.displays
            .iter()
            .map(|d| (d.first_message_ms, d.complete_ms)),
    );
    spans.extend(f.grants.iter().map(|g| (g.t_ms, g.t_ms)));
    let start = spans.iter().map(|s| s.0).reduce(f64::min)?;
    let end = spans.iter().map(|s| s.1).reduce(f64::max)?;
    Some((start, end))
}
