//! The GPU copy of a rank's blocks (docs/ARCHITECTURE.md, Block store): its resident rows, then
//! the cache lines, in an `Rgba32Uint` 2D array texture (one block per row) or one storage
//! buffer, within the adapter's limits.

use super::Gpu;
use super::shaders::Store;
use crate::blocks::Format;
use crate::error::{Error, Result};

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

/// The blocks on the GPU, kept alive while bind groups use them.
pub enum BlockStore {
    Texture {
        texture: wgpu::Texture,
        view: wgpu::TextureView,
        rows_per_layer: u32,
    },
    Buffer(wgpu::Buffer),
}

impl BlockStore {
    /// Uploads the resident rows, with room for the cache lines after them.
    pub fn new(gpu: &Gpu, store: Store, rows: &Rows<'_>) -> Result<BlockStore> {
        Ok(match store {
            Store::Texture => {
                let (texture, rows_per_layer) = upload_texture(gpu, rows)?;
                let view = texture.create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2Array),
                    ..Default::default()
                });
                BlockStore::Texture {
                    texture,
                    view,
                    rows_per_layer,
                }
            }
            Store::Buffer => BlockStore::Buffer(upload_buffer(gpu, rows)?),
        })
    }

    /// Rows per texture layer (`ROWS_PER_LAYER`); 1 for a buffer, which has no layers.
    pub fn rows_per_layer(&self) -> u32 {
        match self {
            BlockStore::Texture { rows_per_layer, .. } => *rows_per_layer,
            BlockStore::Buffer(_) => 1,
        }
    }

    /// Replaces the block in `row` (a cache line) between dispatches.
    pub fn write_row(&self, gpu: &Gpu, format: Format, row: u32, words: &[u32]) {
        match self {
            BlockStore::Texture {
                texture,
                rows_per_layer,
                ..
            } => write_texture_rows(gpu, texture, format, *rows_per_layer, row, words),
            BlockStore::Buffer(b) => gpu.queue.write_buffer(
                b,
                u64::from(row) * u64::from(format.block_bytes),
                bytemuck::cast_slice(words),
            ),
        }
    }

    /// The `blocks` binding.
    pub fn resource(&self) -> wgpu::BindingResource<'_> {
        match self {
            BlockStore::Texture { view, .. } => wgpu::BindingResource::TextureView(view),
            BlockStore::Buffer(b) => b.as_entire_binding(),
        }
    }
}

/// Uploads resident rows into one `Rgba32Uint` 2D array texture, one block per row, with room
/// for the cache lines after them. Returns the texture and its rows per layer.
fn upload_texture(gpu: &Gpu, rows: &Rows<'_>) -> Result<(wgpu::Texture, u32)> {
    let format = rows.format;
    let texels = format.texels();
    let max2d = gpu.limits.max_texture_dimension_2d;
    let count = rows.total().max(1);
    if texels > max2d {
        return Err(Error::Gpu(format!(
            "block of {} bytes needs a texture {texels} texels wide; the adapter allows {max2d}",
            format.block_bytes
        )));
    }
    let per_layer = count.min(max2d);
    let layers = count.div_ceil(per_layer);
    if layers > gpu.limits.max_texture_array_layers {
        return Err(Error::Gpu(format!(
            "{count} blocks ({} MiB: resident blocks and cache) need {layers} texture layers of \
             {per_layer} blocks; the adapter allows {} layers",
            rows.bytes() >> 20,
            gpu.limits.max_texture_array_layers
        )));
    }
    let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let scope_v = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("blocks"),
        size: wgpu::Extent3d {
            width: texels,
            height: per_layer,
            depth_or_array_layers: layers,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Uint,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let resident = rows.resident_rows();
    let mut first = 0;
    while first < resident {
        let n = (resident - first).min(per_layer - first % per_layer);
        write_texture_rows(
            gpu,
            &texture,
            format,
            per_layer,
            first,
            rows.slice(first, n),
        );
        first += n;
    }
    let fail = |e: wgpu::Error| {
        Error::Gpu(format!(
            "cannot hold {} MiB of blocks (resident and cache) in one texture: {e}",
            rows.bytes() >> 20
        ))
    };
    if let Some(e) = pollster::block_on(scope_v.pop()) {
        return Err(fail(e));
    }
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(fail(e));
    }
    Ok((texture, per_layer))
}

/// Writes `data` (whole blocks) into consecutive rows from `first`, all in one layer.
fn write_texture_rows(
    gpu: &Gpu,
    texture: &wgpu::Texture,
    format: Format,
    per_layer: u32,
    first: u32,
    data: &[u32],
) {
    let n = (data.len() / format.words() as usize) as u32;
    gpu.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: 0,
                y: first % per_layer,
                z: first / per_layer,
            },
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
