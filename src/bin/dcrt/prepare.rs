//! `dcrt prepare`: a scene's BVH and blocks, built once into a block file, in memory or out of
//! core within `--memory`.

use crate::BuildArgs;
use anyhow::{Context, Result};
use clap::Args;
use dcrt::blocks::Format;
use dcrt::prepare::budget::Budget;
use dcrt::prepare::{Options, prepare as run};
use dcrt::progress::Progress;
use dcrt::scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct PrepareArgs {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output block file.
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    build: BuildArgs,
    /// Memory the build may use, in binary units (4GiB, 512MiB); a model whose build in memory
    /// needs more is built out of core, in parts that fit. Default: half the memory available.
    #[arg(long)]
    memory: Option<String>,
    /// No progress bars.
    #[arg(long, short)]
    quiet: bool,
}

pub fn prepare(a: PrepareArgs) -> Result<()> {
    // Options first, then the paths, then the work.
    let budget = match &a.memory {
        Some(m) => Budget::parse(m)?,
        None => Budget::default_for_machine(),
    };
    let format = Format::new(a.build.block_size)?;
    let inputs = Scene::input_files(&a.scene)?;
    dcrt::files::check_outputs(&[("block file", &a.output, 1)], &inputs)?;
    let scene = Scene::load(&a.scene)?;
    let o = Options {
        build: a.build.tree()?,
        format,
        budget,
        progress: Progress { quiet: a.quiet },
    };
    let r =
        run(&scene, &a.output, &o).with_context(|| format!("preparing {}", a.output.display()))?;
    let how = match r.parts {
        None => "in memory".to_string(),
        Some(p) => format!(
            "out of core in {} part{} (the largest {} of at most {} triangles; --memory {} MiB)",
            p.count,
            if p.count == 1 { "" } else { "s" },
            p.largest,
            p.capacity,
            budget.bytes >> 20
        ),
    };
    dcrt::report!(
        "{} triangles, {} node + {} triangle{} blocks of {} bytes ({} MiB), BVH depth {}, built \
         {how} in {:.1} s, wrote {}",
        r.triangles,
        r.node_blocks,
        r.tri_blocks,
        match r.attr_blocks {
            0 => String::new(),
            n => format!(" + {n} attribute"),
        },
        r.block_bytes,
        r.bytes() >> 20,
        r.depth,
        r.seconds,
        a.output.display()
    );
    let phases: Vec<String> = r
        .phases
        .iter()
        .map(|(name, s)| format!("{name} {s:.1} s"))
        .collect();
    dcrt::report!(
        "  {}; {:.2} M triangles/s",
        phases.join(", "),
        r.triangles as f64 / r.seconds / 1e6
    );
    Ok(())
}
