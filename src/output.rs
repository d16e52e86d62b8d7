//! Image outputs: PNG (sRGB, 8 bits) for people, OpenEXR (linear f32 `R`, `G`, `B` and the AOVs
//! `Z`, `id`, `N.X`, `N.Y`, `N.Z`) for tools. The EXR channel names and meanings are a contract
//! (docs/ARCHITECTURE.md, EXR channels); they are written through `files` (docs/ARCHITECTURE.md,
//! Outputs).

use crate::error::{Error as DcrtError, Result};
use crate::files::{write_bytes, write_rgb_png};
use crate::gpu::frame::Frame;
use std::path::Path;

/// Extra EXR channels beside `R`, `G`, `B`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum Aov {
    /// `Z`: f32 hit distance along the normalized ray, +inf on a miss.
    Depth,
    /// `id`: u32 primitive id, 0xFFFFFFFF on a miss.
    Id,
    /// `N.X`, `N.Y`, `N.Z`: unit geometric normal.
    Normal,
}

/// Linear to sRGB transfer, then 8 bits.
pub fn srgb8(linear: f32) -> u8 {
    let c = if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    };
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

pub fn to_rgb8(frame: &Frame) -> image::RgbImage {
    to_rgb8_exposed(frame, 0.0)
}

/// One linear channel times `k` = 2^`exposure`, then sRGB 8 bits. Exposure 0 leaves the value
/// untouched (no multiply), so PNGs stay as they were.
pub fn srgb8_exposed(c: f32, exposure: f32, k: f32) -> u8 {
    srgb8(if exposure == 0.0 { c } else { c * k })
}

/// Linear colour times 2^exposure (stops), then sRGB.
pub fn to_rgb8_exposed(frame: &Frame, exposure: f32) -> image::RgbImage {
    let k = exposure.exp2();
    let mut img = image::RgbImage::new(frame.width, frame.height);
    for (p, out) in frame.pixels.iter().zip(img.pixels_mut()) {
        *out = image::Rgb(p.rgb.map(|c| srgb8_exposed(c, exposure, k)));
    }
    img
}

pub fn write_png(path: &Path, frame: &Frame) -> Result<()> {
    write_png_exposed(path, frame, 0.0)
}

/// A PNG of the frame exposed by `exposure` stops.
pub fn write_png_exposed(path: &Path, frame: &Frame, exposure: f32) -> Result<()> {
    write_rgb_png(path, &to_rgb8_exposed(frame, exposure))
}

/// A PNG of the frame exposed by `exposure` stops, with the colour legend drawn over it when
/// given (`--legend`).
pub fn write_png_legend(
    path: &Path,
    frame: &Frame,
    exposure: f32,
    legend: Option<&crate::legend::Legend>,
) -> Result<()> {
    let mut img = to_rgb8_exposed(frame, exposure);
    if let Some(l) = legend {
        l.draw(&mut img)?;
    }
    write_rgb_png(path, &img)
}

pub fn write_exr(path: &Path, frame: &Frame, aovs: &[Aov]) -> Result<()> {
    use exr::prelude::*;
    let px = &frame.pixels;
    let f = |g: &dyn Fn(&crate::gpu::layout::Pixel) -> f32| -> FlatSamples {
        FlatSamples::F32(px.iter().map(g).collect())
    };
    let mut channels: Vec<AnyChannel<FlatSamples>> = vec![
        AnyChannel::new("R", f(&|p| p.rgb[0])),
        AnyChannel::new("G", f(&|p| p.rgb[1])),
        AnyChannel::new("B", f(&|p| p.rgb[2])),
    ];
    if aovs.contains(&Aov::Depth) {
        channels.push(AnyChannel::new("Z", f(&|p| p.depth)));
    }
    if aovs.contains(&Aov::Id) {
        channels.push(AnyChannel::new(
            "id",
            FlatSamples::U32(px.iter().map(|p| p.id).collect()),
        ));
    }
    if aovs.contains(&Aov::Normal) {
        channels.push(AnyChannel::new("N.X", f(&|p| p.normal[0])));
        channels.push(AnyChannel::new("N.Y", f(&|p| p.normal[1])));
        channels.push(AnyChannel::new("N.Z", f(&|p| p.normal[2])));
    }
    let layer = Layer::new(
        (frame.width as usize, frame.height as usize),
        LayerAttributes::default(),
        // Tiles in increasing order, not in the order parallel compression finishes them: the
        // same frame always gives the same file.
        Encoding {
            line_order: LineOrder::Increasing,
            ..Encoding::FAST_LOSSLESS
        },
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    // Encoded in memory: the crate's own file writer removes its target on failure, whatever
    // that target is.
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut bytes)
        .map_err(|e| DcrtError::format(path, None, e.to_string()))?;
    write_bytes(path, bytes.get_ref())
}

/// Reads every channel of an EXR written by `write_exr` (tests and tools): name → samples, with
/// u32 channels kept exact.
pub fn read_exr(path: &Path) -> Result<Vec<(String, ExrSamples)>> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| DcrtError::format(path, None, e.to_string()))?;
    Ok(image
        .layer_data
        .channel_data
        .list
        .iter()
        .map(|c| {
            let s = match &c.sample_data {
                FlatSamples::U32(v) => ExrSamples::U32(v.clone()),
                other => ExrSamples::F32(other.values_as_f32().collect()),
            };
            (c.name.to_string(), s)
        })
        .collect())
}

#[derive(Clone, Debug, PartialEq)]
pub enum ExrSamples {
    F32(Vec<f32>),
    U32(Vec<u32>),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_endpoints() {
        assert_eq!(srgb8(0.0), 0);
        assert_eq!(srgb8(1.0), 255);
        assert_eq!(srgb8(2.0), 255);
        assert_eq!(srgb8(f32::NAN), 0);
        assert_eq!(srgb8(0.2163), 128);
    }
}
