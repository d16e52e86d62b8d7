//! `dcrt info`: the GPU adapters, the one dcrt would use, its limits and features, and MPI; or
//! `dcrt info FILE`: what a mesh file holds.

use anyhow::Result;
use dcrt::gpu::Gpu;
use dcrt::scene::data::Keep;
use std::path::Path;

/// A mesh file's points, triangles, bounds, and every data array with its range.
pub fn mesh(path: &Path) -> Result<()> {
    let (mesh, data) = dcrt::scene::load_mesh_data(path, &Keep::All)?;
    mesh.validate(path)?;
    println!("file: {}", path.display());
    println!("points: {}", mesh.positions.len());
    println!("triangles: {}", mesh.triangles.len());
    let mut b = dcrt::scene::Bounds::default();
    mesh.positions.iter().for_each(|p| b.grow(*p));
    if !b.is_empty() {
        println!("bounds: {:?} .. {:?}", b.min, b.max);
    }
    if !data.parts.is_empty() {
        println!("parts with their own colours: {}", data.parts.len());
    }
    if data.arrays.is_empty() {
        println!("data arrays: none");
        return Ok(());
    }
    println!("data arrays (color_by = NAME; `cell = true` for cell data):");
    for (i, a) in data.arrays.iter().enumerate() {
        let range = match (data.values(i), a.color) {
            (_, Some(_)) => "direct colours".to_string(),
            (Some(v), None) => match dcrt::scene::color::range_of(v) {
                Some((lo, hi)) if a.components == 1 => format!("range [{lo}, {hi}]"),
                Some((lo, hi)) => format!("magnitude range [{lo}, {hi}]"),
                None => "no finite values".into(),
            },
            (None, None) => String::new(),
        };
        println!("  {a}  {range}");
    }
    Ok(())
}

pub fn info(adapter: Option<&str>) -> Result<()> {
    println!("adapters found:");
    for a in dcrt::gpu::adapters() {
        println!("  {}", dcrt::gpu::describe(&a.get_info()));
    }
    let gpu = Gpu::new(adapter)?;
    println!("using: {}", gpu.describe());
    let l = &gpu.limits;
    println!("limits:");
    println!(
        "  max_storage_buffer_binding_size {} MiB",
        l.max_storage_buffer_binding_size >> 20
    );
    println!("  max_buffer_size {} MiB", l.max_buffer_size >> 20);
    println!("  max_texture_dimension_2d {}", l.max_texture_dimension_2d);
    println!("  max_texture_array_layers {}", l.max_texture_array_layers);
    println!(
        "  max_compute_workgroups_per_dimension {}",
        l.max_compute_workgroups_per_dimension
    );
    println!(
        "  max_compute_invocations_per_workgroup {}",
        l.max_compute_invocations_per_workgroup
    );
    println!(
        "  max_storage_buffers_per_shader_stage {}",
        l.max_storage_buffers_per_shader_stage
    );
    println!("features: {:?}", gpu.features);
    // Cluster mode's MPI, when built in (the default `mpi` feature).
    #[cfg(feature = "mpi")]
    match mpi::environment::library_version() {
        Ok(v) => println!(
            "mpi: {}",
            v.trim_end_matches(char::from(0))
                .lines()
                .next()
                .unwrap_or("")
                .trim()
        ),
        Err(e) => println!("mpi: version unreadable ({e})"),
    }
    #[cfg(not(feature = "mpi"))]
    println!("mpi: not built in (build with the default `mpi` feature)");
    Ok(())
}
