//! The switches for measurements (docs/ARCHITECTURE.md, Benchmarks): settings a user never
//! needs, which a bench turns to compare one way of tracing or shading with another. They are
//! options of the bench subcommands only; `dcrt render` runs with every one off
//! (`Switches::default()`), and `dcrt bench job` runs the render path with those it is given.

use clap::Args;
use dcrt::gpu::tracer::{FaultMode, OverlapMode, Settings};
use dcrt::shading::Overrides;

/// Tracer switches: when rays set faults aside, when batches overlap, fetching ahead, and
/// counting block entries in every frame.
#[derive(Args, Clone, Debug)]
pub struct TracerSwitches {
    /// With a distributed cache: when a ray sets absent blocks aside and goes on with the
    /// blocks its GPU holds, instead of suspending at the fault.
    #[arg(long, value_enum, default_value_t = Settings::default().faults)]
    pub faults: FaultMode,
    /// With a distributed cache: when the next batch of rays starts while the last rays of the
    /// current one still wait for blocks, so that the two share fault rounds.
    #[arg(long, value_enum, default_value_t = Settings::default().overlap_batches)]
    pub overlap_batches: OverlapMode,
    /// With an `lru` cache: fetch only the blocks rays fault on, not also the children of the
    /// node blocks among them.
    #[arg(long)]
    pub no_fetch_ahead: bool,
    /// Count node visits and node- and triangle-block entries in every frame (`--stats`
    /// `node_visits`, `block_entries`, `tri_block_entries`; 0 without). The counts slow the trace.
    #[arg(long)]
    pub block_counts: bool,
}

impl Default for TracerSwitches {
    fn default() -> Self {
        let s = Settings::default();
        TracerSwitches {
            faults: s.faults,
            overlap_batches: s.overlap_batches,
            no_fetch_ahead: !s.fetch_ahead,
            block_counts: s.block_counts,
        }
    }
}

impl TracerSwitches {
    /// `base` with the switches set.
    pub fn apply(&self, base: Settings) -> Settings {
        Settings {
            faults: self.faults,
            overlap_batches: self.overlap_batches,
            fetch_ahead: !self.no_fetch_ahead,
            block_counts: self.block_counts,
            ..base
        }
    }
}

/// Shading switches, each the way a robust tracer does not work, to compare with the way it does.
#[derive(Args, Clone, Debug, Default)]
pub struct ShadeSwitches {
    /// Offset secondary-ray origins by this fixed distance instead of integer ulps past the hit
    /// point's error bound.
    #[arg(long)]
    pub epsilon: Option<f32>,
    /// Shadow and occlusion rays find the closest hit instead of stopping at any.
    #[arg(long)]
    pub closest_hit_shadows: bool,
    /// Trace primary rays that miss the model's box too.
    #[arg(long)]
    pub no_cull: bool,
}

impl ShadeSwitches {
    /// The render CLI's shading options `base` with the switches set.
    pub fn apply(&self, base: Overrides) -> Overrides {
        Overrides {
            epsilon: self.epsilon,
            closest_hit_shadows: self.closest_hit_shadows,
            no_cull: self.no_cull,
            ..base
        }
    }
}

/// Every switch of `dcrt bench job`: the tracer's, the shading's, and the display benchmark.
#[derive(Args, Clone, Debug, Default)]
pub struct Switches {
    #[command(flatten)]
    pub tracer: TracerSwitches,
    #[command(flatten)]
    pub shade: ShadeSwitches,
    /// Display benchmark (chapter 5.5), under mpirun: the camera looks away from the model,
    /// tiles are traced once and then resent, and the MPI bandwidth to the display is measured
    /// after the frames.
    #[arg(long)]
    pub display_bench: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        switches: Switches,
    }

    /// The switches' command-line defaults are the library's: `dcrt render` (which has none of
    /// them) and a bench given none trace alike.
    #[test]
    fn defaults_on_the_command_line_are_the_settings_defaults() {
        let parsed = Cli::parse_from(["x"]).switches;
        let s = Settings::default();
        let applied = parsed.tracer.apply(Settings {
            faults: FaultMode::Always,
            overlap_batches: OverlapMode::Never,
            fetch_ahead: !s.fetch_ahead,
            block_counts: true,
            ..s
        });
        assert_eq!(
            (
                applied.faults,
                applied.overlap_batches,
                applied.fetch_ahead,
                applied.block_counts
            ),
            (s.faults, s.overlap_batches, s.fetch_ahead, s.block_counts)
        );
        assert_eq!(
            parsed.shade.apply(Overrides::default()),
            Overrides::default()
        );
        assert!(!parsed.display_bench);
    }
}
