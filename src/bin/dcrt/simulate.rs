//! `dcrt simulate DIR --ranks K`: a cluster run's traces replayed at K ranks.

use anyhow::{Result, bail};
use clap::Args;
use dcrt::simulate::{ClusterModel, simulate as run};
use dcrt::traces::read::Traces;
use std::path::PathBuf;

#[derive(Args)]
pub struct SimulateArgs {
    /// Directory written by `--trace` under mpirun.
    dir: PathBuf,
    /// Total MPI ranks to predict for, as `mpirun -n K` (at least 2).
    #[arg(long)]
    ranks: u32,
    /// Block fetch bandwidth in MB/s (10^6 bytes); default: the measured fetch times.
    #[arg(long)]
    bandwidth: Option<f64>,
    /// Latency of a fault round's fetch in microseconds; default: the measured fetch times.
    #[arg(long)]
    latency: Option<f64>,
    /// The run's `--tile` and `--min-tile`.
    #[arg(long, default_value_t = 128)]
    tile: u32,
    #[arg(long, default_value_t = 16)]
    min_tile: u32,
    /// Render ranks of the predicted run that share one machine's cores; default: all of them,
    /// as in the traced run; 1: a rank per node.
    #[arg(long)]
    ranks_per_node: Option<u32>,
    /// With a distributed cache, shared costs per pixel grow as (render ranks / traced)^W
    /// (0.5 fits this project's 2-core machine at 4 to 6 ranks; 0: the work per pixel as traced).
    #[arg(long, default_value_t = 0.5)]
    work_exponent: f64,
    /// One JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn simulate(a: SimulateArgs) -> Result<()> {
    if a.ranks_per_node == Some(0) {
        bail!("--ranks-per-node must be at least 1");
    }
    let t = Traces::read(&a.dir)?;
    let p = run(
        &t,
        &ClusterModel {
            ranks: a.ranks,
            bandwidth: a.bandwidth.map(|b| b * 1e6),
            latency: a.latency.map(|l| l * 1e-6),
            tile: a.tile,
            min_tile: a.min_tile,
            ranks_per_node: a.ranks_per_node,
            work_exponent: a.work_exponent,
            sharing: None,
        },
    )?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&p)?);
        return Ok(());
    }
    println!(
        "{} ranks ({} render) from traces of {} ranks; costs x{:.2} for core sharing, x{:.2} for the cache's work per pixel; fixed cost of a tile {:.2} ms",
        p.ranks, p.render_ranks, p.traced_ranks, p.sharing_stretch, p.work_stretch, p.tile_fixed_ms
    );
    if let Some(s) = &p.sharing {
        println!(
            "a round waits {:.2} ms + {:.2} ms per rank tracing ({} rounds; {:.2} ranks tracing at once, busy {:.2})",
            s.alone_ms, s.per_rank_ms, s.rounds, s.concurrency, s.busy
        );
    }
    println!(
        "{:>5} {:>12} {:>12} {:>12}",
        "frame", "complete ms", "frame ms", "measured"
    );
    for f in &p.frames {
        let m = f.measured_ms.map_or("-".into(), |m| format!("{m:.1}"));
        println!(
            "{:>5} {:>12.1} {:>12.1} {:>12}",
            f.frame, f.complete_ms, f.frame_ms, m
        );
    }
    let m = p
        .measured_mean_frame_ms
        .map_or(String::new(), |m| format!(" (measured {m:.1})"));
    println!("mean frame interval {:.1} ms{m}", p.mean_frame_ms);
    Ok(())
}
