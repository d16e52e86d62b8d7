//! One process of a cluster job: MPI set-up, start-up and agreement, then its role until the end
//! (docs/ARCHITECTURE.md, Cluster). Only the main thread calls MPI (`Threading::Funneled`).

use super::startup::{self, Role};
use super::{Options, Roles, clock, coordinator, render_rank, rma};
use crate::error::{Error, Result};
use mpi::Threading;
use mpi::topology::Color;
use mpi::traits::*;

pub fn run(opts: &Options) -> Result<()> {
    let (universe, _) = mpi::initialize_with_threading(Threading::Funneled)
        .ok_or_else(|| Error::Mpi("MPI is already initialised".into()))?;
    let world = universe.world();
    let rank = world.rank() as u32;
    let roles = Roles::new(world.size() as u32)?;
    // From here a panic anywhere must take the job down, not leave the others waiting.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default_hook(info);
        eprintln!("rank {rank}: panic: aborting the job");
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
        (Role::Coordinator, _) => coordinator::run(&world, roles, rank, opts, opened.image),
        _ => Err(Error::Mpi("a render rank without its communicator".into())),
    };
    if let Err(e) = result {
        eprintln!("rank {rank}: error: {e}");
        rma::abort_world(1);
    }
    world.barrier();
    Ok(())
}
