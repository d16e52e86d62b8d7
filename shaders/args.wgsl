// Between traversal rounds: turns the live count just produced into indirect dispatch arguments and
// clears the other counter, which the next round appends to.
#import counter

@group(1) @binding(0) var<storage, read_write> produced: Counter;
@group(1) @binding(1) var<storage, read_write> consumed: Counter;

@compute @workgroup_size(1)
fn main() {
    let n = atomicLoad(&produced.count);
    produced.x = (n + WORKGROUP - 1u) / WORKGROUP;
    produced.y = 1u;
    produced.z = 1u;
    atomicStore(&consumed.count, 0u);
}
