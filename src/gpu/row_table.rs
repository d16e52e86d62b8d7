//! The GPU's table of every block's row (`block_rows` in shaders/shared/dc.wgsl) as an R32Uint
//! texture, `WIDTH` blocks a texel row: llvmpipe reads a texel through its gather path, where a
//! storage-buffer load is a loop over the lanes that stalls in each (docs/ARCHITECTURE.md, The
//! trace loop), and the trace loop looks a block up at every iteration.

use super::Gpu;
use crate::error::{Error, Result};

/// Blocks a texel row holds: the pipeline constant ROW_TABLE_WIDTH of shaders/shared/dc.wgsl.
pub const WIDTH: u32 = 4096;

pub struct RowTable {
    texture: wgpu::Texture,
    view: wgpu::TextureView,
}

impl RowTable {
    /// The table holding `rows` (a block's row, or NONE), padded to whole texel rows.
    pub fn new(gpu: &Gpu, rows: &[u32]) -> Result<RowTable> {
        let height = (rows.len() as u32).div_ceil(WIDTH).max(1);
        if height > gpu.limits.max_texture_dimension_2d {
            return Err(Error::Gpu(format!(
                "a table of {} block rows needs a texture {height} texels high; the adapter's \
                 limit is {}",
                rows.len(),
                gpu.limits.max_texture_dimension_2d
            )));
        }
        let table = RowTable::sized(gpu, WIDTH.min(rows.len().max(1) as u32), height);
        let mut padded = rows.to_vec();
        padded.resize(
            (table.texture.width() * height) as usize,
            crate::gpu::layout::NONE,
        );
        table.write(gpu, (0, 0), table.texture.width(), height, &padded);
        Ok(table)
    }

    /// A one-texel table for pipelines that never read it (replicated models, probes).
    pub fn placeholder(gpu: &Gpu) -> RowTable {
        RowTable::sized(gpu, 1, 1)
    }

    fn sized(gpu: &Gpu, width: u32, height: u32) -> RowTable {
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        // Bound as a one-layer array: the blocks' binding kind.
        let (texture, view) =
            gpu.uint_texture_array("block rows", size, wgpu::TextureFormat::R32Uint);
        RowTable { texture, view }
    }

    /// Sets block `block`'s row (takes effect for the next submitted dispatch).
    pub fn set(&self, gpu: &Gpu, block: u32, row: u32) {
        self.write(gpu, (block % WIDTH, block / WIDTH), 1, 1, &[row]);
    }

    fn write(&self, gpu: &Gpu, (x, y): (u32, u32), width: u32, height: u32, data: &[u32]) {
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.texture,
                mip_level: 0,
                origin: wgpu::Origin3d { x, y, z: 0 },
                aspect: wgpu::TextureAspect::All,
            },
            bytemuck::cast_slice(data),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * width),
                rows_per_image: Some(height),
            },
            wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
        );
    }

    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::TextureView(&self.view)
    }
}
