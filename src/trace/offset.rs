//! Secondary-ray origins that cannot hit the surface they leave: the hit point is moved along
//! the geometric normal by a number of ulps of its own coordinates (Wächter & Binder, "A Fast and
//! Robust Method for Avoiding Self-Intersection", Ray Tracing Gems, chapter 6), not by a fixed
//! epsilon that is too small far from the origin and too large near it. The shading kernels
//! implement the same function in WGSL; this one serves the host and the tests.

/// Coordinates smaller than this are offset by a fixed amount (ulps vanish near zero).
const ORIGIN: f32 = 1.0 / 32.0;
/// The fixed offset near zero, times the normal.
const FLOAT_SCALE: f32 = 1.0 / 65536.0;
/// Ulps per unit of the normal's component far from zero.
const INT_SCALE: f32 = 256.0;

/// `p` moved off the surface along `n` (a unit normal pointing to the side the new ray leaves
/// on): by `256 n` ulps of each coordinate, or by `n / 65536` for coordinates below 1/32.
/// Non-finite inputs come back non-finite (the tracer treats such rays as misses).
pub fn offset_ray_origin(p: [f32; 3], n: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|a| {
        // `as` saturates and maps NaN to 0; |n| <= 1 keeps it far from the limits anyway.
        let of = (INT_SCALE * n[a]) as i32;
        let of = if p[a] < 0.0 { -of } else { of };
        let moved = f32::from_bits((p[a].to_bits() as i32).wrapping_add(of) as u32);
        if p[a].abs() < ORIGIN {
            p[a] + FLOAT_SCALE * n[a]
        } else {
            moved
        }
    })
}

/// [`offset_ray_origin`] for a hit point whose triangle has coordinates up to `scale` in
/// magnitude. The intersection test computes the vertices relative to the ray origin, so its
/// rounding is relative to the vertices, not to `p`: where `|p_i| < scale` (a hit near zero on a
/// triangle with far vertices, possible when coordinates have mixed signs) the coordinate moves
/// by `256 n_i` ulps of `scale` instead of ulps of `p_i`. With `scale <= |p_i|` this is exactly
/// the Ray Tracing Gems offset.
pub fn offset_ray_origin_scaled(p: [f32; 3], n: [f32; 3], scale: f32) -> [f32; 3] {
    let exact = offset_ray_origin(p, n);
    let scale = scale.abs();
    if !scale.is_finite() || scale < ORIGIN {
        return exact;
    }
    // The ulp of `scale`: its exponent with a mantissa of one.
    let ulp = f32::from_bits(scale.to_bits() & 0x7f80_0000) * f32::EPSILON;
    std::array::from_fn(|a| {
        if p[a].abs() >= scale {
            exact[a]
        } else {
            p[a] + n[a] * INT_SCALE * ulp
        }
    })
}

/// The largest coordinate magnitude of a triangle: the `scale` of [`offset_ray_origin_scaled`].
pub fn triangle_scale(tri: &[[f32; 3]; 3]) -> f32 {
    tri.iter().flatten().fold(0.0f32, |m, c| m.max(c.abs()))
}

/// The origin of a ray leaving a surface at `p` with geometric normal `n` (either orientation)
/// in direction `w`, on a triangle of coordinates up to `scale`: offset to the side `w` points
/// to.
pub fn spawn_origin(p: [f32; 3], n: [f32; 3], w: [f32; 3], scale: f32) -> [f32; 3] {
    let d: f32 = (0..3).map(|a| n[a] * w[a]).sum();
    let n = if d < 0.0 { n.map(|c| -c) } else { n };
    offset_ray_origin_scaled(p, n, scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_by_ulps_away_from_the_surface() {
        let p = [1.0e6, -3.0, 0.0];
        let o = offset_ray_origin(p, [1.0, 0.0, 0.0]);
        assert_eq!(o[0].to_bits(), p[0].to_bits() + 256);
        assert_eq!(o[1], p[1]);
        assert_eq!(o[2], 0.0);
        // Negative coordinates move towards the normal too.
        let o = offset_ray_origin(p, [0.0, 1.0, -1.0]);
        assert!(o[1] > p[1] && o[2] < 0.0);
        assert_eq!(o[1].to_bits(), p[1].to_bits() - 256);
        assert_eq!(o[2], -FLOAT_SCALE);
        // The side follows the new direction.
        let s = spawn_origin(p, [1.0, 0.0, 0.0], [-0.5, 0.5, 0.0], 0.0);
        assert!(s[0] < p[0]);
    }

    #[test]
    fn scaled_offset_follows_the_triangle_magnitude() {
        let p = [1.0e6, -3.0, 0.0];
        let n = [0.6, 0.8, 0.0];
        // No vertex larger than the point: the Ray Tracing Gems offset exactly.
        assert_eq!(offset_ray_origin_scaled(p, n, 0.0), offset_ray_origin(p, n));
        // Vertices up to 1e6: x moves by ulps of itself, y by 0.8 * 256 ulps of 1e6 (1/16).
        let o = offset_ray_origin_scaled(p, n, 1.0e6);
        assert_eq!(o[0], offset_ray_origin(p, n)[0]);
        assert!((o[1] - 9.8).abs() < 1e-5, "{}", o[1]);
        assert_eq!(o[2], 0.0);
    }

    #[test]
    fn non_finite_stays_non_finite() {
        let o = offset_ray_origin([f32::NAN, f32::INFINITY, 1.0], [0.0, 0.0, f32::NAN]);
        assert!(o[0].is_nan() && !o[1].is_finite());
        assert_eq!(o[2], 1.0);
    }
}
