// Blocks in one storage buffer of 16-byte words, block after block (src/blocks/mod.rs documents
// the byte layout).

override TEXELS_PER_BLOCK: u32 = 512u;

@group(0) @binding(1) var<storage, read> blocks: array<vec4<u32>>;

fn texel(block: u32, t: u32) -> vec4<u32> {
    return blocks[block * TEXELS_PER_BLOCK + t];
}
