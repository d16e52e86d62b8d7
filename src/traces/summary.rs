//! Per frame and rank: rounds, faults, hit rate, what was fetched, the time of each phase and
//! the tiles; and the totals over all of them.

use super::read::{RankFrame, Traces};
use serde::Serialize;
use std::fmt::Write;

#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Row {
    pub frame: u32,
    pub rank: u32,
    pub role: String,
    pub rounds: u64,
    pub fault_rounds: u64,
    /// The fewest fault rounds the cache allowed the frame's blocks (`FrameSummary`).
    pub fault_round_bound: u64,
    pub faults: u64,
    pub lookups: u64,
    pub hits: u64,
    pub hit_rate: f64,
    pub fetched_blocks: u64,
    pub fetched_bytes: u64,
    pub frame_ms: f64,
    /// GPU traversal rounds.
    pub trace_ms: f64,
    pub fetch_ms: f64,
    pub upload_ms: f64,
    pub shade_ms: f64,
    /// Packing and sending the pixels of the rank's tiles.
    pub send_ms: f64,
    pub tiles: u64,
}

impl Row {
    fn of(f: &RankFrame) -> Row {
        let s = &f.frame;
        Row {
            frame: s.frame,
            rank: s.rank,
            role: s.role.clone(),
            rounds: u64::from(s.rounds),
            fault_rounds: u64::from(s.fault_rounds),
            fault_round_bound: u64::from(s.fault_round_bound),
            faults: f.faults(),
            lookups: s.lookups,
            hits: s.hits,
            hit_rate: s.hit_rate,
            fetched_blocks: s.fetched_blocks,
            fetched_bytes: s.fetched_bytes,
            frame_ms: s.frame_ms,
            trace_ms: s.trace_ms,
            fetch_ms: s.fetch_ms,
            upload_ms: s.upload_ms,
            shade_ms: s.shade_ms,
            send_ms: f.tiles.iter().fold(0.0, |a, t| a + t.send_ms),
            tiles: f.tiles.len() as u64,
        }
    }

    fn add(&mut self, r: &Row) {
        self.rounds += r.rounds;
        self.fault_rounds += r.fault_rounds;
        self.fault_round_bound += r.fault_round_bound;
        self.faults += r.faults;
        self.lookups += r.lookups;
        self.hits += r.hits;
        self.fetched_blocks += r.fetched_blocks;
        self.fetched_bytes += r.fetched_bytes;
        self.frame_ms += r.frame_ms;
        self.trace_ms += r.trace_ms;
        self.fetch_ms += r.fetch_ms;
        self.upload_ms += r.upload_ms;
        self.shade_ms += r.shade_ms;
        self.send_ms += r.send_ms;
        self.tiles += r.tiles;
    }
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct RunSummary {
    pub dir: String,
    pub run: Option<String>,
    pub version: u32,
    pub frames: u32,
    pub ranks: Vec<u32>,
    pub rows: Vec<Row>,
    /// Sums over every row; `hit_rate` is hits over lookups (1 without lookups).
    pub totals: Row,
}

impl RunSummary {
    pub fn of(t: &Traces) -> RunSummary {
        let rows: Vec<Row> = t.files.iter().map(Row::of).collect();
        let mut totals = Row {
            role: "all".into(),
            ..Row::default()
        };
        for r in &rows {
            totals.add(r);
        }
        totals.hit_rate = if totals.lookups == 0 {
            1.0
        } else {
            totals.hits as f64 / totals.lookups as f64
        };
        let first = &t.files[0].frame;
        RunSummary {
            dir: t.dir.display().to_string(),
            run: first.run.clone(),
            version: first.version,
            frames: t.frames().len() as u32,
            ranks: t.ranks(),
            rows,
            totals,
        }
    }

    /// A table, one line per frame and rank, then the totals.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{}: run {}, schema version {}, {} frames, ranks {:?}",
            self.dir,
            self.run.as_deref().unwrap_or("(unnamed)"),
            self.version,
            self.frames,
            self.ranks
        );
        let _ = writeln!(
            s,
            "{:>5} {:>4} {:<16} {:>6} {:>6} {:>6} {:>7} {:>6} {:>7} {:>9} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8} {:>5}",
            "frame",
            "rank",
            "role",
            "rounds",
            "fault",
            "bound",
            "faults",
            "hit%",
            "blocks",
            "MiB",
            "frame ms",
            "gpu ms",
            "fetch ms",
            "upld ms",
            "shade ms",
            "send ms",
            "tiles"
        );
        for r in self.rows.iter().chain(std::iter::once(&self.totals)) {
            let frame = if r.role == "all" {
                "all".to_string()
            } else {
                r.frame.to_string()
            };
            let rank = if r.role == "all" {
                String::new()
            } else {
                r.rank.to_string()
            };
            let _ = writeln!(
                s,
                "{frame:>5} {rank:>4} {:<16} {:>6} {:>6} {:>6} {:>7} {:>6.2} {:>7} {:>9.2} {:>9.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>5}",
                r.role,
                r.rounds,
                r.fault_rounds,
                r.fault_round_bound,
                r.faults,
                100.0 * r.hit_rate,
                r.fetched_blocks,
                r.fetched_bytes as f64 / (1024.0 * 1024.0),
                r.frame_ms,
                r.trace_ms,
                r.fetch_ms,
                r.upload_ms,
                r.shade_ms,
                r.send_ms,
                r.tiles
            );
        }
        s
    }
}
