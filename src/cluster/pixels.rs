//! Pixels on their way to the display (chapter 5.2): a render rank packs finished tiles into
//! messages of a few KiB, each a frame number then records of a rectangle and its pixels; the
//! display copies them into the frame on several threads. RGB8 (3 B a pixel, already sRGB as
//! the PNG stores it) by default; whole `Pixel`s (32 B) when the frame goes to EXR.

use super::protocol::{FRAME_HEADER, Tag, malformed};
use crate::error::{Error, Result};
use crate::gpu::frame::{Frame, Rect};
use crate::gpu::layout::Pixel;
use crate::output::srgb8_exposed;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

/// How each pixel travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    Rgb8,
    Full,
}

impl Wire {
    pub fn bytes(self) -> usize {
        match self {
            Wire::Rgb8 => 3,
            Wire::Full => std::mem::size_of::<Pixel>(),
        }
    }

    /// `k` is 2^`exposure`, which applies to RGB8 only (whole pixels stay linear).
    fn encode(self, p: &Pixel, exposure: f32, k: f32, out: &mut Vec<u8>) {
        match self {
            Wire::Rgb8 => out.extend(p.rgb.map(|c| srgb8_exposed(c, exposure, k))),
            Wire::Full => out.extend_from_slice(bytemuck::bytes_of(p)),
        }
    }
}

const RECORD: usize = 16;

/// Packs tiles into messages of about `target` bytes; a tile bigger than that is cut into bands
/// of rows.
pub struct Packer {
    wire: Wire,
    /// PNG exposure in stops, applied before the sRGB encoding of RGB8 pixels.
    exposure: f32,
    target: usize,
    frame: u32,
    buf: Vec<u8>,
}

impl Packer {
    pub fn new(wire: Wire, target: usize, exposure: f32) -> Packer {
        Packer {
            wire,
            exposure,
            target: target.max(FRAME_HEADER + RECORD + 64 * wire.bytes()),
            frame: 0,
            buf: Vec::new(),
        }
    }

    /// How the pixels of the next frame travel (a live view's frames differ): called between
    /// frames, when the last message has been flushed.
    pub fn set_wire(&mut self, wire: Wire) {
        assert!(self.buf.is_empty(), "the wire changes between frames");
        self.wire = wire;
        self.target = self.target.max(FRAME_HEADER + RECORD + 64 * wire.bytes());
    }

    /// Adds the `rect.w * rect.h` pixels of `rect` (row-major) of frame `frame`; returns the
    /// messages that filled up.
    pub fn push(&mut self, frame: u32, rect: Rect, pixels: &[Pixel]) -> Vec<Vec<u8>> {
        let bytes = self.encode(pixels);
        self.push_encoded(frame, rect, &bytes)
    }

    /// The wire form of some pixels.
    pub fn encode(&self, pixels: &[Pixel]) -> Vec<u8> {
        let mut out = Vec::with_capacity(pixels.len() * self.wire.bytes());
        let k = self.exposure.exp2();
        for p in pixels {
            self.wire.encode(p, self.exposure, k, &mut out);
        }
        out
    }

    /// Like `push`, for pixels already encoded by `encode`.
    pub fn push_encoded(&mut self, frame: u32, rect: Rect, bytes: &[u8]) -> Vec<Vec<u8>> {
        let row = rect.w as usize * self.wire.bytes();
        assert_eq!(bytes.len(), row * rect.h as usize, "pixels of {rect:?}");
        let mut full = Vec::new();
        if frame != self.frame && !self.buf.is_empty() {
            full.extend(self.flush());
        }
        self.frame = frame;
        let mut y = 0;
        while y < rect.h {
            if self.buf.is_empty() {
                self.buf.extend_from_slice(&frame.to_le_bytes());
            }
            let room = self.target.saturating_sub(self.buf.len() + RECORD) / row;
            if room == 0 && self.buf.len() > FRAME_HEADER {
                full.extend(self.flush());
                continue;
            }
            let rows = (room.max(1) as u32).min(rect.h - y);
            for v in [rect.x, rect.y + y, rect.w, rows] {
                self.buf.extend_from_slice(&v.to_le_bytes());
            }
            let first = y as usize * row;
            self.buf
                .extend_from_slice(&bytes[first..first + rows as usize * row]);
            y += rows;
            if self.buf.len() >= self.target {
                full.extend(self.flush());
            }
        }
        full
    }

    /// The message being filled, if any.
    pub fn flush(&mut self) -> Option<Vec<u8>> {
        (!self.buf.is_empty()).then(|| std::mem::take(&mut self.buf))
    }
}

/// One frame being assembled: a lock per row, so copy threads write disjoint rows in parallel.
pub struct FrameBuf {
    pub width: u32,
    pub height: u32,
    wire: Wire,
    rows: Vec<Mutex<Vec<u8>>>,
    copied: AtomicU64,
}

impl FrameBuf {
    pub fn new(width: u32, height: u32, wire: Wire) -> FrameBuf {
        let row = width as usize * wire.bytes();
        FrameBuf {
            width,
            height,
            wire,
            rows: (0..height).map(|_| Mutex::new(vec![0; row])).collect(),
            copied: AtomicU64::new(0),
        }
    }

    /// Copies the records of a message from rank `from` into the frame; returns the pixels
    /// copied.
    pub fn copy(&self, from: u32, msg: &[u8]) -> Result<u64> {
        let bpp = self.wire.bytes();
        let bad = |what: &str| malformed(Tag::Pixels, from, what);
        let mut at = FRAME_HEADER;
        let mut pixels = 0u64;
        while at < msg.len() {
            let head = msg
                .get(at..at + RECORD)
                .ok_or_else(|| bad("truncated record"))?;
            let word = |i: usize| u32::from_le_bytes(head[4 * i..4 * i + 4].try_into().unwrap());
            let r = Rect {
                x: word(0),
                y: word(1),
                w: word(2),
                h: word(3),
            };
            if r.x.checked_add(r.w).is_none_or(|e| e > self.width)
                || r.y.checked_add(r.h).is_none_or(|e| e > self.height)
            {
                return Err(bad(&format!(
                    "{r:?} outside the {}x{} frame",
                    self.width, self.height
                )));
            }
            at += RECORD;
            let row = r.w as usize * bpp;
            let data = msg
                .get(at..at + row * r.h as usize)
                .ok_or_else(|| bad("truncated pixels"))?;
            for (i, src) in data.chunks_exact(row).enumerate() {
                let mut dst = self.rows[r.y as usize + i]
                    .lock()
                    .unwrap_or_else(|p| p.into_inner());
                let x0 = r.x as usize * bpp;
                dst[x0..x0 + row].copy_from_slice(src);
            }
            at += row * r.h as usize;
            pixels += r.pixels() as u64;
        }
        self.copied.fetch_add(pixels, Ordering::Relaxed);
        Ok(pixels)
    }

    /// Pixels copied so far (a pixel sent twice counts twice).
    pub fn copied(&self) -> u64 {
        self.copied.load(Ordering::Relaxed)
    }

    /// The assembled image as tightly packed rows.
    pub fn into_bytes(self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.width as usize * self.height as usize * 4);
        for r in self.rows {
            v.extend(r.into_inner().unwrap_or_else(|p| p.into_inner()));
        }
        v
    }

    /// A frame of whole pixels (from `Wire::Full`).
    pub fn into_frame(self) -> Frame {
        assert_eq!(self.wire, Wire::Full);
        let (width, height) = (self.width, self.height);
        Frame {
            width,
            height,
            pixels: bytemuck::pod_collect_to_vec(&self.into_bytes()),
        }
    }
}

enum Job {
    /// A message from a rank.
    Copy(Arc<FrameBuf>, u32, Vec<u8>),
    /// Answers once every job sent before it to this thread is done.
    Fence(Sender<()>),
}

/// The display's copy threads: messages are dealt out in turn; each thread reports the pixels
/// it copied and the first error.
pub struct Copiers {
    senders: Vec<Sender<Job>>,
    handles: Vec<JoinHandle<()>>,
    next: usize,
    errors: Arc<Mutex<Option<Error>>>,
}

impl Copiers {
    pub fn new(threads: u32) -> Copiers {
        let errors = Arc::new(Mutex::new(None));
        let mut senders = Vec::new();
        let mut handles = Vec::new();
        for _ in 0..threads.max(1) {
            let (tx, rx): (Sender<Job>, Receiver<Job>) = channel();
            let errors = errors.clone();
            handles.push(std::thread::spawn(move || {
                for job in rx {
                    match job {
                        Job::Copy(frame, from, msg) => {
                            if let Err(e) = frame.copy(from, &msg) {
                                errors
                                    .lock()
                                    .unwrap_or_else(|p| p.into_inner())
                                    .get_or_insert(e);
                            }
                        }
                        Job::Fence(done) => {
                            let _ = done.send(());
                        }
                    }
                }
            }));
            senders.push(tx);
        }
        Copiers {
            senders,
            handles,
            next: 0,
            errors,
        }
    }

    /// Copies a message from rank `from` into `frame`, on the next thread in turn.
    pub fn copy(&mut self, frame: &Arc<FrameBuf>, from: u32, msg: Vec<u8>) {
        let tx = &self.senders[self.next];
        self.next = (self.next + 1) % self.senders.len();
        // A thread only stops when its sender is dropped, so the send cannot fail.
        let _ = tx.send(Job::Copy(frame.clone(), from, msg));
    }

    /// Waits until every message handed over so far has been copied.
    pub fn fence(&self) -> Result<()> {
        let (tx, rx) = channel();
        for s in &self.senders {
            let _ = s.send(Job::Fence(tx.clone()));
        }
        for _ in &self.senders {
            rx.recv()
                .map_err(|_| Error::Internal("a copy thread stopped".into()))?;
        }
        match self.errors.lock().unwrap_or_else(|p| p.into_inner()).take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

impl Drop for Copiers {
    fn drop(&mut self) {
        self.senders.clear();
        for h in self.handles.drain(..) {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cluster::protocol::message_frame;

    fn pixel(x: u32, y: u32) -> Pixel {
        Pixel {
            rgb: [x as f32 / 100.0, y as f32 / 100.0, 0.5],
            depth: x as f32 + 0.25,
            id: y * 1000 + x,
            normal: [0.0, 1.0, 0.0],
        }
    }

    fn tile(r: Rect) -> Vec<Pixel> {
        (r.y..r.y + r.h)
            .flat_map(|y| (r.x..r.x + r.w).map(move |x| pixel(x, y)))
            .collect()
    }

    /// Tiles packed into small messages and copied back on 3 threads give every pixel exactly.
    #[test]
    fn pack_and_copy_round_trip() {
        let (w, h) = (70, 53);
        for wire in [Wire::Rgb8, Wire::Full] {
            let mut packer = Packer::new(wire, 2048, 0.0);
            let rects = [
                Rect {
                    x: 0,
                    y: 0,
                    w: 64,
                    h: 40,
                },
                Rect {
                    x: 64,
                    y: 0,
                    w: 6,
                    h: 53,
                },
                Rect {
                    x: 0,
                    y: 40,
                    w: 64,
                    h: 13,
                },
            ];
            let mut msgs = Vec::new();
            for r in rects {
                msgs.extend(packer.push(7, r, &tile(r)));
            }
            msgs.extend(packer.flush());
            assert!(msgs.len() > 3, "big tiles are cut into several messages");
            assert!(
                msgs.iter()
                    .all(|m| m.len() <= 2048 + 16 + 70 * wire.bytes())
            );
            let frame = Arc::new(FrameBuf::new(w, h, wire));
            let mut copiers = Copiers::new(3);
            for m in msgs {
                assert_eq!(message_frame(&m), Some(7));
                copiers.copy(&frame, 2, m);
            }
            copiers.fence().unwrap();
            drop(copiers);
            let frame = Arc::into_inner(frame).unwrap();
            let expect = tile(Rect::whole(w, h));
            match wire {
                Wire::Full => {
                    let f = frame.into_frame();
                    for (a, b) in f.pixels.iter().zip(&expect) {
                        assert_eq!(bytemuck::bytes_of(a), bytemuck::bytes_of(b));
                    }
                }
                Wire::Rgb8 => {
                    let bytes = frame.into_bytes();
                    let want: Vec<u8> = expect
                        .iter()
                        .flat_map(|p| p.rgb.map(crate::output::srgb8))
                        .collect();
                    assert_eq!(bytes, want);
                }
            }
        }
    }

    #[test]
    fn records_outside_the_frame_are_errors() {
        let mut packer = Packer::new(Wire::Rgb8, 4096, 0.0);
        let r = Rect {
            x: 8,
            y: 8,
            w: 8,
            h: 8,
        };
        packer.push(0, r, &tile(r));
        let msg = packer.flush().unwrap();
        let small = FrameBuf::new(10, 10, Wire::Rgb8);
        let protocol = |r: Result<u64>| match r {
            Err(Error::Protocol(m)) => m,
            other => panic!("not a protocol error: {other:?}"),
        };
        let e = protocol(small.copy(3, &msg));
        assert!(
            e.contains("PIXELS message from rank 3") && e.contains("outside"),
            "{e}"
        );
        let big = FrameBuf::new(64, 64, Wire::Rgb8);
        let e = protocol(big.copy(3, &msg[..30]));
        assert!(e.contains("truncated"), "{e}");
        assert_eq!(message_frame(&[1, 2]), None);
    }
}
