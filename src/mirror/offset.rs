//! Secondary-ray origins, as `offset_ray` in `shaders/shared/offset.wgsl`: Wächter & Binder, "A
//! Fast and Robust Method for Avoiding Self-Intersection" (Ray Tracing Gems, chapter 6).

/// Coordinates smaller than this are offset by a fixed amount (ulps vanish near zero).
pub const ORIGIN: f32 = 1.0 / 32.0;
/// The fixed offset near zero, times the normal.
pub const FLOAT_SCALE: f32 = 1.0 / 65536.0;
/// Ulps per unit of the normal's component far from zero.
pub const INT_SCALE: f32 = 256.0;

/// `offset_ray`, bit for bit: `p` moved along `n` (a unit normal on the side the new ray
/// leaves to) by `256 n` ulps per component, or by `n / 65536` where a component is within 1/32
/// of zero. Non-finite inputs come back non-finite (the tracer treats such rays as misses).
pub fn offset_ray(p: [f32; 3], n: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|i| {
        if p[i].abs() < ORIGIN {
            p[i] + FLOAT_SCALE * n[i]
        } else {
            // `as` truncates towards zero (and saturates), as WGSL's f32 to i32 conversion does.
            let of = (INT_SCALE * n[i]) as i32;
            let of = if p[i] < 0.0 { -of } else { of };
            f32::from_bits((p[i].to_bits() as i32).wrapping_add(of) as u32)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_by_ulps_away_from_the_surface() {
        let p = [1.0e6, -3.0, 0.0];
        let o = offset_ray(p, [1.0, 0.0, 0.0]);
        assert_eq!(o[0].to_bits(), p[0].to_bits() + 256);
        assert_eq!(o[1], p[1]);
        assert_eq!(o[2], 0.0);
        // Negative coordinates move towards the normal too.
        let o = offset_ray(p, [0.0, 1.0, -1.0]);
        assert!(o[1] > p[1] && o[2] < 0.0);
        assert_eq!(o[1].to_bits(), p[1].to_bits() - 256);
        assert_eq!(o[2], -FLOAT_SCALE);
    }

    #[test]
    fn offset_moves_along_the_normal() {
        for p in [
            [1.0f32, -2.0, 3.0e5],
            [0.001, -0.001, 0.0],
            [-7.0e6, 1.0e-3, 5.0],
        ] {
            let n = [0.0f32, 0.6, 0.8];
            let q = offset_ray(p, n);
            assert_eq!(q[0], p[0], "a zero normal component moves nothing");
            assert!(q[1] > p[1] && q[2] > p[2], "{p:?} -> {q:?}");
        }
    }

    #[test]
    fn non_finite_stays_non_finite() {
        let o = offset_ray([f32::NAN, f32::INFINITY, 1.0], [0.0, 0.0, f32::NAN]);
        assert!(o[0].is_nan() && !o[1].is_finite());
        assert_eq!(o[2], 1.0);
    }
}
