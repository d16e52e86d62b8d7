//! Secondary-ray origins, as in `shaders/shared/offset.wgsl` (pbrt-v4's `OffsetRayOrigin`): the
//! hit point, with a bound on its error, moves along the normal past that bound and then one
//! float further.

/// `offset_distance`: how far along unit normal `n` a point with per-coordinate error `err`
/// must move.
pub fn offset_distance(n: [f32; 3], err: [f32; 3]) -> f32 {
    n[0].abs() * err[0] + n[1].abs() * err[1] + n[2].abs() * err[2]
}

/// `next_up`: the next float above `x` (from either zero, the smallest positive one).
pub fn next_up(x: f32) -> f32 {
    let v = if x == 0.0 { 0.0f32 } else { x };
    let b = v.to_bits();
    f32::from_bits(if v >= 0.0 { b + 1 } else { b - 1 })
}

/// `next_down`: the next float below `x`.
pub fn next_down(x: f32) -> f32 {
    let v = if x == 0.0 { -0.0f32 } else { x };
    let b = v.to_bits();
    f32::from_bits(if v > 0.0 { b - 1 } else { b + 1 })
}

/// `offset_ray`: `p` moved `d` along unit normal `n` (pointing to the side the new ray leaves
/// on), each moved coordinate then one float further. `fused` computes `d * n + p` with one
/// rounding, as a GPU compiler that contracts to a fused multiply-add does; the guarantee holds
/// either way.
pub fn offset_ray_with(p: [f32; 3], n: [f32; 3], d: f32, fused: bool) -> [f32; 3] {
    std::array::from_fn(|i| {
        let offset = d * n[i];
        let q = if fused {
            d.mul_add(n[i], p[i])
        } else {
            p[i] + offset
        };
        if offset > 0.0 {
            next_up(q)
        } else if offset < 0.0 {
            next_down(q)
        } else {
            q
        }
    })
}

/// [`offset_ray_with`] without contraction, the arithmetic WGSL's `offset_ray` writes.
pub fn offset_ray(p: [f32; 3], n: [f32; 3], d: f32) -> [f32; 3] {
    offset_ray_with(p, n, d, false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_past_the_bound_and_one_float_further() {
        let p = [1.0e6f32, -3.0, 0.0];
        // A zero distance moves nothing; a tiny one moves the coordinate one float at least.
        assert_eq!(offset_ray(p, [1.0, 0.0, 0.0], 0.0), p);
        let o = offset_ray(p, [1.0, 0.0, 0.0], 1e-30);
        assert_eq!(o[0].to_bits(), p[0].to_bits() + 1);
        assert_eq!((o[1], o[2]), (p[1], p[2]));
        let o = offset_ray(p, [0.0, 0.6, -0.8], 0.5);
        assert_eq!(o[0], p[0]);
        assert!(
            o[1] > p[1] + 0.3 - 1e-6 && o[1] < p[1] + 0.3 + 1e-5,
            "{}",
            o[1]
        );
        assert!(o[2] < -0.4 && o[2] > -0.4 - 1e-6, "{}", o[2]);
        // From zero both ways.
        assert_eq!(next_up(0.0), f32::from_bits(1));
        assert_eq!(next_up(-0.0), f32::from_bits(1));
        assert_eq!(next_down(0.0), -f32::from_bits(1));
        assert_eq!(next_down(1.0), 1.0 - f32::EPSILON / 2.0);
        assert_eq!(next_up(-1.0), -1.0 + f32::EPSILON / 2.0);
    }

    #[test]
    fn distance_weighs_each_error_by_the_normal() {
        assert_eq!(
            offset_distance([0.0, -0.6, 0.8], [5.0, 1.0, 2.0]),
            0.6 + 1.6
        );
    }

    #[test]
    fn non_finite_stays_non_finite() {
        let o = offset_ray([f32::NAN, f32::INFINITY, 1.0], [0.0, 0.0, f32::NAN], 1.0);
        assert!(o[0].is_nan() && !o[1].is_finite() && o[2].is_nan());
    }
}
