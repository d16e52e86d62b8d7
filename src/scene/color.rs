//! Colouring a mesh by one of its data arrays (ParaView's "Color By").

use super::data::Values;

/// The scalar of tuple `t`: the value itself, or the magnitude of a multi-component tuple (as
/// ParaView colours vectors by default).
pub fn scalar(v: &Values, t: usize) -> f32 {
    let c = v.components.max(1);
    let tuple = &v.data[t * c..(t + 1) * c];
    if c == 1 {
        tuple[0]
    } else {
        tuple
            .iter()
            .map(|x| f64::from(*x).powi(2))
            .sum::<f64>()
            .sqrt() as f32
    }
}

/// The range of an array's scalars over its finite values (`None` when there is none), as
/// ParaView's "Rescale to Data Range" takes it.
pub fn range_of(v: &Values) -> Option<(f32, f32)> {
    let mut r: Option<(f32, f32)> = None;
    for t in 0..v.tuples() {
        let s = scalar(v, t);
        if s.is_finite() {
            r = Some(r.map_or((s, s), |(lo, hi)| (lo.min(s), hi.max(s))));
        }
    }
    r
}
