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

    /// Writes the entries of `changed` blocks (any order, repeats allowed) from `rows`, the
    /// host's copy of the whole table (`CachePolicy::block_rows`); takes effect for the next
    /// submitted dispatch. Blocks of a texel row closer than `MERGE_GAP` go in one write with the
    /// entries between them: a round changes thousands of entries (a load and an eviction each),
    /// and one write per entry cost more than the blocks' own uploads.
    pub fn update(&self, gpu: &Gpu, changed: &mut [u32], rows: &[u32]) {
        for (first, last) in runs(changed) {
            let (x, y) = (first % WIDTH, first / WIDTH);
            let n = last - first + 1;
            self.write(gpu, (x, y), n, 1, &rows[first as usize..=last as usize]);
        }
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

/// Entries written with the ones between them rather than apart (`RowTable::update`): 4 KiB,
/// about what a write call costs besides its bytes.
const MERGE_GAP: u32 = 1024;

/// The changed blocks (sorted here) as inclusive runs `(first, last)`, each within one texel row,
/// merging blocks less than `MERGE_GAP` apart.
fn runs(changed: &mut [u32]) -> Vec<(u32, u32)> {
    changed.sort_unstable();
    let mut out: Vec<(u32, u32)> = Vec::new();
    for &b in changed.iter() {
        match out.last_mut() {
            Some((first, last)) if b / WIDTH == *first / WIDTH && b - *last <= MERGE_GAP => {
                *last = b;
            }
            _ => out.push((b, b)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changed_entries_merge_into_runs_within_a_texel_row() {
        // 5..=9 and 9 + MERGE_GAP merge; the next is one too far; a texel row ends a run.
        let far = 9 + 2 * MERGE_GAP + 1;
        let mut changed = [9, 5, 5, 9 + MERGE_GAP, far, 2 * WIDTH - 1, 2 * WIDTH, 7];
        let want = [
            (5, 9 + MERGE_GAP),
            (far, far),
            (2 * WIDTH - 1, 2 * WIDTH - 1),
            (2 * WIDTH, 2 * WIDTH),
        ];
        assert_eq!(runs(&mut changed), want);
        assert!(runs(&mut []).is_empty());
    }
}
