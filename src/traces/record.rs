//! Every trace record (docs/ARCHITECTURE.md, Traces; Contracts, Trace records), typed once for
//! the writers (the tracer's rounds, the cluster roles' events, the frame loop's totals) and the
//! readers (`traces::read`), and the run clock their times count from. A trace is JSON Lines,
//! one file per frame and rank: the rounds, the events, then the frame record.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;

/// The version of the record schema (docs/ARCHITECTURE.md, Trace records), written in every
/// `frame` record. Files without it are version 0: the same records, no `run`.
pub const VERSION: u32 = 1;

/// What every trace file of one run shares: which run it is, so that traces of different runs
/// in one directory are told apart, and on a cluster the `MPI_Wtime` at the common epoch.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Run {
    pub run: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub epoch_wtime: Option<f64>,
}

static RUN: OnceLock<Run> = OnceLock::new();

/// Sets the run of this process's traces (a cluster sets the job's, agreed at start-up); the
/// first call wins. Without a call a process is a run of its own.
pub fn set_run(run: Run) {
    let _ = RUN.set(run);
}

/// This process's run.
pub fn run() -> &'static Run {
    RUN.get_or_init(|| Run {
        run: local_run_id(),
        epoch_wtime: None,
    })
}

/// A run id from the wall clock and the process id: distinct for runs that do not share a
/// process and a nanosecond.
pub fn local_run_id() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    run_id(nanos, std::process::id())
}

pub fn run_id(nanos: u64, pid: u32) -> String {
    format!("{nanos:016x}-{pid}")
}

static EPOCH: OnceLock<Instant> = OnceLock::new();

/// Sets the instant trace times count from (a cluster: the start-up barrier, `cluster::clock`);
/// the first call wins.
pub fn set_epoch(t: Instant) {
    let _ = EPOCH.set(t);
}

/// The instant trace times count from: the one `set_epoch` set, else the first call's.
pub fn epoch() -> Instant {
    *EPOCH.get_or_init(Instant::now)
}

/// Milliseconds from the trace epoch to `t`.
pub fn ms_since_epoch(t: Instant) -> f64 {
    t.saturating_duration_since(epoch()).as_secs_f64() * 1e3
}

/// A block that faulted in a round.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Fault {
    pub block: u32,
    pub owner: u32,
    pub line: u32,
    /// The block the line held before, if any.
    pub evicted: Option<u32>,
    /// Rays that waited on this block's line in the round.
    pub waiting: u32,
    /// False when another fault of the round took the same line first: it faults again.
    pub served: bool,
}

/// One fault round: the traversal dispatch that faulted, then the fetch and upload that served it.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Round {
    pub batch: u32,
    pub round: u32,
    /// Rays still live after the dispatch.
    pub live: u32,
    pub faults: Vec<Fault>,
    /// Faults that did not fit in the GPU's fault list (they fault again).
    pub dropped: u32,
    pub fetched_blocks: u32,
    /// Of those, the blocks fetched ahead of the rays: children of the node blocks the round's
    /// faults loaded, into lines nothing needed (empty in traces of older builds).
    #[serde(default)]
    pub ahead: Vec<u32>,
    pub fetched_bytes: u64,
    pub fetch_us: f64,
    pub upload_us: f64,
    pub source: String,
    /// Cache lines in which the round's rays found their block (0 in traces of older builds).
    #[serde(default)]
    pub used_lines: u32,
    /// Of those, the lines whose triangle block a ray still live after the round used last:
    /// `lru` keeps them (0 in traces of older builds).
    #[serde(default)]
    pub kept_lines: u32,
    /// When the round's dispatches were submitted, in ms since the trace epoch (absent in traces
    /// of older builds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_ms: Option<f64>,
    /// From the submission until its readback was mapped (the GPU's work and the wait).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wait_ms: Option<f64>,
    /// The round's GPU time from timestamps, where the adapter has them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gpu_ms: Option<f64>,
}

/// The frame's totals.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct FrameSummary {
    pub frame: u32,
    /// `render` (or `single` for a one-process render), `display`, `balancer`, or both joined
    /// by `+` when one rank plays two roles.
    pub role: String,
    pub rank: u32,
    pub ranks: u32,
    pub cache_lines: u32,
    pub cache_map: String,
    pub rounds: u32,
    pub fault_rounds: u32,
    /// Rounds in which more than one batch was in flight (absent in traces of older builds).
    #[serde(default)]
    pub shared_rounds: u32,
    pub lookups: u64,
    pub hits: u64,
    pub misses: u64,
    pub hit_rate: f64,
    pub fetched_blocks: u64,
    pub fetched_bytes: u64,
    /// Distinct borrowed blocks the frame looked up (absent in traces of older builds).
    #[serde(default)]
    pub distinct_blocks: u64,
    /// The fewest fault rounds any schedule could have taken for those blocks through this
    /// cache (absent in traces of older builds).
    #[serde(default)]
    pub fault_round_bound: u32,
    pub frame_ms: f64,
    pub trace_ms: f64,
    pub fetch_ms: f64,
    pub upload_ms: f64,
    pub shade_ms: f64,
    /// When the frame began, in ms since the trace epoch (absent in traces of older builds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_ms: Option<f64>,
}

/// A tile a render rank traced and sent; times in ms on the run clock.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Tile {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
    pub start_ms: f64,
    pub trace_ms: f64,
    pub send_ms: f64,
}

/// What kind of answer the balancer gave.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum GrantKind {
    /// A rank's first tiles of the frame, from the static share.
    Static,
    /// A tile handed out on request.
    Dynamic,
    /// No tile left: the rank's frame is over.
    End,
}

impl std::fmt::Display for GrantKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            GrantKind::Static => "static",
            GrantKind::Dynamic => "dynamic",
            GrantKind::End => "end",
        })
    }
}

/// An answer of the balancer to a render rank: a tile (none for `End`), at `t_ms`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Grant {
    pub rank: u32,
    pub kind: GrantKind,
    pub t_ms: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub w: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<u32>,
}

/// A render rank's report of a frame as the display received it: its tiles, the pixel messages
/// and bytes they took, and its frame statistics (`gpu::frame::FrameStats` as JSON).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Render {
    pub frame: u32,
    pub rank: u32,
    pub tiles: u64,
    pub messages: u32,
    pub bytes: u64,
    pub stats: serde_json::Value,
}

/// How the display assembled a frame.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Display {
    pub messages: u64,
    pub bytes: u64,
    pub pixels: u64,
    pub first_message_ms: f64,
    pub complete_ms: f64,
    pub copy_wait_ms: f64,
    pub copy_threads: u32,
}

/// A cluster event of a frame, written between the rounds and the frame record.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Event {
    Tile(Tile),
    Grant(Grant),
    Render(Render),
    Display(Display),
}

/// The `frame` record, last in a file: the schema version and run (absent before version 1),
/// then the frame's totals (`FrameSummary`, whose fields it derefs to).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct FrameRecord {
    #[serde(default)]
    pub version: u32,
    #[serde(default)]
    pub run: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epoch_wtime: Option<f64>,
    #[serde(flatten)]
    pub summary: FrameSummary,
}

impl std::ops::Deref for FrameRecord {
    type Target = FrameSummary;
    fn deref(&self) -> &FrameSummary {
        &self.summary
    }
}

/// What one frame at one rank writes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameTrace {
    pub rounds: Vec<Round>,
    /// Cluster events of the frame (tiles rendered, grants, reports, assembly).
    pub events: Vec<Event>,
    pub summary: FrameSummary,
}

/// A line of a trace file as written.
#[derive(Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum Record<'a> {
    Round(&'a Round),
    Frame(&'a FrameRecord),
}

impl FrameTrace {
    pub fn file_name(dir: &Path, frame: u32, rank: u32) -> PathBuf {
        dir.join(format!("frame_{frame:04}.rank{rank}.jsonl"))
    }

    /// Writes one JSON object per line: every round (`"type": "round"`), the cluster events,
    /// then the frame (`"type": "frame"`, with the schema `version` and the `run`).
    pub fn write(&self, dir: &Path) -> Result<PathBuf> {
        let path = Self::file_name(dir, self.summary.frame, self.summary.rank);
        let io = |e| Error::io(&path, e);
        crate::files::write_record(&path, |w| {
            for r in &self.rounds {
                serde_json::to_writer(&mut *w, &Record::Round(r))
                    .map_err(|e| Error::Invalid(e.to_string()))?;
                w.write_all(b"\n").map_err(io)?;
            }
            for e in &self.events {
                serde_json::to_writer(&mut *w, e).map_err(|e| Error::Invalid(e.to_string()))?;
                w.write_all(b"\n").map_err(io)?;
            }
            let run = run();
            let frame = FrameRecord {
                version: VERSION,
                run: Some(run.run.clone()),
                epoch_wtime: run.epoch_wtime,
                summary: self.summary.clone(),
            };
            serde_json::to_writer(&mut *w, &Record::Frame(&frame))
                .map_err(|e| Error::Invalid(e.to_string()))?;
            w.write_all(b"\n").map_err(io)
        })?;
        Ok(path)
    }
}
