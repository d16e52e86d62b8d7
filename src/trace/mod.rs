//! CPU tracing: the f64 reference tracer that is the oracle for the GPU kernels, and the
//! self-intersection offset of secondary-ray origins.

pub mod cpu;
pub mod offset;
pub mod shade;
