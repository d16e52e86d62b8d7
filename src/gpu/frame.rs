//! What a frame is and what it cost: the traced pixels, the rectangle of the image a call
//! traces, and the frame's statistics.

use super::layout::Pixel;
use std::time::Duration;

/// What one frame cost.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FrameStats {
    pub rays: u64,
    pub batches: u32,
    /// Trace dispatches, summed over batches (including empty trailing ones).
    pub rounds: u32,
    /// The most rounds any batch needed before no ray was live.
    pub max_live_rounds: u32,
    pub steps: u64,
    pub tri_tests: u64,
    /// Wall time of the whole frame, and of its parts: ray generation and traversal rounds until the
    /// last live count came back; shading and the pixel readback (including the copy into the
    /// frame).
    pub seconds: f64,
    pub trace_seconds: f64,
    pub shade_seconds: f64,
    /// GPU time of the traversal rounds by GPU timestamps (0 when the adapter has none); the rest of
    /// `trace_seconds` is submission, readback and the CPU's fault service.
    pub gpu_seconds: f64,
    /// Distributed cache: cache consultations, hits, misses; blocks fetched and their bytes;
    /// time fetching (CPU) and uploading into the cache.
    pub lookups: u64,
    pub hits: u64,
    pub misses: u64,
    pub fetched_blocks: u64,
    pub fetched_bytes: u64,
    /// Distinct borrowed blocks the frame's rays looked up (resident in the cache or fetched):
    /// `fetched_blocks` over it is how often the frame fetched each block it needed.
    pub distinct_blocks: u64,
    /// The fewest fault rounds any schedule could take to bring those blocks through the
    /// cache (`CachePolicy::fault_round_bound`): `fault_rounds` over it is the scheduler's room.
    pub fault_round_bound: u32,
    pub fetch_seconds: f64,
    pub upload_seconds: f64,
    /// Rounds that had faults.
    pub fault_rounds: u32,
    /// Rounds in which more than one batch was in flight (`Settings::overlap_batches`).
    pub shared_rounds: u32,
    /// Inner-node visits and node-block entries (a visit in another block than the previous);
    /// 0 unless the tracer counts them (`Settings::block_counts`).
    pub node_visits: u64,
    pub block_entries: u64,
    /// Triangle reads from another triangle block than the ray's previous one (as above).
    pub tri_block_entries: u64,
    /// Loop iterations the trace's lanes ran, busy or idle: per subgroup the most iterations
    /// one of its invocations ran, times the subgroup size (as above). `steps` over it is the
    /// share of lanes that did work, what sorting rays could at best gain. The size is the
    /// largest any subgroup of the batch reported: exact where a pipeline's subgroups share one
    /// size (lavapipe, NVIDIA), an upper bound of the lanes where they may differ.
    pub lane_steps: u64,
    /// Samples per pixel traced; secondary rays spawned; rays that entered traversal (primary
    /// rays culled by the model's box and rays not needed do not).
    pub samples: u32,
    pub secondary_rays: u64,
    pub traced_rays: u64,
}

/// A traced frame: one `Pixel` per image pixel, row-major, y down.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Pixel>,
}

/// A rectangle of the image in pixels: what one `render_rect` call traces.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

impl Rect {
    pub fn whole(width: u32, height: u32) -> Rect {
        Rect {
            x: 0,
            y: 0,
            w: width,
            h: height,
        }
    }

    pub fn pixels(&self) -> usize {
        self.w as usize * self.h as usize
    }
}

/// A duration in milliseconds, for reports.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
