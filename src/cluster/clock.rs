//! The job's common clock and run id (docs/ARCHITECTURE.md, Traces): every rank leaves one
//! barrier, takes that instant as the epoch its trace times count from, and notes `MPI_Wtime`
//! there; rank 0's run id is broadcast so that all ranks' traces name the same run.

use crate::traces::record::{self, Run};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::time::Instant;

/// Collective: every rank of `world` calls it once, before its role starts.
pub fn agree(world: &SimpleCommunicator) {
    let mut id = [0u64; 2];
    if world.rank() == 0 {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        id = [nanos, u64::from(std::process::id())];
    }
    world.process_at_rank(0).broadcast_into(&mut id[..]);
    world.barrier();
    record::set_epoch(Instant::now());
    record::set_run(Run {
        run: record::run_id(id[0], id[1] as u32),
        epoch_wtime: Some(mpi::time()),
    });
}

/// The instant the ranks left the barrier (now, if `agree` was not called).
pub fn epoch() -> Instant {
    record::epoch()
}
