//! One process of a cluster job: MPI set-up, start-up and agreement, then its role until the end
//! (docs/ARCHITECTURE.md, Cluster). Only the main thread calls MPI (`Threading::Funneled`).

use super::failure::Failure;
use super::live::LiveDisplay;
use super::startup::{self, Role};
use super::{Options, Roles, Serve, clock, coordinator, render_rank, rma};
use crate::error::{Error, Result};
use mpi::Threading;
use mpi::topology::Color;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::time::{Duration, Instant};

/// Runs this process's role; `serve` at the display of a live view (`Options::live`).
pub fn run(opts: &Options, serve: Option<&mut Serve<'_>>) -> Result<()> {
    let (universe, _) = mpi::initialize_with_threading(Threading::Funneled)
        .ok_or_else(|| Error::Mpi("MPI is already initialised".into()))?;
    let world = universe.world();
    let rank = world.rank() as u32;
    let roles = Roles::new(world.size() as u32)?;
    // From here a panic anywhere must take the job down, not leave the others waiting.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default_hook(info);
        crate::report!("rank {rank}: panic: aborting the job");
        rma::abort_world(101);
    }));

    let Some(opened) = startup::start(&world, opts, roles, rank) else {
        drop(universe);
        std::process::exit(1);
    };

    // Render ranks get a communicator of their own for the block window.
    let color = match roles.render_index(rank) {
        Some(_) => Color::with_value(0),
        None => Color::undefined(),
    };
    let render_comm = world.split_by_color(color);
    // Trace times count from one barrier on every rank, so that tools can line the ranks up.
    clock::agree(&world);
    let result = match (opened.role, render_comm) {
        (Role::Render(r), Some(comm)) => render_rank::run(&world, &comm, roles, rank, opts, *r),
        (Role::Coordinator, _) if opts.live && rank == Roles::DISPLAY => match serve {
            Some(serve) => LiveDisplay::start(&world, roles, opts, opened.image, opened.shading)
                .and_then(|mut d| serve(&mut d)),
            None => Err(Error::Internal("a live view without a server".into())),
        },
        (Role::Coordinator, _) => {
            coordinator::run(&world, roles, rank, opts, opened.image, opened.legend)
        }
        _ => Err(Error::Mpi("a render rank without its communicator".into())),
    };
    if let Err(e) = result {
        crate::report!("rank {rank}: error: {e}");
        rma::abort_world(1);
    }
    Failure::from_env(rank).at_end();
    last_barrier(&world, rank, opts.timeout);
    Ok(())
}

/// The job's last barrier, bounded by the timeout like every other wait: a rank that hangs
/// after its work would otherwise keep every other rank in a blocking barrier for ever.
fn last_barrier(world: &SimpleCommunicator, rank: u32, timeout: Duration) {
    let start = Instant::now();
    let mut request = world.immediate_barrier();
    loop {
        request = match request.test() {
            Ok(_) => return,
            Err(r) => r,
        };
        if start.elapsed() > timeout {
            crate::report!(
                "rank {rank}: error: not every rank reached the end of the job within {} s: a \
                 rank has hung or died",
                timeout.as_secs_f64()
            );
            rma::abort_world(1);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
