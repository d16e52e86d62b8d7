// The samplers and the hemisphere mapping. Integer arithmetic for the samplers, so the CPU
// mirrors in mirror::sampling compute the same bits (docs/ARCHITECTURE.md, Shading).
#import params

const PI: f32 = 3.14159265358979;

// lowbias32 (C. Wellons). Mirrored by mirror::sampling::hash.
fn hash(x: u32) -> u32 {
    var v = x;
    v ^= v >> 16u;
    v *= 0x7feb352du;
    v ^= v >> 15u;
    v *= 0x846ca68bu;
    v ^= v >> 16u;
    return v;
}

// A nested uniform (Owen) scramble of the base-2 digits of x, most significant first, keyed by
// seed: a hash in which each output bit depends only on itself and more significant input bits
// (Laine and Karras; constants of N. Vegdahl), applied to the reversed word. A bijection of
// every aligned block of 2^k values onto an aligned block. Mirrored by mirror::sampling::owen.
fn owen(x: u32, seed: u32) -> u32 {
    var v = reverseBits(x);
    v ^= v * 0x3d20adeau;
    v += seed;
    v *= (seed >> 16u) | 1u;
    v ^= v * 0x05526c56u;
    v ^= v * 0x53a22864u;
    return reverseBits(v);
}

// Sobol' dimension 1 of point i in 32-bit fixed point. Its generator matrix is Pascal's triangle
// mod 2: digit r (weight 2^-(r+1)) is the parity of the bits c of i with c a superset of r
// (Lucas), a superset sum in five shift steps instead of a loop over the bits.
// Mirrored by mirror::sampling::sobol1.
fn sobol1(i: u32) -> u32 {
    var y = i;
    y ^= (y >> 1u) & 0x55555555u;
    y ^= (y >> 2u) & 0x33333333u;
    y ^= (y >> 4u) & 0x0f0f0f0fu;
    y ^= (y >> 8u) & 0x00ff00ffu;
    y ^= (y >> 16u) & 0x0000ffffu;
    return reverseBits(y);
}

fn unit2(x: u32, y: u32) -> vec2<f32> {
    return vec2(f32(x >> 8u), f32(y >> 8u)) * (1.0 / 16777216.0);
}

// Point `index` of dimension pair `dim` of a pixel's samples, in [0,1)^2.
// Sobol' (default): per (seed, pixel, pair), the index is shuffled by an Owen scramble, then
// Sobol' dimensions 0 and 1 of the shuffled index are Owen-scrambled with seeds of their own
// (Burley, JCGT 2020): each pair is a (0,2)-sequence, and pairs are independent of each other.
// With SAMPLER_INDEPENDENT: two hashes of (seed, pixel, pair, index), independent uniforms.
// Mirrored by mirror::sampling::sample2.
fn sample2(pixel: u32, dim: u32, index: u32) -> vec2<f32> {
    let key = hash(pixel ^ hash(dim * 0x9e3779b9u + params.seed));
    if (params.flags & SAMPLER_INDEPENDENT) != 0u {
        let k = hash(index ^ key);
        return unit2(hash(k ^ 0x2c1b3c6du), hash(k ^ 0x297a2d39u));
    }
    let i = owen(index, hash(key ^ 0x68bc21ebu));
    let x = owen(reverseBits(i), hash(key ^ 0x02e5be93u));
    let y = owen(sobol1(i), hash(key ^ 0x967a889bu));
    return unit2(x, y);
}

// Point `index` of dimension pair `dim` as sample2 gives it, except that with Sobol' the index
// shuffle and the top two base-2 digits of each coordinate (which of 4x4 strata of [0,1)^2 the
// point lies in) are keyed by the pixel's 4x2 patch (x / 4, y / 2 of pixel = y * width + x), and
// only the lower digits by the pixel: the k-th points of a patch's pixels share a stratum, so a
// subgroup's k-th AO rays (a 4x2 patch in Z order, tiles.wgsl) leave in nearly one direction
// from nearly one place and traverse alike. A nested scramble of a nested scramble, so each
// pixel's points are still a scrambled (0,2)-sequence, as unbiased and as stratified as
// sample2's; the patch's pixels' errors are correlated instead of independent. Mirrored by
// mirror::sampling::sample2_patch.
fn sample2_patch(pixel: u32, width: u32, dim: u32, index: u32) -> vec2<f32> {
    if (params.flags & SAMPLER_INDEPENDENT) != 0u {
        return sample2(pixel, dim, index);
    }
    let x0 = pixel % width;
    let y0 = pixel / width;
    let pair = hash(dim * 0x9e3779b9u + params.seed);
    let key = hash(pixel ^ pair);
    let group = hash(((y0 >> 1u) * width + (x0 >> 2u)) ^ pair ^ 0x5bd1e995u);
    let i = owen(index, hash(group ^ 0x68bc21ebu));
    let x = owen(reverseBits(i), hash(group ^ 0x02e5be93u));
    let y = owen(sobol1(i), hash(group ^ 0x967a889bu));
    return unit2(below_strata(x, hash(key ^ 0x02e5be93u)), below_strata(y, hash(key ^ 0x967a889bu)));
}

// x with its top two digits kept and the others scrambled by `seed` (a nested scramble of them).
fn below_strata(x: u32, seed: u32) -> u32 {
    return (x & 0xc0000000u) | (owen(x, seed) & 0x3fffffffu);
}

// Cosine-weighted direction about unit n from u in [0,1)^2, with the branchless orthonormal
// basis of Duff et al. (JCGT 2017). Mirrored by mirror::sampling::cosine_dir.
fn cosine_dir(n: vec3<f32>, u: vec2<f32>) -> vec3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    let t = vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    let bt = vec3(b, s + n.y * n.y * a, -n.y);
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    return normalize(r * cos(phi) * t + r * sin(phi) * bt + sqrt(max(0.0, 1.0 - u.x)) * n);
}
