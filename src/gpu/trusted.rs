//! Shader modules without wgpu's loop counters, and the review that makes that sound: one
//! unsafe call, the only unsafe code outside the MPI window wrapper (docs/ARCHITECTURE.md,
//! Shaders).
//!
//! wgpu has naga add a counter to every shader loop, checked and decremented each iteration, so
//! that no driver may treat a loop it finds infinite as unreachable. A CPU driver runs that
//! check as vector code in every lane of every iteration: 3% of the instructions of a cast, AO
//! or path frame on lavapipe. dcrt's kernels are its own and every loop in them ends; `LOOPS`
//! names each one and why, and a test fails when a shader's loops are not the ones reviewed.
//! The other checks (bounds checks where the driver has none) stay on.
#![allow(unsafe_code)]

/// Every loop statement of the WGSL sources (`loop`, `for`, `while`), per file, and why each
/// ends. A changed count fails `every_shader_loop_is_reviewed`: review the loop, then the count.
pub const LOOPS: &[(&str, usize, &str)] = &[
    (
        "traverse.wgsl",
        7,
        "the inner trace loop counts every iteration against params.step_budget before it runs; \
         the outer one runs it again only after a set-aside entry, a fault or an unresolved hit \
         that an iteration of it made (restoring clears the set-aside count); the for loops \
         run over at most TOP + 3 held entries, DEFER_SLOTS set-aside slots",
    ),
    ("gather.wgsl", 2, "k < shading.fan"),
    (
        "probe.wgsl",
        5,
        "bounded by fields of the probe's input and by constants",
    ),
    (
        "requesters.wgsl",
        1,
        "i < the fault count, at most params.dc_fault_cap, in steps of WORKGROUP",
    ),
    ("shared/node.wgsl", 1, "i < 4"),
    (
        "shared/scene.wgsl",
        1,
        "binary search: hi - lo halves while above 1",
    ),
];

/// A shader module from WGSL, with wgpu's bounds checks but without its loop counters (`LOOPS`).
pub fn shader_module(device: &wgpu::Device, name: &str, source: &str) -> wgpu::ShaderModule {
    let mut checks = wgpu::ShaderRuntimeChecks::checked();
    checks.force_loop_bounding = false;
    let desc = wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    };
    // SAFETY: every loop of dcrt's shaders ends (`LOOPS`, checked by the test below), which is
    // all that turning off `force_loop_bounding` asks of the caller.
    unsafe { device.create_shader_module_trusted(desc, checks) }
}

#[cfg(test)]
mod tests {
    use super::LOOPS;
    use std::path::Path;

    /// The loop statements of WGSL text, comments left out.
    fn loops(text: &str) -> usize {
        text.lines()
            .map(|l| l.split("//").next().unwrap_or(""))
            .map(|code| {
                let words: Vec<&str> = code
                    .split(|c: char| !(c.is_alphanumeric() || c == '_'))
                    .collect();
                words
                    .iter()
                    .filter(|w| matches!(**w, "loop" | "for" | "while"))
                    .count()
            })
            .sum()
    }

    #[test]
    fn loop_statements_are_counted_outside_comments() {
        assert_eq!(loops("loop {\n  for (var i = 0u; i < 4u; i++) {}\n}"), 2);
        assert_eq!(loops("// while no ray loops\nlet looped = 1u; // for"), 0);
        assert_eq!(loops("while hi - lo > 1u {"), 1);
    }

    #[test]
    fn every_shader_loop_is_reviewed() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
        let mut found = Vec::new();
        for sub in ["", "shared/"] {
            for entry in std::fs::read_dir(dir.join(sub)).unwrap() {
                let path = entry.unwrap().path();
                if path.extension().is_some_and(|e| e == "wgsl") {
                    let name = format!("{sub}{}", path.file_name().unwrap().to_string_lossy());
                    let n = loops(&std::fs::read_to_string(&path).unwrap());
                    if n > 0 {
                        found.push((name, n));
                    }
                }
            }
        }
        found.sort();
        let mut reviewed: Vec<(String, usize)> =
            LOOPS.iter().map(|&(f, n, _)| (f.to_string(), n)).collect();
        reviewed.sort();
        assert_eq!(
            found, reviewed,
            "the shaders' loops differ from those reviewed in gpu::trusted::LOOPS: kernels are \
             built without wgpu's loop counters, so check that each new loop ends, then update it"
        );
    }
}
