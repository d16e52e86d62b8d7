//! `dcrt bench fuzz --seconds SECONDS`: every mesh loader fed mutations of the files dcrt ships
//! (scenes/meshes/, tests/data/vtk/) for SECONDS each. A loader must answer every input with a
//! mesh that validates or an error; what it returns must also colour without a panic by each of
//! its arrays (`scene::color::resolve`), and its parts must lie in order inside the mesh. A
//! panic, a broken promise or an input slower than a second is written to `fuzz-crashes/` for a
//! regression test. The tests run short versions of the same idea; this is the long run.

use anyhow::{Context, Result, bail};
use base64::Engine;
use clap::Args;
use dcrt::scene::color::{ColorBy, resolve};
use dcrt::scene::data::{Assoc, Keep, MeshData};
use dcrt::scene::mesh::Mesh;
use dcrt::scene::{gltf, obj, ply, stl, vtk};
use std::io::BufReader;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The formats in the order they are fuzzed, with their extension.
const FORMATS: [&str; 7] = ["stl", "vtk", "vtp", "gltf", "glb", "ply", "obj"];

/// One format's run.
#[derive(Debug, Default, serde::Serialize)]
struct Tally {
    format: &'static str,
    seeds: usize,
    inputs: u64,
    /// Inputs the loader read as a mesh (and that passed the checks).
    accepted: u64,
    /// Inputs refused with an error.
    refused: u64,
    /// Panics, broken promises and slow inputs, each saved.
    crashes: u64,
    slowest_ms: f64,
}

#[derive(Args)]
pub struct FuzzArgs {
    /// Seconds of fuzzing per loader.
    #[arg(long)]
    pub seconds: f64,
    /// The tallies as JSON on stdout too.
    #[arg(long)]
    pub json: bool,
}

pub fn run(seconds: f64, json: bool) -> Result<()> {
    if !(seconds > 0.0 && seconds.is_finite()) {
        bail!("--seconds needs a positive number of seconds per format, got {seconds}");
    }
    // Panics are expected findings: report them, not the default hook's backtrace noise.
    std::panic::set_hook(Box::new(|info| {
        dcrt::report!("  panic: {info}");
    }));
    let crashes = PathBuf::from("fuzz-crashes");
    let mut tallies = Vec::new();
    for format in FORMATS {
        let seeds = seeds(format)?;
        let t = fuzz(format, &seeds, Duration::from_secs_f64(seconds), &crashes)?;
        println!(
            "{:<5} {} seeds: {} inputs, {} read, {} refused, {} crashes; slowest {:.1} ms",
            t.format, t.seeds, t.inputs, t.accepted, t.refused, t.crashes, t.slowest_ms
        );
        tallies.push(t);
    }
    let _ = std::panic::take_hook();
    if json {
        println!("{}", serde_json::to_string_pretty(&tallies)?);
    }
    let crashed: u64 = tallies.iter().map(|t| t.crashes).sum();
    if crashed > 0 {
        bail!(
            "{crashed} inputs crashed a loader: see {}",
            crashes.display()
        );
    }
    Ok(())
}

/// The shipped files of a format (and, for STL and GLB, the other form of the same file).
fn seeds(format: &str) -> Result<Vec<Vec<u8>>> {
    let ext = if format == "glb" { "gltf" } else { format };
    let mut out = Vec::new();
    for dir in ["scenes/meshes", "tests/data/vtk"] {
        let Ok(entries) = std::fs::read_dir(dir) else {
            continue;
        };
        let mut paths: Vec<PathBuf> = entries
            .filter_map(|e| Ok::<_, ()>(e.ok()?.path()).ok())
            .collect();
        paths.sort();
        for p in paths {
            if p.extension().and_then(|e| e.to_str()) == Some(ext) {
                let bytes = std::fs::read(&p).with_context(|| p.display().to_string())?;
                out.push(match format {
                    "glb" => glb_of(&bytes).with_context(|| format!("{}: as GLB", p.display()))?,
                    _ => bytes,
                });
            }
        }
    }
    if format == "stl" {
        let ascii: Vec<Vec<u8>> = out.iter().filter_map(|b| ascii_stl(b)).collect();
        out.extend(ascii);
    }
    if out.is_empty() {
        bail!(
            "no .{ext} files in scenes/meshes or tests/data/vtk to fuzz (run from the repository)"
        );
    }
    Ok(out)
}

fn fuzz(format: &'static str, seeds: &[Vec<u8>], time: Duration, crashes: &Path) -> Result<Tally> {
    let mut t = Tally {
        format,
        seeds: seeds.len(),
        ..Tally::default()
    };
    // A seed of its own per format (FNV-1a of the name): reproducible, and never 0.
    let seed = format.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    let mut rng = Rng(seed | 1);
    let start = Instant::now();
    let origin = PathBuf::from(format!("fuzz.{format}"));
    while start.elapsed() < time {
        let mut bytes = seeds[rng.below(seeds.len())].clone();
        for _ in 0..1 + rng.below(4) {
            mutate(&mut bytes, &mut rng);
        }
        t.inputs += 1;
        let t0 = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| check(format, &bytes, &origin)));
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        t.slowest_ms = t.slowest_ms.max(ms);
        let finding = match outcome {
            Ok(Ok(true)) => {
                t.accepted += 1;
                None
            }
            Ok(Ok(false)) => {
                t.refused += 1;
                None
            }
            Ok(Err(broken)) => Some(broken),
            Err(_) => Some("panic".to_string()),
        };
        let finding = finding.or_else(|| (ms > 1000.0).then(|| format!("slow: {ms:.0} ms")));
        if let Some(what) = finding {
            t.crashes += 1;
            std::fs::create_dir_all(crashes)?;
            let file = crashes.join(format!("{format}-{}.{format}", t.crashes));
            std::fs::write(&file, &bytes)?;
            dcrt::report!("{format}: {what}: input saved as {}", file.display());
        }
    }
    Ok(t)
}

/// Reads `bytes` as the format, as dcrt loads a mesh file with every array kept. Ok(true): a
/// mesh that keeps the loaders' promises; Ok(false): an error; Err: a broken promise.
fn check(format: &str, bytes: &[u8], origin: &Path) -> Result<bool, String> {
    let parsed = parse(format, bytes, origin, &Keep::All);
    let Ok((mesh, data)) = parsed else {
        return Ok(false);
    };
    mesh.validate(origin)
        .map_err(|e| format!("a mesh that does not validate: {e}"))?;
    let n = mesh.triangles.len() as u32;
    if !data.triangle_cells.is_empty() && data.triangle_cells.len() != mesh.triangles.len() {
        return Err(format!(
            "{} triangle cells for {} triangles",
            data.triangle_cells.len(),
            n
        ));
    }
    if data.parts.windows(2).any(|w| w[0].first > w[1].first)
        || data.parts.iter().any(|p| p.first > n)
    {
        return Err(format!("parts out of order or past the {n} triangles"));
    }
    for (i, a) in data.arrays.iter().enumerate() {
        let by = ColorBy {
            array: a.name.clone(),
            cell: a.assoc == Assoc::Cell,
            colormap: None,
            range: None,
        };
        // An array listed but not kept (glTF: missing from some primitive) is read on its own,
        // as a scene's color_by reads it.
        let coloured = match data.values(i) {
            Some(_) => resolve(&mesh, &data, &by, origin),
            None => {
                let keep = Keep::One {
                    name: a.name.clone(),
                    assoc: a.assoc,
                };
                match parse(format, bytes, origin, &keep) {
                    Ok((mesh, data)) => resolve(&mesh, &data, &by, origin),
                    Err(e) => Err(e),
                }
            }
        };
        if let Ok(c) = coloured
            && c.words.len() != mesh.triangles.len()
        {
            return Err(format!(
                "array '{}': {} attribute triples",
                a.name,
                c.words.len()
            ));
        }
    }
    Ok(true)
}

fn parse(
    format: &str,
    bytes: &[u8],
    origin: &Path,
    keep: &Keep,
) -> dcrt::error::Result<(Mesh, MeshData)> {
    match format {
        "stl" => {
            stl::parse_stl(bytes, bytes.len() as u64, origin).map(|m| (m, MeshData::default()))
        }
        "obj" => obj::parse_obj(bytes, origin).map(|m| (m, MeshData::default())),
        "ply" => ply::parse_ply_data(BufReader::with_capacity(4096, bytes), origin, keep),
        "vtk" => vtk::legacy::parse_vtk(bytes, origin, keep),
        "vtp" => vtk::xml::parse_vtp(bytes, origin, keep),
        _ => gltf::parse_gltf(bytes, origin, keep),
    }
}

/// One to a few changes of the kinds that break loaders: a byte, a number in the text, a 32-bit
/// word (counts and offsets of binary files), a span cut out or repeated, a truncation.
fn mutate(b: &mut Vec<u8>, rng: &mut Rng) {
    if b.is_empty() {
        b.push(rng.next() as u8);
        return;
    }
    let at = rng.below(b.len());
    match rng.below(8) {
        0 => b[at] = rng.next() as u8,
        1 => b[at] = b" \n\t0123456789-+.eE<>/\"=#,:[]{}"[rng.below(30)],
        2 => {
            // The number (or word) around `at` becomes a boundary value.
            let word = |c: u8| c.is_ascii_alphanumeric() || b"+-.".contains(&c);
            let (mut s, mut e) = (at, at);
            while s > 0 && word(b[s - 1]) {
                s -= 1;
            }
            while e < b.len() && word(b[e]) {
                e += 1;
            }
            const VALUES: [&str; 14] = [
                "0",
                "-1",
                "1",
                "2",
                "3",
                "65535",
                "2147483647",
                "2147483648",
                "4294967295",
                "18446744073709551616",
                "1e39",
                "nan",
                "inf",
                "-0",
            ];
            b.splice(s..e, VALUES[rng.below(VALUES.len())].bytes());
        }
        3 => {
            const WORDS: [u32; 8] = [
                0,
                1,
                0xffff_ffff,
                0x7fff_ffff,
                0x8000_0000,
                0x7fc0_0000,
                0x7f80_0000,
                0x0010_0000,
            ];
            let w = WORDS[rng.below(WORDS.len())].to_le_bytes();
            let at = at.min(b.len().saturating_sub(4));
            for (k, x) in w.iter().enumerate() {
                if let Some(c) = b.get_mut(at + k) {
                    *c = *x;
                }
            }
        }
        4 => {
            let end = (at + 1 + rng.below(64)).min(b.len());
            b.drain(at..end);
        }
        5 => {
            let end = (at + 1 + rng.below(256)).min(b.len());
            let span = b[at..end].to_vec();
            let to = rng.below(b.len() + 1);
            b.splice(to..to, span);
        }
        6 => b.truncate(at),
        _ => b[at] = b[at].wrapping_add(1),
    }
}

/// The same triangles as an ASCII STL (a binary seed's other form).
fn ascii_stl(binary: &[u8]) -> Option<Vec<u8>> {
    let mesh = stl::parse_stl(binary, binary.len() as u64, Path::new("seed.stl")).ok()?;
    let mut s = String::from("solid seed\n");
    for i in 0..mesh.triangles.len().min(200) {
        s += " facet normal 0 0 0\n  outer loop\n";
        for p in mesh.corners(i) {
            s += &format!("   vertex {:e} {:e} {:e}\n", p[0], p[1], p[2]);
        }
        s += "  endloop\n endfacet\n";
    }
    s += "endsolid seed\n";
    Some(s.into_bytes())
}

/// A glTF file with embedded (data URI) buffers as GLB: the buffers become one binary chunk.
fn glb_of(gltf: &[u8]) -> Result<Vec<u8>> {
    let mut j: serde_json::Value = serde_json::from_slice(gltf)?;
    let mut bin = Vec::new();
    let mut starts = Vec::new();
    for b in j["buffers"].as_array().context("no buffers")? {
        let uri = b["uri"].as_str().context("a buffer without a uri")?;
        let (_, data) = uri.split_once(";base64,").context("not a data URI")?;
        starts.push(bin.len() as u64);
        bin.extend(base64::engine::general_purpose::STANDARD.decode(data)?);
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
    }
    for v in j["bufferViews"].as_array_mut().context("no bufferViews")? {
        let b = v["buffer"]
            .as_u64()
            .context("a bufferView without a buffer")? as usize;
        let offset = v["byteOffset"].as_u64().unwrap_or(0) + starts[b];
        v["buffer"] = 0.into();
        v["byteOffset"] = offset.into();
    }
    j["buffers"] = serde_json::json!([{ "byteLength": bin.len() }]);
    Ok(dcrt::scene::gltf::glb_container(
        serde_json::to_vec(&j)?,
        bin,
    ))
}

/// xorshift64: reproducible runs without a dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}
