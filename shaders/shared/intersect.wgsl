// The robust ray/box and ray/triangle tests, and the unit normal of a hit triangle.
#import ray
#import blocks
#import compensated

// Reciprocal of a direction, clamped so that no component is infinite: WGSL does not promise
// IEEE behaviour for 1/0, and a huge finite value gives the same slab answer without NaNs.
// A clamped component is exactly +-PARALLEL_INV, which box_entry recognizes.
const PARALLEL_INV: f32 = 1e20;
fn safe_inverse(d: vec3<f32>) -> vec3<f32> {
    let tiny = 1e-20;
    let s = select(vec3(-PARALLEL_INV), vec3(PARALLEL_INV), d >= vec3(0.0));
    return select(1.0 / d, s, abs(d) < vec3(tiny));
}

// Conservative slab test (Ize, JCGT 2013): the exit distance is widened to cover the rounding of
// the subtraction, the 2.5-ulp WGSL division and the product. Returns the entry distance, or -1.
const EXIT_WIDEN: f32 = 1.0000024;
fn box_entry(lo: vec3<f32>, hi: vec3<f32>, org: vec3<f32>, inv: vec3<f32>, tmax: f32) -> f32 {
    let t0 = (lo - org) * inv;
    let t1 = (hi - org) * inv;
    // A ray parallel to a slab and lying in one of its planes stays in the slab for every t, but
    // 0 * inv gives 0 for that plane and would cut the interval at t = 0: such a ray would slip
    // past a mesh edge or face it runs along. Inside the closed slab, the interval is unbounded.
    let along = abs(inv) == vec3(PARALLEL_INV) & org >= lo & org <= hi;
    let tn = select(min(t0, t1), vec3(-FAR), along);
    let tf = select(max(t0, t1), vec3(FAR), along);
    let enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    let exit = min(min(tf.x, tf.y), tf.z) * EXIT_WIDEN;
    return select(-1.0, enter, enter <= min(exit, tmax));
}

// Per-ray constants of the watertight test (Woop, Benthin & Wald, JCGT 2013).
struct Shear {
    k: vec3<u32>,  // kx, ky, kz
    s: vec3<f32>,  // Sx, Sy, Sz
}

fn max_axis(v: vec3<f32>) -> u32 {
    let a = abs(v);
    return select(select(2u, 1u, a.y >= a.z), select(2u, 0u, a.x >= a.z), a.x >= a.y);
}

fn make_shear(d: vec3<f32>) -> Shear {
    let kz = max_axis(d);
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let t = kx;
        kx = ky;
        ky = t;
    }
    let sz = 1.0 / d[kz];
    return Shear(vec3(kx, ky, kz), vec3(d[kx] * sz, d[ky] * sz, sz));
}

// 2D edge function of the sheared vertices a, b. Evaluated in a canonical vertex order so that two
// triangles sharing an edge compute exactly the negated value even when the compiler contracts
// to fused multiply-adds: that keeps the test watertight.
fn edge(a: vec2<f32>, b: vec2<f32>) -> f32 {
    let swap = a.x > b.x || (a.x == b.x && a.y > b.y);
    let p = select(a, b, swap);
    let q = select(b, a, swap);
    let e = p.x * q.y - p.y * q.x;
    return select(e, -e, swap);
}

// A ray's hit on a triangle: distance and barycentrics (of v0, v1, v2); t < 0 when none.
struct TriHit {
    t: f32,
    b: vec3<f32>,
}

const NO_HIT: TriHit = TriHit(-1.0, vec3(0.0));
// intersect's answer when f32 cannot resolve the hit distance: `resolve_hit` decides.
const UNRESOLVED_T: f32 = -2.0;

// The triangle relative to the origin, sheared so that the ray runs along z, and the edge
// functions of the watertight test (Woop, Benthin & Wald) with pbrt-v4's bound on their error.
struct Sheared {
    a2: vec2<f32>,
    b2: vec2<f32>,
    c2: vec2<f32>,
    z: vec3<f32>,
    uvw: vec3<f32>,
    delta_e: f32,
}

fn shear_triangle(tri: Tri, org: vec3<f32>, sh: Shear) -> Sheared {
    let a = tri.v0 - org;
    let b = tri.v1 - org;
    let c = tri.v2 - org;
    let a2 = vec2(a[sh.k.x] - sh.s.x * a[sh.k.z], a[sh.k.y] - sh.s.y * a[sh.k.z]);
    let b2 = vec2(b[sh.k.x] - sh.s.x * b[sh.k.z], b[sh.k.y] - sh.s.y * b[sh.k.z]);
    let c2 = vec2(c[sh.k.x] - sh.s.x * c[sh.k.z], c[sh.k.y] - sh.s.y * c[sh.k.z]);
    let z = sh.s.z * vec3(a[sh.k.z], b[sh.k.z], c[sh.k.z]);
    let max_z = max(max(abs(z.x), abs(z.y)), abs(z.z));
    let max_x = max(max(abs(a2.x), abs(b2.x)), abs(c2.x));
    let max_y = max(max(abs(a2.y), abs(b2.y)), abs(c2.y));
    let delta_x = gamma(5.0) * (max_x + max_z);
    let delta_y = gamma(5.0) * (max_y + max_z);
    let delta_e = 2.0 * (gamma(2.0) * max_x * max_y + delta_y * max_x + delta_x * max_y);
    let uvw = vec3(edge(c2, b2), edge(a2, c2), edge(b2, a2));
    return Sheared(a2, b2, c2, z, uvw, delta_e);
}

// Whether the ray's line crosses the triangle (edge functions of one sign, not all zero).
fn crosses(s: Sheared) -> bool {
    let e = s.uvw;
    let det = e.x + e.y + e.z;
    return !(any(e < vec3(0.0)) && any(e > vec3(0.0))) && det != 0.0;
}

// The hit in (0, tmax], NO_HIT, or UNRESOLVED_T when f32's distance cannot be trusted (then
// `resolve_hit` decides, outside the traversal loop: a CPU driver runs a branch's code whenever
// any lane takes it, and rarely needed extended precision in the loop cost a quarter of the
// time). Degenerate triangles (det == 0) never hit. Unless `camera` (the ray leaves no surface),
// a hit must be proven in front of the origin despite rounding.
fn intersect(tri: Tri, org: vec3<f32>, sh: Shear, tmax: f32) -> TriHit {
    let s = shear_triangle(tri, org, sh);
    if !crosses(s) {
        return NO_HIT;
    }
    let u = s.uvw.x;
    let v = s.uvw.y;
    let w = s.uvw.z;
    let z = s.z;
    let det = u + v + w;
    let tt = u * z.x + v * z.y + w * z.z;
    // Sign-aware: the hit is in front when tt and det agree in sign.
    let stt = select(tt, -tt, det < 0.0);
    let t = stt / abs(det);
    // How far t may be from the exact distance. pbrt-v4 bounds it by its edge functions' error
    // times the largest |z|, which for a small triangle far away is 1000 times too wide. To first
    // order, t - T = (sum e_i (z_i - t) + sum u_i dz_i + rounding) / det, with e_i each edge
    // function's error (pbrt's delta_e) and dz_i each z's: what the edge functions' error moves
    // is the spread of the z's about t, not the z's themselves; the factor 2 covers second-order
    // terms while delta_e is below 1% of det. Huge triangles seen close up (terms of 1e24
    // cancelling to 1e16) get a bound as wide as their cancellation.
    let e = abs(s.uvw);
    let spread = abs(z.x - t) + abs(z.y - t) + abs(z.z - t);
    let delta_t = 2.0 * (s.delta_e * spread + gamma(7.0) * dot(e, abs(z))
        + gamma(2.0) * abs(t) * (e.x + e.y + e.z)) / abs(det) + gamma(4.0) * abs(t);
    let first_order = 100.0 * s.delta_e < abs(det);
    // Resolved: t is proven in front of the origin and within 1.2e-4 of itself.
    if t * 1.2207031e-4 > delta_t && first_order {
        if t > tmax {
            return NO_HIT;
        }
        return TriHit(t, s.uvw / det);
    }
    // Certainly behind: no hit.
    if t < -delta_t && first_order {
        return NO_HIT;
    }
    // Huge triangles seen close up, the triangle a secondary ray leaves, its neighbours.
    return TriHit(UNRESOLVED_T, vec3(0.0));
}

// What `intersect` left unresolved: the hit in (0, tmax] or NO_HIT, from the distance to the
// triangle's plane in extended precision (`plane_hit`). Flat triangles (area within rounding of
// zero) have no plane to speak of and are not hit.
fn resolve_hit(tri: Tri, org: vec3<f32>, sh: Shear, tmax: f32, camera: bool) -> TriHit {
    let s = shear_triangle(tri, org, sh);
    let det = s.uvw.x + s.uvw.y + s.uvw.z;
    if flat(tri) {
        return NO_HIT;
    }
    return plane_hit(tri, org, sh, s.uvw / det, s.delta_e / abs(det), tmax, camera);
}

// The hit at barycentrics b from the watertight test (b_i within b_err (1 + 3 |b_i|) of the
// exact ones, to first order: b_err bounds each edge function's error over |det|) when f32's t
// cannot resolve it: the distance to the triangle's plane in extended precision. For any normal
// n (here the rounded one), h(p) = n . (p - org) is affine, so t (n . dir) = h(hit point) = the
// sum of b_i h(v_i) when the b_i sum to 1: n's error then weighs with the distance to the hit,
// not with the vertices' distance from the origin, and each h(v_i) is exact products summed with
// compensation. A ray leaving a surface gets the hit only if it is proven in front of its origin.
fn plane_hit(tri: Tri, org: vec3<f32>, sh: Shear, b: vec3<f32>, b_err: f32, tmax: f32,
             camera: bool) -> TriHit {
    let e1 = tri.v1 - tri.v0;
    let e2 = tri.v2 - tri.v0;
    let n = cross(e1 / max3(abs(e1)), e2 / max3(abs(e2)));
    let h = vec3(dot_difference(n, tri.v0, org), dot_difference(n, tri.v1, org),
                 dot_difference(n, tri.v2, org));
    let num = dot(b, h);
    // The direction as the shear has it, (sx, sy, 1) on axes (kx, ky, kz), is the ray's over
    // its kz component: rebuilding it keeps the ray's direction out of the traversal loop's
    // registers (live across the loop it cost a quarter of the cast time on a CPU driver).
    let nk = vec3(n[sh.k.x], n[sh.k.y], n[sh.k.z]);
    let dk = vec3(sh.s.x, sh.s.y, 1.0);
    let den = dot(nk, dk);
    let t = num * sh.s.z / den;
    // The error of each h: its final rounding and the compensated sum's (Ogita, Rump & Oishi:
    // gamma(15)^2 of the terms' magnitudes, under 2^-40; 2^-38 taken), plus products a driver
    // flushes to zero.
    let an = abs(n);
    let ao = abs(org);
    let mag = vec3(dot(an, abs(tri.v0) + ao), dot(an, abs(tri.v1) + ao), dot(an, abs(tri.v2) + ao));
    let h_err = gamma(1.0) * abs(h) + 3.7e-12 * mag + vec3(1e-36);
    let ab = abs(b);
    let bary_err = b_err * (vec3(1.0) + 3.0 * ab) * 1.01 + gamma(4.0) * ab;
    let num_err = dot(bary_err, abs(h)) + dot(ab + bary_err, h_err) + gamma(3.0) * dot(ab, abs(h));
    // sx, sy and sz are rounded (a division, a product): a relative error of the direction,
    // which moves t in proportion (gamma(12) of t), as does the rounding of n . d.
    let den_err = gamma(3.0) * dot(abs(nk), abs(dk));
    if !(abs(den) > den_err) {
        return NO_HIT;
    }
    let t_err = (num_err + abs(num) * den_err / abs(den)) * abs(sh.s.z) / abs(den)
        + gamma(12.0) * abs(t);
    let proven = t > select(t_err, 0.0, camera);
    if !proven || t > tmax {
        return NO_HIT;
    }
    return TriHit(t, b);
}

// Whether a triangle's area is within rounding of zero: its edges' cross product against the
// rounding of computing it.
fn flat(tri: Tri) -> bool {
    return normal_error(tri) >= 1.0;
}

// A bound on the angle (in radians, at most 1) between unit_normal(tri) and the exact normal:
// the rounding of the edges' cross product over its length. About 1e-7 for a well-shaped
// triangle; 1 when the triangle is within rounding of flat and its normal means nothing.
fn normal_error(tri: Tri) -> f32 {
    let e1 = tri.v1 - tri.v0;
    let e2 = tri.v2 - tri.v0;
    let c = max3(abs(cross(e1, e2)));
    let noise = gamma(8.0) * max3(abs(e1)) * max3(abs(e2));
    return select(1.0, min(1.0, noise / c), c > noise);
}

// Bound on the relative rounding error of n correctly rounded f32 operations (pbrt's gamma).
fn gamma(n: f32) -> f32 {
    let u = 5.9604645e-8;  // 2^-24
    return n * u / (1.0 - n * u);
}

// The hit point from barycentrics b of v0, v1, v2, as v0 + b1 (v1 - v0) + b2 (v2 - v0), and a
// bound on each coordinate's distance from the triangle's plane (after pbrt-v4). Along the
// edges, errors in b (WGSL divides within 2.5 ulps) only move the point within the plane; what
// moves it off the plane is the rounding of the edges, products and sums, which the bound
// covers. Unlike origin + t * direction, the error scales with the triangle's coordinates, not
// with the ray's length.
fn hit_point(tri: Tri, b: vec3<f32>) -> vec3<f32> {
    return tri.v0 + b.y * (tri.v1 - tri.v0) + b.z * (tri.v2 - tri.v0);
}

fn hit_point_error(tri: Tri, b: vec3<f32>) -> vec3<f32> {
    let m1 = abs(b.y * (tri.v1 - tri.v0));
    let m2 = abs(b.z * (tri.v2 - tri.v0));
    return gamma(6.0) * (abs(tri.v0) + m1 + m2);
}

fn max3(v: vec3<f32>) -> f32 {
    return max(max(v.x, v.y), v.z);
}

// Unit geometric normal, normalize((v1 - v0) x (v2 - v0)), scaled before squaring: a plain
// normalize loses the squares to denormals below ~1e-10 across (a normal that is not unit, or
// NaN) and overflows above ~1e10 (a zero normal). A hit triangle has nonzero edges; if its
// edges are parallel in f32 (a needle), any unit vector perpendicular to the first edge is
// returned.
fn unit_normal(tri: Tri) -> vec3<f32> {
    let e1 = tri.v1 - tri.v0;
    let e2 = tri.v2 - tri.v0;
    let c = cross(e1 / max3(abs(e1)), e2 / max3(abs(e2)));
    let m = max3(abs(c));
    let p = select(vec3(0.0, -e1.z, e1.y), vec3(-e1.y, e1.x, 0.0), abs(e1.x) > abs(e1.z));
    let n = select(p / max3(abs(p)), c / m, m > 0.0);
    return normalize(n);
}
