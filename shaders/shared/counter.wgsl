// A count of rays and the indirect dispatch arguments made from it (host: gpu::layout::Counter).

const WORKGROUP: u32 = 64u;

// Mirrors gpu::layout::Counter: a live-ray count followed by indirect dispatch arguments.
struct Counter {
    count: atomic<u32>,
    x: u32,
    y: u32,
    z: u32,
}
