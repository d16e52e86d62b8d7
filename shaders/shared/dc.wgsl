// The distributed cache on the GPU (docs/ARCHITECTURE.md, The distributed cache): `locate` maps
// a block id to the row that holds it, or records a fault and answers NONE. The host changes the
// table and the cache rows only between dispatches.
#import params

// Pipelines built for the distributed cache set DC; replicated ones leave it false and pay for
// no cache check at all.
override DC: bool = false;

// Mirrors gpu::layout::FaultHeader, followed by dc_fault_cap words of the round's deduplicated
// faulted blocks, then as many of their least requesters (written by requesters.wgsl).
struct Faults {
    count: atomic<u32>,
    dropped: atomic<u32>,
    pad0: u32,
    pad1: u32,
    blocks: array<u32>,
}
// The row of every block on this GPU (resident or cached), NONE when absent: one load replaces
// the ownership and tag arithmetic. The host updates it between rounds. A texture of
// ROW_TABLE_WIDTH blocks a texel row (gpu::row_table), not a buffer: a CPU driver fetches texels
// through a gather, and runs a buffer load as a loop over the lanes that stalls in each.
@group(0) @binding(3) var block_rows: texture_storage_2d_array<r32uint, read>;
override ROW_TABLE_WIDTH: u32 = 4096u;  // the host's gpu::row_table::WIDTH

fn block_row(k: u32) -> u32 {
    return textureLoad(block_rows, vec2(k % ROW_TABLE_WIDTH, k / ROW_TABLE_WIDTH), 0).x;
}
@group(0) @binding(4) var<storage, read_write> faults: Faults;
// Per block, this round: 0 while no ray has requested it, else the complement of its least
// requester (`request`), which requesters.wgsl moves into the fault list, clearing the word.
@group(0) @binding(5) var<storage, read_write> requested: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read_write> waiters: array<atomic<u32>>;    // per cache line
// Per cache line, nonzero once a ray of the round found its block there: the host's recency for
// the Lru mapping, and with the fault list the frame's distinct borrowed blocks. Then, at
// dc_lines + line, nonzero when a ray still live after the round last used a triangle block
// there (`keep_line`): with the node blocks the round used, the lines Lru does not evict next
// round. Plain stores: racing writers write the same value.
@group(0) @binding(9) var<storage, read_write> line_used: array<u32>;

// Per invocation, summed into Stats by the traversal kernel.
var<private> dc_hits: u32 = 0u;
var<private> dc_misses: u32 = 0u;

// The cache mapping as a pipeline constant: 0 Ize, 1 block k's line is k mod lines (Demarle,
// Lru), 2 (the default: the mirror kernel, which tests both) params.dc_map. A kernel built for
// one mapping carries no code of the other: a CPU driver runs both sides of a branch, and with
// Ize's divisions at each of trace's request sites an `lru` 1/8 frame took 3-6% more GPU time.
override DC_MAP: u32 = 2u;

// Mirrored by dc::cache_line.
fn cache_line(k: u32) -> u32 {
    let map = select(DC_MAP, params.dc_map, DC_MAP == 2u);
    if map == 0u {
        // Ize: count only the blocks this rank does not own, so no line is wasted.
        let n = params.dc_ranks;
        return (k - (k + (n - params.dc_rank)) / n) % params.dc_lines;
    }
    return k % params.dc_lines;
}

// The row of block k, or NONE with a fault recorded.
fn locate(k: u32) -> u32 {
    let row = lookup(k);
    if DC && row == NONE {
        request(k, NONE);
    }
    return row;
}

// The row of block k, or NONE when absent, without recording the fault: the caller requests it
// later (`request`). The trace loop does so after the loop: on a CPU driver a branch's code runs
// in every iteration however few lanes take it, and the request's atomics there cost a third of
// a cached frame's instructions.
fn lookup(k: u32) -> u32 {
    if !DC {
        return k;
    }
    let row = block_row(k);
    if row < params.dc_cache_row {
        return row;  // owned, or the replicated root
    }
    if row != NONE {
        dc_hits += 1u;
        line_used[row - params.dc_cache_row] = 1u;
        return row;
    }
    dc_misses += 1u;
    return NONE;
}

// A fault's requester: ray slot `ray` of the batch in lane params.lane. Mirrored by
// gpu::rounds::requester.
fn requester(ray: u32) -> u32 {
    return (params.lane << REQUESTER_LANE_SHIFT) | ray;
}
const REQUESTER_LANE_SHIFT: u32 = 28u;

// Marks the cache line of `row` (a block row, or NONE) as one a ray still live needs again: the
// leaves it set aside on its stack are mostly next to the last one it tested.
fn keep_line(row: u32) {
    if row != NONE && row >= params.dc_cache_row {
        line_used[params.dc_lines + row - params.dc_cache_row] = 1u;
    }
}

// Records a fault on block k, listed once per round however many rays ask. Every request also
// keeps the block's least requester, `who` (`requester`, or NONE for kernels without ray slots):
// the host serves a block by it and counts it to that ray's tile (gpu::rounds::serve_order,
// FaultDensity). The least, not the first to list the block: which ray is first depends on how
// the driver's threads interleave the workgroups, and the rounds with it.
fn request(k: u32, who: u32) {
    atomicAdd(&waiters[cache_line(k)], 1u);
    // The complement orders the least requester highest; a kernel without ray slots asks with 1,
    // below every ray (and 0 stays "not requested").
    let key = select(~who, 1u, who == NONE);
    if atomicMax(&requested[k], key) == 0u {
        let i = atomicAdd(&faults.count, 1u);
        if i < params.dc_fault_cap {
            faults.blocks[i] = k;
        } else {
            atomicAdd(&faults.dropped, 1u);
        }
    }
}
