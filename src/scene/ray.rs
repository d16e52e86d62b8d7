//! The ray both tracers take: the GPU's `Tracer::trace_rays` and the reference.

/// A ray: origin and direction in f32 as the GPU gets them (the direction need not be unit).
///
/// Hits are reported at `origin + t * dir` for `t` in `(0, tmax]` (`reference::Reference::closest_hit`, and the GPU's `Tracer::trace_rays`) or
/// `(0, tmax)` (`any_hit`); `t` is in units of `dir`'s length. A ray whose origin or
/// direction has a NaN or infinite component, whose direction is zero, or whose `tmax` is NaN or
/// not positive hits nothing. `tmax` may be `f32::INFINITY`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
    pub tmax: f32,
}
