//! Checks of options shared by the commands, made before any work.

use anyhow::{Result, bail};
use dcrt::gpu::tracer::MAX_STEP_BUDGET;

pub fn check_budget(b: u32) -> Result<()> {
    if !(1..=MAX_STEP_BUDGET).contains(&b) {
        bail!(
            "--step-budget {b} is out of range 1..={MAX_STEP_BUDGET} (lavapipe stops loops at 65,535)"
        );
    }
    Ok(())
}
