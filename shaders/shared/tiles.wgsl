// Which pixel a ray slot of a batch is: batches are runs of 8x8 tiles over the rectangle being
// rendered, in bands params.band_tiles wide (0: one band), row by row within a band, the bands
// left to right and every other one bottom to top, so that a batch is a compact patch. Within a
// tile the slots go in Z order (Morton: x from the index's even bits, y from its odd bits), so
// that any 2^k consecutive slots, a subgroup of rays, are a patch of 2x2, 4x2, 4x4 or 8x4
// pixels rather than a thin row: nearby rays take more nearly the same path, and a subgroup runs
// as long as its longest ray. Mirrored by mirror::tiles::tile_pixel.
#import params

const TILE: u32 = 8u;

// The pixel of batch slot i, relative to the rectangle's corner (params.rect_x, rect_y).
fn tile_pixel(i: u32) -> vec2<u32> {
    let tile = params.first_tile + i / (TILE * TILE);
    let local = i % (TILE * TILE);
    let tiles_y = (params.rect_h + TILE - 1u) / TILE;
    let band = select(params.band_tiles, params.tiles_x, params.band_tiles == 0u);
    let b = tile / (band * tiles_y);
    let within = tile % (band * tiles_y);
    // Only the last band may be narrower.
    let width = min(band, params.tiles_x - b * band);
    let row = within / width;
    let ty = select(row, tiles_y - 1u - row, b % 2u == 1u);
    return vec2((b * band + within % width) * TILE + z_x(local), ty * TILE + z_x(local >> 1u));
}

// The ray slot of ray k of batch slot i in a wave of `fan` rays a slot, by kind: tile by tile,
// then k, then the slot's place in its tile (batches are whole tiles), so that a subgroup's lanes
// trace the same ray k of neighbouring pixels (rays to the same light; a path's sun rays apart
// from its bounce rays, an AO sample's k-th directions, which share a stratum across a 4x2 patch
// of pixels: sampling.wgsl, sample2_patch) rather than a mix of kinds.
fn wave_slot(i: u32, k: u32, fan: u32) -> u32 {
    let t = i / (TILE * TILE);
    return (t * fan + k) * (TILE * TILE) + i % (TILE * TILE);
}

// The batch slot and k of wave ray slot j: wave_slot's inverse.
fn wave_ray(j: u32, fan: u32) -> vec2<u32> {
    let g = j / (TILE * TILE);
    let t = g / fan;
    return vec2(t * (TILE * TILE) + j % (TILE * TILE), g - t * fan);
}

// The x of Z-order index l in an 8x8 tile: its bits 0, 2 and 4 (of l >> 1, the y).
fn z_x(l: u32) -> u32 {
    return (l & 1u) | ((l >> 1u) & 2u) | ((l >> 2u) & 4u);
}
