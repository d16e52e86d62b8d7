//! The load balancer's tile schedule (chapter 5.1): large tiles first, the first assignment of
//! every frame static and always the same, the rest handed out on demand and split as the frame
//! runs out so that render ranks finish together. Pure logic, no MPI: the balancer role feeds it.

use crate::gpu::frame::Rect;
use std::collections::VecDeque;

/// Tiles a rank receives unasked at the start of each frame: one to render, one queued, so
/// its request for more travels while the GPU works.
pub const STATIC_TILES: usize = 2;

/// One frame's schedule.
#[derive(Clone, Debug)]
pub struct Schedule {
    /// Each render rank's static first assignment, taken on its first request of the frame.
    reserved: Vec<Option<Vec<Rect>>>,
    /// The rest, in image order.
    queue: VecDeque<Rect>,
    queued_pixels: u64,
    min_tile: u32,
}

impl Schedule {
    /// The schedule of a `width` x `height` frame for `ranks` render ranks, with tiles of `tile`
    /// pixels a side, split down to `min_tile` toward the end. Sizes are multiples of the
    /// GPU's 8-pixel tile except at the image's right and bottom edges.
    pub fn new(width: u32, height: u32, ranks: u32, tile: u32, min_tile: u32) -> Schedule {
        let ranks = ranks.max(1) as usize;
        let min_tile = min_tile.max(8).next_multiple_of(8);
        let mut tile = tile.max(min_tile).next_multiple_of(8);
        // Small images: shrink the tiles until every rank has its static tiles and some left.
        while tile > min_tile && tiles(width, height, tile).len() < 2 * STATIC_TILES * ranks {
            tile = (tile / 2).max(min_tile).next_multiple_of(8);
        }
        let mut queue: VecDeque<Rect> = tiles(width, height, tile).into();
        // Rank r's static tiles are r, r + ranks, ...: interleaved, so that each rank starts in
        // a different part of the image.
        let mut reserved = vec![Some(Vec::new()); ranks];
        let take = (STATIC_TILES * ranks).min(queue.len());
        let first: Vec<Rect> = queue.drain(..take).collect();
        for (i, r) in first.into_iter().enumerate() {
            if let Some(v) = reserved[i % ranks].as_mut() {
                v.push(r);
            }
        }
        let queued_pixels = queue.iter().map(|r| r.pixels() as u64).sum();
        Schedule {
            reserved,
            queue,
            queued_pixels,
            min_tile,
        }
    }

    /// The static first assignment of render rank `rank` (once; empty after).
    pub fn first(&mut self, rank: u32) -> Vec<Rect> {
        self.reserved
            .get_mut(rank as usize)
            .and_then(Option::take)
            .unwrap_or_default()
    }

    /// The next tile on demand, or `None` when the frame's dynamic part is all handed out.
    /// When fewer than two tiles per rank remain, the front tile is split in four.
    pub fn next_tile(&mut self) -> Option<Rect> {
        let ranks = self.reserved.len() as u64;
        loop {
            let front = *self.queue.front()?;
            let splittable = front.w > self.min_tile || front.h > self.min_tile;
            if !splittable || self.queued_pixels >= 2 * ranks * front.pixels() as u64 {
                break;
            }
            self.queue.pop_front();
            for q in quarters(front, self.min_tile).into_iter().rev() {
                self.queue.push_front(q);
            }
        }
        let r = self.queue.pop_front()?;
        self.queued_pixels -= r.pixels() as u64;
        Some(r)
    }

    /// Whether every tile, static and dynamic, has been handed out.
    pub fn exhausted(&self) -> bool {
        self.queue.is_empty() && self.reserved.iter().all(Option::is_none)
    }
}

/// The image cut into `tile`-sided tiles, row-major.
fn tiles(width: u32, height: u32, tile: u32) -> Vec<Rect> {
    let mut v = Vec::new();
    for y in (0..height).step_by(tile as usize) {
        for x in (0..width).step_by(tile as usize) {
            v.push(Rect {
                x,
                y,
                w: tile.min(width - x),
                h: tile.min(height - y),
            });
        }
    }
    v
}

/// `r` split in (up to) four, row-major; halves are multiples of 8 and at least `min` wide.
fn quarters(r: Rect, min: u32) -> Vec<Rect> {
    let cut = |len: u32| -> Vec<(u32, u32)> {
        let half = (len / 2).next_multiple_of(8);
        if len > min && half >= min && half < len {
            vec![(0, half), (half, len - half)]
        } else {
            vec![(0, len)]
        }
    };
    let mut v = Vec::new();
    for &(dy, h) in &cut(r.h) {
        for &(dx, w) in &cut(r.w) {
            v.push(Rect {
                x: r.x + dx,
                y: r.y + dy,
                w,
                h,
            });
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hands out a whole frame as the balancer would (static first, then on demand, ranks in
    /// turn) and checks that every pixel is covered exactly once.
    fn run(w: u32, h: u32, ranks: u32, tile: u32, min: u32) -> Vec<(u32, Rect)> {
        let mut s = Schedule::new(w, h, ranks, tile, min);
        let mut grants = Vec::new();
        for r in 0..ranks {
            grants.extend(s.first(r).into_iter().map(|t| (r, t)));
        }
        let mut r = 0;
        while let Some(t) = s.next_tile() {
            grants.push((r, t));
            r = (r + 1) % ranks;
        }
        assert!(s.exhausted());
        let mut seen = vec![0u8; (w * h) as usize];
        for &(_, t) in &grants {
            assert!(
                t.w > 0 && t.h > 0 && t.x + t.w <= w && t.y + t.h <= h,
                "{t:?}"
            );
            for y in t.y..t.y + t.h {
                for x in t.x..t.x + t.w {
                    seen[(y * w + x) as usize] += 1;
                }
            }
        }
        assert!(seen.iter().all(|&c| c == 1), "{w}x{h}, {ranks} ranks");
        grants
    }

    #[test]
    fn every_pixel_is_handed_out_once() {
        for &(w, h) in &[(1, 1), (7, 5), (64, 64), (61, 45), (640, 480), (1920, 1080)] {
            for ranks in 1..=6 {
                run(w, h, ranks, 128, 16);
            }
        }
    }

    #[test]
    fn tiles_shrink_toward_the_end_of_the_frame() {
        let g = run(1024, 768, 3, 128, 16);
        let first = g[0].1.pixels();
        let last = g.last().unwrap().1.pixels();
        assert_eq!(first, 128 * 128);
        assert!(last <= 16 * 16, "last tile {:?}", g.last());
        // Sizes never grow once they have shrunk.
        let dynamic: Vec<usize> = g[3 * STATIC_TILES..].iter().map(|t| t.1.pixels()).collect();
        assert!(dynamic.windows(2).all(|p| p[1] <= p[0]), "{dynamic:?}");
    }

    #[test]
    fn first_assignment_is_static_and_interleaved() {
        let mut a = Schedule::new(640, 480, 3, 64, 16);
        let mut b = Schedule::new(640, 480, 3, 64, 16);
        // Taken in another order, still the same tiles.
        let (b2, b0) = (b.first(2), b.first(0));
        assert_eq!(a.first(0), b0);
        assert_eq!(a.first(2), b2);
        assert_eq!(a.first(0), vec![], "only once");
        let r1 = a.first(1);
        assert_eq!(r1.len(), STATIC_TILES);
        assert_eq!(
            r1[0],
            Rect {
                x: 64,
                y: 0,
                w: 64,
                h: 64
            }
        );
        assert_eq!(
            r1[1],
            Rect {
                x: 256,
                y: 0,
                w: 64,
                h: 64
            }
        );
    }

    #[test]
    fn small_images_still_give_every_rank_work() {
        let mut s = Schedule::new(32, 32, 5, 128, 8);
        for r in 0..5 {
            assert!(!s.first(r).is_empty(), "rank {r}");
        }
    }
}
