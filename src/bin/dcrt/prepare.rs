//! `dcrt prepare`: a scene's BVH and blocks, built once into a block file.

use crate::PrepareArgs;
use crate::checks::check_writable;
use anyhow::{Context, Result};
use dcrt::blocks::Format;
use dcrt::render::Prepared;
use dcrt::scene::Scene;

pub fn prepare(a: PrepareArgs) -> Result<()> {
    check_writable(&a.output)?;
    let format = Format::new(a.block_size)?;
    let scene = Scene::load(&a.scene)?;
    let p = Prepared::new(&scene, a.bvh_preset, format)?;
    let camera = scene.camera_or_default(&p.model);
    let meta = p.meta(&scene, camera, scene.width, scene.height);
    // Write beside the target and rename, so a failed write never leaves a half file behind.
    let tmp = a.output.with_extension("dcb.partial");
    dcrt::blocks::file::write(&tmp, &p.blocks, &meta)?;
    std::fs::rename(&tmp, &a.output)
        .with_context(|| format!("{}: cannot rename into place", a.output.display()))?;
    eprintln!(
        "{} triangles, {} node + {} triangle blocks of {} bytes ({} MiB), BVH depth {}, wrote {}",
        p.model.triangles.len(),
        p.blocks.node_blocks,
        p.blocks.tri_blocks,
        format.block_bytes,
        p.blocks.bytes() >> 20,
        p.bvh.depth,
        a.output.display()
    );
    Ok(())
}
