//! `dcrt prepare`: a scene's BVH and blocks, built once into a block file.

use crate::PrepareArgs;
use anyhow::Result;
use dcrt::blocks::Format;
use dcrt::render::Prepared;
use dcrt::scene::Scene;

pub fn prepare(a: PrepareArgs) -> Result<()> {
    let inputs = Scene::input_files(&a.scene)?;
    dcrt::output::check_outputs(&[("block file", &a.output, 1)], &inputs)?;
    let format = Format::new(a.block_size)?;
    let scene = Scene::load(&a.scene)?;
    let p = Prepared::new(&scene, a.bvh_preset, format)?;
    let camera = scene.camera_or_default(&p.model);
    let meta = p.meta(&scene, camera, scene.width, scene.height);
    // Written beside the target and renamed into place: a failed write leaves no half file.
    dcrt::blocks::file::write(&a.output, &p.blocks, &meta)?;
    let attrs = match p.blocks.attrs.blocks {
        0 => String::new(),
        n => format!(" + {n} attribute"),
    };
    eprintln!(
        "{} triangles, {} node + {} triangle{attrs} blocks of {} bytes ({} MiB), BVH depth {}, \
         wrote {}",
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
