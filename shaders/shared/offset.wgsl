// Secondary-ray origins: Wächter & Binder, "A Fast and Robust Method for Avoiding
// Self-Intersection" (Ray Tracing Gems, ch. 6): move p along n by a number of ulps per component
// (a relative offset), and by a fixed amount near the origin where ulps are tiny. Mirrored by
// mirror::offset::offset_ray.

const OFFSET_ORIGIN: f32 = 0.03125;
const OFFSET_FLOAT_SCALE: f32 = 1.52587890625e-05;  // 1 / 65536
const OFFSET_INT_SCALE: f32 = 256.0;

fn offset_ray(p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let of_i = vec3<i32>(OFFSET_INT_SCALE * n);
    let p_i = bitcast<vec3<f32>>(bitcast<vec3<i32>>(p) + select(of_i, -of_i, p < vec3(0.0)));
    return select(p_i, p + OFFSET_FLOAT_SCALE * n, abs(p) < vec3(OFFSET_ORIGIN));
}
