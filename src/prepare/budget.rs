//! The memory `dcrt prepare` may use (`--memory`), and what fits in it: the whole model built in
//! memory, or parts of how many triangles (docs/ARCHITECTURE.md, Out-of-core prepare).

use crate::error::{Error, Result};
use crate::render::memory;

/// Peak bytes per triangle of the in-memory build, which holds the triangles, their boxes,
/// obvhs's BVH2, the layout and the packed blocks at once: 283 measured (peak RSS of rm at 10M
/// and 30M triangles, 2.62 and 7.81 GiB), with a margin.
pub const IN_CORE_BYTES_PER_TRIANGLE: u64 = 300;
/// Peak bytes per triangle of a part's build: its triangles, their boxes, obvhs's BVH2 and the
/// layout (the blocks are written as they are made). The whole process peaked at 296-330 bytes
/// per triangle of its largest part (rm, parts of 2-7.6M triangles, the program's own memory
/// included); parts are cut to at most `partition::SLACK` of the capacity, which covers that.
pub const PART_BYTES_PER_TRIANGLE: u64 = 300;
/// What the process holds besides the model: the program, threads, I/O buffers, the partition's
/// histogram.
pub const FIXED_BYTES: u64 = 12 << 20;
/// The least `--memory` accepted: the fixed part and room for parts of a useful size.
pub const MIN_BYTES: u64 = 16 << 20;

/// A memory budget in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Budget {
    pub bytes: u64,
}

impl Budget {
    /// `--memory SIZE`: a size in binary units, at least `MIN_BYTES` and at most the machine's
    /// memory.
    pub fn parse(text: &str) -> Result<Budget> {
        let bytes =
            crate::size::parse_size(text).map_err(|e| Error::Invalid(format!("--memory {e}")))?;
        Budget::of(bytes, memory::total())
            .map_err(|e| Error::Invalid(format!("--memory '{}': {e}", text.trim())))
    }

    fn of(bytes: u64, total: Option<u64>) -> std::result::Result<Budget, String> {
        if bytes < MIN_BYTES {
            return Err(format!(
                "{} MiB is too little: give at least {} MiB",
                bytes >> 20,
                MIN_BYTES >> 20
            ));
        }
        if let Some(t) = total
            && bytes > t
        {
            return Err(format!(
                "more than the {:.1} GiB this machine has",
                t as f64 / (1u64 << 30) as f64
            ));
        }
        Ok(Budget { bytes })
    }

    /// Without `--memory`: half of the memory available now (others may need the rest), or
    /// 4 GiB where that cannot be read.
    pub fn default_for_machine() -> Budget {
        let bytes = memory::available().map_or(4 << 30, |a| a / 2);
        Budget {
            bytes: bytes.max(MIN_BYTES),
        }
    }

    /// The most triangles built in memory whole.
    pub fn in_core_triangles(&self) -> u64 {
        self.bytes.saturating_sub(FIXED_BYTES) / IN_CORE_BYTES_PER_TRIANGLE
    }

    /// The most triangles of a part built out of core.
    pub fn part_triangles(&self) -> u64 {
        (self.bytes.saturating_sub(FIXED_BYTES) / PART_BYTES_PER_TRIANGLE).max(1)
    }

    /// I/O buffer bytes for each of `files` files written at once.
    pub fn buffer_bytes(&self, files: usize) -> usize {
        let share = self.bytes / 32 / files.max(1) as u64;
        share.clamp(4 << 10, 1 << 20) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_budgets_say_what_is_wrong() {
        let gib16 = Some(16u64 << 30);
        assert_eq!(Budget::of(4 << 30, gib16), Ok(Budget { bytes: 4 << 30 }));
        let e = Budget::of(1 << 20, gib16).unwrap_err();
        assert!(e.contains("at least 16 MiB"), "{e}");
        let e = Budget::of(17 << 30, gib16).unwrap_err();
        assert!(e.contains("16.0 GiB this machine has"), "{e}");
        for (text, want) in [
            ("4GB", "4GiB"),
            ("0", "binary unit"),
            ("0GiB", "too little"),
            ("abc", "binary unit"),
            ("1000TiB", "this machine has"),
        ] {
            let e = Budget::parse(text).unwrap_err().to_string();
            assert!(e.contains("--memory") && e.contains(want), "{text}: {e}");
        }
    }

    #[test]
    fn parts_are_smaller_than_the_budget() {
        let b = Budget { bytes: 1 << 30 };
        assert!(b.part_triangles() * PART_BYTES_PER_TRIANGLE < b.bytes);
        assert!(b.in_core_triangles() <= b.part_triangles());
    }
}
