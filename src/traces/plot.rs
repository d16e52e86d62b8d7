//! `dcrt trace plot`: a trace directory as one picture (PNG or SVG) in `chart`'s look. A heading
//! (the directory's name, the ranks and their roles, frames, cache lines per render rank and
//! mapping, run), a legend of the ranks that trace (render or single), then five panels: rounds,
//! MiB fetched and hit rate per frame, a line per rank; the share of each phase (GPU rounds,
//! fetch, upload, shade, send) of each rank's time over all frames, stacked bars; and a heat map
//! of cache-line faults over frames (every render rank's lines summed; lines and frames binned
//! when there are more than pixels) with its colour bar. The line panels' y axes end at the
//! largest value, labelled.

use super::read::Traces;
use crate::chart::{self, Area, Axis, Entry, Format, Swatch};
use crate::error::Result;
use plotters::prelude::*;
use std::path::Path;

/// The phases of a rank's time, in the order they stack.
pub const PHASES: [&str; 5] = ["GPU rounds", "fetch", "upload", "shade", "send"];

/// The picture's width, and the heights of its panels, in pixels.
const W: u32 = 1200;
const LINE_PANEL: u32 = 270;
const PHASE_PANEL: u32 = 320;
const HEAT_PANEL: u32 = 380;
/// The colour bar's width beside the heat map.
const BAR_W: u32 = 130;
/// Marks on the lines up to this many frames (past it they would hide the lines).
const MARKED_FRAMES: usize = 40;

/// Draws `t` to `path` as `format` (whole or not at all).
pub fn draw(t: &Traces, path: &Path, format: Format) -> Result<()> {
    // The layout measures text: no font, no picture (and a clear error).
    chart::font()?;
    let p = Plot::of(t);
    chart::save(path, format, (W, p.height()?), |root| p.draw(root))
}

/// What the picture shows, gathered from the traces.
struct Plot {
    title: String,
    about: Vec<String>,
    frames: Vec<u32>,
    /// Ranks that trace (render or single), ascending.
    ranks: Vec<u32>,
    /// Per rank, per frame: rounds, MiB fetched, hit rate (`None`: no record).
    rounds: Vec<Vec<Option<f64>>>,
    mib: Vec<Vec<Option<f64>>>,
    hit_rate: Vec<Vec<Option<f64>>>,
    /// Per rank, ms in each of `PHASES` over all frames.
    phases: Vec<[f64; 5]>,
    /// Cache lines (the most any rank has), and faults per (frame index, line).
    lines: u32,
    faults: Vec<(usize, u32)>,
}

impl Plot {
    fn of(t: &Traces) -> Plot {
        let frames = t.frames();
        let tracing = |f: &super::read::RankFrame| {
            f.frame
                .role
                .split('+')
                .any(|r| matches!(r, "render" | "single"))
        };
        let ranks: Vec<u32> = t
            .ranks()
            .into_iter()
            .filter(|&r| t.files.iter().any(|f| f.frame.rank == r && tracing(f)))
            .collect();
        let series = |value: &dyn Fn(&super::read::RankFrame) -> f64| -> Vec<Vec<Option<f64>>> {
            ranks
                .iter()
                .map(|&r| frames.iter().map(|&f| t.get(f, r).map(value)).collect())
                .collect()
        };
        let phases = ranks
            .iter()
            .map(|&r| {
                let mut p = [0.0f64; 5];
                for f in t.files.iter().filter(|f| f.frame.rank == r) {
                    let s = &f.frame;
                    let send: f64 = f.tiles.iter().map(|t| t.send_ms).sum();
                    for (a, b) in
                        p.iter_mut()
                            .zip([s.trace_ms, s.fetch_ms, s.upload_ms, s.shade_ms, send])
                    {
                        *a += b;
                    }
                }
                p
            })
            .collect();
        let lines = t
            .files
            .iter()
            .map(|f| f.frame.cache_lines)
            .max()
            .unwrap_or(0);
        let mut faults = Vec::new();
        for f in &t.files {
            let col = frames.iter().position(|&x| x == f.frame.frame).unwrap_or(0);
            for r in &f.rounds {
                faults.extend(r.faults.iter().map(|x| (col, x.line)));
            }
        }
        let name = t
            .dir
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_else(|| t.dir.display().to_string());
        Plot {
            title: format!("Trace of {name}"),
            about: about(t, &frames, lines),
            rounds: series(&|f| f64::from(f.frame.rounds)),
            mib: series(&|f| f.frame.fetched_bytes as f64 / (1024.0 * 1024.0)),
            hit_rate: series(&|f| f.frame.hit_rate),
            frames,
            ranks,
            phases,
            lines,
            faults,
        }
    }

    fn rank_legend(&self) -> Vec<Entry> {
        let marked = self.marked();
        self.ranks
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let m = marked.then(|| chart::mark(i));
                Entry::new(format!("rank {r}"), chart::colour(i), Swatch::Line(m))
            })
            .collect()
    }

    fn phase_legend() -> Vec<Entry> {
        PHASES
            .iter()
            .enumerate()
            .map(|(i, p)| Entry::new(*p, chart::colour(i), Swatch::Box))
            .collect()
    }

    /// Whether points get marks: few frames, or colours that repeat.
    fn marked(&self) -> bool {
        self.frames.len() <= MARKED_FRAMES || self.ranks.len() > chart::PALETTE.len()
    }

    fn top(&self) -> Result<u32> {
        Ok(chart::heading_height(self.about.len()) + chart::legend_height(W, &self.rank_legend())?)
    }

    fn height(&self) -> Result<u32> {
        let phase_legend = chart::legend_height(W, &Plot::phase_legend())?;
        Ok(self.top()? + 3 * LINE_PANEL + PHASE_PANEL + phase_legend + HEAT_PANEL)
    }

    fn draw(&self, root: &Area) -> Result<()> {
        let (head, rest) = root.split_vertically(chart::heading_height(self.about.len()));
        chart::heading(&head, &self.title, &self.about)?;
        let (key, rest) =
            rest.split_vertically(self.top()? - chart::heading_height(self.about.len()));
        chart::legend(&key, &self.rank_legend())?;
        let (a, rest) = rest.split_vertically(LINE_PANEL);
        self.lines_panel(&a, "Rounds per frame", "rounds", &self.rounds, Axis::up_to)?;
        let (a, rest) = rest.split_vertically(LINE_PANEL);
        self.lines_panel(
            &a,
            "Blocks fetched per frame",
            "fetched (MiB)",
            &self.mib,
            Axis::up_to,
        )?;
        let (a, rest) = rest.split_vertically(LINE_PANEL);
        let share = |_: f64, _: usize| Axis::share();
        self.lines_panel(
            &a,
            "Cache hit rate per frame",
            "hit rate (hits / lookups)",
            &self.hit_rate,
            share,
        )?;
        let phase_h = PHASE_PANEL + chart::legend_height(W, &Plot::phase_legend())?;
        let (a, rest) = rest.split_vertically(phase_h);
        self.phases_panel(&a)?;
        self.heat_panel(&rest)
    }

    fn lines_panel(
        &self,
        area: &Area,
        title: &str,
        y_desc: &str,
        series: &[Vec<Option<f64>>],
        axis: impl Fn(f64, usize) -> Axis,
    ) -> Result<()> {
        let area = chart::titled(area, title)?;
        let max = series
            .iter()
            .flatten()
            .flatten()
            .copied()
            .fold(0.0, f64::max);
        let x = self.frame_axis();
        let y = axis(max, 6);
        let mut c = chart::linear(&area, (&x, "frame"), (&y, y_desc))?;
        let marked = self.marked();
        for (i, s) in series.iter().enumerate() {
            let colour = chart::colour(i);
            let points: Vec<(f64, f64)> = self
                .frames
                .iter()
                .zip(s)
                .filter_map(|(&f, v)| v.map(|v| (f64::from(f), v)))
                .collect();
            c.draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                .map_err(chart::fail)?;
            if marked {
                let m = chart::mark(i);
                c.draw_series(
                    points
                        .into_iter()
                        .map(|p| chart::marker(m, p, 8, colour, true)),
                )
                .map_err(chart::fail)?;
            }
        }
        Ok(())
    }

    fn frame_axis(&self) -> Axis {
        let first = self.frames.first().copied().unwrap_or(0);
        let last = self.frames.last().copied().unwrap_or(0);
        Axis::whole(first, last, 10)
    }

    fn phases_panel(&self, area: &Area) -> Result<()> {
        let area = chart::titled_with_legend(
            area,
            "Share of each phase in a rank's time (all frames)",
            &Plot::phase_legend(),
        )?;
        let first = self.ranks.first().copied().unwrap_or(0);
        let last = self.ranks.last().copied().unwrap_or(0);
        let mut x = Axis::whole(first, last, 24);
        if self.ranks.len() <= 24 {
            x.ticks = self.ranks.iter().map(|&r| f64::from(r)).collect();
        }
        let mut c = chart::linear(&area, (&x, "rank"), (&Axis::share(), "share of time"))?;
        for (&r, p) in self.ranks.iter().zip(&self.phases) {
            let total: f64 = p.iter().sum();
            if total <= 0.0 {
                continue;
            }
            let r = f64::from(r);
            let mut y = 0.0;
            for (i, v) in p.iter().enumerate() {
                let h = v / total;
                c.draw_series(std::iter::once(Rectangle::new(
                    [(r - 0.38, y), (r + 0.38, y + h)],
                    chart::colour(i).filled(),
                )))
                .map_err(chart::fail)?;
                y += h;
            }
        }
        Ok(())
    }

    fn heat_panel(&self, area: &Area) -> Result<()> {
        let (w, h) = area.dim_in_pixel();
        // The plot's pixels: the panel less its title, axis labels and the colour bar.
        let (cols_px, rows_px) = ((w - BAR_W - 110) as usize, (h - 100) as usize);
        let frames = self.frames.len().max(1);
        let per_col = frames.div_ceil(cols_px.max(1));
        let per_row = (self.lines as usize).div_ceil(rows_px.max(1)).max(1);
        let cols = frames.div_ceil(per_col);
        let rows = (self.lines as usize).div_ceil(per_row);
        let mut counts = vec![0u64; cols * rows];
        for &(col, line) in &self.faults {
            let row = (line as usize / per_row).min(rows.saturating_sub(1));
            if let Some(c) = counts.get_mut(row * cols + col / per_col) {
                *c += 1;
            }
        }
        let max = counts.iter().copied().max().unwrap_or(0);
        let cell = if per_col > 1 || per_row > 1 {
            let s = |n: usize| if n == 1 { "" } else { "s" };
            format!(
                "; a cell is {per_col} frame{} x {per_row} line{}",
                s(per_col),
                s(per_row)
            )
        } else {
            String::new()
        };
        let what = if self.lines == 0 {
            " (no cache: nothing faults)".to_string()
        } else if max == 0 {
            " (no faults)".to_string()
        } else {
            cell
        };
        let title = format!("Cache-line faults per frame, every render rank's lines summed{what}");
        let area = chart::titled(area, &title)?;
        let (plot, bar) = area.split_horizontally(w - BAR_W);
        let x = self.frame_axis();
        let mut y = Axis::up_to(f64::from(self.lines), 6);
        y.range = 0.0..f64::from(self.lines.max(1));
        let mut c = chart::linear(&plot, (&x, "frame"), (&y, "cache line"))?;
        let edge = |col: usize| -> (f64, f64) {
            let a = self.frames[col * per_col];
            let b = self.frames[((col + 1) * per_col).min(frames) - 1];
            (f64::from(a) - 0.5, f64::from(b) + 0.5)
        };
        c.draw_series(
            counts
                .iter()
                .enumerate()
                .filter(|e| *e.1 > 0)
                .map(|(i, &n)| {
                    let (row, col) = (i / cols, i % cols);
                    let (x0, x1) = edge(col);
                    let y0 = (row * per_row) as f64;
                    let y1 = (((row + 1) * per_row).min(self.lines as usize)) as f64;
                    Rectangle::new(
                        [(x0, y0), (x1, y1)],
                        chart::heat(n as f64, max as f64).filled(),
                    )
                }),
        )
        .map_err(chart::fail)?;
        chart::colour_bar(&bar, "faults", max as f64)
    }
}

/// The heading's lines: ranks and roles, frames, the cache, the run.
fn about(t: &Traces, frames: &[u32], lines: u32) -> Vec<String> {
    let mut roles: Vec<(String, Vec<u32>)> = Vec::new();
    for r in t.ranks() {
        let role = t
            .files
            .iter()
            .find(|f| f.frame.rank == r)
            .map_or(String::new(), |f| f.frame.role.clone());
        match roles.iter_mut().find(|x| x.0 == role) {
            Some(x) => x.1.push(r),
            None => roles.push((role, vec![r])),
        }
    }
    let world = t.files.iter().map(|f| f.frame.ranks).max().unwrap_or(0);
    let roles: Vec<String> = roles
        .iter()
        .map(|(role, r)| format!("{role}: {}", ranks_named(r)))
        .collect();
    let (first, last) = (frames.first().unwrap_or(&0), frames.last().unwrap_or(&0));
    let frames = if frames.len() == 1 {
        format!("1 frame ({first})")
    } else {
        format!("{} frames ({first}-{last})", frames.len())
    };
    let s = |n: u32| if n == 1 { "" } else { "s" };
    let ranks = format!("{world} rank{} ({}); {frames}", s(world), roles.join(", "));
    let cache = if lines == 0 {
        "no cache (every block owned or replicated)".to_string()
    } else {
        let maps: Vec<&str> = {
            let mut m: Vec<&str> = t
                .files
                .iter()
                .filter(|f| f.frame.cache_lines > 0)
                .map(|f| f.frame.cache_map.as_str())
                .collect();
            m.sort_unstable();
            m.dedup();
            m
        };
        // The block size is not in the records; a fetch tells it.
        let (blocks, bytes) = t.files.iter().fold((0u64, 0u64), |a, f| {
            (a.0 + f.frame.fetched_blocks, a.1 + f.frame.fetched_bytes)
        });
        let size = bytes.checked_div(blocks).map_or(String::new(), |block| {
            format!(
                " of {} KiB blocks ({} MiB)",
                chart::number(block as f64 / 1024.0),
                chart::number(f64::from(lines) * block as f64 / (1024.0 * 1024.0))
            )
        });
        format!(
            "cache: {lines} line{} per render rank{size}, mapping {}",
            s(lines),
            maps.join(", ")
        )
    };
    let run = t
        .files
        .first()
        .and_then(|f| f.frame.run.clone())
        .map_or(String::new(), |r| format!("; run {r}"));
    vec![ranks, format!("{cache}{run}")]
}

/// "rank 0", "ranks 2-4, 7".
fn ranks_named(r: &[u32]) -> String {
    format!("rank{} {}", if r.len() == 1 { "" } else { "s" }, spans(r))
}

/// Ranks as runs: `[2, 3, 4, 7]` is "2-4, 7".
fn spans(r: &[u32]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < r.len() {
        let mut j = i;
        while j + 1 < r.len() && r[j + 1] == r[j] + 1 {
            j += 1;
        }
        out.push(if j == i {
            r[i].to_string()
        } else {
            format!("{}-{}", r[i], r[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

#[cfg(test)]
mod tests {
    #[test]
    fn spans_join_runs() {
        assert_eq!(super::spans(&[2, 3, 4, 7]), "2-4, 7");
        assert_eq!(super::spans(&[0]), "0");
        assert_eq!(super::spans(&[]), "");
    }
}
