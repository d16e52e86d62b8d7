// The robust ray/box and ray/triangle tests, and the unit normal of a hit triangle.
#import ray
#import blocks

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

// The hit in (0, tmax), or NO_HIT. Degenerate triangles (det == 0) never hit. Unless `camera`
// (the ray leaves no surface), a hit must be proven in front of the origin despite rounding.
fn intersect(tri: Tri, org: vec3<f32>, sh: Shear, tmax: f32, camera: bool) -> TriHit {
    let a = tri.v0 - org;
    let b = tri.v1 - org;
    let c = tri.v2 - org;
    let a2 = vec2(a[sh.k.x] - sh.s.x * a[sh.k.z], a[sh.k.y] - sh.s.y * a[sh.k.z]);
    let b2 = vec2(b[sh.k.x] - sh.s.x * b[sh.k.z], b[sh.k.y] - sh.s.y * b[sh.k.z]);
    let c2 = vec2(c[sh.k.x] - sh.s.x * c[sh.k.z], c[sh.k.y] - sh.s.y * c[sh.k.z]);
    let u = edge(c2, b2);
    let v = edge(a2, c2);
    let w = edge(b2, a2);
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return NO_HIT;
    }
    let det = u + v + w;
    if det == 0.0 {
        return NO_HIT;
    }
    let z = sh.s.z * vec3(a[sh.k.z], b[sh.k.z], c[sh.k.z]);
    let tt = u * z.x + v * z.y + w * z.z;
    // Sign-aware: the hit is in front when tt and det agree in sign.
    let stt = select(tt, -tt, det < 0.0);
    if stt <= 0.0 {
        return NO_HIT;
    }
    let t = stt / abs(det);
    if t <= 0.0 || t >= tmax {
        return NO_HIT;
    }
    let hit = TriHit(t, vec3(u, v, w) / det);
    // A hit closer than the rounding error of t may be behind the origin: a ray leaving a
    // surface would hit it again (pbrt-v4's conservative t; a needle's error grows with its
    // length over its width, beyond any origin offset).
    let max_z = max(max(abs(z.x), abs(z.y)), abs(z.z));
    let max_x = max(max(abs(a2.x), abs(b2.x)), abs(c2.x));
    let max_y = max(max(abs(a2.y), abs(b2.y)), abs(c2.y));
    let max_e = max(max(abs(u), abs(v)), abs(w));
    let delta_x = gamma(5.0) * (max_x + max_z);
    let delta_y = gamma(5.0) * (max_y + max_z);
    let delta_z = gamma(3.0) * max_z;
    let delta_e = 2.0 * (gamma(2.0) * max_x * max_y + delta_y * max_x + delta_x * max_y);
    let delta_t = 3.0 * (gamma(3.0) * max_e * max_z + delta_e * max_z + delta_z * max_e) / abs(det);
    if t > delta_t {
        return hit;
    }
    // pbrt's bound is a worst case that also rejects far, small triangles and huge ones seen
    // close up. Two cases need no proof that t > 0, if the triangle is not degenerate (its
    // object-space area above rounding; the shear's rounding can make a zero-area triangle look
    // hit): a ray from the camera, which leaves no surface, and a triangle whose vertices all
    // lie in front of the origin beyond their rounding (t is an average of their distances with
    // the barycentric weights, so it is positive).
    let in_front = min(min(z.x, z.y), z.z) > delta_z;
    if (camera || in_front) && !flat(tri) {
        return hit;
    }
    return NO_HIT;
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
