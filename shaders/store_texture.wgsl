// Blocks in an Rgba32Uint 2D array texture: block k is row k % rows_per_layer of layer
// k / rows_per_layer, one 16-byte texel per 4 words (blocks.rs documents the byte layout).
@group(0) @binding(1) var blocks: texture_2d_array<u32>;

fn texel(block: u32, t: u32) -> vec4<u32> {
    let layer = block / params.rows_per_layer;
    let row = block - layer * params.rows_per_layer;
    return textureLoad(blocks, vec2<u32>(t, row), layer, 0);
}
