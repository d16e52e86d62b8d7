//! The samplers and the hemisphere mapping of `shaders/shared/sampling.wgsl`.

use crate::shading::Sampler;

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

/// `owen`, bit for bit: a nested uniform (Owen) scramble of the base-2 digits of `x`, most
/// significant first, keyed by `seed`.
pub fn owen(x: u32, seed: u32) -> u32 {
    let mut v = x.reverse_bits();
    v ^= v.wrapping_mul(0x3d20_adea);
    v = v.wrapping_add(seed);
    v = v.wrapping_mul((seed >> 16) | 1);
    v ^= v.wrapping_mul(0x0552_6c56);
    v ^= v.wrapping_mul(0x53a2_2864);
    v.reverse_bits()
}

/// `sobol1`, bit for bit: Sobol' dimension 1 of point `i` in 32-bit fixed point.
pub fn sobol1(i: u32) -> u32 {
    let mut y = i;
    y ^= (y >> 1) & 0x5555_5555;
    y ^= (y >> 2) & 0x3333_3333;
    y ^= (y >> 4) & 0x0f0f_0f0f;
    y ^= (y >> 8) & 0x00ff_00ff;
    y ^= (y >> 16) & 0x0000_ffff;
    y.reverse_bits()
}

fn unit2(x: u32, y: u32) -> [f32; 2] {
    [(x >> 8) as f32, (y >> 8) as f32].map(|v| v * (1.0 / 16_777_216.0))
}

/// `sample2`, bit for bit: point `index` of dimension pair `dim` of pixel `pixel`'s samples.
/// `seed` is the GPU's `params.seed`; `sampler` its `SAMPLER_INDEPENDENT` flag.
pub fn sample2(sampler: Sampler, seed: u32, pixel: u32, dim: u32, index: u32) -> [f32; 2] {
    let key = hash(pixel ^ hash(dim.wrapping_mul(0x9e37_79b9).wrapping_add(seed)));
    match sampler {
        Sampler::Independent => {
            let k = hash(index ^ key);
            unit2(hash(k ^ 0x2c1b_3c6d), hash(k ^ 0x297a_2d39))
        }
        Sampler::Sobol => {
            let i = owen(index, hash(key ^ 0x68bc_21eb));
            let x = owen(i.reverse_bits(), hash(key ^ 0x02e5_be93));
            let y = owen(sobol1(i), hash(key ^ 0x967a_889b));
            unit2(x, y)
        }
    }
}

/// `sample2_patch`, bit for bit: `sample2`, except that with Sobol' the index shuffle and the
/// top two base-2 digits of each coordinate are keyed by the 4x2 patch of pixels that `pixel`
/// (`y * width + x`) lies in, the lower digits by the pixel: the k-th points of a patch's pixels
/// share one of 4x4 strata of [0,1)^2, and each pixel's points stay a scrambled (0,2)-sequence.
pub fn sample2_patch(
    sampler: Sampler,
    seed: u32,
    pixel: u32,
    width: u32,
    dim: u32,
    index: u32,
) -> [f32; 2] {
    if sampler == Sampler::Independent {
        return sample2(sampler, seed, pixel, dim, index);
    }
    let (x0, y0) = (pixel % width, pixel / width);
    let pair = hash(dim.wrapping_mul(0x9e37_79b9).wrapping_add(seed));
    let key = hash(pixel ^ pair);
    let group = hash(((y0 >> 1).wrapping_mul(width).wrapping_add(x0 >> 2)) ^ pair ^ 0x5bd1_e995);
    let i = owen(index, hash(group ^ 0x68bc_21eb));
    let x = owen(i.reverse_bits(), hash(group ^ 0x02e5_be93));
    let y = owen(sobol1(i), hash(group ^ 0x967a_889b));
    unit2(
        below_strata(x, hash(key ^ 0x02e5_be93)),
        below_strata(y, hash(key ^ 0x967a_889b)),
    )
}

/// `below_strata`: `x` with its top two digits kept and the others scrambled by `seed`.
fn below_strata(x: u32, seed: u32) -> u32 {
    (x & 0xc000_0000) | (owen(x, seed) & 0x3fff_ffff)
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

    /// Sobol' dimension 1 the textbook way: the direction numbers v_0 = 1/2,
    /// v_k = v_{k-1} xor v_{k-1} / 2, xor-ed for the set bits of i.
    fn sobol1_by_directions(i: u32) -> u32 {
        let mut v = 0x8000_0000u32;
        let mut x = 0;
        for bit in 0..32 {
            if (i >> bit) & 1 == 1 {
                x ^= v;
            }
            v ^= v >> 1;
        }
        x
    }

    #[test]
    fn sobol1_matches_its_direction_numbers() {
        let mut r = 0x1234_5678u32;
        for i in (0..4096).chain((0..4096).map(|_| {
            r = hash(r);
            r
        })) {
            assert_eq!(sobol1(i), sobol1_by_directions(i), "point {i}");
        }
    }

    #[test]
    fn owen_permutes_aligned_blocks() {
        // Scrambling is a bijection of every aligned block of 2^k values: the first 2^k points
        // of a scrambled (0,2)-sequence are still a net.
        for seed in [0u32, 1, 0xdead_beef, 0x8000_0001] {
            for k in [1u32, 4, 10] {
                let n = 1u32 << k;
                let mut seen: Vec<u32> = (0..n).map(|i| owen(i, seed)).collect();
                let block = seen[0] >> k;
                assert!(seen.iter().all(|v| v >> k == block), "seed {seed} k {k}");
                seen.sort_unstable();
                seen.dedup();
                assert_eq!(seen.len() as u32, n, "seed {seed} k {k}: a permutation");
            }
        }
    }

    #[test]
    fn sobol_pairs_are_nets_and_in_range() {
        // The first 64 points of every pair of a pixel put exactly one point in each cell of
        // every 2^a x 2^b grid with a + b = 6: a (0,6,2)-net. Independent points collide.
        for dim in [0u32, 1, 2, 7] {
            let pts: Vec<[f32; 2]> = (0..64)
                .map(|i| sample2(Sampler::Sobol, 7, 1234, dim, i))
                .collect();
            for a in 0..=6 {
                let (nx, ny) = (1usize << a, 1usize << (6 - a));
                let mut cells = vec![0u32; 64];
                for [x, y] in &pts {
                    assert!((0.0..1.0).contains(x) && (0.0..1.0).contains(y));
                    cells[(y * ny as f32) as usize * nx + (x * nx as f32) as usize] += 1;
                }
                assert!(cells.iter().all(|&c| c == 1), "dim {dim}, {nx}x{ny}");
            }
        }
        let mut cells = [0u32; 64];
        for i in 0..64 {
            let [x, y] = sample2(Sampler::Independent, 7, 1234, 1, i);
            assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y));
            cells[(y * 8.0) as usize * 8 + (x * 8.0) as usize] += 1;
        }
        assert!(
            cells.iter().any(|&c| c > 1),
            "independent points are not a net"
        );
    }

    /// Which of the 4x4 strata of [0,1)^2 a point lies in.
    fn stratum([x, y]: [f32; 2]) -> (u32, u32) {
        ((x * 4.0) as u32, (y * 4.0) as u32)
    }

    #[test]
    fn patch_samples_share_strata_across_a_patch_and_stay_nets_per_pixel() {
        let width = 37;
        let at = |x: u32, y: u32| y * width + x;
        let point = |pixel, i| sample2_patch(Sampler::Sobol, 7, pixel, width, 1, i);
        // Each pixel's 64 first points are a (0,6,2)-net, as sample2's are.
        for pixel in [at(0, 0), at(5, 3), at(36, 9)] {
            for a in 0..=6 {
                let (nx, ny) = (1usize << a, 1usize << (6 - a));
                let mut cells = vec![0u32; 64];
                for i in 0..64 {
                    let [x, y] = point(pixel, i);
                    assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y));
                    cells[(y * ny as f32) as usize * nx + (x * nx as f32) as usize] += 1;
                }
                assert!(cells.iter().all(|&c| c == 1), "pixel {pixel}, {nx}x{ny}");
            }
        }
        // Point i of every pixel of the patch at x 4..8, y 2..4 is in one stratum, not at one
        // place; the patches beside it take other strata for some i.
        let mut differs = [0u32; 4];
        for i in 0..256 {
            let first = point(at(4, 2), i);
            for (x, y) in (4..8).flat_map(|x| (2..4).map(move |y| (x, y))) {
                let p = point(at(x, y), i);
                assert_eq!(stratum(p), stratum(first), "point {i} of pixel ({x}, {y})");
                assert!(
                    (x, y) == (4, 2) || p != first,
                    "point {i} of ({x}, {y}) repeats (4, 2)'s"
                );
            }
            for (n, (x, y)) in [(3, 2), (8, 2), (4, 1), (4, 4)].into_iter().enumerate() {
                differs[n] += u32::from(stratum(point(at(x, y), i)) != stratum(first));
            }
        }
        assert!(
            differs.iter().all(|&d| d > 128),
            "neighbouring patches: {differs:?}"
        );
        // Independent samples are sample2's.
        for i in 0..64 {
            assert_eq!(
                sample2_patch(Sampler::Independent, 7, at(5, 5), width, 1, i),
                sample2(Sampler::Independent, 7, at(5, 5), 1, i)
            );
        }
    }

    #[test]
    fn pairs_are_decorrelated_within_a_pixel() {
        // One pixel's 1024 samples of the depth-0 and depth-1 bounce pairs (2 and 4), as points
        // (x of one, x of the other) on a 16x16 grid: independent dimensions fill nearly every
        // cell (about 5 of 256 stay empty); dimensions that are one sequence shifted put the
        // points on a line and fill a few dozen.
        for sampler in [Sampler::Sobol, Sampler::Independent] {
            for pixel in [0u32, 99, 4242] {
                let mut cells = [false; 256];
                for i in 0..1024 {
                    let a = sample2(sampler, 3, pixel, 2, i)[0];
                    let b = sample2(sampler, 3, pixel, 4, i)[0];
                    cells[(b * 16.0) as usize * 16 + (a * 16.0) as usize] = true;
                }
                let filled = cells.iter().filter(|&&c| c).count();
                assert!(
                    filled >= 236,
                    "{sampler:?}, pixel {pixel}: {filled} of 256 cells"
                );
            }
        }
    }

    #[test]
    fn cosine_directions_are_unit_and_above_the_surface() {
        let n = [0.0f32, -0.6, 0.8];
        for i in 0..256 {
            let d = cosine_dir(n, sample2(Sampler::Sobol, 0, 5, 1, i));
            let len: f32 = d.iter().map(|c| c * c).sum::<f32>().sqrt();
            assert!((len - 1.0).abs() < 1e-5);
            assert!(d.iter().zip(n).map(|(a, b)| a * b).sum::<f32>() >= -1e-6);
        }
    }
}
