// Colour by data (docs/ARCHITECTURE.md, Colour by data): ParaView's colormaps as 256 linear
// colours each, then the linear values of the 256 sRGB levels (host: colormap::palette).

@group(0) @binding(7) var<storage, read> palette: array<vec4<f32>>;

// Where the sRGB decode table starts: after the four maps (colormap::Colormap::ALL).
const SRGB_LEVELS: u32 = 1024u;

// The colour of scalar s in map `map` for the range starting at `lo`, `scale` = 256 / (hi - lo):
// bin floor((s - lo) * scale) clamped to 0..255, as vtkLookupTable indexes it. NaN takes the
// first colour. Mirrored by mirror::colormap::colormap.
fn colormap(s: f32, lo: f32, scale: f32, map: u32) -> vec3<f32> {
    let x = (s - lo) * scale;
    let bin = select(0u, u32(min(x, 255.0)), x >= 1.0);
    return palette[min(map, 3u) * 256u + bin].xyz;
}

// A direct colour packed as 8-bit sRGB (r | g << 8 | b << 16), as linear RGB. Mirrored by
// mirror::colormap::srgb_color.
fn srgb_color(w: u32) -> vec3<f32> {
    return vec3(palette[SRGB_LEVELS + (w & 0xffu)].x, palette[SRGB_LEVELS + ((w >> 8u) & 0xffu)].x,
                palette[SRGB_LEVELS + ((w >> 16u) & 0xffu)].x);
}
