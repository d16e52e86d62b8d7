//! `dcrt trace summary|perfetto|plot DIR`: reading what `--trace DIR` wrote.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use dcrt::chart::Format;
use dcrt::traces::read::Traces;
use dcrt::traces::{perfetto, plot, summary::RunSummary};
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
    /// One picture of the run: a heading (the directory's name, ranks and roles, frames, cache
    /// lines and mapping), rounds, MiB fetched and hit rate per frame (a line per rank), each
    /// phase's share of a rank's time, and a heat map of cache-line faults over frames with its
    /// colour bar; titled panels, labelled axes, legends. Needs a TrueType font (DejaVu Sans or
    /// DCRT_FONT).
    Plot {
        /// Directory written by `--trace`.
        dir: PathBuf,
        /// The picture: .png or .svg (or any name with --format).
        #[arg(short, long)]
        output: PathBuf,
        /// png or svg; by default the output's extension says. A flag that contradicts the
        /// extension is an error.
        #[arg(long)]
        format: Option<Format>,
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
        Tool::Plot {
            dir,
            output,
            format,
        } => {
            let format = Format::of(&output, format)?;
            plot::draw(&Traces::read(&dir)?, &output, format)?;
        }
    }
    Ok(())
}
