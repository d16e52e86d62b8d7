//! `dcrt trace summary|perfetto|plot DIR`: reading what `--trace DIR` wrote.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use dcrt::traces::{Traces, perfetto, plot, summary::RunSummary};
use std::path::PathBuf;

#[derive(Args)]
pub struct TraceArgs {
    #[command(subcommand)]
    tool: Tool,
}

#[derive(Subcommand)]
enum Tool {
    /// Per frame and rank: rounds, faults, hit rate, fetches, time per phase, tiles; totals.
    Summary {
        /// Directory written by `--trace`.
        dir: PathBuf,
        /// One JSON object on stdout instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// Chrome Trace Event JSON for Perfetto (ui.perfetto.dev): one process per rank.
    Perfetto {
        dir: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// PNG: rounds, MiB fetched and hit rate per frame and rank, phase shares per rank, and a
    /// heat map of cache-line faults over frames.
    Plot {
        dir: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
    },
}

pub fn trace(a: TraceArgs) -> Result<()> {
    match a.tool {
        Tool::Summary { dir, json } => {
            let s = RunSummary::of(&Traces::read(&dir)?);
            if json {
                println!("{}", serde_json::to_string_pretty(&s)?);
            } else {
                print!("{}", s.table());
            }
        }
        Tool::Perfetto { dir, output } => {
            let t = Traces::read(&dir)?;
            let text = serde_json::to_string(&perfetto::timeline(&t))?;
            std::fs::write(&output, text).with_context(|| output.display().to_string())?;
        }
        Tool::Plot { dir, output } => plot::draw(&Traces::read(&dir)?, &output)?,
    }
    Ok(())
}
