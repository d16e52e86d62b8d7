//! CPU tracing: the f64 reference tracer that is the oracle for the GPU kernels.

pub mod cpu;
pub mod shade;
