//! The integration tests: one binary, a module per area. GPU tests run on whatever adapter
//! `Gpu::new` picks (lavapipe on machines without a GPU); nextest gives each a timeout.

// The tests print with `eprintln!`, which the test harness captures (a plain write to stderr
// would not be); `dcrt::report!` is for the crate's own messages.
#![allow(clippy::disallowed_macros)]

mod bad_input;
mod cli;
mod cluster;
mod color;
mod common;
mod convergence;
mod dc;
mod docs;
mod frames;
mod gpu_vs_cpu;
mod layout;
mod limits;
mod mirror;
mod outputs;
mod plot;
mod prepare;
mod robust;
mod scale;
mod shaders;
mod shading;
mod soak;
mod tools;
mod trace_loop;
mod view;
