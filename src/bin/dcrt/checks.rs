//! Checks of options shared by the commands, made before any work.

use anyhow::{Result, bail};
use dcrt::gpu::tracer::MAX_STEP_BUDGET;
use std::path::Path;

pub fn check_budget(b: u32) -> Result<()> {
    if !(1..=MAX_STEP_BUDGET).contains(&b) {
        bail!(
            "--step-budget {b} is out of range 1..={MAX_STEP_BUDGET} (lavapipe stops loops at 65,535)"
        );
    }
    Ok(())
}

/// Fails before any work if an output cannot be created, so no render is lost to a typo.
pub fn check_writable(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!(
            "{}: the output directory {} does not exist",
            path.display(),
            dir.display()
        );
    }
    Ok(())
}
