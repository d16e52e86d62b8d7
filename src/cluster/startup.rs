//! Start-up of a cluster job: every rank opens what its role needs, then all agree that
//! everyone could, and on the image and the model, before any collective that a failed rank
//! would never join. A disagreement is reported by the rank it concerns.

use super::{Options, Roles};
use crate::dc::{CacheMap, CacheSize, Ranks};
use crate::error::Result;
use crate::gpu::Gpu;
use crate::gpu::tracer::Settings;
use crate::render::Loaded;
use crate::scene::check_image_size;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

/// The image every rank agrees on.
#[derive(Clone, Copy, Debug)]
pub struct Image {
    pub width: u32,
    pub height: u32,
}

/// What a rank opened before the agreement.
pub struct Opened {
    pub image: Image,
    fingerprint: u64,
    pub role: Role,
}

pub enum Role {
    /// The display, the balancer or both.
    Coordinator,
    Render(Box<RenderSetup>),
}

/// A render rank's model and GPU, before the block window exists.
pub struct RenderSetup {
    pub loaded: Loaded,
    pub gpu: Gpu,
    /// With a distributed cache: this rank's place, its resident blocks and the cache.
    pub dc: Option<(Ranks, Vec<u32>, CacheSize, CacheMap)>,
    pub settings: Settings,
}

/// Opens this rank's input and agrees with the others. `None`: the job must stop, and what is
/// wrong has been said.
pub fn start(
    world: &SimpleCommunicator,
    opts: &Options,
    roles: Roles,
    rank: u32,
) -> Option<Opened> {
    let opened = open(opts, roles, rank);
    // Said before anything else: once any rank exits non-zero, mpirun may kill the others
    // before they print.
    if let Err(e) = &opened {
        eprintln!("error: rank {rank}: {e}");
    }
    let check = match &opened {
        Ok(o) => [
            1,
            o.image.width,
            o.image.height,
            opts.frames,
            o.fingerprint as u32,
            (o.fingerprint >> 32) as u32,
        ],
        Err(_) => [0; 6],
    };
    let mut all = vec![[0u32; 6]; roles.size as usize];
    world.all_gather_into(&check[..], bytemuck::cast_slice_mut::<_, u32>(&mut all[..]));
    let opened = opened.ok()?;
    if let Some((concerned, problem)) = disagreement(&all, roles) {
        if rank == 0 || concerned == rank {
            eprintln!("error: {problem}");
        }
        return None;
    }
    Some(opened)
}

fn open(opts: &Options, roles: Roles, rank: u32) -> Result<Opened> {
    let of = Loaded::image_of(&opts.input)?;
    let image = Image {
        width: opts.width.unwrap_or(of.width),
        height: opts.height.unwrap_or(of.height),
    };
    check_image_size(image.width, image.height)?;
    // Applied here, after the scene is read, so that a rank that cannot read it still takes
    // part in the agreement.
    let shading = opts.shade.apply(of.shading)?;
    let Some(index) = roles.render_index(rank) else {
        return Ok(Opened {
            image,
            fingerprint: 0,
            role: Role::Coordinator,
        });
    };
    let loaded = Loaded::open(&opts.input, opts.preset, opts.format)?;
    let gpu = Gpu::new(opts.adapter.as_deref())?;
    let dc = match opts.cache {
        // A single render rank owns every block: a cache would only slow its pipelines down.
        Some(_) if roles.render_ranks() == 1 => {
            eprintln!("rank {rank}: the only render rank owns every block: no cache needed");
            None
        }
        None => None,
        Some((size, map)) => {
            let ranks = Ranks::new(roles.render_ranks(), index)?;
            Some((ranks, loaded.resident(ranks)?, size, map))
        }
    };
    Ok(Opened {
        image,
        fingerprint: loaded.fingerprint(),
        role: Role::Render(Box::new(RenderSetup {
            loaded,
            gpu,
            dc,
            settings: Settings {
                shading,
                ..opts.settings
            },
        })),
    })
}

/// The first problem in what the ranks reported (opened, width, height, frames, fingerprint low
/// and high words), and the rank it concerns (`u32::MAX`: the failed rank spoke for itself).
fn disagreement(all: &[[u32; 6]], roles: Roles) -> Option<(u32, String)> {
    if let Some(r) = all.iter().position(|c| c[0] == 0) {
        return Some((
            u32::MAX,
            format!(
                "rank {r} could not open its input (its message above says why); every rank stops"
            ),
        ));
    }
    let first = roles.first_render() as usize;
    for (r, c) in all.iter().enumerate() {
        if c[1..4] != all[0][1..4] {
            return Some((
                r as u32,
                format!(
                    "rank {r} has a {}x{} image of {} frames, rank 0 {}x{} of {}: every rank must \
                     be given the same input and options",
                    c[1], c[2], c[3], all[0][1], all[0][2], all[0][3]
                ),
            ));
        }
        if r > first && c[4..] != all[first][4..] {
            return Some((
                r as u32,
                format!(
                    "rank {r}'s model differs from rank {first}'s (block fingerprints \
                     {:08x}{:08x} and {:08x}{:08x}): every rank must read the same model",
                    c[5], c[4], all[first][5], all[first][4]
                ),
            ));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rank_that_differs_is_named() {
        let roles = Roles::new(4).unwrap();
        let ok = [1, 64, 48, 2, 0xaa, 0xbb];
        let coord = [1, 64, 48, 2, 0, 0];
        assert_eq!(disagreement(&[coord, coord, ok, ok], roles), None);
        let (r, m) = disagreement(&[coord, coord, ok, [0; 6]], roles).unwrap();
        assert_eq!(r, u32::MAX);
        assert!(m.starts_with("rank 3 could not open its input"), "{m}");
        let (r, m) = disagreement(&[coord, coord, ok, [1, 64, 40, 2, 0xaa, 0xbb]], roles).unwrap();
        assert_eq!(r, 3);
        assert!(
            m.starts_with("rank 3 has a 64x40 image of 2 frames, rank 0 64x48"),
            "{m}"
        );
        let (r, m) = disagreement(&[coord, coord, ok, [1, 64, 48, 2, 0xab, 0xbb]], roles).unwrap();
        assert_eq!(r, 3);
        assert!(
            m.contains("rank 3's model differs from rank 2's (block fingerprints 000000bb000000ab"),
            "{m}"
        );
    }
}
