//! Cluster mode (docs/ARCHITECTURE.md, Cluster; chapter 5): `mpirun -n K dcrt render ...`.
//! Rank 0 is the display, rank 1 the load balancer, the others render (with 2 ranks the display
//! also balances; with 1 rank there is no MPI at all). Render ranks trace the tiles the balancer
//! hands them and send the pixels to the display; with a distributed cache each holds only its
//! own blocks and reads borrowed ones from their owners with one-sided MPI.
//!
//! `node` is one process from MPI set-up to the end: `startup` (open, agree), then
//! `render_rank` or `coordinator` (`balancer` and `display`), or in a live view `live` at the
//! display. `protocol` holds the messages,
//! `mailbox` sends and waits for them, `liveness` tells a working rank from a stopped one, `schedule` decides the tiles, `pixels` packs and
//! assembles them, `rma` (the unsafe MPI calls) reads borrowed blocks.

pub mod pixels;
pub mod protocol;
pub mod schedule;

#[cfg(feature = "mpi")]
mod balancer;
#[cfg(feature = "mpi")]
mod clock;
#[cfg(feature = "mpi")]
mod coordinator;
#[cfg(feature = "mpi")]
mod display;
#[cfg(feature = "mpi")]
mod display_bench;
#[cfg(feature = "mpi")]
mod failure;
#[cfg(feature = "mpi")]
pub mod live;
#[cfg(feature = "mpi")]
mod liveness;
#[cfg(feature = "mpi")]
mod mailbox;
#[cfg(feature = "mpi")]
mod node;
#[cfg(feature = "mpi")]
mod render_rank;
#[cfg(feature = "mpi")]
mod rma;
#[cfg(feature = "mpi")]
mod startup;

use crate::blocks::Format;
use crate::bvh::Build;
use crate::dc::{CacheMap, CacheSize, Replicate};
use crate::error::{Error, Result};
use crate::gpu::tracer::Settings;
use crate::output::Aov;
use crate::shading::Overrides;
use std::path::PathBuf;
use std::time::Duration;

/// How many ranks the launcher started, from the variables mpirun and srun set; `None` when this
/// process was started on its own.
pub fn launched_ranks() -> Option<u32> {
    first_number(SIZE_VARS, |v| std::env::var(v).ok())
}

/// This process's rank in the launcher's job, from the same launchers' variables; `None` when
/// it was started on its own.
pub fn launched_rank() -> Option<u32> {
    first_number(RANK_VARS, |v| std::env::var(v).ok())
}

/// The launchers' variables for the job's size and this process's rank: Open MPI, PMI, PMIx,
/// MVAPICH, Slurm.
const SIZE_VARS: &[&str] = &[
    "OMPI_COMM_WORLD_SIZE",
    "PMI_SIZE",
    "PMIX_SIZE",
    "MV2_COMM_WORLD_SIZE",
    "SLURM_STEP_NUM_TASKS",
];
const RANK_VARS: &[&str] = &[
    "OMPI_COMM_WORLD_RANK",
    "PMI_RANK",
    "PMIX_RANK",
    "MV2_COMM_WORLD_RANK",
    "SLURM_PROCID",
];

/// The first of the variables `names` that holds a number (Open MPI's own first), the
/// environment given as a function of the variable's name.
fn first_number(names: &[&str], var: impl Fn(&str) -> Option<String>) -> Option<u32> {
    names.iter().find_map(|v| var(v)?.trim().parse().ok())
}

/// Which rank does what.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Roles {
    pub size: u32,
}

impl Roles {
    pub fn new(size: u32) -> Result<Roles> {
        if size < 2 {
            return Err(Error::Invalid(format!(
                "cluster mode needs at least 2 ranks, got {size}"
            )));
        }
        Ok(Roles { size })
    }
    pub const DISPLAY: u32 = 0;
    pub fn balancer(&self) -> u32 {
        if self.size == 2 { 0 } else { 1 }
    }
    pub fn first_render(&self) -> u32 {
        if self.size == 2 { 1 } else { 2 }
    }
    pub fn render_ranks(&self) -> u32 {
        self.size - self.first_render()
    }
    /// The render index (0..render_ranks) of a world rank, if it renders.
    pub fn render_index(&self, rank: u32) -> Option<u32> {
        (rank >= self.first_render() && rank < self.size).then(|| rank - self.first_render())
    }
    pub fn render_rank(&self, index: u32) -> u32 {
        self.first_render() + index
    }
    pub fn name(&self, rank: u32) -> &'static str {
        match (rank == Self::DISPLAY, rank == self.balancer()) {
            (true, true) => "display+balancer",
            (true, false) => "display",
            (false, true) => "balancer",
            _ => "render",
        }
    }
}

/// A cluster's distributed cache: its size, mapping, and what every rank replicates.
#[derive(Clone, Copy, Debug)]
pub struct CacheOptions {
    pub size: CacheSize,
    pub map: CacheMap,
    pub replicate: Replicate,
}

/// Everything a cluster render needs, as the command line gave it.
#[derive(Clone, Debug)]
pub struct Options {
    pub input: PathBuf,
    pub output: PathBuf,
    pub exr: Option<PathBuf>,
    pub aovs: Vec<Aov>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub frames: u32,
    pub trace: Option<PathBuf>,
    pub adapter: Option<String>,
    /// Tracer settings; their shading is replaced by the scene's with `shade` applied, by each
    /// rank once it has read the scene (so that a rank that cannot read it still takes part in
    /// the agreement).
    pub settings: Settings,
    pub shade: Overrides,
    pub build: Build,
    pub format: Format,
    /// The distributed cache; `None` replicates the model on every rank.
    pub cache: Option<CacheOptions>,
    /// Threads the display copies pixels with.
    pub copy_threads: u32,
    /// Side of the balancer's large tiles, and of the smallest it splits them into.
    pub tile: u32,
    pub min_tile: u32,
    /// PNG exposure in stops.
    pub exposure: f32,
    /// Target size of a pixel message.
    pub message_bytes: usize,
    /// How long any wait (for a message, for the GPU) may last before the job is aborted.
    pub timeout: Duration,
    /// Benchmark of the display (chapter 5.5): the camera looks away from the model and does
    /// not orbit, a tile traced once is sent again instead of traced again, so the display and
    /// the network set the frame rate; then MPI bandwidth to the display is measured.
    pub display_bench: bool,
    /// A live view (`dcrt view` under mpirun): the display serves the frames its clients ask
    /// for (`live`), one at a time, until the job is ended by a signal; `frames` is not used.
    pub live: bool,
    /// Where rank 0 writes the run's figures as JSON (frame times, the render ranks'
    /// statistics, the display benchmark).
    pub stats: Option<PathBuf>,
    /// The display draws the colour legend on the PNGs (`render::legend_of`).
    pub legend: bool,
    /// A camera replacing the model's (`--camera` FILE.pvcc).
    pub camera: Option<crate::scene::Camera>,
}

/// Runs this process's role of a cluster render. Returns only on rank 0's success or a clean
/// failure agreed by all ranks; errors in the middle of a frame abort the whole job.
pub fn run(opts: &Options) -> Result<()> {
    #[cfg(feature = "mpi")]
    {
        node::run(opts, None)
    }
    #[cfg(not(feature = "mpi"))]
    {
        let _ = opts;
        Err(Error::Mpi(
            "started by an MPI launcher, but this dcrt was built without the `mpi` feature".into(),
        ))
    }
}

/// What serves a live view at the display rank: it makes frames with the `LiveDisplay` for as
/// long as the view runs.
#[cfg(feature = "mpi")]
pub type Serve<'s> = dyn FnMut(&mut live::LiveDisplay<'_>) -> Result<()> + 's;

/// Runs this process's role of a live view (`dcrt view` under mpirun): `serve` at the display
/// rank, with the `live::LiveDisplay` that makes its frames; it returns only on an error, which
/// ends the job.
#[cfg(feature = "mpi")]
pub fn view(opts: &Options, serve: &mut Serve<'_>) -> Result<()> {
    if !opts.live {
        return Err(Error::Internal(
            "a live view's options without `live`".into(),
        ));
    }
    node::run(opts, Some(serve))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn launchers_are_recognised_by_their_variables() {
        let env = |pairs: &[(&str, &str)]| {
            let pairs: Vec<(String, String)> = pairs
                .iter()
                .map(|(n, v)| (n.to_string(), v.to_string()))
                .collect();
            move |k: &str| pairs.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone())
        };
        // Each launcher's size and rank variable alone, as launchers write them (stray white
        // space included); what is not a number is no size.
        let cases: [(&[&str], &str, &str, Option<u32>); 14] = [
            (SIZE_VARS, "OMPI_COMM_WORLD_SIZE", "4", Some(4)),
            (SIZE_VARS, "PMI_SIZE", "3", Some(3)),
            (SIZE_VARS, "PMIX_SIZE", " 6\n", Some(6)),
            (SIZE_VARS, "MV2_COMM_WORLD_SIZE", "2", Some(2)),
            (SIZE_VARS, "SLURM_STEP_NUM_TASKS", "8", Some(8)),
            (SIZE_VARS, "SLURM_STEP_NUM_TASKS", "x", None),
            (RANK_VARS, "OMPI_COMM_WORLD_RANK", "0", Some(0)),
            (RANK_VARS, "PMI_RANK", "2", Some(2)),
            (RANK_VARS, "PMIX_RANK", "5\n", Some(5)),
            (RANK_VARS, "MV2_COMM_WORLD_RANK", "1", Some(1)),
            (RANK_VARS, "SLURM_PROCID", "7", Some(7)),
            (RANK_VARS, "SLURM_PROCID", "", None),
            (SIZE_VARS, "OMPI_COMM_WORLD_RANK", "1", None),
            (RANK_VARS, "OMPI_COMM_WORLD_SIZE", "4", None),
        ];
        for (vars, name, value, want) in cases {
            assert_eq!(
                first_number(vars, env(&[(name, value)])),
                want,
                "{name}={value:?}"
            );
        }
        assert_eq!(first_number(SIZE_VARS, env(&[])), None);
        assert_eq!(first_number(RANK_VARS, env(&[])), None);
        // Open MPI's own variables first.
        let both = env(&[("SLURM_STEP_NUM_TASKS", "8"), ("OMPI_COMM_WORLD_SIZE", "4")]);
        assert_eq!(first_number(SIZE_VARS, both), Some(4));
        let both = env(&[("SLURM_PROCID", "3"), ("OMPI_COMM_WORLD_RANK", "1")]);
        assert_eq!(first_number(RANK_VARS, both), Some(1));
    }

    #[test]
    fn roles_for_every_size() {
        let two = Roles::new(2).unwrap();
        assert_eq!((two.balancer(), two.render_ranks()), (0, 1));
        assert_eq!(two.name(0), "display+balancer");
        assert_eq!(two.render_index(1), Some(0));
        for k in 3..9 {
            let r = Roles::new(k).unwrap();
            assert_eq!(r.balancer(), 1);
            assert_eq!(r.render_ranks(), k - 2);
            assert_eq!(r.render_index(0), None);
            assert_eq!(r.render_index(1), None);
            for i in 0..r.render_ranks() {
                assert_eq!(r.render_index(r.render_rank(i)), Some(i));
            }
            assert_eq!(r.render_index(k), None);
        }
        assert!(Roles::new(1).is_err());
    }
}
