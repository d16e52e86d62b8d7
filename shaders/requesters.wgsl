// After a round's kernels, with a distributed cache: each listed block's least requester is
// moved from `requested` into the fault list, after the blocks (word dc_fault_cap + i for the
// block at i), and the block's word is cleared for the next round. The host then reads the list
// alone, which grows with the round's faults, not with the model (a word per block would be
// 2.4 MB a round at 100M triangles). A single workgroup: a round lists at most dc_fault_cap
// blocks, 1,024 iterations of its loop at the most.
#import params
#import dc
#import counter

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(local_invocation_index) lid: u32) {
    let n = min(atomicLoad(&faults.count), params.dc_fault_cap);
    for (var i = lid; i < n; i += WORKGROUP) {
        let k = faults.blocks[i];
        faults.blocks[params.dc_fault_cap + i] = atomicExchange(&requested[k], 0u);
    }
}
