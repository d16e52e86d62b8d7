//! The GPU copy of a rank's blocks (docs/ARCHITECTURE.md, Block store): its resident rows, then
//! the cache lines, in `Rgba32Uint` 2D array textures (one block per row; more than one texture
//! when one resource cannot hold them all) or one storage buffer, within the adapter's limits.

use super::Gpu;
use super::kernels::Constants;
use super::shaders::{Override, Store};
use crate::blocks::Format;
use crate::error::{Error, Result};

/// Textures one store may span: `blocks`, `blocks_1`, `blocks_2`, `blocks_3` in
/// `shaders/shared/store_texture.wgsl`.
pub const MAX_PARTS: u32 = 4;

/// The rows of blocks a GPU holds: the resident ones it is given, then `lines` cache lines.
pub struct Rows<'a> {
    pub format: Format,
    pub resident: &'a [u32],
    pub lines: u32,
}

impl Rows<'_> {
    pub fn resident_rows(&self) -> u32 {
        (self.resident.len() / self.format.words() as usize) as u32
    }
    fn total(&self) -> u32 {
        self.resident_rows() + self.lines
    }
    fn bytes(&self) -> u64 {
        u64::from(self.total()) * u64::from(self.format.block_bytes)
    }
    fn slice(&self, first: u32, n: u32) -> &[u32] {
        let bw = self.format.words() as usize;
        &self.resident[first as usize * bw..(first + n) as usize * bw]
    }
}

/// How a texture store lays its rows out: `rows_per_layer` rows a layer, `layers_per_part`
/// layers a texture, `parts` textures (the last may have fewer layers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextureShape {
    /// Rows in all: resident blocks and cache lines.
    pub rows: u32,
    pub rows_per_layer: u32,
    pub layers_per_part: u32,
    pub parts: u32,
    /// Layers in all.
    pub layers: u32,
}

/// The adapter limits a texture store must keep within.
#[derive(Clone, Copy, Debug)]
pub struct TextureLimits {
    pub max_2d: u32,
    pub max_layers: u32,
    /// Bytes one texture may hold (the adapter's largest allocation: `max_buffer_size`).
    pub max_bytes: u64,
}

impl TextureShape {
    /// The shape of `rows` blocks of `format` within `limits`, or an error naming the sizes and
    /// the limit exceeded.
    pub fn new(rows: u32, format: Format, limits: TextureLimits) -> Result<TextureShape> {
        let texels = format.texels();
        let block = u64::from(format.block_bytes);
        let rows = rows.max(1);
        let total_mib = (u64::from(rows) * block) >> 20;
        if texels > limits.max_2d || block > limits.max_bytes {
            return Err(Error::Gpu(format!(
                "a block of {block} bytes needs a texture row {texels} texels wide; the adapter \
                 allows {} texels and {} bytes a texture",
                limits.max_2d, limits.max_bytes
            )));
        }
        let by_bytes = (limits.max_bytes / block).min(u64::from(u32::MAX)) as u32;
        let rows_per_layer = rows.min(limits.max_2d).min(by_bytes);
        let layers = rows.div_ceil(rows_per_layer);
        let layer_bytes = u64::from(rows_per_layer) * block;
        let by_bytes = (limits.max_bytes / layer_bytes).min(u64::from(u32::MAX)) as u32;
        let layers_per_part = layers.min(limits.max_layers).min(by_bytes);
        let parts = layers.div_ceil(layers_per_part);
        if parts > MAX_PARTS {
            return Err(Error::Gpu(format!(
                "{rows} blocks ({total_mib} MiB: resident blocks and cache) need {parts} \
                 textures of at most {layers_per_part} layers of {rows_per_layer} blocks \
                 ({} MiB, the adapter's limit for one resource); a store spans at most \
                 {MAX_PARTS}: use more ranks or a smaller cache",
                (u64::from(layers_per_part) * layer_bytes) >> 20
            )));
        }
        Ok(TextureShape {
            rows,
            rows_per_layer,
            layers_per_part,
            parts,
            layers,
        })
    }

    /// Layers of texture `part`.
    pub fn part_layers(&self, part: u32) -> u32 {
        (self.layers - part * self.layers_per_part).min(self.layers_per_part)
    }

    /// Where row `row` lives: (texture, layer in it, row in the layer).
    pub fn locate(&self, row: u32) -> (u32, u32, u32) {
        let layer = row / self.rows_per_layer;
        (
            layer / self.layers_per_part,
            layer % self.layers_per_part,
            row % self.rows_per_layer,
        )
    }
}

/// One texture of a texture store.
pub struct Part {
    texture: wgpu::Texture,
    view: wgpu::TextureView,
}

/// The blocks on the GPU, kept alive while bind groups use them.
pub enum BlockStore {
    Texture {
        parts: Vec<Part>,
        shape: TextureShape,
    },
    Buffer {
        buffer: wgpu::Buffer,
        rows: u32,
    },
}

impl BlockStore {
    /// Uploads the resident rows, with room for the cache lines after them; a texture holds at
    /// most `max_texture_bytes` (`None`: as much as the adapter allocates at once).
    pub fn new(
        gpu: &Gpu,
        store: Store,
        rows: &Rows<'_>,
        max_texture_bytes: Option<u64>,
    ) -> Result<BlockStore> {
        Ok(match store {
            Store::Texture => {
                let limits = TextureLimits {
                    max_2d: gpu.limits.max_texture_dimension_2d,
                    max_layers: gpu.limits.max_texture_array_layers,
                    max_bytes: max_texture_bytes.unwrap_or(gpu.limits.max_buffer_size),
                };
                let shape = TextureShape::new(rows.total(), rows.format, limits)?;
                let parts = upload_texture(gpu, rows, shape)?;
                BlockStore::Texture { parts, shape }
            }
            Store::Buffer => BlockStore::Buffer {
                buffer: upload_buffer(gpu, rows)?,
                rows: rows.total(),
            },
        })
    }

    /// The block store module the kernels are composed with (`compose::STORE_MODULES`).
    pub fn module(&self) -> &'static str {
        match self {
            BlockStore::Texture { shape, .. } if shape.parts > 1 => "store_texture_parts",
            BlockStore::Texture { .. } => Store::Texture.module(),
            BlockStore::Buffer { .. } => Store::Buffer.module(),
        }
    }

    /// The pipeline constants of the store's addressing (`ROWS_PER_LAYER`, `LAYERS_PER_PART`);
    /// a buffer has one part of one-row layers.
    pub fn set_constants(&self, c: &mut Constants) {
        let (rows, layers) = match self {
            BlockStore::Texture { shape, .. } => (shape.rows_per_layer, shape.layers_per_part),
            BlockStore::Buffer { .. } => (1, 1),
        };
        c.count(Override::RowsPerLayer, rows)
            .count(Override::LayersPerPart, layers);
    }

    /// Textures the store spans (1 for a buffer).
    pub fn parts(&self) -> u32 {
        match self {
            BlockStore::Texture { shape, .. } => shape.parts,
            BlockStore::Buffer { .. } => 1,
        }
    }

    /// Rows it holds: resident blocks, then cache lines.
    pub fn rows(&self) -> u32 {
        match self {
            BlockStore::Texture { shape, .. } => shape.rows,
            BlockStore::Buffer { rows, .. } => *rows,
        }
    }

    /// What holds the blocks, for reports: "1 texture", "2 textures", "1 buffer".
    pub fn describe(&self) -> String {
        match self.parts() {
            _ if matches!(self, BlockStore::Buffer { .. }) => "1 buffer".into(),
            1 => "1 texture".into(),
            n => format!("{n} textures"),
        }
    }

    /// Replaces the blocks in consecutive rows from `first` (cache lines) between dispatches:
    /// `words` holds whole blocks. One write a layer: a write call costs about what 4 KiB of
    /// copying does, and a round loads thousands of blocks, many into adjacent lines.
    pub fn write_rows(&self, gpu: &Gpu, format: Format, first: u32, words: &[u32]) {
        match self {
            BlockStore::Texture { parts, shape } => {
                let (per_layer, bw) = (shape.rows_per_layer, format.words() as usize);
                let (mut row, mut rest) = (first, words);
                while !rest.is_empty() {
                    let n = (rest.len() / bw).min((per_layer - row % per_layer) as usize);
                    let (now, later) = rest.split_at(n * bw);
                    write_texture_rows(gpu, parts, *shape, format, row, now);
                    (row, rest) = (row + n as u32, later);
                }
            }
            BlockStore::Buffer { buffer, .. } => gpu.queue.write_buffer(
                buffer,
                u64::from(first) * u64::from(format.block_bytes),
                bytemuck::cast_slice(words),
            ),
        }
    }

    /// What binds to the kernels' `name`: `blocks` and, for a texture store in parts,
    /// `blocks_1` .. `blocks_3` (parts the store lacks are bound to its first, never read).
    pub fn resource(&self, name: &str) -> Option<wgpu::BindingResource<'_>> {
        let part = match name {
            "blocks" => 0,
            "blocks_1" => 1,
            "blocks_2" => 2,
            "blocks_3" => 3,
            _ => return None,
        };
        Some(match self {
            BlockStore::Texture { parts, .. } => {
                let p = parts.get(part).unwrap_or(&parts[0]);
                wgpu::BindingResource::TextureView(&p.view)
            }
            BlockStore::Buffer { buffer, .. } => buffer.as_entire_binding(),
        })
    }
}

/// Creates the textures of `shape` and uploads the resident rows into them.
fn upload_texture(gpu: &Gpu, rows: &Rows<'_>, shape: TextureShape) -> Result<Vec<Part>> {
    let format = rows.format;
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let scope_v = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let parts: Vec<Part> = (0..shape.parts)
        .map(|p| {
            let size = wgpu::Extent3d {
                width: format.texels(),
                height: shape.rows_per_layer,
                depth_or_array_layers: shape.part_layers(p),
            };
            let (texture, view) =
                gpu.uint_texture_array("blocks", size, wgpu::TextureFormat::Rgba32Uint);
            Part { texture, view }
        })
        .collect();
    let resident = rows.resident_rows();
    let per_layer = shape.rows_per_layer;
    let mut first = 0;
    while first < resident {
        let n = (resident - first).min(per_layer - first % per_layer);
        write_texture_rows(gpu, &parts, shape, format, first, rows.slice(first, n));
        first += n;
    }
    let fail = |e: wgpu::Error| {
        Error::Gpu(format!(
            "cannot hold {} MiB of blocks (resident and cache) in {} texture(s): {e}",
            rows.bytes() >> 20,
            shape.parts
        ))
    };
    if let Some(e) = pollster::block_on(scope_v.pop()) {
        return Err(fail(e));
    }
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(fail(e));
    }
    Ok(parts)
}

/// Writes `data` (whole blocks) into consecutive rows from `first`, all in one layer.
fn write_texture_rows(
    gpu: &Gpu,
    parts: &[Part],
    shape: TextureShape,
    format: Format,
    first: u32,
    data: &[u32],
) {
    let n = (data.len() / format.words() as usize) as u32;
    let (part, layer, y) = shape.locate(first);
    gpu.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &parts[part as usize].texture,
            mip_level: 0,
            origin: wgpu::Origin3d { x: 0, y, z: layer },
            aspect: wgpu::TextureAspect::All,
        },
        bytemuck::cast_slice(data),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(format.block_bytes),
            rows_per_image: Some(n),
        },
        wgpu::Extent3d {
            width: format.texels(),
            height: n,
            depth_or_array_layers: 1,
        },
    );
}

/// Uploads resident rows into one storage buffer with room for the cache lines.
fn upload_buffer(gpu: &Gpu, rows: &Rows<'_>) -> Result<wgpu::Buffer> {
    let limit = gpu.storage_limit();
    if rows.bytes() > limit {
        return Err(Error::Gpu(format!(
            "{} MiB of blocks (resident and cache) exceed the adapter's {} MiB storage buffer \
             binding; use the texture store",
            rows.bytes() >> 20,
            limit >> 20
        )));
    }
    let buf = gpu.buffer(
        "blocks",
        rows.bytes(),
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    );
    gpu.queue
        .write_buffer(&buf, 0, bytemuck::cast_slice(rows.resident));
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAVAPIPE: TextureLimits = TextureLimits {
        max_2d: 16384,
        max_layers: 2048,
        max_bytes: 2047 << 20,
    };

    fn format() -> Format {
        Format::new(8192).unwrap()
    }

    /// Every row has one place, inside its part's layers, and no two rows share it.
    fn check_places(shape: TextureShape) {
        let mut seen = std::collections::HashSet::new();
        for row in 0..shape.rows {
            let (part, layer, y) = shape.locate(row);
            assert!(part < shape.parts, "row {row}: {shape:?}");
            assert!(layer < shape.part_layers(part), "row {row}: {shape:?}");
            assert!(y < shape.rows_per_layer, "row {row}: {shape:?}");
            assert!(
                seen.insert((part, layer, y)),
                "row {row} shares its texel row"
            );
        }
    }

    #[test]
    fn a_store_that_fits_one_texture_is_one_texture() {
        let s = TextureShape::new(17_493, format(), LAVAPIPE).unwrap();
        assert_eq!((s.parts, s.rows_per_layer, s.layers), (1, 16384, 2));
        assert_eq!(s.layers_per_part, 2);
        check_places(s);
    }

    #[test]
    fn a_store_larger_than_one_resource_spans_several_textures() {
        // The 300M model's rank at 8 ranks and a 1/8 cache: 3,367 MiB of 8 KiB blocks.
        let rows = (3367u32 << 20) / 8192;
        let s = TextureShape::new(rows, format(), LAVAPIPE).unwrap();
        assert_eq!(s.parts, 2);
        // 15 layers of 16384 blocks (1,920 MiB) a texture: each within the 2,047 MiB limit.
        assert_eq!(s.layers_per_part, 15);
        for p in 0..s.parts {
            let bytes = u64::from(s.part_layers(p)) * u64::from(s.rows_per_layer) * 8192;
            assert!(bytes <= LAVAPIPE.max_bytes, "part {p}: {bytes} bytes");
        }
        check_places(s);
        // Small limits: layers shrink to what one texture may hold.
        let small = TextureLimits {
            max_bytes: 5 * 8192,
            ..LAVAPIPE
        };
        let s = TextureShape::new(17, format(), small).unwrap();
        assert_eq!((s.rows_per_layer, s.layers_per_part, s.parts), (5, 1, 4));
        assert_eq!(s.part_layers(3), 1);
        check_places(s);
    }

    #[test]
    fn a_store_beyond_four_textures_is_refused_naming_its_size() {
        let e = TextureShape::new(5 * 15 * 16384, format(), LAVAPIPE).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("9600 MiB") && msg.contains("need 5 textures"),
            "{msg}"
        );
        let tiny = TextureLimits {
            max_bytes: 4096,
            ..LAVAPIPE
        };
        let msg = TextureShape::new(1, format(), tiny)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("8192 bytes"), "{msg}");
    }
}
