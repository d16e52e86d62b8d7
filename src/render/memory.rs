//! Estimates of memory before large allocations, so that a request no node can hold is refused
//! with its size and how to lower it, instead of an allocation abort (docs/ARCHITECTURE.md,
//! Robustness). The estimates are deliberately low: they refuse what cannot fit, never what may.

use crate::error::{Error, Result};
use crate::scene::Scene;

/// Peak bytes per generated triangle while a model is generated, built and packed (about 300
/// measured for the rm generator at 1M triangles: mesh, triangle list, boxes, BVH2, layout,
/// blocks).
pub const BYTES_PER_GENERATED_TRIANGLE: u64 = 256;
/// Bytes per pixel of a whole-image frame: the traced pixels (32) and the PNG (3, rounded up).
pub const BYTES_PER_PIXEL: u64 = 36;

/// Bytes per pixel and EXR channel while a frame's EXR is written, beside `BYTES_PER_PIXEL`: the
/// channel's f32 samples and the file, encoded whole in memory before it is written. Measured:
/// peak RSS of a 4096x4096 render with all eight channels (`--aov depth,id,normal`) 725 MB above
/// the same render without `--exr` (43 bytes a pixel, 5.4 a channel; 4.2 a channel at 2048x2048).
pub const EXR_BYTES_PER_CHANNEL_PIXEL: u64 = 5;

/// Memory the kernel says is available (`MemAvailable` in /proc/meminfo); `None` where it
/// cannot be read.
pub fn available() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// This process's resident memory now and at its peak (`VmRSS`, `VmHWM` in /proc/self/status),
/// in bytes; `None` where they cannot be read.
pub fn resident() -> Option<(u64, u64)> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib = |key: &str| -> Option<u64> {
        let line = status.lines().find(|l| l.starts_with(key))?;
        Some(line.split_whitespace().nth(1)?.parse::<u64>().ok()? * 1024)
    };
    Some((kib("VmRSS:")?, kib("VmHWM:")?))
}

/// All the memory the kernel has (`MemTotal`); `None` where it cannot be read.
pub fn total() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn gib(b: u64) -> f64 {
    b as f64 / (1u64 << 30) as f64
}

/// Refuses `bytes` for `what` when more than `available` is free; `lower` says how to ask for
/// less.
pub fn check(what: &str, bytes: u64, available: Option<u64>, lower: &str) -> Result<()> {
    match available {
        Some(a) if bytes > a => Err(Error::Invalid(format!(
            "{what} needs about {:.1} GiB, more than the {:.1} GiB of memory available: {lower}",
            gib(bytes),
            gib(a)
        ))),
        _ => Ok(()),
    }
}

/// Before a scene's generators run: their triangles' estimated peak (a generator without
/// `triangles` makes a default that is small, and does not count).
pub fn check_generators(scene: &Scene) -> Result<()> {
    let triangles: u64 = scene
        .meshes
        .iter()
        .filter(|m| m.generator.is_some())
        .filter_map(|m| m.triangles)
        .sum();
    check(
        &format!(
            "generating {triangles} triangles for {}",
            scene.path.display()
        ),
        triangles.saturating_mul(BYTES_PER_GENERATED_TRIANGLE),
        available(),
        "lower the generators' `triangles`",
    )
}

/// Before a whole image of `width` x `height` is traced.
pub fn check_image(width: u32, height: u32) -> Result<()> {
    check_image_with_exr(width, height, 0, available())
}

/// The channels of an EXR with `aovs`: `R`, `G`, `B`, then `Z`, `id`, `N.X`..`N.Z`.
pub fn exr_channels(aovs: &[crate::output::Aov]) -> u32 {
    use crate::output::Aov;
    3 + aovs
        .iter()
        .map(|a| match a {
            Aov::Depth | Aov::Id => 1,
            Aov::Normal => 3,
        })
        .sum::<u32>()
}

/// Before a whole image is traced and written, with an EXR of `exr_channels` channels (0: no
/// EXR), against `available` bytes.
pub fn check_image_with_exr(
    width: u32,
    height: u32,
    exr_channels: u32,
    available: Option<u64>,
) -> Result<()> {
    let pixels = u64::from(width) * u64::from(height);
    let per_pixel = BYTES_PER_PIXEL + u64::from(exr_channels) * EXR_BYTES_PER_CHANNEL_PIXEL;
    let (what, lower) = if exr_channels == 0 {
        (
            format!("a {width}x{height} image"),
            "lower --width and --height",
        )
    } else {
        (
            format!("a {width}x{height} image with an EXR of {exr_channels} channels"),
            "lower --width and --height, or ask for fewer --aov",
        )
    };
    check(&what, pixels * per_pixel, available, lower)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn too_much_is_refused_with_its_size() {
        let e = check(
            "a 16384x16384 image",
            9 << 30,
            Some(8 << 30),
            "lower --width",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("a 16384x16384 image needs about 9.0 GiB, more than the 8.0 GiB"),
            "{e}"
        );
        assert!(e.contains("lower --width"), "{e}");
        assert!(check("x", 8 << 30, Some(8 << 30), "").is_ok());
        assert!(check("x", u64::MAX, None, "").is_ok());
    }

    /// The EXR writer's memory counts: a 16384x16384 image fits in 12 GiB alone (9 GiB), not with
    /// an all-AOV EXR (about 19 GiB), and the message names the channels.
    #[test]
    fn an_exr_adds_its_channels_to_the_image_estimate() {
        use crate::output::Aov;
        let all = exr_channels(&[Aov::Depth, Aov::Id, Aov::Normal]);
        assert_eq!(all, 8);
        assert_eq!(exr_channels(&[]), 3);
        let gib12 = Some(12 << 30);
        assert!(check_image_with_exr(16384, 16384, 0, gib12).is_ok());
        let e = check_image_with_exr(16384, 16384, all, gib12)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a 16384x16384 image with an EXR of 8 channels needs about 19.0 GiB"),
            "{e}"
        );
        assert!(e.contains("fewer --aov"), "{e}");
    }
}
