// Which pixel a ray slot of a batch is: batches are runs of 8x8 tiles over the rectangle being
// rendered, in bands params.band_tiles wide (0: one band), row by row within a band, the bands
// left to right and every other one bottom to top, so that a batch is a compact patch. Mirrored
// by mirror::tiles::tile_pixel.
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
    return vec2((b * band + within % width) * TILE + local % TILE, ty * TILE + local / TILE);
}
