//! The colour legend (`--legend`): a scalar bar per array whose values colour the image, drawn
//! into the PNG's 8-bit sRGB pixels after exposure (so its colours are the colormap's own), at
//! the image's right edge: the 256 colours from the range's start (bottom) to its end (top),
//! five labels beside them and the array's name above. Text needs a TrueType font (`font`).

use crate::colormap::Colormap;
use crate::error::{Error, Result};
use crate::scene::color::Look;
use plotters::prelude::*;
use std::path::PathBuf;
use std::sync::OnceLock;

/// One scalar bar.
#[derive(Clone, Debug, PartialEq)]
pub struct Bar {
    pub array: String,
    pub colormap: Colormap,
    pub range: [f32; 2],
}

/// The bars of a model: one per distinct (array, colormap, range) among its looks, in order.
pub fn bars(looks: &[Look]) -> Vec<Bar> {
    let mut out: Vec<Bar> = Vec::new();
    for l in looks {
        if let Look::Scalars {
            array,
            colormap,
            range,
            ..
        } = l
        {
            let b = Bar {
                array: array.clone(),
                colormap: *colormap,
                range: *range,
            };
            if !out.contains(&b) {
                out.push(b);
            }
        }
    }
    out
}

/// What `--legend` draws: the bars, and whether the text is dark (on a light background).
#[derive(Clone, Debug, PartialEq)]
pub struct Legend {
    pub bars: Vec<Bar>,
    pub dark_text: bool,
}

impl Legend {
    /// The legend of a model with `looks` on `background` (linear RGB); an error when no mesh is
    /// coloured by values.
    pub fn new(looks: &[Look], background: [f32; 3]) -> Result<Legend> {
        let bars = bars(looks);
        if bars.is_empty() {
            return Err(Error::Invalid(
                "--legend: no mesh is coloured by values (color_by naming an array of values)"
                    .into(),
            ));
        }
        let luminance = 0.2126 * background[0] + 0.7152 * background[1] + 0.0722 * background[2];
        font()?;
        Ok(Legend {
            bars,
            dark_text: luminance > 0.18,
        })
    }

    /// Draws the bars into `img` (8-bit sRGB).
    pub fn draw(&self, img: &mut image::RgbImage) -> Result<()> {
        let (w, h) = img.dimensions();
        let family = font()?;
        let text_px = (h as f64 / 28.0).clamp(8.0, 28.0);
        let bar_w = ((w as f64) * 0.03).max(6.0) as i32;
        let bar_h = ((h as f64) * 0.6).max(16.0) as i32;
        let top = ((h as f64 - bar_h as f64) / 2.0) as i32;
        let slot = bar_w + (text_px * 4.5) as i32;
        let color = if self.dark_text { BLACK } else { WHITE };
        let style = TextStyle::from((family, text_px).into_font()).color(&color);
        let fail = |e: String| Error::Internal(format!("drawing the legend: {e}"));
        let buf: &mut [u8] = img.as_mut();
        let area = BitMapBackend::with_buffer(buf, (w, h)).into_drawing_area();
        for (k, bar) in self.bars.iter().rev().enumerate() {
            let x0 = w as i32 - (k as i32 + 1) * slot;
            let colors = bar.colormap.srgb();
            // Row y shows the bin of the value at its height, the range's start at the bottom.
            for y in 0..bar_h {
                let bin = ((bar_h - 1 - y) as usize * colors.len()) / bar_h as usize;
                let [r, g, b] = colors[bin];
                area.draw(&Rectangle::new(
                    [(x0, top + y), (x0 + bar_w, top + y + 1)],
                    RGBColor(r, g, b).filled(),
                ))
                .map_err(|e| fail(e.to_string()))?;
            }
            area.draw(&Rectangle::new(
                [(x0, top), (x0 + bar_w, top + bar_h)],
                color.stroke_width(1),
            ))
            .map_err(|e| fail(e.to_string()))?;
            let [lo, hi] = bar.range;
            for (t, text) in (0..5).zip(labels(lo, hi)) {
                let y = top + bar_h - 1 - (t * (bar_h - 1)) / 4;
                area.draw(&Text::new(
                    text,
                    (x0 + bar_w + 3, y - (text_px / 2.0) as i32),
                    style.clone(),
                ))
                .map_err(|e| fail(e.to_string()))?;
            }
            let title_y = (top - (text_px * 1.6) as i32).max(0);
            area.draw(&Text::new(bar.array.clone(), (x0, title_y), style.clone()))
                .map_err(|e| fail(e.to_string()))?;
        }
        area.present().map_err(|e| fail(e.to_string()))
    }
}

/// The five tick labels of a bar over `lo..hi`, in one notation: scientific when the range's
/// largest magnitude is 1e5 or more or below 1e-3, else fixed with four significant digits of
/// that magnitude.
pub fn labels(lo: f32, hi: f32) -> Vec<String> {
    let big = lo.abs().max(hi.abs());
    let scientific = big != 0.0 && !(1e-3..1e5).contains(&big);
    let digits = (3 - big.max(1e-3).log10().floor() as i32).clamp(0, 6) as usize;
    (0..5)
        .map(|t| {
            let v = lo + (hi - lo) * t as f32 / 4.0;
            if scientific {
                format!("{v:.3e}")
            } else {
                fixed(v, digits)
            }
        })
        .collect()
}

/// `v` with `digits` decimals, trailing zeros dropped.
fn fixed(v: f32, digits: usize) -> String {
    let s = format!("{v:.digits$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" { "0".into() } else { s }
}

/// The font family registered with plotters for the legend's and the figures' text:
/// `DCRT_FONT`, else DejaVu Sans where Debian's fonts-dejavu-core puts it (`scripts/setup.sh`
/// installs it). Loaded once.
pub fn font() -> Result<&'static str> {
    const FAMILY: &str = "dcrt-sans";
    static LOADED: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    let loaded = LOADED.get_or_init(|| {
        let candidates: Vec<PathBuf> = match std::env::var_os("DCRT_FONT") {
            Some(p) => vec![PathBuf::from(p)],
            None => vec![
                PathBuf::from("/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"),
                PathBuf::from("/usr/share/fonts/TTF/DejaVuSans.ttf"),
            ],
        };
        for p in &candidates {
            if let Ok(bytes) = std::fs::read(p) {
                // plotters keeps fonts for the life of the process.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                return plotters::style::register_font(FAMILY, FontStyle::Normal, bytes)
                    .map_err(|_| format!("{}: not a TrueType font", p.display()));
            }
        }
        Err(format!(
            "no font for text at {}: install fonts-dejavu-core (scripts/setup.sh) or set \
             DCRT_FONT to a .ttf file",
            candidates
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(" or ")
        ))
    });
    match loaded {
        Ok(()) => Ok(FAMILY),
        Err(e) => Err(Error::Invalid(e.clone())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_share_one_notation() {
        assert_eq!(labels(0.0, 2.0), ["0", "0.5", "1", "1.5", "2"]);
        assert_eq!(
            labels(-2.5, 160.0),
            ["-2.5", "38.1", "78.8", "119.4", "160"]
        );
        // A range reaching 1e5 is scientific throughout (it mixed 99192 and 1.056e5).
        assert_eq!(
            labels(96000.0, 108800.0),
            ["9.600e4", "9.920e4", "1.024e5", "1.056e5", "1.088e5"]
        );
        assert_eq!(labels(0.0, 0.0004)[4], "4.000e-4");
        assert_eq!(labels(0.0, 0.0004)[0], "0.000e0");
        assert_eq!(labels(12000.0, 12345.67)[4], "12346");
    }

    #[test]
    fn one_bar_per_array_and_range() {
        let s = |a: &str, r: [f32; 2]| Look::Scalars {
            array: a.into(),
            colormap: Colormap::Viridis,
            range: r,
            cell: false,
        };
        let looks = [
            s("p", [0.0, 1.0]),
            Look::Constant,
            s("p", [0.0, 1.0]),
            s("q", [0.0, 1.0]),
        ];
        assert_eq!(bars(&looks).len(), 2);
        let colours = Look::Colors {
            array: "rgb".into(),
            cell: true,
        };
        assert!(Legend::new(&[colours], [0.0; 3]).is_err());
    }
}
