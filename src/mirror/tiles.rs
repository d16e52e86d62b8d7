//! Which pixel a ray slot of a batch is, as `tile_pixel` in `shaders/shared/tiles.wgsl`: batches
//! are runs of 8x8 tiles over the rectangle being rendered, in bands `band` tiles wide, row by row
//! within a band, the bands left to right and every other one bottom to top, and within a tile in
//! Z order (`z_x`). Where a batch would be a thin stripe across the rectangle, bands make it a
//! compact patch, so its rays touch fewer blocks (docs/ARCHITECTURE.md, The distributed cache).

/// Tile edge in pixels (`TILE`).
pub const TILE: u32 = 8;

/// The widest batch of whole rows, as width over height (`Tiling::new`). rm 3M at 1024x1024,
/// rank 0 of 8, `lru`: at a 1/8 cache (rows 4.8 times wider than tall) rows took fewer fault
/// rounds than square patches, at 1/32 (19 times) patches fetched a fifth less (docs/notes).
const STRIPE_ASPECT: u64 = 8;

/// How a rectangle's tiles are ordered: its size in tiles and the band width (`Params::tiles_x`,
/// `Params::band_tiles`; the height comes from `Params::rect_h`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tiling {
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// Tiles across a band; 0 or `tiles_x`: one band, rows across the whole rectangle.
    pub band: u32,
}

impl Tiling {
    /// The tiling of a `w` x `h` rectangle traced in batches of `per_batch` tiles. A batch of
    /// whole rows (one band) shares its long edge with the batch before it, whose blocks are
    /// still cached; a square patch touches fewer blocks of its own. Rows are kept while a batch
    /// of them is at most `STRIPE_ASPECT` times wider than tall; thinner ones become bands of
    /// equal width about as wide as a batch is tall (square patches).
    pub fn new(w: u32, h: u32, per_batch: u32) -> Tiling {
        let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let band = if u64::from(tiles_x).pow(2) <= STRIPE_ASPECT * u64::from(per_batch) {
            tiles_x
        } else {
            let bands = (f64::from(tiles_x) / f64::from(per_batch.max(1)).sqrt()).round();
            tiles_x.div_ceil((bands as u32).clamp(1, tiles_x))
        };
        Tiling {
            tiles_x,
            tiles_y,
            band,
        }
    }

    pub fn tiles(&self) -> u32 {
        self.tiles_x * self.tiles_y
    }
}

/// `tile_pixel`: the pixel of batch slot `i`, relative to the rectangle's corner, for a batch
/// starting at tile `first_tile`.
pub fn tile_pixel(first_tile: u32, t: Tiling, i: u32) -> (u32, u32) {
    let (x, y) = tile_corner(first_tile + i / (TILE * TILE), t);
    let local = i % (TILE * TILE);
    (x + z_x(local), y + z_x(local >> 1))
}

/// The top left pixel of tile `tile` (counted over the whole rectangle), relative to the
/// rectangle's corner: `tile_pixel` of the tile's first slot.
pub fn tile_corner(tile: u32, t: Tiling) -> (u32, u32) {
    let band = if t.band == 0 { t.tiles_x } else { t.band };
    let b = tile / (band * t.tiles_y);
    let within = tile % (band * t.tiles_y);
    // Only the last band may be narrower.
    let width = band.min(t.tiles_x - b * band);
    let row = within / width;
    let ty = if b % 2 == 1 { t.tiles_y - 1 - row } else { row };
    ((b * band + within % width) * TILE, ty * TILE)
}

/// `z_x`: the x of Z-order index `l` in an 8x8 tile, its bits 0, 2 and 4 (of `l >> 1`, the y).
pub fn z_x(l: u32) -> u32 {
    (l & 1) | ((l >> 1) & 2) | ((l >> 2) & 4)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every pixel of a `w` x `h` rectangle once, over batches of `per_batch` tiles.
    fn covers_once(w: u32, h: u32, per_batch: u32) -> Tiling {
        let t = Tiling::new(w, h, per_batch);
        let (pw, ph) = (t.tiles_x * TILE, t.tiles_y * TILE);
        let mut seen = vec![0u32; (pw * ph) as usize];
        for first in (0..t.tiles()).step_by(per_batch as usize) {
            for i in 0..per_batch.min(t.tiles() - first) * TILE * TILE {
                let (x, y) = tile_pixel(first, t, i);
                assert!(x < pw && y < ph, "slot {i} of batch {first}: ({x}, {y})");
                seen[(y * pw + x) as usize] += 1;
            }
        }
        assert!(
            seen.iter().all(|&n| n == 1),
            "{w}x{h} in batches of {per_batch}"
        );
        t
    }

    #[test]
    fn slots_cover_each_pixel_of_the_tiles_once() {
        // A rectangle 3 tiles wide, 2 high, in batches of 2 tiles: rows across it.
        let t = covers_once(24, 16, 2);
        assert_eq!(t.band, 3);
        assert_eq!(tile_pixel(0, t, 9), (1, 2));
        assert_eq!(tile_pixel(4, t, 0), (8, 8));
        for (w, h, per_batch) in [(24, 16, 6), (1024, 1024, 860), (1000, 300, 37), (8, 8, 1)] {
            covers_once(w, h, per_batch);
        }
        // 40 tiles wide in batches of 20: bands of 5 tiles (8 bands, the odd ones upward).
        let t = covers_once(320, 80, 20);
        assert_eq!(t.band, 5);
        assert_eq!(tile_pixel(50, t, 0), (40, 72));
    }

    /// Any 2^k consecutive slots of a tile are a patch: 8 of them 4x2 pixels, 32 of them 8x4.
    #[test]
    fn slots_within_a_tile_go_in_z_order() {
        let t = Tiling::new(8, 8, 1);
        let patch = |from: u32, n: u32| {
            let mut p: Vec<(u32, u32)> = (from..from + n).map(|i| tile_pixel(0, t, i)).collect();
            p.sort_by_key(|&(x, y)| (y, x));
            p
        };
        let rect = |x0: u32, y0: u32, w: u32, h: u32| -> Vec<(u32, u32)> {
            (y0..y0 + h)
                .flat_map(|y| (x0..x0 + w).map(move |x| (x, y)))
                .collect()
        };
        assert_eq!(patch(0, 8), rect(0, 0, 4, 2));
        assert_eq!(patch(8, 8), rect(0, 2, 4, 2));
        assert_eq!(patch(16, 16), rect(4, 0, 4, 4));
        assert_eq!(patch(32, 32), rect(0, 4, 8, 4));
        assert_eq!(patch(0, 4), rect(0, 0, 2, 2));
    }

    #[test]
    fn batches_stay_rows_unless_thin() {
        // 1024x1024 in batches of 3440 tiles: rows 27 tiles high, 4.8 times wider.
        assert_eq!(Tiling::new(1024, 1024, 3440).band, 128);
        assert_eq!(Tiling::new(1024, 1024, 128 * 128).band, 128);
        assert_eq!(Tiling::new(1024, 1024, 860).band, 32);
    }

    #[test]
    fn a_batch_is_a_compact_patch() {
        // 1024x1024 in batches of 860 tiles: four bands 32 tiles wide, a batch about 32 x 27
        // tiles (or two pieces side by side where it crosses into the next band).
        let t = Tiling::new(1024, 1024, 860);
        assert_eq!(t.band, 32);
        for first in (0..t.tiles()).step_by(860) {
            let n = 860.min(t.tiles() - first);
            let (mut lo, mut hi) = ((u32::MAX, u32::MAX), (0, 0));
            for i in 0..n * TILE * TILE {
                let (x, y) = tile_pixel(first, t, i);
                lo = (lo.0.min(x), lo.1.min(y));
                hi = (hi.0.max(x), hi.1.max(y));
            }
            let area = u64::from(hi.0 - lo.0 + 1) * u64::from(hi.1 - lo.1 + 1);
            assert!(
                area <= 2 * u64::from(n * TILE * TILE),
                "batch at tile {first} spans {lo:?}..{hi:?}"
            );
        }
    }
}
