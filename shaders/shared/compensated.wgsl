// Dot products beyond f32's precision, for the few values f32 cannot resolve (the distance to a
// huge triangle's plane seen close up). Tests compare it with exact values through the mirror
// kernel.
//
// Two things stand in the way in a shader. WGSL lets a * b + c be fused, so Dekker's product
// (an unfused product and its exact error) is not safe: here a product is split into four
// products of 12-bit halves, made by masking the significand, each exact in f32, so fusing
// changes nothing. And shader compilers treat float arithmetic as real arithmetic (they rewrite
// (a + b) - a as b, a b + a c as a (b + c), and reassociate), which cancels the error terms of
// a compensated sum: every intermediate goes through `keep`.
#import params

// x unchanged, but hidden from the compiler's algebra: an exclusive or with Params.opaque_zero,
// whose value (0) the compiler cannot know, leaves it nothing to rewrite.
fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.opaque_zero);
}

// x as high + low halves of at most 12 significant bits each.
fn split(x: f32) -> vec2<f32> {
    let h = bitcast<f32>(bitcast<u32>(x) & 0xfffff000u);
    return vec2(h, keep(x - h));
}

// a + b exactly, as the rounded sum and its rounding error (Knuth's TwoSum).
fn two_sum(a: f32, b: f32) -> vec2<f32> {
    let s = keep(a + b);
    let bv = keep(s - a);
    let av = keep(s - bv);
    return vec2(s, keep(a - av) + keep(b - bv));
}

// The pair s plus x: the rounding of the high sum goes into the low part (Ogita, Rump & Oishi's
// Sum2: error below u |sum| + gamma(n - 1)^2 times the terms' magnitudes).
fn sum_add(s: vec2<f32>, x: f32) -> vec2<f32> {
    let t = two_sum(s.x, x);
    return vec2(t.x, keep(s.y + t.y));
}

// s + n (v - o): v - o as an exact pair, n times its high part as four exact products, the small
// product of its low part rounded once.
fn sum_product_of_difference(s: vec2<f32>, n: f32, v: f32, o: f32) -> vec2<f32> {
    let d = two_sum(v, -o);
    let p = split(n);
    let q = split(d.x);
    var r = sum_add(s, keep(p.x * q.x));
    r = sum_add(r, keep(p.x * q.y));
    r = sum_add(r, keep(p.y * q.x));
    r = sum_add(r, keep(p.y * q.y));
    return sum_add(r, keep(n * d.y));
}

// n . (v - o), within u |result| + 2^-38 sum |n_k| (|v_k| + |o_k|) (plus products below f32's
// smallest normal, which a driver may flush to zero).
fn dot_difference(n: vec3<f32>, v: vec3<f32>, o: vec3<f32>) -> f32 {
    var s = vec2(0.0);
    s = sum_product_of_difference(s, n.x, v.x, o.x);
    s = sum_product_of_difference(s, n.y, v.y, o.y);
    s = sum_product_of_difference(s, n.z, v.z, o.z);
    return s.x + s.y;
}
