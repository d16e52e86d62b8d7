// Which pixel a ray slot of a batch is: batches are runs of 8x8 tiles, row by row over the
// rectangle being rendered. Mirrored by mirror::tiles::tile_pixel.
#import params

const TILE: u32 = 8u;

// The pixel of batch slot i, relative to the rectangle's corner (params.rect_x, rect_y).
fn tile_pixel(i: u32) -> vec2<u32> {
    let tile = params.first_tile + i / (TILE * TILE);
    let local = i % (TILE * TILE);
    return vec2((tile % params.tiles_x) * TILE + local % TILE, (tile / params.tiles_x) * TILE + local / TILE);
}
