//! Fault density (docs/ARCHITECTURE.md, Overlapping batches): where a rectangle's blocks are
//! dense, per 8x8 tile, from the last frame's faults, so that the batch scheduler makes batches
//! over dense parts of the image smaller than those over sparse parts.

use super::frame::Rect;
use super::tracer::Tracer;
use crate::mirror::tiles::{TILE, Tiling, tile_pixel};
use std::ops::{Range, RangeInclusive};

impl Tracer<'_> {
    /// The last frame's faults per 8x8 tile of its rectangle, row by row (`FaultDensity`): of the
    /// blocks each tile's batch faulted on, how many had a ray of the tile as least requester.
    /// `None` until a frame has been traced in batches sized to a short cache.
    pub fn tile_faults(&self) -> Option<(Rect, Vec<f64>)> {
        let d = self.density.as_ref()?;
        Some((d.rect, d.per_tile.clone()))
    }

    /// Records the faults of a finished batch (per tile of `tiles` of `rect` in `tiling`'s order)
    /// into this frame's fault density, for the next frame's `batch_tiles`.
    pub(super) fn note_batch_faults(
        &mut self,
        rect: Rect,
        tiling: Tiling,
        tiles: Range<u32>,
        faults: &[u32],
    ) {
        if self.dc.is_none() || !self.fits_by_batches() {
            return;
        }
        let d = self
            .next_density
            .get_or_insert_with(|| FaultDensity::new(rect, tiling));
        if d.rect != rect {
            *d = FaultDensity::new(rect, tiling);
        }
        d.note(tiling, tiles, faults);
    }
}

/// Where a rectangle's blocks are dense: per 8x8 tile (by position, whatever the batch order),
/// how many of the blocks its batch faulted on in the last frame had a ray of the tile as least
/// requester.
pub(super) struct FaultDensity {
    pub rect: Rect,
    tiles_x: u32,
    pub(super) per_tile: Vec<f64>,
}

impl FaultDensity {
    pub fn new(rect: Rect, tiling: Tiling) -> FaultDensity {
        FaultDensity {
            rect,
            tiles_x: tiling.tiles_x,
            per_tile: vec![0.0; tiling.tiles() as usize],
        }
    }

    /// The slot of batch tile `t` of `tiling`.
    pub(super) fn slot(&self, tiling: Tiling, t: u32) -> usize {
        let (x, y) = tile_pixel(t, tiling, 0);
        ((y / TILE) * self.tiles_x + x / TILE) as usize
    }

    /// The faults of a batch's `tiles` of `tiling`, the first tile's at `faults[0]` (tiles past
    /// the end of `faults` had none).
    pub fn note(&mut self, tiling: Tiling, tiles: Range<u32>, faults: &[u32]) {
        for (i, t) in tiles.enumerate() {
            let slot = self.slot(tiling, t);
            if let Some(p) = self.per_tile.get_mut(slot) {
                *p = f64::from(faults.get(i).copied().unwrap_or(0));
            }
        }
    }

    /// The tiles a batch starting at tile `first` of `tiling` takes: until their faults reach
    /// `target`, within `size` (its end also where the rectangle's tiles end).
    pub fn batch(&self, tiling: Tiling, first: u32, size: RangeInclusive<u32>, target: f64) -> u32 {
        let (least, most) = (*size.start(), *size.end());
        let (mut n, mut expected) = (0, 0.0);
        while n < most && (n < least || expected < target) {
            expected += self
                .per_tile
                .get(self.slot(tiling, first + n))
                .copied()
                .unwrap_or(0.0);
            n += 1;
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_takes_tiles_until_their_faults_reach_the_target() {
        // 8x4 tiles in rows; every tile of the batch that traced them faulted 10 times.
        let rows = Tiling::new(64, 32, 32);
        let mut d = FaultDensity::new(Rect::whole(64, 32), rows);
        d.note(rows, 0..32, &[10; 32]);
        assert_eq!(d.batch(rows, 0, 1..=32, 45.0), 5);
        assert_eq!(d.batch(rows, 0, 1..=32, 50.0), 5);
        assert_eq!(d.batch(rows, 0, 1..=32, 51.0), 6);
        // At least `least` tiles, at most `most`.
        assert_eq!(d.batch(rows, 0, 8..=32, 5.0), 8);
        assert_eq!(d.batch(rows, 0, 1..=3, 1e9), 3);
    }

    #[test]
    fn dense_tiles_make_smaller_batches() {
        // Every tile of the first two rows faulted 6 times, of the last two once.
        let rows = Tiling::new(64, 32, 16);
        let mut d = FaultDensity::new(Rect::whole(64, 32), rows);
        d.note(rows, 0..16, &[6; 16]);
        d.note(rows, 16..32, &[1; 16]);
        assert_eq!(d.batch(rows, 0, 1..=32, 25.0), 5);
        assert_eq!(d.batch(rows, 16, 1..=16, 25.0), 16);
        assert_eq!(d.batch(rows, 16, 1..=16, 8.0), 8);
    }

    #[test]
    fn densities_belong_to_tile_positions_not_to_batch_order() {
        // Noted in one order (bands 2 tiles wide, every other one upward), read in another
        // (rows): the faults stay with the tiles that made them.
        let (w, h) = (64, 32);
        let bands = Tiling {
            tiles_x: 8,
            tiles_y: 4,
            band: 2,
        };
        let rows = Tiling::new(w, h, 32);
        let mut d = FaultDensity::new(Rect::whole(w, h), bands);
        // The first band: tiles x 0..2 of every row, 8 faults each.
        d.note(bands, 0..8, &[8; 8]);
        for t in 0..32 {
            let expect = if t % 8 < 2 { 8.0 } else { 0.0 };
            assert_eq!(d.per_tile[d.slot(rows, t)], expect, "tile {t}");
        }
    }
}
