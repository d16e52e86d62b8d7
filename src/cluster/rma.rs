//! One-sided MPI over `mpi::ffi`: all of dcrt's unsafe code but one call
//! (`gpu::trusted`). rsmpi 0.8 has no safe RMA API, so
//! this module wraps the few window calls the distributed cache needs (chapter 5.3: a render rank
//! reads a borrowed block straight out of its owner's memory with a passive `MPI_Get`) and MPI
//! progress polling for ranks that wait on their GPU.
#![allow(unsafe_code)]

use crate::error::{Error, Result};
use mpi::ffi;
use mpi::raw::AsRaw;
use mpi::topology::SimpleCommunicator;
use std::os::raw::c_int;

fn check(what: &str, code: c_int) -> Result<()> {
    if code == ffi::MPI_SUCCESS as c_int {
        Ok(())
    } else {
        Err(Error::Mpi(format!("{what} failed with MPI error {code}")))
    }
}

/// A window over the blocks this rank owns, in slot order: `words` u32 per block.
pub struct Window {
    win: ffi::MPI_Win,
    /// Words exposed, in memory MPI allocated (and frees in `MPI_Win_free`).
    words: usize,
}

impl Window {
    /// Collective over `comm`: every member exposes a copy of `memory` (possibly empty) for
    /// reading. MPI allocates the exposed memory (`MPI_Win_allocate`), so that each transport
    /// can place it where its Gets are cheapest (a shared segment on one node). Over Open MPI
    /// 4.1's osc ucx, windows created on our own heap memory (`MPI_Win_create`) corrupted the
    /// heap or hung in about a third of the runs of 6 ranks on a 1M-triangle model; with
    /// allocated windows 39 of 39 such runs passed.
    pub fn create(comm: &SimpleCommunicator, memory: &[u32]) -> Result<Window> {
        let bytes = (memory.len() * 4) as ffi::MPI_Aint;
        let mut base: *mut u32 = std::ptr::null_mut();
        let mut win: ffi::MPI_Win = unsafe { ffi::RSMPI_WIN_NULL };
        // SAFETY: MPI writes the address of `bytes` new bytes into `base`, and the window into
        // `win`.
        check("MPI_Win_allocate", unsafe {
            ffi::MPI_Win_allocate(
                bytes,
                4,
                ffi::RSMPI_INFO_NULL,
                comm.as_raw(),
                (&mut base as *mut *mut u32).cast(),
                &mut win,
            )
        })?;
        if !memory.is_empty() {
            // SAFETY: `base` holds `memory.len()` u32 (MPI memory is aligned for any type), and
            // no other rank reads it before the first Get, which comes after the frame's first
            // message, well after this copy.
            unsafe { std::ptr::copy_nonoverlapping(memory.as_ptr(), base, memory.len()) };
        }
        // One passive-target epoch for the window's whole life, opened while every rank is
        // known to be alive: over osc ucx lock_all waits on every target, so an epoch a round
        // would hang on a stopped rank that the round does not even read from.
        // SAFETY: the window was just created; unlocked in `drop` before it is freed.
        check("MPI_Win_lock_all", unsafe { ffi::MPI_Win_lock_all(0, win) })?;
        Ok(Window {
            win,
            words: memory.len(),
        })
    }

    /// Bytes this rank exposes.
    pub fn exposed_bytes(&self) -> u64 {
        self.words as u64 * 4
    }

    /// Reads each `(target rank, word offset)` piece of `words` u32 into the matching piece of
    /// `out`: a request-based Get each in the window's epoch, tested until all are in. `out.len()` must be `gets.len() * words`. While some are not in,
    /// `waiting` is called between tests with the target ranks still owed (so that the caller
    /// can tell the others it waits, and give up): a Get to a stopped rank never completes over
    /// TCP. If `waiting` gives up, the read cannot be abandoned (MPI still owns `out`): the error
    /// is reported and the job aborted here.
    pub fn get_all(
        &self,
        gets: &[(u32, u64)],
        words: usize,
        out: &mut [u32],
        waiting: &mut dyn FnMut(&[u32]) -> Result<()>,
    ) -> Result<()> {
        if out.len() != gets.len() * words {
            return Err(Error::Mpi(format!(
                "{} words of room for {} blocks of {words}",
                out.len(),
                gets.len()
            )));
        }
        let count =
            c_int::try_from(words).map_err(|_| Error::Mpi(format!("{words} words in one Get")))?;
        // SAFETY: the window is live and in its epoch; `u32` matches MPI_UINT32_T; each
        // destination piece is `words` u32 inside `out`, which outlives every request: each is
        // tested to completion below, or the process aborts while one is still open.
        unsafe {
            let mut result = Ok(());
            let mut requests = Vec::with_capacity(gets.len());
            for (&(rank, disp), dst) in gets.iter().zip(out.chunks_mut(words)) {
                let mut request = ffi::RSMPI_REQUEST_NULL;
                result = check(
                    "MPI_Rget",
                    ffi::MPI_Rget(
                        dst.as_mut_ptr().cast(),
                        count,
                        ffi::RSMPI_UINT32_T,
                        rank as c_int,
                        disp as ffi::MPI_Aint,
                        count,
                        ffi::RSMPI_UINT32_T,
                        self.win,
                        &mut request,
                    ),
                );
                if result.is_err() {
                    break;
                }
                requests.push((request, rank));
            }
            while result.is_ok() && !requests.is_empty() {
                let mut owed = Vec::new();
                let mut kept = Vec::with_capacity(requests.len());
                for (mut request, rank) in requests {
                    let mut done: c_int = 0;
                    let test = check(
                        "MPI_Test",
                        ffi::MPI_Test(&mut request, &mut done, ffi::RSMPI_STATUS_IGNORE),
                    );
                    if test.is_err() {
                        result = test;
                    }
                    if done == 0 && result.is_ok() {
                        kept.push((request, rank));
                        if !owed.contains(&rank) {
                            owed.push(rank);
                        }
                    }
                }
                requests = kept;
                if !requests.is_empty()
                    && result.is_ok()
                    && let Err(e) = waiting(&owed)
                {
                    crate::report!("error: {e}");
                    abort_world(1);
                }
            }
            if let Err(e) = &result
                && !requests.is_empty()
            {
                // A Get failed with others in flight: they would write into `out` later.
                crate::report!("error: {e}");
                abort_world(1);
            }
            result
        }
    }
}

impl Drop for Window {
    fn drop(&mut self) {
        // SAFETY: collective; every member drops its window at the same point of the protocol
        // (after the last frame). The memory is released after the window.
        unsafe {
            ffi::MPI_Win_unlock_all(self.win);
            ffi::MPI_Win_free(&mut self.win);
        }
    }
}

/// Lets MPI make progress on what other ranks asked of this one (a passive Get over TCP is only
/// served when the target enters MPI): one non-blocking probe on MPI_COMM_WORLD.
pub fn poll_world() {
    let mut flag: c_int = 0;
    // SAFETY: called only between MPI_Init and MPI_Finalize (the hook is installed and removed
    // by the cluster code inside that span); status is ignored.
    unsafe {
        ffi::MPI_Iprobe(
            ffi::RSMPI_ANY_SOURCE,
            ffi::RSMPI_ANY_TAG,
            ffi::RSMPI_COMM_WORLD,
            &mut flag,
            ffi::RSMPI_STATUS_IGNORE,
        );
    }
}

/// Ends the whole job from any thread (the panic hook): `MPI_Abort` on MPI_COMM_WORLD.
pub fn abort_world(code: i32) -> ! {
    // SAFETY: MPI_Abort may be called from any state after MPI_Init.
    unsafe {
        ffi::MPI_Abort(ffi::RSMPI_COMM_WORLD, code);
    }
    std::process::exit(code)
}
