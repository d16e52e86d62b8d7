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

// The x of Z-order index l in an 8x8 tile: its bits 0, 2 and 4 (of l >> 1, the y).
fn z_x(l: u32) -> u32 {
    return (l & 1u) | ((l >> 1u) & 2u) | ((l >> 2u) & 4u);
}
