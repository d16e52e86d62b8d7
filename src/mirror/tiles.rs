//! Which pixel a ray slot of a batch is, as `tile_pixel` in `shaders/shared/tiles.wgsl`: batches
//! are runs of 8x8 tiles, row by row over the rectangle being rendered.

/// Tile edge in pixels (`TILE`).
pub const TILE: u32 = 8;

/// `tile_pixel`: the pixel of batch slot `i`, relative to the rectangle's corner, for a batch
/// starting at tile `first_tile` of a rectangle `tiles_x` tiles wide.
pub fn tile_pixel(first_tile: u32, tiles_x: u32, i: u32) -> (u32, u32) {
    let tile = first_tile + i / (TILE * TILE);
    let local = i % (TILE * TILE);
    (
        (tile % tiles_x) * TILE + local % TILE,
        (tile / tiles_x) * TILE + local / TILE,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_cover_each_pixel_of_the_tiles_once() {
        // A rectangle 3 tiles wide, 2 high, traced in batches of 2 tiles.
        let mut seen = vec![0u32; 24 * 16];
        for first in (0..6).step_by(2) {
            for i in 0..2 * TILE * TILE {
                let (x, y) = tile_pixel(first, 3, i);
                seen[(y * 24 + x) as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n == 1));
        assert_eq!(tile_pixel(0, 3, 9), (1, 1));
        assert_eq!(tile_pixel(4, 3, 0), (8, 8));
    }
}
