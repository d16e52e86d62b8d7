//! What the server's threads and the GPU thread share (docs/ARCHITECTURE.md, Live view): the
//! clients' wishes (camera and shading, numbered), the newest frames, the statistics. Only the
//! newest of anything is kept: a frame nobody took yet is replaced, never queued.

use crate::scene::Camera;
use crate::shading::Mode;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// After an interactive camera, how long without a newer one before the view counts as at rest
/// (a client that stopped dragging without saying so still gets its refined frame).
pub const REST: Duration = Duration::from_millis(300);

/// What the clients asked for. Every change takes the next `seq`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wish {
    pub seq: u64,
    pub camera: Camera,
    pub mode: Mode,
    pub spp: u32,
    /// Sent while the camera moves (a drag): frames at reduced size until it rests.
    pub interactive: bool,
}

/// A frame for the page: JPEG bytes and what they show.
#[derive(Debug)]
pub struct LiveFrame {
    pub jpeg: Vec<u8>,
    /// What the page's overlay shows of this frame (JSON).
    pub info: serde_json::Value,
}

/// A finished frame: full size, every requested sample.
#[derive(Debug)]
pub struct StillFrame {
    pub seq: u64,
    pub image: image::RgbImage,
}

/// A frame on its way to the encoder thread.
#[derive(Debug)]
pub struct RawFrame {
    pub image: image::RgbImage,
    pub info: serde_json::Value,
}

/// The newest value of something, or nothing, with a wait for the next one: a slot, not a queue.
pub struct Latest<T> {
    slot: Mutex<Option<T>>,
    ready: Condvar,
}

impl<T> Default for Latest<T> {
    fn default() -> Self {
        Latest {
            slot: Mutex::new(None),
            ready: Condvar::new(),
        }
    }
}

impl<T> Latest<T> {
    /// Puts `v` in the slot, replacing what nobody took.
    pub fn put(&self, v: T) {
        *lock(&self.slot) = Some(v);
        self.ready.notify_all();
    }

    /// Waits for a value and takes it.
    pub fn take(&self) -> T {
        let mut g = lock(&self.slot);
        loop {
            if let Some(v) = g.take() {
                return v;
            }
            g = self.ready.wait(g).unwrap_or_else(|e| e.into_inner());
        }
    }
}

/// A mutex whose holder panicked still holds a consistent value here (every update is one
/// assignment): take it.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The newest wish and when it came.
struct Newest {
    wish: Wish,
    at: Instant,
}

pub struct Shared {
    wish: Mutex<Newest>,
    changed: Condvar,
    /// The newest frame of any kind, for the page.
    pub live: watch::Sender<Option<Arc<LiveFrame>>>,
    /// The newest finished frame, for `GET /frame.png`.
    pub still: watch::Sender<Option<Arc<StillFrame>>>,
    /// The frames to encode.
    pub raw: Latest<RawFrame>,
    /// `GET /stats`.
    pub stats: Mutex<serde_json::Value>,
    /// Required in every request's query (`token=`) when set.
    pub token: Option<String>,
    /// The requested samples per pixel may not exceed this (the command line's `--spp` bound).
    pub max_spp: u32,
    /// The first camera: the page's reset and the centre and distance of its axis views.
    pub home: Camera,
}

impl Shared {
    pub fn new(first: Wish, token: Option<String>, max_spp: u32) -> Arc<Shared> {
        Arc::new(Shared {
            wish: Mutex::new(Newest {
                wish: first,
                at: Instant::now(),
            }),
            changed: Condvar::new(),
            live: watch::Sender::new(None),
            still: watch::Sender::new(None),
            raw: Latest::default(),
            stats: Mutex::new(serde_json::json!({})),
            token,
            max_spp,
            home: first.camera,
        })
    }

    pub fn wish(&self) -> Wish {
        lock(&self.wish).wish
    }

    /// Changes the wish with `f` and gives it the next number, which it returns.
    pub fn change(&self, f: impl FnOnce(&mut Wish)) -> u64 {
        let mut n = lock(&self.wish);
        f(&mut n.wish);
        n.wish.seq += 1;
        n.at = Instant::now();
        self.changed.notify_all();
        n.wish.seq
    }

    /// The next frame to make: the wish and whether to render it at rest (full size, every
    /// sample). Waits while the newest wish is `done` (finished). An interactive wish already
    /// `drawn` at reduced size counts as at rest once `REST` passed since it came without a
    /// newer one. With a `slice`, waits at most that long and then says `None` (a display rank
    /// has work between frames).
    pub fn next_job(
        &self,
        done: Option<u64>,
        drawn: Option<u64>,
        slice: Option<Duration>,
    ) -> Option<(Wish, bool)> {
        let start = Instant::now();
        let mut n = lock(&self.wish);
        loop {
            let w = n.wish;
            // How long to wait for a newer wish; `None`: until one comes.
            let mut wait = None;
            if Some(w.seq) != done {
                if !w.interactive {
                    return Some((w, true));
                }
                if Some(w.seq) != drawn {
                    return Some((w, false));
                }
                let quiet = n.at.elapsed();
                if quiet >= REST {
                    return Some((w, true));
                }
                wait = Some(REST - quiet);
            }
            if let Some(slice) = slice {
                let left = slice.saturating_sub(start.elapsed());
                if left.is_zero() {
                    return None;
                }
                wait = Some(wait.map_or(left, |d: Duration| d.min(left)));
            }
            n = match wait {
                None => self.changed.wait(n).unwrap_or_else(|e| e.into_inner()),
                Some(d) => {
                    self.changed
                        .wait_timeout(n, d)
                        .unwrap_or_else(|e| e.into_inner())
                        .0
                }
            };
        }
    }

    /// Whether a wish newer than `seq` came.
    pub fn superseded(&self, seq: u64) -> bool {
        lock(&self.wish).wish.seq != seq
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wish() -> Wish {
        Wish {
            seq: 0,
            camera: Camera {
                position: [0.0, -2.0, 0.0],
                focal_point: [0.0; 3],
                view_up: [0.0, 0.0, 1.0],
                view_angle: 30.0,
                parallel_scale: None,
            },
            mode: Mode::Cast,
            spp: 1,
            interactive: false,
        }
    }

    #[test]
    fn latest_keeps_only_the_newest() {
        let l = Latest::default();
        l.put(1);
        l.put(2);
        assert_eq!(l.take(), 2);
        l.put(3);
        assert_eq!(l.take(), 3);
    }

    #[test]
    fn jobs_follow_the_wishes() {
        let s = Shared::new(wish(), None, 16);
        // The first wish at rest.
        assert_eq!(s.next_job(None, None, None), Some((wish(), true)));
        // Finished: nothing to do within a slice.
        let slice = Some(Duration::from_millis(20));
        assert_eq!(s.next_job(Some(0), None, slice), None);
        let seq = s.change(|w| w.interactive = true);
        assert_eq!(seq, 1);
        // A drag: reduced first, then at rest once nothing newer came for `REST`, however the
        // waits are sliced.
        let (w, still) = s.next_job(Some(0), None, None).unwrap();
        assert_eq!((w.seq, still), (1, false));
        assert_eq!(s.next_job(Some(0), Some(1), slice), None, "not yet at rest");
        // (Were the rest counted from each wait, this would never end: every slice is shorter.)
        let (w, still) = loop {
            if let Some(job) = s.next_job(Some(0), Some(1), slice) {
                break job;
            }
        };
        assert_eq!((w.seq, still), (1, true));
        assert!(!s.superseded(1));
        s.change(|w| w.interactive = false);
        assert!(s.superseded(1));
    }
}
