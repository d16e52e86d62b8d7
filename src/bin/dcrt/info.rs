//! `dcrt info`: the GPU adapters, the one dcrt would use, its limits and features, and MPI.

use anyhow::Result;
use dcrt::gpu::Gpu;

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
