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

/// Memory the kernel says is available (`MemAvailable` in /proc/meminfo); `None` where it
/// cannot be read.
pub fn available() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
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
    check(
        &format!("a {width}x{height} image"),
        u64::from(width) * u64::from(height) * BYTES_PER_PIXEL,
        available(),
        "lower --width and --height",
    )
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
}
