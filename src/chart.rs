//! The one look of every chart dcrt draws (`dcrt trace plot`, the bench's figures and its
//! shading plot; docs/ARCHITECTURE.md, Charts): PNG or SVG from the same drawing code (`Backend`),
//! written through `files` (nothing on failure); a heading; panels with a title, labelled axes
//! and ticks; legends that wrap below a panel's title; a colour bar for heat maps. Text is set
//! in `legend::font`'s family (an SVG names DejaVu Sans, which measured it).

use crate::error::{Error, Result};
use plotters::coord::Shift;
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters_backend::{
    BackendColor, BackendCoord, BackendTextStyle, DrawingErrorKind, FontFamily, FontStyle,
    FontTransform, text_anchor,
};
use std::path::Path;

/// What a chart is written as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Png,
    Svg,
}

impl std::str::FromStr for Format {
    type Err = Error;
    fn from_str(s: &str) -> Result<Format> {
        match s.to_ascii_lowercase().as_str() {
            "png" => Ok(Format::Png),
            "svg" => Ok(Format::Svg),
            _ => Err(Error::Invalid(format!(
                "unknown picture format \"{s}\": png or svg"
            ))),
        }
    }
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(match self {
            Format::Png => "png",
            Format::Svg => "svg",
        })
    }
}

impl Format {
    /// The format of `path`: `asked` when given (an error when the name ends in the other
    /// format's extension), else the name's extension (`.png`, `.svg`); an error when neither
    /// says.
    pub fn of(path: &Path, asked: Option<Format>) -> Result<Format> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let named = ext.as_deref().and_then(|e| e.parse::<Format>().ok());
        match (asked, named) {
            (Some(a), Some(n)) if a != n => Err(Error::Invalid(format!(
                "{}: --format {a}, but the name ends in .{n}",
                path.display()
            ))),
            (Some(a), _) => Ok(a),
            (None, Some(n)) => Ok(n),
            (None, None) => Err(Error::Invalid(format!(
                "{}: the name does not say the picture's format: end it in .png or .svg, or give \
                 --format png|svg",
                path.display()
            ))),
        }
    }
}

/// The font family of an SVG's text: the one whose widths laid it out, then any sans-serif.
const SVG_FAMILY: &str = "DejaVu Sans, sans-serif";

/// A drawing backend that is a PNG's pixels or an SVG's elements, so that one drawing function
/// serves both.
pub enum Backend<'a> {
    Png(BitMapBackend<'a>),
    Svg(SVGBackend<'a>),
}

/// The drawing area every chart function draws on.
pub type Area<'a> = DrawingArea<Backend<'a>, Shift>;

/// A backend's failure, as text.
#[derive(Debug)]
pub struct BackendError(String);

impl std::fmt::Display for BackendError {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BackendError {}

fn lift<E: std::error::Error + Send + Sync>(
    e: DrawingErrorKind<E>,
) -> DrawingErrorKind<BackendError> {
    match e {
        DrawingErrorKind::DrawingError(e) => {
            DrawingErrorKind::DrawingError(BackendError(e.to_string()))
        }
        DrawingErrorKind::FontError(f) => DrawingErrorKind::FontError(f),
    }
}

/// A text style with the SVG's font family in place of the registered one.
struct SvgText<'s, T>(&'s T);

impl<T: BackendTextStyle> BackendTextStyle for SvgText<'_, T> {
    type FontError = T::FontError;
    fn color(&self) -> BackendColor {
        self.0.color()
    }
    fn size(&self) -> f64 {
        self.0.size()
    }
    fn transform(&self) -> FontTransform {
        self.0.transform()
    }
    fn style(&self) -> FontStyle {
        self.0.style()
    }
    fn anchor(&self) -> text_anchor::Pos {
        self.0.anchor()
    }
    fn family(&self) -> FontFamily<'_> {
        FontFamily::Name(SVG_FAMILY)
    }
    fn layout_box(
        &self,
        text: &str,
    ) -> std::result::Result<((i32, i32), (i32, i32)), T::FontError> {
        self.0.layout_box(text)
    }
    fn draw<E, F: FnMut(i32, i32, BackendColor) -> std::result::Result<(), E>>(
        &self,
        text: &str,
        pos: BackendCoord,
        draw: F,
    ) -> std::result::Result<std::result::Result<(), E>, T::FontError> {
        self.0.draw(text, pos, draw)
    }
}

type Drawn<T = ()> = std::result::Result<T, DrawingErrorKind<BackendError>>;

macro_rules! either {
    ($self:ident, $b:ident => $e:expr) => {
        match $self {
            Backend::Png($b) => $e.map_err(lift),
            Backend::Svg($b) => $e.map_err(lift),
        }
    };
}

impl DrawingBackend for Backend<'_> {
    type ErrorType = BackendError;

    fn get_size(&self) -> (u32, u32) {
        match self {
            Backend::Png(b) => b.get_size(),
            Backend::Svg(b) => b.get_size(),
        }
    }
    fn ensure_prepared(&mut self) -> Drawn {
        either!(self, b => b.ensure_prepared())
    }
    fn present(&mut self) -> Drawn {
        either!(self, b => b.present())
    }
    fn draw_pixel(&mut self, point: BackendCoord, color: BackendColor) -> Drawn {
        either!(self, b => b.draw_pixel(point, color))
    }
    fn draw_line<S: plotters_backend::BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Drawn {
        either!(self, b => b.draw_line(from, to, style))
    }
    fn draw_rect<S: plotters_backend::BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Drawn {
        either!(self, b => b.draw_rect(upper_left, bottom_right, style, fill))
    }
    fn draw_path<S: plotters_backend::BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Drawn {
        either!(self, b => b.draw_path(path, style))
    }
    fn draw_circle<S: plotters_backend::BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Drawn {
        either!(self, b => b.draw_circle(center, radius, style, fill))
    }
    fn fill_polygon<S: plotters_backend::BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Drawn {
        either!(self, b => b.fill_polygon(vert, style))
    }
    fn draw_text<T: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &T,
        pos: BackendCoord,
    ) -> Drawn {
        match self {
            Backend::Png(b) => b.draw_text(text, style, pos).map_err(lift),
            Backend::Svg(b) => b.draw_text(text, &SvgText(style), pos).map_err(lift),
        }
    }
    fn estimate_text_size<T: BackendTextStyle>(&self, text: &str, style: &T) -> Drawn<(u32, u32)> {
        either!(self, b => b.estimate_text_size(text, style))
    }
    fn blit_bitmap(&mut self, pos: BackendCoord, size: (u32, u32), src: &[u8]) -> Drawn {
        either!(self, b => b.blit_bitmap(pos, size, src))
    }
}

/// A drawing error as dcrt's.
pub fn fail<E: std::fmt::Display>(e: E) -> Error {
    Error::Internal(format!("drawing a chart: {e}"))
}

/// Draws a `w` x `h` picture on a white ground with `draw` and writes it to `path` as `format`
/// through `files` (whole or not at all; nothing when drawing fails).
pub fn save(
    path: &Path,
    format: Format,
    (w, h): (u32, u32),
    draw: impl FnOnce(&Area) -> Result<()>,
) -> Result<()> {
    font()?;
    match format {
        Format::Png => {
            let mut buf = vec![255u8; (w as usize) * (h as usize) * 3];
            {
                let root =
                    Backend::Png(BitMapBackend::with_buffer(&mut buf, (w, h))).into_drawing_area();
                root.fill(&WHITE).map_err(fail)?;
                draw(&root)?;
                root.present().map_err(fail)?;
            }
            let img = image::RgbImage::from_raw(w, h, buf)
                .ok_or_else(|| fail("a picture buffer of the wrong size"))?;
            crate::files::write_rgb_png(path, &img)
        }
        Format::Svg => {
            let mut svg = String::new();
            {
                let root =
                    Backend::Svg(SVGBackend::with_string(&mut svg, (w, h))).into_drawing_area();
                root.fill(&WHITE).map_err(fail)?;
                draw(&root)?;
                root.present().map_err(fail)?;
            }
            crate::files::write_bytes(path, svg.as_bytes())
        }
    }
}

/// The family of every chart's text (`legend::font`: a clear error without a font).
pub fn font() -> Result<&'static str> {
    crate::legend::font()
}

/// Text sizes in pixels: the picture's heading, a panel's title, axis descriptions and legends,
/// tick labels.
pub const HEADING: f64 = 24.0;
pub const TITLE: f64 = 19.0;
pub const LABEL: f64 = 16.0;
pub const TICK: f64 = 14.0;

/// Text of `size` in the charts' family.
pub fn text(size: f64) -> TextStyle<'static> {
    // `font` has been checked by `save` before anything is drawn.
    (crate::legend::font().unwrap_or("sans-serif"), size)
        .into_font()
        .color(&BLACK)
}

/// Colours for categories (ranks, caches, phases): Tableau's ten.
pub const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// The colour of category `i`; past the palette's ten, `mark(i)` tells categories apart.
pub fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// A point's mark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    Circle,
    Triangle,
    Square,
    Cross,
    Diamond,
}

/// The mark of category `i`: a circle for the first ten, then another shape for each next ten.
pub fn mark(i: usize) -> Mark {
    const MARKS: [Mark; 5] = [
        Mark::Circle,
        Mark::Triangle,
        Mark::Square,
        Mark::Cross,
        Mark::Diamond,
    ];
    MARKS[(i / PALETTE.len()) % MARKS.len()]
}

/// Mark `m` at `at` (in a chart's coordinates), `size` pixels across, filled or hollow.
pub fn marker<C>(m: Mark, at: C, size: i32, colour: RGBColor, filled: bool) -> Marker<C> {
    Marker {
        at,
        mark: m,
        r: (size / 2).max(1),
        colour,
        filled,
    }
}

/// A point's mark as a plotters element.
pub struct Marker<C> {
    at: C,
    mark: Mark,
    r: i32,
    colour: RGBColor,
    filled: bool,
}

impl<'a, C> plotters::element::PointCollection<'a, C> for &'a Marker<C> {
    type Point = &'a C;
    type IntoIter = std::iter::Once<&'a C>;
    fn point_iter(self) -> Self::IntoIter {
        std::iter::once(&self.at)
    }
}

impl<DB: DrawingBackend, C> plotters::element::Drawable<DB> for Marker<C> {
    fn draw<I: Iterator<Item = BackendCoord>>(
        &self,
        mut points: I,
        backend: &mut DB,
        _: (u32, u32),
    ) -> std::result::Result<(), DrawingErrorKind<DB::ErrorType>> {
        let Some((x, y)) = points.next() else {
            return Ok(());
        };
        let (r, filled) = (self.r, self.filled);
        let style = if filled {
            self.colour.filled()
        } else {
            self.colour.stroke_width(2)
        };
        let polygon = |backend: &mut DB, p: Vec<BackendCoord>| {
            if filled {
                backend.fill_polygon(p, &style)
            } else {
                let mut closed = p.clone();
                closed.push(p[0]);
                backend.draw_path(closed, &style)
            }
        };
        match self.mark {
            Mark::Circle => backend.draw_circle((x, y), r as u32, &style, filled),
            Mark::Square => backend.draw_rect((x - r, y - r), (x + r, y + r), &style, filled),
            Mark::Triangle => polygon(
                backend,
                vec![(x, y - r - 1), (x + r + 1, y + r), (x - r - 1, y + r)],
            ),
            Mark::Diamond => polygon(
                backend,
                vec![
                    (x, y - r - 1),
                    (x + r + 1, y),
                    (x, y + r + 1),
                    (x - r - 1, y),
                ],
            ),
            Mark::Cross => {
                let line = self.colour.stroke_width(2);
                backend.draw_line((x - r, y - r), (x + r, y + r), &line)?;
                backend.draw_line((x - r, y + r), (x + r, y - r), &line)
            }
        }
    }
}

/// What stands for a series in a legend.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Swatch {
    /// A line, with a mark on it when given.
    Line(Option<Mark>),
    /// A filled box (bars, areas).
    Box,
    /// A mark alone, filled or hollow.
    Mark(Mark, bool),
}

/// One entry of a legend.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub label: String,
    pub colour: RGBColor,
    pub swatch: Swatch,
}

impl Entry {
    pub fn new(label: impl Into<String>, colour: RGBColor, swatch: Swatch) -> Entry {
        Entry {
            label: label.into(),
            colour,
            swatch,
        }
    }
}

const SWATCH_W: i32 = 26;
const ENTRY_GAP: i32 = 22;
const ROW: i32 = (LABEL * 1.5) as i32;
const LEGEND_PAD: i32 = 8;

/// Where each entry goes in a legend `width` pixels wide: (x, row), rows wrapping.
fn legend_layout(width: u32, entries: &[Entry]) -> Result<Vec<(i32, i32)>> {
    let font = text(LABEL);
    let mut out = Vec::with_capacity(entries.len());
    let (mut x, mut row) = (LEGEND_PAD, 0);
    for e in entries {
        let (tw, _) = font.font.box_size(&e.label).map_err(fail)?;
        let w = SWATCH_W + 6 + tw as i32;
        if x > LEGEND_PAD && x + w > width as i32 - LEGEND_PAD {
            x = LEGEND_PAD;
            row += 1;
        }
        out.push((x, row));
        x += w + ENTRY_GAP;
    }
    Ok(out)
}

/// The height of `entries` as a legend `width` pixels wide (0 without entries).
pub fn legend_height(width: u32, entries: &[Entry]) -> Result<u32> {
    let rows = legend_layout(width, entries)?
        .last()
        .map_or(0, |&(_, r)| r + 1);
    Ok(if rows == 0 {
        0
    } else {
        (rows * ROW + LEGEND_PAD) as u32
    })
}

/// Draws `entries` left to right on `area`, wrapping to new rows at its right edge.
pub fn legend(area: &Area, entries: &[Entry]) -> Result<()> {
    let (w, _) = area.dim_in_pixel();
    let font = text(LABEL).pos(Pos::new(HPos::Left, VPos::Center));
    for (e, (x, row)) in entries.iter().zip(legend_layout(w, entries)?) {
        let y = row * ROW + ROW / 2 + LEGEND_PAD / 2;
        let c = e.colour;
        match e.swatch {
            Swatch::Line(m) => {
                area.draw(&PathElement::new(
                    vec![(x, y), (x + SWATCH_W, y)],
                    c.stroke_width(3),
                ))
                .map_err(fail)?;
                if let Some(m) = m {
                    area.draw(&marker(m, (x + SWATCH_W / 2, y), 9, c, true))
                        .map_err(fail)?;
                }
            }
            Swatch::Box => area
                .draw(&Rectangle::new(
                    [(x + 3, y - 7), (x + SWATCH_W - 3, y + 7)],
                    c.filled(),
                ))
                .map_err(fail)?,
            Swatch::Mark(m, filled) => area
                .draw(&marker(m, (x + SWATCH_W / 2, y), 11, c, filled))
                .map_err(fail)?,
        }
        area.draw(&Text::new(
            e.label.clone(),
            (x + SWATCH_W + 6, y),
            font.clone(),
        ))
        .map_err(fail)?;
    }
    Ok(())
}

/// The picture's heading: `title` large, then `lines` below it, on `area`'s top.
pub fn heading(area: &Area, title: &str, lines: &[String]) -> Result<()> {
    area.draw(&Text::new(title.to_string(), (12, 8), text(HEADING)))
        .map_err(fail)?;
    for (i, l) in lines.iter().enumerate() {
        let y = 8 + (HEADING * 1.4) as i32 + i as i32 * (LABEL * 1.35) as i32;
        area.draw(&Text::new(l.clone(), (12, y), text(LABEL)))
            .map_err(fail)?;
    }
    Ok(())
}

/// The height `heading` takes with `lines` lines below the title.
pub fn heading_height(lines: usize) -> u32 {
    (8.0 + HEADING * 1.4 + lines as f64 * LABEL * 1.35 + 6.0) as u32
}

/// A panel's title on `area`'s top, and the area below it.
pub fn titled<'a>(area: &Area<'a>, title: &str) -> Result<Area<'a>> {
    let h = (TITLE * 1.6) as u32;
    let (top, rest) = area.split_vertically(h);
    top.draw(&Text::new(
        title.to_string(),
        (12, (TITLE * 0.3) as i32),
        text(TITLE),
    ))
    .map_err(fail)?;
    Ok(rest)
}

/// A panel's title, then a legend of `entries` wrapping below it, and the area below both.
pub fn titled_with_legend<'a>(area: &Area<'a>, title: &str, entries: &[Entry]) -> Result<Area<'a>> {
    let rest = titled(area, title)?;
    let (w, _) = rest.dim_in_pixel();
    let h = legend_height(w, entries)?;
    let (top, rest) = rest.split_vertically(h);
    legend(&top, entries)?;
    Ok(rest)
}

/// An axis: its range, the values that get a tick and a label, and how a label is written.
#[derive(Clone, Debug)]
pub struct Axis {
    pub range: std::ops::Range<f64>,
    pub ticks: Vec<f64>,
    pub label: fn(f64) -> String,
}

/// A round step (1, 2 or 5 times a power of ten) near `span / n`.
fn round_step(span: f64, n: usize) -> f64 {
    let raw = span / n.max(1) as f64;
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&s| s >= raw)
        .unwrap_or(10.0 * p)
}

impl Axis {
    /// From 0 to `max`: round steps, at most about `n` of them, and `max` itself, the top,
    /// labelled with `number`. Nothing but 0 and 1 when `max` is not above 0.
    pub fn up_to(max: f64, n: usize) -> Axis {
        if !(max > 0.0 && max.is_finite()) {
            return Axis {
                range: 0.0..1.0,
                ticks: vec![0.0, 1.0],
                label: number,
            };
        }
        let step = round_step(max, n);
        let mut ticks: Vec<f64> = (0..)
            .map(|i| f64::from(i) * step)
            .take_while(|&t| t < max - 0.4 * step)
            .collect();
        ticks.push(max);
        Axis {
            range: 0.0..max * 1.04,
            ticks,
            label: number,
        }
    }

    /// A share from 0 to 1 in steps of 0.2.
    pub fn share() -> Axis {
        Axis {
            range: 0.0..1.02,
            ticks: (0..=5).map(|i| f64::from(i) / 5.0).collect(),
            label: number,
        }
    }

    /// Whole numbers `first..=last` (frames, ranks' places), half a step of room each side;
    /// at most about `n` ticks, always `first` and `last`.
    pub fn whole(first: u32, last: u32, n: usize) -> Axis {
        let (a, b) = (f64::from(first), f64::from(last.max(first)));
        let step = round_step((b - a).max(1.0), n).max(1.0);
        let mut ticks: Vec<f64> = (0..)
            .map(|i| a + f64::from(i) * step)
            .take_while(|&t| t < b - 0.6 * step)
            .collect();
        ticks.push(b);
        Axis {
            range: a - 0.5..b + 0.5,
            ticks,
            label: number,
        }
    }

    fn coord(&self) -> Ticked {
        Ticked {
            inner: self.range.clone().into(),
            ticks: self.ticks.clone(),
        }
    }
}

/// A linear f64 axis with its ticks at given values.
pub struct Ticked {
    inner: RangedCoordf64,
    ticks: Vec<f64>,
}

impl Ranged for Ticked {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;
    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }
    fn key_points<H: KeyPointHint>(&self, _: H) -> Vec<f64> {
        self.ticks.clone()
    }
    fn range(&self) -> std::ops::Range<f64> {
        self.inner.range()
    }
}

/// `v` to three significant digits, no trailing zeros; whole numbers as they are.
pub fn number(v: f64) -> String {
    if v == v.round() && v.abs() < 1e15 {
        return format!("{v:.0}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 12) as usize;
    let s = format!("{v:.digits$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" { "0".into() } else { s }
}

/// A linear chart's context.
pub type Linear<'a, 'b> = ChartContext<'a, Backend<'b>, Cartesian2d<Ticked, Ticked>>;

/// A chart on `area` over axes `x` and `y`, described by `x_desc` and `y_desc` (with units),
/// its grid at the ticks.
pub fn linear<'a, 'b>(
    area: &'a Area<'b>,
    (x, x_desc): (&Axis, &str),
    (y, y_desc): (&Axis, &str),
) -> Result<Linear<'a, 'b>> {
    let mut chart = ChartBuilder::on(area)
        .margin(10)
        .margin_left(14)
        .x_label_area_size(50)
        .y_label_area_size(76)
        .build_cartesian_2d(x.coord(), y.coord())
        .map_err(fail)?;
    let (xl, yl) = (x.label, y.label);
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style(text(LABEL))
        .label_style(text(TICK))
        .bold_line_style(RGBColor(225, 225, 225))
        .x_label_formatter(&move |v| xl(*v))
        .y_label_formatter(&move |v| yl(*v))
        .draw()
        .map_err(fail)?;
    Ok(chart)
}

/// A chart's context with a log y axis (and a linear or log x axis).
pub type LogY<'a, 'b, X> = ChartContext<'a, Backend<'b>, Cartesian2d<X, LogTicked>>;

/// A log f64 axis with ticks at 1, 2 and 5 times the powers of ten in its range (only the
/// powers when those are many; every digit when they are few).
pub struct LogTicked {
    inner: plotters::coord::combinators::LogCoord<f64>,
    ticks: Vec<f64>,
}

impl LogTicked {
    pub fn new(lo: f64, hi: f64) -> LogTicked {
        LogTicked {
            inner: (lo..hi).log_scale().into(),
            ticks: log_ticks(lo, hi),
        }
    }
}

/// The ticks of a log axis over `lo..hi`.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let of = |digits: &[f64]| -> Vec<f64> {
        let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
        (a..=b)
            .flat_map(|k| digits.iter().map(move |m| m * 10f64.powi(k)))
            .filter(|v| (lo..=hi).contains(v))
            .collect()
    };
    let t = of(&[1.0, 2.0, 5.0]);
    if t.len() > 12 {
        of(&[1.0])
    } else if t.len() < 4 {
        of(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    } else {
        t
    }
}

impl Ranged for LogTicked {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;
    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }
    fn key_points<H: KeyPointHint>(&self, _: H) -> Vec<f64> {
        self.ticks.clone()
    }
    fn range(&self) -> std::ops::Range<f64> {
        self.inner.range()
    }
}

/// A chart on `area` with a log y axis over `lo..hi`: a linear x axis over `x`, or a log one
/// when `log_x`; ticks labelled with `number`.
pub fn log_y<'a, 'b>(
    area: &'a Area<'b>,
    x: std::ops::Range<f64>,
    (lo, hi): (f64, f64),
    descs: (&str, &str),
) -> Result<LogY<'a, 'b, RangedCoordf64>> {
    log_chart(area, x.into(), LogTicked::new(lo, hi), descs)
}

/// A chart on `area` with both axes log: x over `x`, y over `y`, ticks labelled with `number`.
pub fn log_log<'a, 'b>(
    area: &'a Area<'b>,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    descs: (&str, &str),
) -> Result<LogY<'a, 'b, LogTicked>> {
    log_chart(area, LogTicked::new(x0, x1), LogTicked::new(y0, y1), descs)
}

/// The charts' look for an x axis of any kind over a log y axis.
fn log_chart<'a, 'b, X>(
    area: &'a Area<'b>,
    x: X,
    y: LogTicked,
    (x_desc, y_desc): (&str, &str),
) -> Result<LogY<'a, 'b, X>>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let mut chart = ChartBuilder::on(area)
        .margin(10)
        .margin_left(14)
        .x_label_area_size(50)
        .y_label_area_size(76)
        .build_cartesian_2d(x, y)
        .map_err(fail)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style(text(LABEL))
        .label_style(text(TICK))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(245, 245, 245))
        .x_label_formatter(&|v| number(*v))
        .y_label_formatter(&|v| number(*v))
        .draw()
        .map_err(fail)?;
    Ok(chart)
}

/// The range of a log axis covering the positive, finite `values`, a factor 1.5 of room each
/// side (0.1..10 without any).
pub fn log_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        (0.1, 10.0)
    } else {
        (lo / 1.5, hi * 1.5)
    }
}

/// The colour of a heat map's cell of `v` out of `max`: white for none, else viridis from dark
/// (few) to yellow (`max`).
pub fn heat(v: f64, max: f64) -> RGBColor {
    if v < 0.5 || max <= 0.0 {
        return WHITE;
    }
    let map = crate::colormap::Colormap::Viridis.srgb();
    let i = ((v / max).clamp(0.0, 1.0) * (map.len() - 1) as f64).round() as usize;
    let [r, g, b] = map[i];
    RGBColor(r, g, b)
}

/// A colour bar of `heat` over 0..`max` on `area`, `title` above it, labelled on its right.
pub fn colour_bar(area: &Area, title: &str, max: f64) -> Result<()> {
    let axis = Axis::up_to(max, 5);
    let (top, rest) = area.split_vertically((LABEL * 1.6) as u32);
    top.draw(&Text::new(title.to_string(), (4, 2), text(LABEL)))
        .map_err(fail)?;
    let mut chart = ChartBuilder::on(&rest)
        .margin(10)
        .x_label_area_size(50)
        .right_y_label_area_size(60)
        .build_cartesian_2d(0.0..1.0, axis.coord())
        .map_err(fail)?;
    let steps = 128;
    let top_value = axis.range.end;
    chart
        .draw_series((0..steps).map(|i| {
            let a = top_value * f64::from(i) / f64::from(steps);
            let b = top_value * f64::from(i + 1) / f64::from(steps);
            Rectangle::new([(0.0, a), (1.0, b)], heat((a + b) / 2.0, max).filled())
        }))
        .map_err(fail)?;
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(0.0, 0.0), (1.0, top_value)],
            BLACK.stroke_width(1),
        )))
        .map_err(fail)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .label_style(text(TICK))
        .y_label_formatter(&|v| number(*v))
        .draw()
        .map_err(fail)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_from_names_and_flags() {
        let p = Path::new("a/plot.png");
        assert_eq!(Format::of(p, None).unwrap(), Format::Png);
        assert_eq!(Format::of(Path::new("x.SVG"), None).unwrap(), Format::Svg);
        assert_eq!(Format::of(p, Some(Format::Png)).unwrap(), Format::Png);
        let e = Format::of(p, Some(Format::Svg)).unwrap_err().to_string();
        assert!(e.contains("--format svg") && e.contains(".png"), "{e}");
        assert_eq!(
            Format::of(Path::new("plot"), Some(Format::Svg)).unwrap(),
            Format::Svg
        );
        let e = Format::of(Path::new("plot.jpg"), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--format png|svg"), "{e}");
        assert!("gif".parse::<Format>().is_err());
    }

    #[test]
    fn axes_end_at_the_maximum() {
        let a = Axis::up_to(57.0, 6);
        assert_eq!(a.ticks.last(), Some(&57.0));
        assert_eq!(a.ticks[..3], [0.0, 10.0, 20.0]);
        assert!(a.ticks.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(Axis::up_to(0.0, 5).ticks, [0.0, 1.0]);
        let f = Axis::whole(3, 3, 8);
        assert_eq!(f.ticks, [3.0]);
        assert!(f.range.start < 3.0 && f.range.end > 3.0);
        let f = Axis::whole(0, 999, 8);
        assert_eq!((f.ticks[1], *f.ticks.last().unwrap()), (200.0, 999.0));
    }

    #[test]
    fn numbers_keep_three_digits() {
        assert_eq!(number(57.0), "57");
        assert_eq!(number(0.234375), "0.234");
        assert_eq!(number(0.0012345), "0.00123");
        assert_eq!(number(123.45), "123");
        assert_eq!(number(1.5), "1.5");
        assert_eq!(log_ticks(3.0, 150.0), [5.0, 10.0, 20.0, 50.0, 100.0]);
        assert_eq!(
            log_ticks(30.0, 90.0),
            [30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0]
        );
    }
}
