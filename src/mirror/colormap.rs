//! CPU twins of `shaders/shared/colormap.wgsl`: the colour of a scalar in a colormap, and the
//! decoding of a packed sRGB colour, bit for bit as the kernels compute them from the palette.

use crate::colormap::{ENTRIES, palette};
use std::sync::OnceLock;

fn table() -> &'static [[f32; 4]] {
    static P: OnceLock<Vec<[f32; 4]>> = OnceLock::new();
    P.get_or_init(palette)
}

/// The bin of `s` for a range starting at `lo` with `scale` = 256 / (hi - lo): `floor((s - lo) *
/// scale)` clamped to 0..255; NaN takes bin 0. One subtraction and one multiplication, each
/// correctly rounded in f32 on both sides.
pub fn bin(s: f32, lo: f32, scale: f32) -> usize {
    let x = (s - lo) * scale;
    if x >= 1.0 { x.min(255.0) as usize } else { 0 }
}

/// `colormap(s, lo, scale, map)`: the linear colour of bin `bin(s, lo, scale)` of map `map`.
pub fn colormap(s: f32, lo: f32, scale: f32, map: u32) -> [f32; 3] {
    let c = table()[map.min(3) as usize * ENTRIES + bin(s, lo, scale)];
    [c[0], c[1], c[2]]
}

/// `srgb_color(w)`: the linear colour of a packed 8-bit sRGB colour.
pub fn srgb_color(w: u32) -> [f32; 3] {
    let levels = ENTRIES * 4;
    [0, 8, 16].map(|s| table()[levels + ((w >> s) & 0xff) as usize][0])
}
