//! The sampler and the hemisphere mapping of `shaders/shared/sampling.wgsl`.

/// `hash` (lowbias32, C. Wellons), bit for bit.
pub fn hash(x: u32) -> u32 {
    let mut v = x;
    v ^= v >> 16;
    v = v.wrapping_mul(0x7feb_352d);
    v ^= v >> 15;
    v = v.wrapping_mul(0x846c_a68b);
    v ^= v >> 16;
    v
}

/// `sample2`, bit for bit: point `index` of the R2 sequence in 32-bit fixed point, rotated per
/// pixel and dimension pair by a hash. `seed` is the GPU's `params.seed`.
pub fn sample2(seed: u32, pixel: u32, dim: u32, index: u32) -> [f32; 2] {
    let h = hash(pixel ^ hash(dim.wrapping_mul(0x9e37_79b9).wrapping_add(seed)));
    let x = hash(h).wrapping_add(index.wrapping_mul(3_242_174_889));
    let y = hash(h ^ 0x68bc_21eb).wrapping_add(index.wrapping_mul(2_447_445_414));
    [(x >> 8) as f32, (y >> 8) as f32].map(|v| v * (1.0 / 16_777_216.0))
}

/// `cosine_dir`: a cosine-weighted direction about unit `n` from `u` in [0,1)^2, with the
/// branchless orthonormal basis of Duff et al. (JCGT 2017).
pub fn cosine_dir(n: [f32; 3], u: [f32; 2]) -> [f32; 3] {
    let s = if n[2] >= 0.0 { 1.0f32 } else { -1.0 };
    let a = -1.0 / (s + n[2]);
    let b = n[0] * n[1] * a;
    let t = [1.0 + s * n[0] * n[0] * a, s * b, -s * n[0]];
    let bt = [b, s + n[1] * n[1] * a, -n[1]];
    let r = u[0].sqrt();
    let phi = 2.0 * std::f32::consts::PI * u[1];
    let z = (1.0 - u[0]).max(0.0).sqrt();
    let d: [f32; 3] =
        std::array::from_fn(|i| r * phi.cos() * t[i] + r * phi.sin() * bt[i] + z * n[i]);
    let l = d.iter().map(|c| c * c).sum::<f32>().sqrt();
    if d.iter().all(|c| c.is_finite()) && l > 0.0 && l.is_finite() {
        d.map(|c| c / l)
    } else {
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampler_is_stratified_and_in_range() {
        // 64 points of one pixel's sequence fall in 64 different cells of an 8x8 grid at most
        // twice each (R2 is a low-discrepancy lattice; a random set would collide far more).
        let mut cells = [0u32; 64];
        for i in 0..64 {
            let [x, y] = sample2(7, 1234, 1, i);
            assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y));
            cells[(y * 8.0) as usize * 8 + (x * 8.0) as usize] += 1;
        }
        assert!(cells.iter().all(|&c| c <= 2), "{cells:?}");
        assert!(cells.iter().filter(|&&c| c > 0).count() >= 48);
    }

    #[test]
    fn cosine_directions_are_unit_and_above_the_surface() {
        let n = [0.0f32, -0.6, 0.8];
        for i in 0..256 {
            let d = cosine_dir(n, sample2(0, 5, 1, i));
            let len: f32 = d.iter().map(|c| c * c).sum::<f32>().sqrt();
            assert!((len - 1.0).abs() < 1e-5);
            assert!(d.iter().zip(n).map(|(a, b)| a * b).sum::<f32>() >= -1e-6);
        }
    }
}
