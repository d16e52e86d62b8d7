//! The frames of a live view under mpirun (docs/ARCHITECTURE.md, Live view): made by the render
//! ranks, a `JOB` each, through the display rank's `cluster::live::LiveDisplay`. A pass to be
//! added to others travels as whole pixels, every other frame as RGB8.

use super::producer::{Figures, Frames, Made, Share};
use crate::cluster::live::{Assembled, LiveDisplay, Pixels};
use crate::cluster::protocol::{FrameReport, Job};
use crate::error::Result;
use crate::scene::Camera;
use crate::shading::Shading;
use std::time::Duration;

/// How long the display waits for a wish before it looks after the ranks.
const SLICE: Duration = Duration::from_millis(50);

impl Frames for LiveDisplay<'_> {
    fn render(
        &mut self,
        camera: &Camera,
        shading: Shading,
        (width, height): (u32, u32),
        sums: bool,
    ) -> Result<Made> {
        let job = Job {
            frame: 0,
            width,
            height,
            camera: *camera,
            mode: shading.mode,
            first_sample: shading.first_sample,
            spp: shading.spp,
            part_of_spp: shading.part_of_spp,
            whole_pixels: sums,
        };
        let Assembled {
            pixels,
            reports,
            seconds,
        } = LiveDisplay::render(self, &job)?;
        let figures = figures(&reports, seconds);
        Ok(match pixels {
            Pixels::Whole(frame) => Made::Linear(frame, figures),
            Pixels::Rgb8(image) => Made::Rgb8(image, figures),
        })
    }

    fn slice(&self) -> Option<Duration> {
        Some(SLICE)
    }

    fn between(&mut self) -> Result<()> {
        self.wait(Duration::ZERO)
    }
}

/// A frame's figures from the render ranks' reports: the phases of the slowest rank, the most
/// fault rounds of any, the cache's counts summed.
fn figures(reports: &[FrameReport], seconds: f64) -> Figures {
    let num = |r: &FrameReport, k: &str| r.stats.rest.get(k).and_then(|v| v.as_f64());
    let count = |k: &str| -> u64 {
        reports
            .iter()
            .map(|r| num(r, k).unwrap_or(0.0) as u64)
            .sum()
    };
    let slowest = reports
        .iter()
        .max_by(|a, b| a.stats.seconds.total_cmp(&b.stats.seconds));
    let phase = |k: &str| slowest.and_then(|r| num(r, k)).unwrap_or(0.0);
    Figures {
        seconds,
        trace_seconds: phase("trace_seconds"),
        shade_seconds: phase("shade_seconds"),
        fetch_seconds: slowest.map_or(0.0, |r| r.stats.fetch_seconds),
        upload_seconds: phase("upload_seconds"),
        fault_rounds: reports
            .iter()
            .map(|r| r.stats.fault_rounds)
            .max()
            .unwrap_or(0),
        fetched_bytes: count("fetched_bytes"),
        lookups: count("lookups"),
        hits: count("hits"),
        shares: reports
            .iter()
            .map(|r| Share {
                rank: r.rank,
                tiles: r.tiles,
                pixels: r.pixels,
            })
            .collect(),
    }
}
