//! The layout probe (tests): the `probe` kernel reads every member of every host-written struct
//! through the kernels' own accessors and writes it out as raw words, so a test can compare each
//! member with what the host wrote.

use super::kernels::{Constants, Dispatch, Kernel};
use super::layout::{MirrorCase, MirrorResult, Params, RayState, ShadeParams};
use super::shaders::Override;
use super::tracer::Tracer;
use crate::error::Result;

/// Words the probe writes: every `Params` member, `params.pad0` nodes of 16 words (unused words as 0), `params.pad1`
/// triangles of 10, two ray states, `params.mesh_count` meshes and the shading parameters.
pub fn probe_words(params: &Params) -> u32 {
    let params_words = (size_of::<Params>() / 4) as u32;
    let ray_words = (size_of::<RayState>() / 4) as u32;
    let mesh_words = (size_of::<super::layout::MeshInfo>() / 4) as u32;
    let shade_words = (size_of::<ShadeParams>() / 4) as u32;
    params_words
        + 16 * params.pad0
        + 10 * params.pad1
        + 2 * ray_words
        + mesh_words * params.mesh_count
        + shade_words
}

impl Tracer<'_> {
    /// Runs the layout probe: `rays` must hold two states; returns the words the probe wrote.
    /// `params` replaces the tracer's own for the probe, so the caller controls every member.
    pub fn probe(
        &mut self,
        params: Params,
        rays: &[RayState; 2],
        shading: &ShadeParams,
    ) -> Result<Vec<u32>> {
        let gpu = self.gpu;
        gpu.write(&self.params_buf, &params);
        let init = |label, contents: &[u8], usage| gpu.buffer_init(label, contents, usage);
        let input = init(
            "probe rays",
            bytemuck::cast_slice(rays),
            wgpu::BufferUsages::STORAGE,
        );
        let shade = init(
            "probe shading",
            bytemuck::bytes_of(shading),
            wgpu::BufferUsages::STORAGE,
        );
        let bytes = u64::from(probe_words(&params)) * 4;
        let out = gpu.buffer(
            "probe out",
            bytes,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let lists = super::batch::Lists::FILL_FIRST;
        // Built here, for the tests that call it: production tracers never build the probe.
        let mut constants = self.constants.clone();
        constants.count(Override::Mode, self.settings.shading.mode as u32);
        let kernel = Kernel::new(gpu, "probe", self.store.module(), &constants);
        let bound = kernel.bind(gpu, |name| match name {
            "probe_rays" => Some(input.as_entire_binding()),
            "out" => Some(out.as_entire_binding()),
            "probe_shading" => Some(shade.as_entire_binding()),
            _ => self.resource(name, lists),
        });
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        kernel.dispatch(&mut enc, &bound, Dispatch::Over(1), None);
        gpu.queue.submit([enc.finish()]);
        let data = gpu.read_buffer(&out, 0, bytes)?;
        gpu.write(&self.params_buf, &self.params);
        Ok(bytemuck::pod_collect_to_vec(&data))
    }
}

/// Runs the mirror kernel (tests): each case through the shared WGSL functions that have CPU
/// twins in `mirror` (and `dc::cache_line`), with `params` as the uniform (its `seed`,
/// `first_tile`, `tiles_x` and `dc_*` matter), and `rows` as the block-row table (`block_row`
/// of case i reads entry i; empty: a placeholder).
pub fn run_mirror(
    gpu: &super::Gpu,
    params: &Params,
    cases: &[MirrorCase],
    rows: &[u32],
) -> Result<Vec<MirrorResult>> {
    use wgpu::BufferUsages as U;
    let mut constants = Constants::default();
    constants.count(Override::RowTableWidth, super::row_table::WIDTH);
    let kernel = Kernel::new(
        gpu,
        "mirror",
        super::shaders::Store::Texture.module(),
        &constants,
    );
    let init = |label, contents: &[u8], usage| gpu.buffer_init(label, contents, usage);
    let params_buf = init("params", bytemuck::bytes_of(params), U::UNIFORM);
    let input = init("mirror in", bytemuck::cast_slice(cases), U::STORAGE);
    let bytes = (cases.len() * size_of::<MirrorResult>()) as u64;
    let out = gpu.buffer("mirror out", bytes, U::STORAGE | U::COPY_SRC);
    // The cache's tables, one buffer each (a binding may not share a writable buffer):
    // `cache_line` reads only `params`.
    let rows = if rows.is_empty() {
        super::row_table::RowTable::placeholder(gpu)
    } else {
        super::row_table::RowTable::new(gpu, rows)?
    };
    let unused: Vec<wgpu::Buffer> = (0..4)
        .map(|_| gpu.buffer("unused", 32, U::STORAGE))
        .collect();
    let palette = init(
        "palette",
        bytemuck::cast_slice(&crate::colormap::palette()),
        U::STORAGE,
    );
    let bound = kernel.bind(gpu, |name| match name {
        "params" => Some(params_buf.as_entire_binding()),
        "mirror_in" => Some(input.as_entire_binding()),
        "mirror_out" => Some(out.as_entire_binding()),
        "block_rows" => Some(rows.binding()),
        "faults" => Some(unused[0].as_entire_binding()),
        "requested" => Some(unused[1].as_entire_binding()),
        "waiters" => Some(unused[2].as_entire_binding()),
        "line_used" => Some(unused[3].as_entire_binding()),
        "palette" => Some(palette.as_entire_binding()),
        _ => None,
    });
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let groups = Dispatch::Over(cases.len() as u32);
    kernel.dispatch(&mut enc, &bound, groups, None);
    gpu.queue.submit([enc.finish()]);
    let data = gpu.read_buffer(&out, 0, bytes)?;
    Ok(bytemuck::pod_collect_to_vec(&data))
}
