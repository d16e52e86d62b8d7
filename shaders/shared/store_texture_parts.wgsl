// Blocks in two to four Rgba32Uint 2D array textures, for a store larger than one resource may
// be (lavapipe: 2 GiB). Block k is row k % ROWS_PER_LAYER of layer k / ROWS_PER_LAYER counted
// across the textures, LAYERS_PER_PART layers each (the last may have fewer); otherwise as
// store_texture.wgsl, which a store that fits one texture uses (the extra bindings cost every
// dispatch).

override ROWS_PER_LAYER: u32 = 16384u;
override LAYERS_PER_PART: u32 = 2048u;

@group(0) @binding(1) var blocks: texture_storage_2d_array<rgba32uint, read>;
// With fewer than four parts, the missing ones are bound to part 0 and never read.
@group(0) @binding(10) var blocks_1: texture_storage_2d_array<rgba32uint, read>;
@group(0) @binding(11) var blocks_2: texture_storage_2d_array<rgba32uint, read>;
@group(0) @binding(12) var blocks_3: texture_storage_2d_array<rgba32uint, read>;

fn texel(block: u32, t: u32) -> vec4<u32> {
    let layer = block / ROWS_PER_LAYER;
    let at = vec2<u32>(t, block - layer * ROWS_PER_LAYER);
    let part = layer / LAYERS_PER_PART;
    let l = layer - part * LAYERS_PER_PART;
    switch part {
        case 0u: {
            return textureLoad(blocks, at, l);
        }
        case 1u: {
            return textureLoad(blocks_1, at, l);
        }
        case 2u: {
            return textureLoad(blocks_2, at, l);
        }
        default: {
            return textureLoad(blocks_3, at, l);
        }
    }
}
