// Secondary-ray origins that cannot lie behind the surface they leave (pbrt-v4's
// OffsetRayOrigin): the hit point, computed from barycentrics with a bound on its error
// (hit_point_error in intersect.wgsl), moves along the normal by that bound, then one float
// further from where it was. Mirrored by mirror::offset.

// How far along unit normal n a point with per-coordinate error `err` must move.
fn offset_distance(n: vec3<f32>, err: vec3<f32>) -> f32 {
    return dot(abs(n), err);
}

// The next float up and down (zero counts as both signs).
fn next_up(x: f32) -> f32 {
    let v = select(x, 0.0, x == 0.0);
    let b = bitcast<u32>(v);
    return bitcast<f32>(select(b - 1u, b + 1u, v >= 0.0));
}

fn next_down(x: f32) -> f32 {
    let v = select(x, bitcast<f32>(0x80000000u), x == 0.0);
    let b = bitcast<u32>(v);
    return bitcast<f32>(select(b + 1u, b - 1u, v > 0.0));
}

// p moved `d` along unit normal n (n points to the side the new ray leaves on), each moved
// coordinate then one float further: the rounding of the sum cannot bring it back.
fn offset_ray(p: vec3<f32>, n: vec3<f32>, d: f32) -> vec3<f32> {
    let offset = d * n;
    let q = p + offset;
    let up = vec3(next_up(q.x), next_up(q.y), next_up(q.z));
    let down = vec3(next_down(q.x), next_down(q.y), next_down(q.z));
    return select(select(q, down, offset < vec3(0.0)), up, offset > vec3(0.0));
}
