// The 4-wide BVH node and the decoding of its quantized child boxes (the byte layout is
// documented at bvh::Node). No bindings: the mirror kernel tests these against their CPU twins.

// Mirrors bvh::Node: a 4-wide node, its children's boxes quantized on a per-node grid.
struct Node {
    origin: vec3<f32>,
    exponents: u32,   // per axis (byte) the biased f32 exponent of the grid step
    child_base: u32,  // the first inner child; inner children are adjacent in slot order
    tri_base: u32,    // the first triangle of the leaf children, adjacent in slot order
    counts: u32,      // per slot (byte): EMPTY, INNER or the leaf's triangle count
    lo: vec3<u32>,    // per axis, byte i: slot i's lower bound in grid steps
    hi: vec3<u32>,
}

// Node.counts bytes.
const EMPTY: u32 = 0u;
const INNER: u32 = 255u;

struct Box {
    lo: vec3<f32>,
    hi: vec3<f32>,
}

// The node in texels a..d (16 words).
fn node_of(a: vec4<u32>, b: vec4<u32>, c: vec4<u32>, d: vec4<u32>) -> Node {
    return Node(bitcast<vec3<f32>>(a.xyz), a.w, b.x, b.y, b.z, c.xyz, vec3(c.w, d.x, d.y));
}

// The grid step per axis, a power of two (0 on an axis where every child is flat).
fn node_step(n: Node) -> vec3<f32> {
    return bitcast<vec3<f32>>(((vec3(n.exponents) >> vec3(0u, 8u, 16u)) & vec3(0xffu)) << vec3(23u));
}

// Slot i's box (mirror: bvh::Node::child_box): `q * step` is exact, and the host chose each q so
// that the one rounding of the sum falls outside the exact box.
fn child_box(n: Node, step: vec3<f32>, i: u32) -> Box {
    let s = vec3(8u * i);
    let lo = vec3<f32>((n.lo >> s) & vec3(0xffu));
    let hi = vec3<f32>((n.hi >> s) & vec3(0xffu));
    return Box(n.origin + lo * step, n.origin + hi * step);
}

// The union of the used slots' boxes (mirror: bvh::Node::bounds): the root's holds the scene.
fn node_bounds(n: Node) -> Box {
    let step = node_step(n);
    var b = Box(vec3(3.0e38), vec3(-3.0e38));
    for (var i = 0u; i < 4u; i++) {
        if ((n.counts >> (8u * i)) & 0xffu) != EMPTY {
            let c = child_box(n, step, i);
            b = Box(min(b.lo, c.lo), max(b.hi, c.hi));
        }
    }
    return b;
}
