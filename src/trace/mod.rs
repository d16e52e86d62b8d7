//! CPU tracing: the f64 reference tracer that is the oracle for the GPU kernels, and the
//! reference images of the shading modes.

pub mod cpu;
pub mod shade;
