// Blocks in an Rgba32Uint 2D array texture: block k is row k % ROWS_PER_LAYER of layer
// k / ROWS_PER_LAYER, one 16-byte texel per 4 words (src/blocks/mod.rs documents the byte
// layout).

override ROWS_PER_LAYER: u32 = 16384u;

@group(0) @binding(1) var blocks: texture_storage_2d_array<rgba32uint, read>;

fn texel(block: u32, t: u32) -> vec4<u32> {
    let layer = block / ROWS_PER_LAYER;
    let row = block - layer * ROWS_PER_LAYER;
    return textureLoad(blocks, vec2<u32>(t, row), layer);
}
