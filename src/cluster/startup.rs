//! Start-up of a cluster job: every rank opens what its role needs, then all agree that
//! everyone could, and on the image and the model, before any collective that a failed rank
//! would never join. A disagreement is reported by the rank it concerns.

use super::{Options, Roles};
use crate::blocks::ranks::Ranks;
use crate::dc::{CacheMap, CacheSize};
use crate::error::Result;
use crate::gpu::Gpu;
use crate::gpu::tracer::Settings;
use crate::render::{ImageOf, Loaded};
use crate::scene::check_image_size;
use crate::shading::{Mode, Sampler, Shading};
use clap::ValueEnum;
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
    /// The scene's shading with the command line's changes, as every rank applies them.
    pub shading: Shading,
    /// What every rank must agree on, as `Report` words.
    report: Report,
    pub role: Role,
    /// The display's colour legend, with `--legend`.
    pub legend: Option<crate::legend::Legend>,
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

/// What one rank reports for the agreement: everything that shapes the image, as words (hashes
/// where the value is large). The model's words, from `FINGERPRINT` on, are compared between
/// render ranks only (the display and the balancer do not read the model).
type Report = [u32; WORDS];
const WORDS: usize = 14;
const OPENED: usize = 0;
/// Width, height, frames.
const SIZE: std::ops::Range<usize> = 1..4;
/// Mode (its index among `Mode`'s values), samples per pixel, seed, sampler (its index among
/// `Sampler`'s values).
const MODE: usize = 4;
const SPP: usize = 5;
const SEED: usize = 6;
const SAMPLER: usize = 7;
/// A hash of the whole of the shading settings (lights, rays, depths, sky, offsets...).
const SHADING: usize = 8;
/// A hash of what the display applies: exposure, background, AOVs, the display benchmark.
const DISPLAY: usize = 9;
/// The block fingerprint's low and high words, then hashes of the camera and of the mesh table.
const FINGERPRINT: std::ops::Range<usize> = 10..12;
const CAMERA: usize = 12;
const MESHES: usize = 13;

/// A stable hash of a value's `Debug` form (every rank runs the same build: floats print the same).
fn digest(v: &impl std::fmt::Debug) -> u32 {
    crc32fast::hash(format!("{v:?}").as_bytes())
}

fn report(opts: &Options, image: Image, shading: &Shading, of: &ImageOf) -> Report {
    let mut r = [0; WORDS];
    r[OPENED] = 1;
    r[SIZE].copy_from_slice(&[image.width, image.height, opts.frames]);
    r[MODE] = Mode::value_variants()
        .iter()
        .position(|m| *m == shading.mode)
        .unwrap_or(usize::MAX) as u32;
    r[SPP] = shading.spp;
    r[SEED] = shading.seed;
    r[SAMPLER] = Sampler::value_variants()
        .iter()
        .position(|s| *s == shading.sampler)
        .unwrap_or(usize::MAX) as u32;
    r[SHADING] = digest(shading);
    r[DISPLAY] = digest(&(
        opts.exposure.to_bits(),
        of.background.map(f32::to_bits),
        &opts.aovs,
        opts.exr.is_some(),
        opts.display_bench,
    ));
    r
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
        crate::report!("error: rank {rank}: {e}");
    }
    let check = match &opened {
        Ok(o) => o.report,
        Err(_) => [0; WORDS],
    };
    let mut all = vec![[0u32; WORDS]; roles.size as usize];
    world.all_gather_into(&check[..], bytemuck::cast_slice_mut::<_, u32>(&mut all[..]));
    let opened = opened.ok()?;
    if let Some((concerned, problem)) = disagreement(&all, roles) {
        if rank == 0 || concerned == rank {
            crate::report!("error: {problem}");
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
    if rank == Roles::DISPLAY {
        use crate::render::memory;
        let exr = opts
            .exr
            .as_ref()
            .map_or(0, |_| memory::exr_channels(&opts.aovs));
        memory::check_image_with_exr(image.width, image.height, exr, memory::available())?;
    }
    let legend = match rank == Roles::DISPLAY && opts.legend {
        true => Some(crate::render::legend_of(&opts.input)?),
        false => None,
    };
    // Applied here, after the scene is read, so that a rank that cannot read it still takes
    // part in the agreement.
    let shading = opts.shade.apply(of.shading)?;
    let mut report = report(opts, image, &shading, &of);
    let Some(index) = roles.render_index(rank) else {
        return Ok(Opened {
            image,
            shading,
            report,
            role: Role::Coordinator,
            legend,
        });
    };
    let mut loaded = Loaded::open(&opts.input, opts.build, opts.format)?;
    if let Some(c) = opts.camera {
        loaded.camera = c;
    }
    let gpu = Gpu::new(opts.adapter.as_deref())?;
    let dc = match opts.cache {
        // A single render rank owns every block: a cache would only slow its pipelines down.
        Some(_) if roles.render_ranks() == 1 => {
            crate::report!("rank {rank}: the only render rank owns every block: no cache needed");
            None
        }
        None => None,
        Some(c) => {
            let ranks = Ranks::new(roles.render_ranks(), index)?
                .replicating(c.replicate.blocks(loaded.node_blocks()));
            Some((ranks, loaded.resident(ranks)?, c.size, c.map))
        }
    };
    let fingerprint = loaded.fingerprint();
    report[FINGERPRINT].copy_from_slice(&[fingerprint as u32, (fingerprint >> 32) as u32]);
    report[CAMERA] = digest(&loaded.camera);
    report[MESHES] = digest(&(&loaded.meshes, loaded.depth, loaded.triangles));
    Ok(Opened {
        image,
        shading,
        report,
        legend,
        role: Role::Render(Box::new(RenderSetup {
            loaded,
            gpu,
            dc,
            // A live view's batches are sized for any mode a client may switch to.
            settings: Settings {
                shading,
                ..Settings {
                    shading: match opts.live {
                        true => shading.widest_mode(),
                        false => shading,
                    },
                    ..opts.settings
                }
                .for_image(image.width, image.height)
            },
        })),
    })
}

/// The first problem in what the ranks reported (`Report`), and the rank it concerns
/// (`u32::MAX`: the failed rank spoke for itself).
fn disagreement(all: &[Report], roles: Roles) -> Option<(u32, String)> {
    if let Some(r) = all.iter().position(|c| c[OPENED] == 0) {
        return Some((
            u32::MAX,
            format!(
                "rank {r} could not open its input (its message above says why); every rank stops"
            ),
        ));
    }
    const SAME: &str = "every rank must be given the same input and options";
    let first = roles.first_render() as usize;
    let mode = |c: &Report| {
        Mode::value_variants()
            .get(c[MODE] as usize)
            .map_or("?", |m| m.name())
    };
    let sampler = |c: &Report| {
        Sampler::value_variants()
            .get(c[SAMPLER] as usize)
            .map_or("?", |s| s.name())
    };
    for (r, c) in all.iter().enumerate() {
        let z = &all[0];
        if c[SIZE] != z[SIZE] {
            return Some((
                r as u32,
                format!(
                    "rank {r} has a {}x{} image of {} frames, rank 0 {}x{} of {}: {SAME}",
                    c[1], c[2], c[3], z[1], z[2], z[3]
                ),
            ));
        }
        if c[MODE..=SAMPLER] != z[MODE..=SAMPLER] {
            return Some((
                r as u32,
                format!(
                    "rank {r} renders --mode {} --spp {} --seed {} --sampler {}, rank 0 --mode {} \
                     --spp {} --seed {} --sampler {}: {SAME}",
                    mode(c),
                    c[SPP],
                    c[SEED],
                    sampler(c),
                    mode(z),
                    z[SPP],
                    z[SEED],
                    sampler(z)
                ),
            ));
        }
        if c[SHADING] != z[SHADING] {
            return Some((
                r as u32,
                format!(
                    "rank {r}'s shading settings (lights, rays, depths, sky, sun) differ from \
                     rank 0's: {SAME}"
                ),
            ));
        }
        if c[DISPLAY] != z[DISPLAY] {
            return Some((
                r as u32,
                format!("rank {r}'s exposure, background or AOVs differ from rank 0's: {SAME}"),
            ));
        }
        if r <= first {
            continue;
        }
        let f = &all[first];
        if c[FINGERPRINT] != f[FINGERPRINT] {
            return Some((
                r as u32,
                format!(
                    "rank {r}'s model differs from rank {first}'s (block fingerprints \
                     {:08x}{:08x} and {:08x}{:08x}): every rank must read the same model",
                    c[FINGERPRINT.end - 1],
                    c[FINGERPRINT.start],
                    f[FINGERPRINT.end - 1],
                    f[FINGERPRINT.start]
                ),
            ));
        }
        if c[CAMERA] != f[CAMERA] {
            return Some((
                r as u32,
                format!(
                    "rank {r}'s camera differs from rank {first}'s (the same blocks seen from \
                     another view): every rank must read the same model and scene"
                ),
            ));
        }
        if c[MESHES] != f[MESHES] {
            return Some((
                r as u32,
                format!(
                    "rank {r}'s mesh table (colours, depth, triangles) differs from rank \
                     {first}'s: every rank must read the same model"
                ),
            ));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(size: [u32; 3], mode: u32, rest: [u32; 5], model: [u32; 4]) -> Report {
        let mut r = [0; WORDS];
        r[OPENED] = 1;
        r[SIZE].copy_from_slice(&size);
        r[MODE] = mode;
        r[SPP..=DISPLAY].copy_from_slice(&rest);
        r[FINGERPRINT.start..].copy_from_slice(&model);
        r
    }

    #[test]
    fn the_rank_that_differs_is_named() {
        let roles = Roles::new(4).unwrap();
        let size = [64, 48, 2];
        let rest = [1, 0, 0, 7, 9];
        let ok = words(size, 0, rest, [0xaa, 0xbb, 3, 4]);
        let coord = words(size, 0, rest, [0; 4]);
        assert_eq!(disagreement(&[coord, coord, ok, ok], roles), None);
        let (r, m) = disagreement(&[coord, coord, ok, [0; WORDS]], roles).unwrap();
        assert_eq!(r, u32::MAX);
        assert!(m.starts_with("rank 3 could not open its input"), "{m}");
        let cases = [
            (
                words([64, 40, 2], 0, rest, [0xaa, 0xbb, 3, 4]),
                "rank 3 has a 64x40 image of 2 frames, rank 0 64x48",
            ),
            (
                words(size, 2, rest, [0xaa, 0xbb, 3, 4]),
                "rank 3 renders --mode ao --spp 1 --seed 0 --sampler sobol, rank 0 --mode cast \
                 --spp 1 --seed 0 --sampler sobol",
            ),
            (
                words(size, 0, [4, 0, 0, 7, 9], [0xaa, 0xbb, 3, 4]),
                "rank 3 renders --mode cast --spp 4",
            ),
            (
                words(size, 0, [1, 0, 1, 7, 9], [0xaa, 0xbb, 3, 4]),
                "rank 3 renders --mode cast --spp 1 --seed 0 --sampler independent, rank 0 \
                 --mode cast --spp 1 --seed 0 --sampler sobol",
            ),
            (
                words(size, 0, [1, 0, 0, 8, 9], [0xaa, 0xbb, 3, 4]),
                "rank 3's shading settings",
            ),
            (
                words(size, 0, [1, 0, 0, 7, 1], [0xaa, 0xbb, 3, 4]),
                "rank 3's exposure, background or AOVs",
            ),
            (
                words(size, 0, rest, [0xab, 0xbb, 3, 4]),
                "rank 3's model differs from rank 2's (block fingerprints 000000bb000000ab",
            ),
            (
                words(size, 0, rest, [0xaa, 0xbb, 5, 4]),
                "rank 3's camera differs from rank 2's",
            ),
            (
                words(size, 0, rest, [0xaa, 0xbb, 3, 5]),
                "rank 3's mesh table",
            ),
        ];
        for (bad, expect) in cases {
            let (r, m) = disagreement(&[coord, coord, ok, bad], roles).unwrap();
            assert_eq!(r, 3);
            assert!(m.starts_with(expect), "{m}");
        }
        // The display and the balancer have no model: theirs is not compared.
        let (r, m) = disagreement(&[coord, words(size, 3, rest, [0; 4]), ok, ok], roles).unwrap();
        assert_eq!(r, 1);
        assert!(m.starts_with("rank 1 renders --mode path"), "{m}");
    }
}
