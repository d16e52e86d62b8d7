//! The messages of cluster mode and their bytes (docs/ARCHITECTURE.md, Cluster). All go over
//! MPI_COMM_WORLD; control words are little-endian `u32`. Per frame f:
//! - a render rank sends `ASK(f)` to the balancer; the first answer of a frame is the rank's
//!   static tiles, later ones one tile each, and an empty `WORK` ends the rank's frame. A rank
//!   asks again as soon as it starts its last queued tile, so the answer travels while it traces.
//! - finished tiles go to the display in `PIXELS` messages (laid out by `pixels`); `DONE(f)`
//!   (the rank's `FrameReport`) follows the rank's last pixels of the frame, in order, since MPI
//!   keeps the order of messages between two ranks.
//! - the display writes frame f once every render rank's `DONE(f)` is in and every pixel copied.
//! - after the frames of the display benchmark, `BANDWIDTH` messages measure the link.
//! - in a live view (`dcrt view` under mpirun) the display sends each render rank a `JOB(f)`
//!   before frame f (its size, camera and samples: the frames are not known in advance), and
//!   while no frame is being made an empty `ALIVE` to every rank every quarter of the timeout.
//!   Before any, the first render rank sends the display `HOME`: the model's camera (JSON),
//!   which the display, which does not read the model, shows first.
//! - a render rank busy on its GPU sends an empty `ALIVE` to the display and the balancer every
//!   quarter of the job's timeout, so that they can tell a rank that works from one that has
//!   stopped (docs/ARCHITECTURE.md, Cluster).
//!
//! Decoding checks only the layout; a malformed message is an `Error::Protocol` that names its
//! tag and sender.

use crate::error::{Error, Result};
use crate::gpu::frame::Rect;
use serde::{Deserialize, Serialize};

/// Bytes of the frame number that starts every `PIXELS` and `DONE` message.
pub const FRAME_HEADER: usize = 4;

/// The frame number a pixel message (or any message that starts with one) is for; `None` when
/// it is too short.
pub fn message_frame(msg: &[u8]) -> Option<u32> {
    msg.get(..FRAME_HEADER)
        .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
}

/// A message's MPI tag.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tag {
    Ask = 1,
    Work = 2,
    Pixels = 3,
    Done = 4,
    Bandwidth = 5,
    Alive = 6,
    Job = 7,
    Home = 8,
}

impl Tag {
    pub const ALL: [Tag; 8] = [
        Tag::Ask,
        Tag::Work,
        Tag::Pixels,
        Tag::Done,
        Tag::Bandwidth,
        Tag::Alive,
        Tag::Job,
        Tag::Home,
    ];

    pub fn raw(self) -> i32 {
        self as i32
    }

    pub fn from_raw(tag: i32) -> Option<Tag> {
        Tag::ALL.into_iter().find(|t| t.raw() == tag)
    }

    pub fn name(self) -> &'static str {
        match self {
            Tag::Ask => "ASK",
            Tag::Work => "WORK",
            Tag::Pixels => "PIXELS",
            Tag::Done => "DONE",
            Tag::Bandwidth => "BANDWIDTH",
            Tag::Alive => "ALIVE",
            Tag::Job => "JOB",
            Tag::Home => "HOME",
        }
    }
}

/// The error for a `tag` message from rank `from` that does not make sense.
pub fn malformed(tag: Tag, from: u32, why: impl std::fmt::Display) -> Error {
    Error::Protocol(format!(
        "malformed {} message from rank {from}: {why}",
        tag.name()
    ))
}

fn words(v: &[u32]) -> Vec<u8> {
    bytemuck::cast_slice(v).to_vec()
}

fn read_words(tag: Tag, from: u32, b: &[u8]) -> Result<Vec<u32>> {
    if !b.len().is_multiple_of(4) {
        return Err(malformed(tag, from, format!("{} bytes", b.len())));
    }
    Ok(bytemuck::pod_collect_to_vec(b))
}

/// A render rank asks the balancer for work in `frame`, whose image is `width` x `height` (a
/// live view changes it from frame to frame).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ask {
    pub frame: u32,
    pub width: u32,
    pub height: u32,
}

impl Ask {
    pub fn encode(&self) -> Vec<u8> {
        words(&[self.frame, self.width, self.height])
    }

    pub fn decode(from: u32, msg: &[u8]) -> Result<Ask> {
        match read_words(Tag::Ask, from, msg)?[..] {
            [frame, width, height] if width > 0 && height > 0 => Ok(Ask {
                frame,
                width,
                height,
            }),
            ref w => Err(malformed(Tag::Ask, from, format!("{w:?}"))),
        }
    }
}

/// The display's order to render frame `frame` of a live view: its size, camera and samples
/// (`mode`, and `Shading`'s `first_sample`, `spp` and `part_of_spp`; the rest of the shading is
/// what every rank agreed on at start-up), and whether its pixels travel whole (`Wire::Full`,
/// for sums of sample passes at the display) or as RGB8.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Job {
    pub frame: u32,
    pub width: u32,
    pub height: u32,
    pub camera: crate::scene::Camera,
    pub mode: crate::shading::Mode,
    pub first_sample: u32,
    pub spp: u32,
    pub part_of_spp: Option<u32>,
    pub whole_pixels: bool,
}

impl Job {
    /// The frame number, then the job as JSON.
    pub fn encode(&self) -> Result<Vec<u8>> {
        let mut msg = words(&[self.frame]);
        serde_json::to_writer(&mut msg, self)
            .map_err(|e| Error::Internal(format!("frame job: {e}")))?;
        Ok(msg)
    }

    pub fn decode(from: u32, msg: &[u8]) -> Result<Job> {
        let bad = |why: String| malformed(Tag::Job, from, why);
        let frame = message_frame(msg).ok_or_else(|| bad(format!("{} bytes", msg.len())))?;
        let job: Job = serde_json::from_slice(&msg[4..]).map_err(|e| bad(e.to_string()))?;
        if job.frame != frame || job.width == 0 || job.height == 0 {
            return Err(bad(format!(
                "frame {} of {}x{} in a message for frame {frame}",
                job.frame, job.width, job.height
            )));
        }
        Ok(job)
    }
}

/// The balancer's answer: tiles of `frame` to trace; none ends the rank's frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Work {
    pub frame: u32,
    pub tiles: Vec<Rect>,
}

impl Work {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = vec![self.frame, self.tiles.len() as u32];
        for t in &self.tiles {
            w.extend([t.x, t.y, t.w, t.h]);
        }
        words(&w)
    }

    pub fn decode(from: u32, msg: &[u8]) -> Result<Work> {
        let w = read_words(Tag::Work, from, msg)?;
        let &[frame, n, ref rects @ ..] = &w[..] else {
            return Err(malformed(Tag::Work, from, format!("{w:?}")));
        };
        if rects.len() != 4 * n as usize {
            return Err(malformed(
                Tag::Work,
                from,
                format!("{n} tiles in {} words: {w:?}", w.len()),
            ));
        }
        let tiles = rects
            .chunks_exact(4)
            .map(|t| Rect {
                x: t[0],
                y: t[1],
                w: t[2],
                h: t[3],
            })
            .collect();
        Ok(Work { frame, tiles })
    }
}

/// A render rank's account of one frame, its `DONE` message. The render rank sends the tracer's
/// `FrameStats` as `stats`; the display reads them as `ReportStats`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameReport<S = ReportStats> {
    pub frame: u32,
    pub rank: u32,
    /// Tiles traced, their pixels, and the pixel messages and bytes they took.
    pub tiles: u64,
    #[serde(default)]
    pub pixels: u64,
    pub messages: u32,
    pub bytes: u64,
    pub stats: S,
}

/// The figures of a `FrameStats` that the display sums into its line per frame; the others
/// travel in `rest` as they came, into the traces and the statistics file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReportStats {
    pub seconds: f64,
    pub fault_rounds: u64,
    pub fetched_blocks: u64,
    pub fetch_seconds: f64,
    #[serde(flatten)]
    pub rest: serde_json::Map<String, serde_json::Value>,
}

impl<S: Serialize> FrameReport<S> {
    /// The frame number, then the report as JSON.
    pub fn encode(&self) -> Result<Vec<u8>> {
        let mut msg = words(&[self.frame]);
        serde_json::to_writer(&mut msg, self)
            .map_err(|e| Error::Internal(format!("frame report: {e}")))?;
        Ok(msg)
    }
}

impl FrameReport {
    pub fn decode(from: u32, msg: &[u8]) -> Result<FrameReport> {
        let bad = |why: String| malformed(Tag::Done, from, why);
        let frame = message_frame(msg).ok_or_else(|| bad(format!("{} bytes", msg.len())))?;
        let report: FrameReport =
            serde_json::from_slice(&msg[4..]).map_err(|e| bad(e.to_string()))?;
        if report.frame != frame || report.rank != from {
            return Err(bad(format!(
                "the report of rank {} for frame {} in a message for frame {frame}",
                report.rank, report.frame
            )));
        }
        Ok(report)
    }

    /// The report as the traces and the statistics file record it.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("a map of numbers")
    }

    /// The report as the display's trace records it.
    pub fn to_record(&self) -> crate::traces::record::Render {
        crate::traces::record::Render {
            frame: self.frame,
            rank: self.rank,
            tiles: self.tiles,
            messages: self.messages,
            bytes: self.bytes,
            stats: serde_json::to_value(&self.stats).expect("a map of numbers"),
        }
    }
}

/// A message as received.
#[derive(Debug)]
pub enum Message {
    Ask(Ask),
    Work(Work),
    Pixels {
        frame: u32,
        bytes: Vec<u8>,
    },
    Done(FrameReport),
    Bandwidth(Vec<u8>),
    /// A render rank is busy on its GPU, or a live view's display waits for its user (no
    /// payload).
    Alive,
    Job(Job),
    Home(crate::scene::Camera),
}

impl Message {
    pub fn decode(tag: i32, from: u32, bytes: Vec<u8>) -> Result<Message> {
        let Some(tag) = Tag::from_raw(tag) else {
            return Err(Error::Protocol(format!(
                "unexpected message (tag {tag}) from rank {from}"
            )));
        };
        Ok(match tag {
            Tag::Ask => Message::Ask(Ask::decode(from, &bytes)?),
            Tag::Work => Message::Work(Work::decode(from, &bytes)?),
            Tag::Pixels => Message::Pixels {
                frame: message_frame(&bytes).ok_or_else(|| {
                    malformed(Tag::Pixels, from, format!("{} bytes", bytes.len()))
                })?,
                bytes,
            },
            Tag::Done => Message::Done(FrameReport::decode(from, &bytes)?),
            Tag::Bandwidth => Message::Bandwidth(bytes),
            Tag::Job => Message::Job(Job::decode(from, &bytes)?),
            Tag::Home => Message::Home(
                serde_json::from_slice(&bytes)
                    .map_err(|e| malformed(Tag::Home, from, e.to_string()))?,
            ),
            Tag::Alive if bytes.is_empty() => Message::Alive,
            Tag::Alive => {
                return Err(malformed(
                    Tag::Alive,
                    from,
                    format!("{} bytes", bytes.len()),
                ));
            }
        })
    }

    pub fn tag(&self) -> Tag {
        match self {
            Message::Ask(_) => Tag::Ask,
            Message::Work(_) => Tag::Work,
            Message::Pixels { .. } => Tag::Pixels,
            Message::Done(_) => Tag::Done,
            Message::Bandwidth(_) => Tag::Bandwidth,
            Message::Alive => Tag::Alive,
            Message::Job(_) => Tag::Job,
            Message::Home(_) => Tag::Home,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::frame::FrameStats;

    fn protocol_error(r: Result<Message>) -> String {
        match r {
            Err(Error::Protocol(m)) => m,
            other => panic!("not a protocol error: {other:?}"),
        }
    }

    #[test]
    fn tags_round_trip() {
        for t in Tag::ALL {
            assert_eq!(Tag::from_raw(t.raw()), Some(t));
        }
        assert_eq!(Tag::from_raw(0), None);
        assert_eq!(Tag::Work.raw(), 2, "the tag numbers are the wire's");
    }

    #[test]
    fn ask_and_work_round_trip() {
        let ask = Ask {
            frame: 7,
            width: 64,
            height: 48,
        };
        assert_eq!(ask.encode(), words(&[7, 64, 48]));
        match Message::decode(Tag::Ask.raw(), 3, ask.encode()).unwrap() {
            Message::Ask(a) => assert_eq!(a, ask),
            m => panic!("{m:?}"),
        }
        for n in [0, 1, 2] {
            let work = Work {
                frame: 3,
                tiles: (0..n)
                    .map(|i| Rect {
                        x: i * 8,
                        y: 16,
                        w: 8,
                        h: 24,
                    })
                    .collect(),
            };
            assert_eq!(work.encode().len(), 8 + 16 * n as usize);
            assert_eq!(Work::decode(1, &work.encode()).unwrap(), work);
        }
    }

    #[test]
    fn malformed_messages_name_their_tag_and_sender() {
        let e = protocol_error(Message::decode(Tag::Ask.raw(), 4, vec![1, 2, 3]));
        assert!(e.contains("ASK message from rank 4"), "{e}");
        let e = protocol_error(Message::decode(Tag::Ask.raw(), 4, vec![0; 8]));
        assert!(e.contains("ASK message from rank 4"), "{e}");
        let e = protocol_error(Message::decode(Tag::Ask.raw(), 4, words(&[1, 0, 8])));
        assert!(e.contains("ASK message from rank 4: [1, 0, 8]"), "{e}");
        let e = protocol_error(Message::decode(
            Tag::Work.raw(),
            1,
            words(&[0, 2, 1, 2, 3, 4]),
        ));
        assert!(e.contains("WORK message from rank 1: 2 tiles"), "{e}");
        let e = protocol_error(Message::decode(Tag::Pixels.raw(), 2, vec![1]));
        assert!(e.contains("PIXELS message from rank 2"), "{e}");
        let mut done = words(&[0]);
        done.extend(b"{\"frame\": 0}");
        let e = protocol_error(Message::decode(Tag::Done.raw(), 5, done));
        assert!(e.contains("DONE message from rank 5"), "{e}");
        let e = protocol_error(Message::decode(Tag::Alive.raw(), 3, vec![0]));
        assert!(e.contains("ALIVE message from rank 3: 1 bytes"), "{e}");
        assert!(matches!(
            Message::decode(Tag::Alive.raw(), 3, vec![]),
            Ok(Message::Alive)
        ));
        let mut job = words(&[3]);
        job.extend(b"{\"frame\": 3}");
        let e = protocol_error(Message::decode(Tag::Job.raw(), 0, job));
        assert!(e.contains("JOB message from rank 0"), "{e}");
        let e = protocol_error(Message::decode(Tag::Home.raw(), 2, b"{}".to_vec()));
        assert!(e.contains("HOME message from rank 2"), "{e}");
        let e = protocol_error(Message::decode(9, 2, vec![]));
        assert!(e.contains("(tag 9) from rank 2"), "{e}");
    }

    #[test]
    fn jobs_round_trip_and_say_what_is_wrong() {
        let job = Job {
            frame: 4,
            width: 32,
            height: 24,
            camera: crate::scene::Camera {
                position: [0.0, -2.0, 0.5],
                focal_point: [0.0; 3],
                view_up: [0.0, 0.0, 1.0],
                view_angle: 30.0,
                parallel_scale: None,
            },
            mode: crate::shading::Mode::Ao,
            first_sample: 2,
            spp: 1,
            part_of_spp: Some(8),
            whole_pixels: true,
        };
        let msg = job.encode().unwrap();
        assert_eq!(message_frame(&msg), Some(4));
        match Message::decode(Tag::Job.raw(), 0, msg.clone()).unwrap() {
            Message::Job(j) => assert_eq!(j, job),
            m => panic!("{m:?}"),
        }
        let mut other = msg.clone();
        other[0] = 5;
        let e = protocol_error(Message::decode(Tag::Job.raw(), 0, other));
        assert!(
            e.contains("JOB message from rank 0: frame 4 of 32x24 in a message for frame 5"),
            "{e}"
        );
        let empty = Job { width: 0, ..job }.encode().unwrap();
        let e = protocol_error(Message::decode(Tag::Job.raw(), 0, empty));
        assert!(e.contains("frame 4 of 0x24"), "{e}");
    }

    /// The render rank sends `FrameStats`; the display reads `ReportStats`, and writes back every
    /// figure it was sent.
    #[test]
    fn frame_reports_carry_every_statistic() {
        let stats = FrameStats {
            seconds: 0.25,
            fault_rounds: 3,
            fetched_blocks: 12,
            fetch_seconds: 0.0625,
            rays: 99,
            ..FrameStats::default()
        };
        let sent = FrameReport {
            frame: 2,
            rank: 3,
            tiles: 5,
            pixels: 320,
            messages: 4,
            bytes: 1000,
            stats: &stats,
        };
        let msg = sent.encode().unwrap();
        assert_eq!(message_frame(&msg), Some(2));
        let got = FrameReport::decode(3, &msg).unwrap();
        assert_eq!((got.frame, got.rank, got.tiles), (2, 3, 5));
        assert_eq!(got.stats.seconds, 0.25);
        assert_eq!(got.stats.fault_rounds, 3);
        assert_eq!(got.stats.fetched_blocks, 12);
        assert_eq!(got.stats.fetch_seconds, 0.0625);
        assert_eq!(got.to_json(), serde_json::to_value(&sent).unwrap());
        assert!(
            FrameReport::decode(4, &msg).is_err(),
            "another rank's report"
        );
    }
}
