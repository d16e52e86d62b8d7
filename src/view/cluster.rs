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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::frame::FrameStats;

    /// The figures read from a render rank's report by name are the `FrameStats` it sent: a
    /// field renamed on one side would otherwise show as 0 in the overlay.
    #[test]
    fn figures_come_from_the_reports_as_sent() {
        let report = |rank: u32, seconds: f64, rounds: u32| {
            let stats = FrameStats {
                seconds,
                trace_seconds: seconds / 2.0,
                shade_seconds: seconds / 4.0,
                fetch_seconds: seconds / 8.0,
                upload_seconds: seconds / 16.0,
                fault_rounds: rounds,
                fetched_bytes: 1000 * u64::from(rank),
                lookups: 100,
                hits: 90,
                ..FrameStats::default()
            };
            let sent = FrameReport {
                frame: 3,
                rank,
                tiles: u64::from(rank),
                pixels: 64 * u64::from(rank),
                messages: 1,
                bytes: 10,
                stats: &stats,
            };
            FrameReport::decode(rank, &sent.encode().unwrap()).unwrap()
        };
        let f = figures(&[report(2, 0.5, 7), report(3, 1.0, 4)], 1.25);
        assert_eq!(f.seconds, 1.25);
        // The slowest rank's phases.
        assert_eq!(
            (
                f.trace_seconds,
                f.shade_seconds,
                f.fetch_seconds,
                f.upload_seconds
            ),
            (0.5, 0.25, 0.125, 0.0625)
        );
        assert_eq!(f.fault_rounds, 7, "the most of any rank");
        assert_eq!((f.fetched_bytes, f.lookups, f.hits), (5000, 200, 180));
        let shares: Vec<(u32, u64, u64)> = f
            .shares
            .iter()
            .map(|s| (s.rank, s.tiles, s.pixels))
            .collect();
        assert_eq!(shares, [(2, 2, 128), (3, 3, 192)]);
    }
}
