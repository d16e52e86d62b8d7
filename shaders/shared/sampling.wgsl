// The sampler and the hemisphere mapping. Integer arithmetic for the sampler, so the CPU mirrors
// in mirror::sampling compute the same bits.
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

// The R2 sequence (Roberts 2018) in 32-bit fixed point, rotated per pixel and dimension pair by
// a hash (Cranley-Patterson). Mirrored by mirror::sampling::sample2.
fn sample2(pixel: u32, dim: u32, index: u32) -> vec2<f32> {
    let h = hash(pixel ^ hash(dim * 0x9e3779b9u + params.seed));
    let x = hash(h) + index * 3242174889u;
    let y = hash(h ^ 0x68bc21ebu) + index * 2447445414u;
    return vec2(f32(x >> 8u), f32(y >> 8u)) * (1.0 / 16777216.0);
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
