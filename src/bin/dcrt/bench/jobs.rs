//! The `mpirun` jobs of `dcrt bench cluster` and `dcrt bench figures`: jobs of this same binary's
//! `bench job` (the render path with the measurement switches) side by side with a
//! single-process run of the same model; frame times, block fetch costs per transport and the
//! display's frame rate against the MPI bandwidth (chapter 5.5).

use anyhow::{Context, Result, bail};
use serde::Serialize;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// An Open MPI transport for one-sided Gets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Transport {
    /// Open MPI's defaults on one node: shared memory (vader, osc rdma/sm).
    Shm,
    /// `--mca btl tcp,self --mca osc pt2pt`: what a TCP-only cluster uses.
    TcpPt2pt,
    /// `--mca osc ucx`.
    Ucx,
}

/// The subcommand of this binary a bench job runs: `dcrt render`'s options, and the switches.
pub const JOB: [&str; 2] = ["bench", "job"];

impl Transport {
    pub fn mca(self) -> &'static [&'static str] {
        match self {
            Transport::Shm => &[],
            Transport::TcpPt2pt => &["--mca", "btl", "tcp,self", "--mca", "osc", "pt2pt"],
            Transport::Ucx => &["--mca", "osc", "ucx"],
        }
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The dcrt binary to start.
    pub exe: PathBuf,
    /// Where outputs and statistics go.
    pub dir: PathBuf,
    /// Prepared models by name.
    pub models: Vec<(String, PathBuf)>,
    pub ranks: Vec<u32>,
    /// `None` replicates; otherwise a `--cache` size.
    pub caches: Vec<Option<String>>,
    pub transports: Vec<Transport>,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    /// Copy-thread counts of the display benchmark (empty: skip it), and its rank count.
    pub copy_threads: Vec<u32>,
    pub display_ranks: u32,
    pub timeout_seconds: u64,
}

/// One configuration's figures.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub model: String,
    pub ranks: u32,
    pub render_ranks: u32,
    pub cache: String,
    pub transport: Transport,
    /// Steady frame time: mean interval between frames completing at the display, frame 0 (cold
    /// caches, pipeline compilation) excluded; for one process the mean render time of the same
    /// frames.
    pub frame_ms: f64,
    /// `frame_ms` over the single-process figure of the same model from the same run.
    pub vs_single: f64,
    pub fault_rounds_per_frame: f64,
    pub blocks_per_frame: f64,
    pub fetch_us_per_block: f64,
    pub fetch_us_per_round: f64,
}

pub fn run(cmd: &mut Command, what: &str) -> Result<()> {
    let out = cmd
        .output()
        .with_context(|| format!("{what}: cannot start (apt install openmpi-bin)"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = err.lines().rev().take(12).collect();
        bail!(
            "{what} failed ({}):\n{}",
            out.status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
    Ok(())
}

fn read_stats(path: &Path) -> Result<Value> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(0.0)
}

impl Plan {
    fn render_args(&self, model: &Path, out: &str, stats: &Path) -> Vec<String> {
        let png = self.dir.join(format!("{out}.png"));
        [
            JOB[0],
            JOB[1],
            &model.to_string_lossy(),
            "-o",
            &png.to_string_lossy(),
            "--frames",
            &self.frames.to_string(),
            "--width",
            &self.width.to_string(),
            "--height",
            &self.height.to_string(),
            "--stats",
            &stats.to_string_lossy(),
            "--timeout",
            &self.timeout_seconds.to_string(),
        ]
        .map(String::from)
        .to_vec()
    }

    fn mpirun(&self, k: u32, transport: Transport) -> Command {
        mpirun(&self.exe, k, transport)
    }

    /// Frame time of one process, then every rank count and cache on shared memory, then the
    /// distributed cache at the largest rank count on every transport.
    pub fn frame_times(&self) -> Result<Vec<Row>> {
        let mut rows = Vec::new();
        for (name, model) in &self.models {
            let stats = self.dir.join(format!("{name}-single.json"));
            let mut cmd = Command::new(&self.exe);
            cmd.args(self.render_args(model, &format!("{name}-single"), &stats));
            run(&mut cmd, &format!("{name}: single process"))?;
            let s = read_stats(&stats)?;
            let frames = s["frames"].as_array().cloned().unwrap_or_default();
            let steady: Vec<f64> = frames.iter().skip(1).map(|x| f(&x["frame_ms"])).collect();
            let single_ms = steady.iter().sum::<f64>() / steady.len().max(1) as f64;
            rows.push(Row {
                model: name.clone(),
                ranks: 1,
                render_ranks: 1,
                cache: "replicated".into(),
                transport: Transport::Shm,
                frame_ms: single_ms,
                vs_single: 1.0,
                fault_rounds_per_frame: 0.0,
                blocks_per_frame: 0.0,
                fetch_us_per_block: 0.0,
                fetch_us_per_round: 0.0,
            });
            let max_k = self.ranks.iter().copied().max().unwrap_or(2);
            let mut configs = Vec::new();
            for &k in &self.ranks {
                for c in &self.caches {
                    configs.push((k, c.clone(), Transport::Shm));
                }
            }
            for &t in self.transports.iter().filter(|&&t| t != Transport::Shm) {
                for c in self.caches.iter().filter(|c| c.is_some()) {
                    configs.push((max_k, c.clone(), t));
                }
            }
            for (k, cache, t) in configs {
                let tag = format!(
                    "{name}-k{k}-{}-{t:?}",
                    cache
                        .as_deref()
                        .unwrap_or("repl")
                        .replace('/', "of")
                        .replace(':', "-")
                );
                let stats = self.dir.join(format!("{tag}.json"));
                let mut cmd = self.mpirun(k, t);
                cmd.args(self.render_args(model, &tag, &stats));
                if let Some(c) = &cache {
                    // SIZE[:MAP[:OVERLAP[:REPLICATE]]], as `--caches` checked it.
                    let mut parts = c.split(':');
                    let size = parts.next().unwrap_or(c);
                    let map = parts.next().unwrap_or("ize");
                    cmd.args(["--cache", size, "--cache-map", map]);
                    if let Some(o) = parts.next() {
                        cmd.args(["--overlap-batches", o]);
                    }
                    if let Some(r) = parts.next() {
                        cmd.args(["--replicate-blocks", r]);
                    }
                }
                run(&mut cmd, &tag)?;
                rows.push(cluster_row(
                    name,
                    k,
                    cache.as_deref(),
                    t,
                    &read_stats(&stats)?,
                    single_ms,
                ));
            }
        }
        Ok(rows)
    }

    /// The display benchmark for each copy-thread count: one job each, its frame rate and the
    /// MPI bandwidth measured in the same job.
    pub fn display(&self, model: &Path) -> Result<Vec<Value>> {
        let mut out = Vec::new();
        for &threads in &self.copy_threads {
            let tag = format!("display-{threads}");
            let stats = self.dir.join(format!("{tag}.json"));
            let mut cmd = self.mpirun(self.display_ranks, Transport::Shm);
            cmd.args(self.render_args(model, &tag, &stats)).args([
                "--display-bench",
                "--copy-threads",
                &threads.to_string(),
            ]);
            run(&mut cmd, &tag)?;
            out.push(read_stats(&stats)?["display_bench"].clone());
        }
        Ok(out)
    }
}

/// `mpirun` of `k` ranks of `exe` over `transport`, oversubscribed (more ranks than cores).
pub fn mpirun(exe: &Path, k: u32, transport: Transport) -> Command {
    let mut cmd = Command::new("mpirun");
    cmd.arg("--oversubscribe")
        .args(transport.mca())
        .args(["-n", &k.to_string()])
        .arg(exe);
    cmd
}

fn cluster_row(
    model: &str,
    k: u32,
    cache: Option<&str>,
    t: Transport,
    s: &Value,
    single_ms: f64,
) -> Row {
    let frames = s["frames"].as_array().cloned().unwrap_or_default();
    let done: Vec<f64> = frames.iter().map(|x| f(&x["complete_ms"])).collect();
    let frame_ms = if done.len() >= 2 {
        (done[done.len() - 1] - done[0]) / (done.len() - 1) as f64
    } else {
        done.first().copied().unwrap_or(f64::NAN)
    };
    let (mut rounds, mut blocks, mut fetch) = (0.0, 0.0, 0.0);
    for fr in frames.iter().skip(1) {
        for r in fr["render"].as_array().into_iter().flatten() {
            rounds += f(&r["stats"]["fault_rounds"]);
            blocks += f(&r["stats"]["fetched_blocks"]);
            fetch += f(&r["stats"]["fetch_seconds"]);
        }
    }
    let n = frames.len().saturating_sub(1).max(1) as f64;
    let per = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    Row {
        model: model.into(),
        ranks: k,
        render_ranks: s["render_ranks"].as_u64().unwrap_or(0) as u32,
        cache: cache.unwrap_or("replicated").into(),
        transport: t,
        frame_ms,
        vs_single: frame_ms / single_ms,
        fault_rounds_per_frame: rounds / n,
        blocks_per_frame: blocks / n,
        fetch_us_per_block: per(fetch * 1e6, blocks),
        fetch_us_per_round: per(fetch * 1e6, rounds),
    }
}

/// The rows as a table for people.
pub fn table(rows: &[Row]) -> String {
    let mut s = format!(
        "{:<10} {:>5} {:>6} {:<10} {:<9} {:>10} {:>8} {:>12} {:>12} {:>10} {:>10}\n",
        "model",
        "ranks",
        "render",
        "cache",
        "transport",
        "frame ms",
        "x single",
        "rounds/frame",
        "blocks/frame",
        "us/block",
        "us/round"
    );
    for r in rows {
        s += &format!(
            "{:<10} {:>5} {:>6} {:<10} {:<9} {:>10.1} {:>8.2} {:>12.1} {:>12.1} {:>10.1} {:>10.1}\n",
            r.model,
            r.ranks,
            r.render_ranks,
            r.cache,
            serde_json::to_value(r.transport)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default(),
            r.frame_ms,
            r.vs_single,
            r.fault_rounds_per_frame,
            r.blocks_per_frame,
            r.fetch_us_per_block,
            r.fetch_us_per_round
        );
    }
    s
}
