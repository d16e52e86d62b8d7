// The live list a kernel appends its rays to, for the next traversal round's indirect dispatch.
#import counter

@group(1) @binding(4) var<storage, read_write> live_out: array<u32>;
@group(1) @binding(5) var<storage, read_write> counter_out: Counter;

var<workgroup> wg_count: atomic<u32>;
var<workgroup> wg_base: u32;

// Appends `value` to the live list when `live`, with one global atomic per workgroup instead of
// one per ray. Every invocation of the workgroup must call it (it holds a barrier).
fn append_live(live: bool, lid: u32, value: u32) {
    var slot = 0u;
    if live {
        slot = atomicAdd(&wg_count, 1u);
    }
    workgroupBarrier();
    if lid == 0u {
        wg_base = atomicAdd(&counter_out.count, atomicLoad(&wg_count));
    }
    let base = workgroupUniformLoad(&wg_base);
    if live {
        live_out[base + slot] = value;
    }
}
