//! CPU twins of shared WGSL functions, each named after the WGSL function it mirrors and tested
//! against it through the `mirror` kernel (`tests/all/mirror.rs`): the host and the CPU reference
//! use these where they must agree with the GPU. Integer functions agree bit for bit; float ones
//! within a few ulps (WGSL allows less precise `cos`, `sqrt` and division).

pub mod colormap;
pub mod offset;
pub mod sampling;
pub mod tiles;
