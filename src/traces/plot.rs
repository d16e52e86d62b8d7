//! A PNG of a trace directory, drawn with the `image` crate. Panels from top to bottom: rounds
//! per frame, MiB fetched per frame, hit rate per frame (0..1), one line per rank in the colour
//! of `PALETTE` (ranks that trace, in order); the share of each phase per rank (bars of GPU rounds, fetch, upload, shade,
//! send in `PHASES` colours); and a heat map of the cache lines' faults over frames (lines down,
//! frames across, brighter is more faults; every rank's lines summed). Each line panel's top is
//! the largest value; axes start at 0.

use super::read::Traces;
use crate::error::{Error, Result};
use image::{Rgb, RgbImage};
use std::path::Path;

pub const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
];

/// GPU rounds, fetch, upload, shade, send.
pub const PHASES: [[u8; 3]; 5] = [
    [31, 119, 180],
    [214, 39, 40],
    [255, 127, 14],
    [44, 160, 44],
    [148, 103, 189],
];

const W: u32 = 800;
const PANEL: u32 = 160;
const PAD: u32 = 20;

pub fn draw(t: &Traces, path: &Path) -> Result<()> {
    let img = render(t);
    img.save(path)
        .map_err(|e| Error::io(path, std::io::Error::other(e)))
}

/// The picture, without writing it.
pub fn render(t: &Traces) -> RgbImage {
    let frames = t.frames();
    // Ranks that trace: the display and the balancer have no rounds to draw.
    let ranks: Vec<u32> = t
        .ranks()
        .into_iter()
        .filter(|&r| {
            t.files
                .iter()
                .any(|f| f.frame.rank == r && matches!(f.frame.role.as_str(), "render" | "single"))
        })
        .collect();
    let h = 5 * (PANEL + PAD) + PAD;
    let mut img = RgbImage::from_pixel(W, h, Rgb([255, 255, 255]));
    let series = |value: &dyn Fn(&super::RankFrame) -> f64| -> Vec<Vec<f64>> {
        ranks
            .iter()
            .map(|&r| {
                frames
                    .iter()
                    .map(|&f| t.get(f, r).map(value).unwrap_or(0.0))
                    .collect()
            })
            .collect()
    };
    let panels: [Vec<Vec<f64>>; 3] = [
        series(&|f| f64::from(f.frame.rounds)),
        series(&|f| f.frame.fetched_bytes as f64 / (1024.0 * 1024.0)),
        series(&|f| f.frame.hit_rate),
    ];
    for (i, p) in panels.iter().enumerate() {
        let top = PAD + i as u32 * (PANEL + PAD);
        let max = if i == 2 {
            1.0
        } else {
            p.iter().flatten().copied().fold(0.0, f64::max)
        };
        lines(&mut img, top, p, max);
    }
    phases(&mut img, PAD + 3 * (PANEL + PAD), t, &ranks);
    heat(&mut img, PAD + 4 * (PANEL + PAD), t, &frames);
    img
}

fn axes(img: &mut RgbImage, top: u32) {
    let grey = Rgb([0, 0, 0]);
    for x in PAD..W - PAD {
        img.put_pixel(x, top + PANEL, grey);
    }
    for y in top..=top + PANEL {
        img.put_pixel(PAD, y, grey);
    }
}

fn lines(img: &mut RgbImage, top: u32, series: &[Vec<f64>], max: f64) {
    axes(img, top);
    let n = series.first().map_or(0, Vec::len);
    let x = |i: usize| PAD + 1 + (i as u32 * (W - 2 * PAD - 2)) / (n.max(2) - 1) as u32;
    let y = |v: f64| {
        let f = if max > 0.0 {
            (v / max).clamp(0.0, 1.0)
        } else {
            0.0
        };
        top + PANEL - (f * f64::from(PANEL)) as u32
    };
    for (k, s) in series.iter().enumerate() {
        let c = Rgb(PALETTE[k % PALETTE.len()]);
        for i in 0..s.len() {
            let (x0, y0) = (x(i), y(s[i]));
            dot(img, x0, y0, c);
            if i + 1 < s.len() {
                segment(img, (x0, y0), (x(i + 1), y(s[i + 1])), c);
            }
        }
    }
}

fn phases(img: &mut RgbImage, top: u32, t: &Traces, ranks: &[u32]) {
    axes(img, top);
    let bar = (W - 2 * PAD - 2) / ranks.len().max(1) as u32;
    for (k, &r) in ranks.iter().enumerate() {
        let mut p = [0.0f64; 5];
        for f in t.files.iter().filter(|f| f.frame.rank == r) {
            let s = &f.frame;
            let send: f64 = f.tiles.iter().map(|t| t.send_ms).sum();
            for (a, b) in p
                .iter_mut()
                .zip([s.trace_ms, s.fetch_ms, s.upload_ms, s.shade_ms, send])
            {
                *a += b;
            }
        }
        let total: f64 = p.iter().sum();
        if total <= 0.0 {
            continue;
        }
        let x0 = PAD + 1 + k as u32 * bar;
        let mut y = top + PANEL;
        for (i, v) in p.iter().enumerate() {
            let hgt = ((v / total) * f64::from(PANEL)).round() as u32;
            for yy in y.saturating_sub(hgt)..y {
                for xx in x0 + 2..x0 + bar.saturating_sub(2).max(3) {
                    img.put_pixel(xx, yy, Rgb(PHASES[i]));
                }
            }
            y = y.saturating_sub(hgt);
        }
    }
}

fn heat(img: &mut RgbImage, top: u32, t: &Traces, frames: &[u32]) {
    axes(img, top);
    let lines = t
        .files
        .iter()
        .map(|f| f.frame.cache_lines)
        .max()
        .unwrap_or(0);
    if lines == 0 || frames.is_empty() {
        return;
    }
    let rows = lines.min(PANEL);
    let mut counts = vec![0u32; (rows as usize) * frames.len()];
    for f in &t.files {
        let col = frames
            .iter()
            .position(|&x| x == f.frame.frame)
            .expect("frame");
        for r in &f.rounds {
            for fault in &r.faults {
                let row = (u64::from(fault.line) * u64::from(rows) / u64::from(lines)) as usize;
                counts[row.min(rows as usize - 1) * frames.len() + col] += 1;
            }
        }
    }
    let max = counts.iter().copied().max().unwrap_or(0).max(1);
    let cw = (W - 2 * PAD - 2) / frames.len() as u32;
    let rh = (PANEL / rows).max(1);
    for row in 0..rows as usize {
        for col in 0..frames.len() {
            let v = counts[row * frames.len() + col];
            let g = (255.0 * (f64::from(v) / f64::from(max)).sqrt()) as u8;
            let c = Rgb([g, (g as u32 * 3 / 4) as u8, 255 - g]);
            for yy in 0..rh {
                for xx in 0..cw.max(1) {
                    img.put_pixel(
                        PAD + 1 + col as u32 * cw + xx,
                        top + row as u32 * rh + yy,
                        c,
                    );
                }
            }
        }
    }
}

fn dot(img: &mut RgbImage, x: u32, y: u32, c: Rgb<u8>) {
    for dy in 0..3 {
        for dx in 0..3 {
            let (xx, yy) = ((x + dx).saturating_sub(1), (y + dy).saturating_sub(1));
            if xx < img.width() && yy < img.height() {
                img.put_pixel(xx, yy, c);
            }
        }
    }
}

fn segment(img: &mut RgbImage, a: (u32, u32), b: (u32, u32), c: Rgb<u8>) {
    let steps = a.0.abs_diff(b.0).max(a.1.abs_diff(b.1)).max(1);
    for i in 0..=steps {
        let f = f64::from(i) / f64::from(steps);
        let x = f64::from(a.0) + f * (f64::from(b.0) - f64::from(a.0));
        let y = f64::from(a.1) + f * (f64::from(b.1) - f64::from(a.1));
        img.put_pixel(x.round() as u32, y.round() as u32, c);
    }
}
