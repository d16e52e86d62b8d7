//! Helpers shared by the integration tests.

use dcrt::blocks::Format;
use dcrt::bvh::Build;
use dcrt::gpu::Gpu;
use dcrt::gpu::frame::{Frame, FrameStats};
use dcrt::gpu::layout::Pixel;
use dcrt::gpu::tracer::Settings;
use dcrt::reference::{Hit, Reference};
use dcrt::render::Prepared;
use dcrt::scene::ray::Ray;
use dcrt::scene::{Camera, Model, Scene};
use std::path::{Path, PathBuf};

pub fn gpu() -> Gpu {
    Gpu::new(None).expect("a GPU adapter (lavapipe: apt install mesa-vulkan-drivers)")
}

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn scene(name: &str) -> Scene {
    Scene::load(&repo().join("scenes").join(name)).unwrap()
}

pub fn prepare(model: Model) -> Prepared {
    Prepared::from_model(model, Build::default(), Format::default(), 0.0).unwrap()
}

pub fn render(
    gpu: &Gpu,
    prepared: &Prepared,
    camera: &Camera,
    w: u32,
    h: u32,
    settings: Settings,
) -> (Frame, FrameStats) {
    let mut tracer = prepared.tracer(gpu, settings).unwrap();
    tracer.render(&camera.basis(w, h), [0.1, 0.2, 0.3]).unwrap()
}

/// Asserts that two frames hold the same pixels bit for bit (colours and AOVs), naming the first
/// pixel that differs and `what` was compared.
pub fn assert_same_pixels(a: &Frame, b: &Frame, what: &str) {
    assert_eq!(a.pixels.len(), b.pixels.len(), "{what}: pixel counts");
    for (i, (p, q)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        assert_eq!(
            bytemuck::bytes_of(p),
            bytemuck::bytes_of(q),
            "{what}: pixel {i}"
        );
    }
}

/// The reference hit of every pixel, through the same pixel-centre rays.
pub fn reference(model: &Model, camera: &Camera, w: u32, h: u32) -> Vec<Option<Hit>> {
    let basis = camera.basis(w, h);
    let rays: Vec<Ray> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (o, d) = basis.pixel_ray(x, y);
            Ray {
                origin: o.map(|c| c as f32),
                dir: d.map(|c| c as f32),
                tmax: f32::INFINITY,
            }
        })
        .collect();
    Reference::new(&model.triangles).closest_hits(&rays)
}

pub fn is_miss(p: &Pixel) -> bool {
    p.id == u32::MAX
}

/// A temporary directory removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        let p = std::env::temp_dir().join(format!("dcrt-test-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }
    pub fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
    pub fn write(&self, name: &str, data: impl AsRef<[u8]>) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, data).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub fn dcrt(args: &[&dyn AsRef<std::ffi::OsStr>]) -> std::process::Output {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"));
    for a in args {
        cmd.arg(a);
    }
    cmd.output().unwrap()
}

pub fn exists(p: &Path) -> bool {
    p.exists()
}

/// SplitMix64: a small seeded generator, so every run traces the same rays.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn f(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f()
    }
    /// Uniform on the unit sphere.
    pub fn dir(&mut self) -> [f64; 3] {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, std::f64::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        [r * phi.cos(), r * phi.sin(), z]
    }
    /// Uniform in the ball of radius `r`.
    pub fn in_ball(&mut self, r: f64) -> [f64; 3] {
        loop {
            let p = [0; 3].map(|_| self.range(-r, r));
            if p.iter().map(|c| c * c).sum::<f64>() < r * r {
                return p;
            }
        }
    }
}

/// The names in `dir`, sorted: what a run left behind.
pub fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// `dcrt ARGS` with `dir` on a full file system: in a private mount namespace (`unshare -m`,
/// as root), `dir`'s files go onto a tmpfs mounted over it, all but `kib` KiB of its space is
/// taken, dcrt runs there (writes past the space fail with ENOSPC), and afterwards what dcrt
/// left replaces `dir`'s files, so that the caller sees the outcome in `dir`. (A file size limit,
/// `ulimit -f`, would also stop the GPU driver's own memory files.)
pub fn on_full_disk(
    dir: &Path,
    kib: u32,
    args: &[&dyn AsRef<std::ffi::OsStr>],
) -> std::process::Output {
    const SCRIPT: &str = r#"set -eu
dir=$1; kib=$2; shift 2
keep=$(mktemp -d)
cp -a "$dir"/. "$keep"/
mount -t tmpfs -o size=32m dcrt-full "$dir"
cp -a "$keep"/. "$dir"/
dd if=/dev/zero of="$dir/.fill" bs=64k 2>/dev/null || true
[ "$kib" -eq 0 ] || truncate -s -"$kib"K "$dir/.fill"
set +e
"$@"; rc=$?
set -e
rm -f "$dir/.fill"
find "$keep" -mindepth 1 -delete
cp -a "$dir"/. "$keep"/
umount "$dir"
find "$dir" -mindepth 1 -delete
cp -a "$keep"/. "$dir"/
rm -rf "$keep"
exit $rc
"#;
    let mut cmd = std::process::Command::new("unshare");
    cmd.args(["-m", "bash", "-c", SCRIPT, "full-disk"])
        .arg(dir)
        .arg(kib.to_string())
        .arg(env!("CARGO_BIN_EXE_dcrt"));
    for a in args {
        cmd.arg(a);
    }
    let out = cmd.output().unwrap();
    // The script's own failures (no permission to mount) are not dcrt's.
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("unshare:") && !err.contains("mount:"),
        "the full-disk harness failed: {err}"
    );
    out
}

/// Asserts that two frames are bit-identical, naming the first pixel that is not.
pub fn same_pixels(a: &Frame, b: &Frame, what: &str) {
    assert_eq!(
        (a.width, a.height, a.pixels.len()),
        (b.width, b.height, b.pixels.len()),
        "{what}: frames of different sizes"
    );
    for (i, (p, q)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        assert_eq!(
            bytemuck::bytes_of(p),
            bytemuck::bytes_of(q),
            "{what}: pixel {i}: {p:?} against {q:?}"
        );
    }
}
