//! The Mitsuba 3 peer of `dcrt bench shading --peer mitsuba`: the exchange directory that
//! `scripts/mitsuba-peer.sh` renders (`scene.json`, one binary PLY per mesh), the script's run,
//! and reading its images back.

use anyhow::{Context, Result, bail};
use dcrt::scene::{CameraBasis, Model};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The script, found beside the sources this binary was built from.
pub fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/mitsuba-peer.sh")
}

#[derive(serde::Serialize, serde::Deserialize, Debug, PartialEq)]
pub struct CameraFile {
    pub origin: [f32; 3],
    pub forward: [f32; 3],
    pub right: [f32; 3],
    pub up: [f32; 3],
}

#[derive(serde::Serialize, serde::Deserialize, Debug, PartialEq)]
pub struct MeshFile {
    pub file: String,
    pub albedo: [f32; 3],
}

/// `scene.json`: everything the peer needs, in dcrt's terms (the script maps depths onto
/// Mitsuba's).
#[derive(serde::Serialize, serde::Deserialize, Debug, PartialEq)]
pub struct SceneFile {
    pub width: u32,
    pub height: u32,
    /// As `CameraBasis`: ray d = normalize(forward + sx * right + sy * up).
    pub camera: CameraFile,
    pub meshes: Vec<MeshFile>,
    pub sky: [f32; 3],
    pub max_depth: u32,
    pub rr_depth: u32,
    pub seed: u32,
    pub spp: Vec<u32>,
}

/// What the script prints (one JSON line, the last of its stdout).
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone)]
pub struct Output {
    pub mitsuba: String,
    pub variant: String,
    pub max_depth: u32,
    pub rr_depth: u32,
    pub threads: u32,
    pub load_seconds: f64,
    pub timed: String,
    pub renders: Vec<Render>,
}

#[derive(serde::Serialize, serde::Deserialize, Debug, Clone)]
pub struct Render {
    pub spp: u32,
    pub seconds: f64,
    pub passes: u32,
    pub file: String,
}

/// Writes `scene.json` and `mesh<i>.ply` (one per mesh of the model) into `dir`.
pub fn write_dir(
    dir: &Path,
    model: &Model,
    basis: &CameraBasis,
    (sky, max_depth, rr_depth, seed): ([f32; 3], u32, u32, u32),
    spp: &[u32],
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut meshes = Vec::new();
    for (i, &first) in model.mesh_first.iter().enumerate() {
        let end = model
            .mesh_first
            .get(i + 1)
            .map_or(model.triangles.len(), |&e| e as usize);
        let file = format!("mesh{i}.ply");
        write_ply(&dir.join(&file), &model.triangles[first as usize..end])?;
        meshes.push(MeshFile {
            file,
            albedo: model.colors[i],
        });
    }
    let scene = SceneFile {
        width: basis.width,
        height: basis.height,
        camera: CameraFile {
            origin: basis.origin,
            forward: basis.forward,
            right: basis.right,
            up: basis.up,
        },
        meshes,
        sky,
        max_depth,
        rr_depth,
        seed,
        spp: spp.to_vec(),
    };
    let path = dir.join("scene.json");
    std::fs::write(&path, serde_json::to_string_pretty(&scene)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// A binary little-endian PLY of unshared triangles (three vertices each, in order).
pub fn write_ply(path: &Path, triangles: &[[[f32; 3]; 3]]) -> Result<()> {
    let n = triangles.len();
    let mut out = Vec::with_capacity(200 + n * (36 + 13));
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
         property float y\nproperty float z\nelement face {n}\n\
         property list uchar int vertex_indices\nend_header\n",
        3 * n
    )?;
    for c in triangles.iter().flatten().flatten() {
        out.extend_from_slice(&c.to_le_bytes());
    }
    for i in 0..n as u32 {
        out.push(3);
        for k in 0..3 {
            out.extend_from_slice(&(3 * i + k).to_le_bytes());
        }
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}

/// An image the script wrote: `width * height` linear RGB f32 little-endian, rows from the top.
pub fn read_image(path: &Path, width: u32, height: u32) -> Result<Vec<[f32; 3]>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let n = width as usize * height as usize;
    if bytes.len() != n * 12 {
        bail!(
            "{}: {} bytes, expected {} ({width}x{height} RGB f32)",
            path.display(),
            bytes.len(),
            n * 12
        );
    }
    let v: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    if let Some(i) = v.iter().position(|x| !x.is_finite() || *x < 0.0) {
        bail!(
            "{}: pixel {} has {} (not finite and non-negative)",
            path.display(),
            i / 3,
            v[i]
        );
    }
    Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Runs the script on `dir`; its stderr (installation, errors) goes to ours. Any failure is an
/// error naming the script.
pub fn run_script(dir: &Path) -> Result<Output> {
    let script = script();
    if !script.is_file() {
        bail!(
            "the Mitsuba peer script {} does not exist",
            script.display()
        );
    }
    let out = Command::new("bash")
        .arg(&script)
        .arg(dir)
        .stdin(Stdio::null())
        .stderr(Stdio::inherit())
        .output()
        .with_context(|| format!("running {}", script.display()))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        bail!(
            "{} {} failed ({}); its stdout: {}",
            script.display(),
            dir.display(),
            out.status,
            stdout.trim()
        );
    }
    let line = stdout.lines().rev().find(|l| !l.trim().is_empty());
    let line = line.with_context(|| format!("{} printed nothing", script.display()))?;
    serde_json::from_str(line).with_context(|| {
        format!(
            "{}: its last line is not the expected JSON: {line}",
            script.display()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("dcrt-peer-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn exchange_directory_round_trips_through_dcrts_own_ply_loader() {
        let tris = vec![
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            [[0.5, -2.0, 3.25], [1e-3, 7.0, -1.0], [0.0, 0.0, 1e6]],
        ];
        let mut model = Model::from_triangles(tris.clone());
        model.mesh_first.push(1);
        model.colors.push([0.1, 0.2, 0.3]);
        let basis = CameraBasis {
            origin: [0.0, 0.0, 5.0],
            forward: [0.0, 0.0, -1.0],
            right: [0.8, 0.0, 0.0],
            up: [0.0, 0.4, 0.0],
            width: 8,
            height: 4,
            parallel: false,
        };
        let d = scratch("dir");
        write_dir(&d, &model, &basis, ([1.0; 3], 3, 3, 7), &[1, 2, 4]).unwrap();
        let s: SceneFile =
            serde_json::from_str(&std::fs::read_to_string(d.join("scene.json")).unwrap()).unwrap();
        assert_eq!((s.width, s.height, s.max_depth, s.seed), (8, 4, 3, 7));
        assert_eq!(s.camera.right, basis.right);
        assert_eq!(s.spp, vec![1, 2, 4]);
        assert_eq!(s.meshes.len(), 2);
        assert_eq!(s.meshes[1].albedo, [0.1, 0.2, 0.3]);
        for (k, m) in s.meshes.iter().enumerate() {
            let mesh = dcrt::scene::ply::load_ply(&d.join(&m.file)).unwrap();
            assert_eq!(mesh.triangle_count(), 1);
            assert_eq!(mesh.corners(0), tris[k]);
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn images_are_read_back_and_bad_ones_refused() {
        let d = scratch("img");
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("a.f32");
        let v: Vec<f32> = (0..2 * 3 * 3).map(|i| i as f32 * 0.5).collect();
        std::fs::write(&p, bytemuck::cast_slice::<f32, u8>(&v)).unwrap();
        let img = read_image(&p, 3, 2).unwrap();
        assert_eq!(img.len(), 6);
        assert_eq!(img[1], [1.5, 2.0, 2.5]);
        let e = read_image(&p, 3, 3).unwrap_err().to_string();
        assert!(e.contains("72 bytes, expected 108"), "{e}");
        let e = read_image(&p, 3, 1).unwrap_err().to_string();
        assert!(e.contains("72 bytes, expected 36"), "{e}");
        let mut bad = v.clone();
        bad[7] = f32::NAN;
        std::fs::write(&p, bytemuck::cast_slice::<f32, u8>(&bad)).unwrap();
        let e = read_image(&p, 3, 2).unwrap_err().to_string();
        assert!(e.contains("pixel 2"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
