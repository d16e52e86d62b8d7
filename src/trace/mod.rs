//! Secondary-ray origins: the self-intersection offset. (The f64 reference tracer is
//! `crate::reference`.)

pub mod offset;
