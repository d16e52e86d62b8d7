//! Scenes: the TOML scene file (docs/ARCHITECTURE.md, Scene keys), mesh files and procedural
//! generators, and the flattened triangle model the BVH is built from.

pub mod camera;
pub mod color;
pub mod data;
pub mod generate;
pub mod gltf;
pub mod mesh;
pub mod obj;
pub mod ply;
pub mod pvcc;
pub mod ray;
pub mod stl;
pub mod stream;
mod strict;
pub mod vtk;

use crate::error::{Error, Result};
pub use camera::{Camera, CameraBasis};
use generate::Generator;
use mesh::Mesh;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The largest image side we accept; beyond it a render is a typo, not a request.
pub const MAX_IMAGE_SIDE: u32 = 16384;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    /// A prepared block file (`dcrt prepare`) instead of meshes.
    model: Option<PathBuf>,
    camera: Option<Camera>,
    image: Option<ImageSpec>,
    #[serde(rename = "mesh", default)]
    meshes: Vec<MeshSpec>,
    render: Option<RenderSpec>,
    #[serde(rename = "light", default)]
    lights: Vec<LightSpec>,
}

/// `[render]`: the shading mode and its settings (the command line overrides them).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderSpec {
    mode: Option<crate::shading::Mode>,
    spp: Option<u32>,
    seed: Option<u32>,
    sampler: Option<crate::shading::Sampler>,
    ao_rays: Option<u32>,
    ao_distance: Option<f32>,
    max_depth: Option<u32>,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    sky: Option<[f32; 3]>,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    sun: Option<[f32; 3]>,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    sun_direction: Option<[f32; 3]>,
    ambient: Option<f32>,
    /// Whether shadows mode adds a key light when the scene has no `[[light]]`.
    default_light: Option<bool>,
}

/// `[[light]]`: `type = "directional"` with `direction` (where the light travels) or
/// `type = "point"` with `position`; `color` (default white) times `intensity` (default 1).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LightSpec {
    #[serde(rename = "type")]
    kind: LightKind,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    direction: Option<[f32; 3]>,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    position: Option<[f32; 3]>,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    color: Option<[f32; 3]>,
    intensity: Option<f32>,
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(rename_all = "lowercase")]
enum LightKind {
    Directional,
    Point,
}

fn shading_of(
    render: Option<RenderSpec>,
    lights: &[LightSpec],
) -> std::result::Result<crate::shading::Shading, String> {
    use crate::shading::{Light, Shading};
    let r = render.unwrap_or_default();
    let d = Shading::default();
    let mut s = Shading {
        mode: r.mode.unwrap_or(d.mode),
        spp: r.spp.unwrap_or(d.spp),
        seed: r.seed.unwrap_or(d.seed),
        sampler: r.sampler.unwrap_or(d.sampler),
        ao_rays: r.ao_rays.unwrap_or(d.ao_rays),
        ao_distance: r.ao_distance.unwrap_or(d.ao_distance),
        max_depth: r.max_depth.unwrap_or(d.max_depth),
        sky: r.sky.unwrap_or(d.sky),
        sun: r.sun.unwrap_or(d.sun),
        sun_dir: r.sun_direction,
        ambient: r.ambient.unwrap_or(d.ambient),
        default_light: r.default_light.unwrap_or(d.default_light),
        ..d
    };
    for (i, l) in lights.iter().enumerate() {
        let at = |m: &str| format!("light {}: {m}", i + 1);
        let k = l.intensity.unwrap_or(1.0);
        let color = l.color.unwrap_or([1.0; 3]).map(|c| c * k);
        let light = match (l.kind, l.direction, l.position) {
            (LightKind::Directional, Some(dir), None) => Light::Directional { dir, color },
            (LightKind::Point, None, Some(pos)) => Light::Point { pos, color },
            (LightKind::Directional, _, _) => {
                return Err(at(
                    "a directional light needs `direction` (and no `position`)",
                ));
            }
            (LightKind::Point, _, _) => {
                return Err(at("a point light needs `position` (and no `direction`)"));
            }
        };
        s.add_light(light).map_err(|e| at(&e.to_string()))?;
    }
    s.validate()
        .map_err(|e| format!("[render]/[[light]]: {e}"))?;
    Ok(s)
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImageSpec {
    width: u32,
    height: u32,
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    background: Option<[f32; 3]>,
}

/// One `[[mesh]]` entry: a file or a generator, with a colour and an optional placement.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// OBJ or PLY file, relative to the scene file.
    pub file: Option<PathBuf>,
    /// Procedural generator name (`rm`, `assembly`).
    pub generator: Option<String>,
    /// Generator target size in triangles.
    pub triangles: Option<u64>,
    pub seed: Option<u64>,
    /// Linear RGB albedo in [0, 1].
    #[serde(default, deserialize_with = "strict::opt_f32x3")]
    pub color: Option<[f32; 3]>,
    /// Applied after `scale`.
    #[serde(default, deserialize_with = "strict::opt_f64x3")]
    pub translate: Option<[f64; 3]>,
    pub scale: Option<f64>,
    /// A data array of the file to colour by (ParaView's "Color By"; `dcrt info FILE` lists
    /// them): point data, or cell data with `cell = true`.
    pub color_by: Option<String>,
    /// The colormap values are mapped through (default `cool-to-warm`).
    pub colormap: Option<crate::colormap::Colormap>,
    /// The values mapped onto the colormap's ends (default: the data range).
    #[serde(default, deserialize_with = "strict::opt_range")]
    pub range: Option<[f32; 2]>,
    /// `color_by` names cell data.
    pub cell: Option<bool>,
}

impl MeshSpec {
    /// What the entry colours by, if anything.
    pub fn color_by(&self) -> Option<color::ColorBy> {
        Some(color::ColorBy {
            array: self.color_by.clone()?,
            cell: self.cell.unwrap_or(false),
            colormap: self.colormap,
            range: self.range,
        })
    }

    /// The data arrays a loader must keep for this entry.
    pub fn keep(&self) -> data::Keep {
        match self.color_by() {
            Some(by) => data::Keep::One {
                assoc: by.assoc(),
                name: by.array,
            },
            None => data::Keep::None,
        }
    }
}

/// A parsed and checked scene file.
#[derive(Clone, Debug)]
pub struct Scene {
    pub path: PathBuf,
    pub camera: Option<Camera>,
    pub width: u32,
    pub height: u32,
    /// Linear RGB of rays that hit nothing.
    pub background: [f32; 3],
    /// Whether `[image]` was given (a prepared model keeps its own size otherwise).
    pub image_given: bool,
    pub meshes: Vec<MeshSpec>,
    /// A prepared block file, relative to the scene file.
    pub model: Option<PathBuf>,
    /// `[render]` and `[[light]]`.
    pub shading: crate::shading::Shading,
}

pub const DEFAULT_COLOR: [f32; 3] = [0.8, 0.8, 0.8];
pub const DEFAULT_BACKGROUND: [f32; 3] = [0.05, 0.05, 0.08];
const DEFAULT_GENERATOR_TRIANGLES: u64 = 100_000;

impl Scene {
    pub fn load(path: &Path) -> Result<Scene> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if matches!(
            ext.as_deref(),
            Some("ply" | "obj" | "stl" | "vtk" | "vtp" | "gltf" | "glb")
        ) {
            return Err(Error::format(
                path,
                None,
                "expected a scene (.toml) or a block file (.dcb); a mesh is named by a [[mesh]] \
                 entry of a scene",
            ));
        }
        let bytes = read_input(path, MAX_SCENE_BYTES, "scene")?;
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            let line = bytes[..e.valid_up_to()]
                .iter()
                .filter(|&&b| b == b'\n')
                .count()
                + 1;
            Error::format(
                path,
                Some(format!("line {line}")),
                "not valid UTF-8 text (is this a scene file?)",
            )
        })?;
        Scene::parse(text, path)
    }

    /// The files a render or prepare of `path` reads: the scene or block file itself, and the
    /// meshes or the block file a scene names. Outputs are checked against them.
    pub fn input_files(path: &Path) -> Result<Vec<PathBuf>> {
        let mut files = vec![path.to_path_buf()];
        if path.extension().is_some_and(|e| e == "dcb") {
            return Ok(files);
        }
        let scene = Scene::load(path)?;
        let dir = path.parent().unwrap_or(Path::new("."));
        files.extend(scene.model.iter().map(|m| dir.join(m)));
        files.extend(
            scene
                .meshes
                .iter()
                .filter_map(|m| m.file.as_ref())
                .map(|f| dir.join(f)),
        );
        Ok(files)
    }

    /// Parses scene text; `path` names the file in errors and anchors relative mesh paths.
    pub fn parse(text: &str, path: &Path) -> Result<Scene> {
        let file: SceneFile = toml::from_str(text)
            .map_err(|e| Error::format(path, None, e.to_string().trim_end().to_string()))?;
        let bad = |msg: String| Error::format(path, None, msg);
        if let Some(c) = &file.camera {
            c.validate().map_err(|e| bad(e.to_string()))?;
        }
        let image_given = file.image.is_some();
        let image = file.image.unwrap_or(ImageSpec {
            width: 512,
            height: 512,
            background: None,
        });
        check_image_size(image.width, image.height).map_err(|e| bad(e.to_string()))?;
        let background = image.background.unwrap_or(DEFAULT_BACKGROUND);
        check_color(background).map_err(|m| bad(format!("image.background: {m}")))?;
        if file
            .model
            .as_ref()
            .is_some_and(|m| m.as_os_str().is_empty())
        {
            return Err(bad("model: the path is empty".into()));
        }
        match (&file.model, file.meshes.is_empty()) {
            (None, true) => return Err(bad("the scene has no [[mesh]] entries".into())),
            (Some(_), false) => {
                return Err(bad(
                    "give either `model` (a prepared .dcb) or [[mesh]] entries, not both".into(),
                ));
            }
            _ => {}
        }
        for (i, m) in file.meshes.iter().enumerate() {
            let at = |m: &str| bad(format!("mesh {}: {m}", i + 1));
            match (&m.file, &m.generator) {
                (Some(_), Some(_)) => {
                    return Err(at("give either `file` or `generator`, not both"));
                }
                (None, None) => return Err(at("needs a `file` or a `generator`")),
                (Some(_), None) if m.triangles.is_some() || m.seed.is_some() => {
                    return Err(at("`triangles` and `seed` are for generators only"));
                }
                (None, Some(g)) => {
                    if Generator::parse(g).is_none() {
                        return Err(at(&format!(
                            "unknown generator '{g}' (known: {})",
                            Generator::NAMES.join(", ")
                        )));
                    }
                    if let Some(t) = m.triangles
                        && !(1..=MAX_GENERATED_TRIANGLES).contains(&t)
                    {
                        return Err(at(&format!(
                            "triangles must be between 1 and {MAX_GENERATED_TRIANGLES}, got {t}"
                        )));
                    }
                }
                _ => {}
            }
            if m.file.as_ref().is_some_and(|f| f.as_os_str().is_empty()) {
                return Err(at("file: the path is empty"));
            }
            if let Some(c) = m.color {
                check_color(c).map_err(|e| at(&format!("color: {e}")))?;
            }
            if let Some(s) = m.scale
                && !(s.is_finite() && s > 0.0)
            {
                return Err(at(&format!("scale must be finite and positive, got {s}")));
            }
            if let Some(t) = m.translate
                && !t.iter().all(|v| v.is_finite())
            {
                return Err(at("translate must be finite"));
            }
            match &m.color_by {
                None if m.colormap.is_some() || m.range.is_some() || m.cell.is_some() => {
                    return Err(at("`colormap`, `range` and `cell` go with `color_by`"));
                }
                Some(_) if m.generator.is_some() => {
                    return Err(at("generated meshes have no data arrays to colour by"));
                }
                Some(name) if name.is_empty() => return Err(at("color_by: the name is empty")),
                _ => {}
            }
        }
        let shading = shading_of(file.render, &file.lights).map_err(bad)?;
        Ok(Scene {
            shading,
            path: path.to_path_buf(),
            camera: file.camera,
            width: image.width,
            height: image.height,
            background,
            image_given,
            meshes: file.meshes,
            model: file.model,
        })
    }

    /// A scene made in code from one generator, with its default view.
    pub fn generated(generator: Generator, triangles: u64, width: u32, height: u32) -> Scene {
        Scene {
            path: PathBuf::from(format!("<{}>", generator.name())),
            camera: None,
            width,
            height,
            background: DEFAULT_BACKGROUND,
            image_given: true,
            model: None,
            shading: crate::shading::Shading::default(),
            meshes: vec![MeshSpec {
                file: None,
                generator: Some(generator.name().into()),
                triangles: Some(triangles),
                seed: None,
                color: None,
                translate: None,
                scale: None,
                color_by: None,
                colormap: None,
                range: None,
                cell: None,
            }],
        }
    }

    /// Why the scene's meshes must be loaded whole (`load_model`) rather than streamed
    /// (`stream`, geometry and one colour per mesh): a mesh coloured by data, or a glTF file,
    /// whose parts bring colours of their own. `None` when streaming loses nothing.
    pub fn needs_whole_meshes(&self) -> Option<String> {
        self.meshes.iter().enumerate().find_map(|(i, spec)| {
            if spec.color_by().is_some() {
                return Some(format!("mesh {} is coloured by data", i + 1));
            }
            let file = spec.file.as_ref()?;
            let ext = Path::new(file).extension()?.to_str()?.to_ascii_lowercase();
            matches!(ext.as_str(), "gltf" | "glb")
                .then(|| format!("mesh {} is a glTF file (its parts' colours)", i + 1))
        })
    }

    /// Loads every mesh and flattens them into one triangle list in primitive-id order, with
    /// the attributes of meshes coloured by data.
    pub fn load_model(&self) -> Result<Model> {
        let dir = self.mesh_dir()?;
        let mut model = Model::default();
        // Per mesh: its mesh-table entries and, when coloured by data, its colouring.
        let mut coloured = Vec::new();
        for spec in &self.meshes {
            let (mesh, data, origin) = if let Some(file) = &spec.file {
                let path = dir.join(file);
                let (mesh, data) = load_mesh_data(&path, &spec.keep())?;
                (mesh, data, path)
            } else {
                let name = spec.generator.as_deref().unwrap_or_default();
                let g = Generator::parse(name)
                    .ok_or_else(|| Error::Invalid(format!("unknown generator '{name}'")))?;
                let mesh = g.generate(
                    spec.triangles.unwrap_or(DEFAULT_GENERATOR_TRIANGLES),
                    spec.seed.unwrap_or(1),
                );
                let origin = PathBuf::from(format!("<generator {name}>"));
                (mesh, data::MeshData::default(), origin)
            };
            mesh.validate(&origin)?;
            if mesh.triangles.is_empty() {
                return Err(Error::format(
                    &origin,
                    None,
                    "the mesh has no triangles (no faces read)",
                ));
            }
            let colours = match spec.color_by() {
                Some(by) => Some(color::resolve(&mesh, &data, &by, &origin)?),
                None => None,
            };
            let entries = model.colors.len();
            model.push(&mesh, spec, &origin, &data.parts)?;
            coloured.push((entries..model.colors.len(), colours));
        }
        if model.triangles.is_empty() {
            return Err(Error::format(
                &self.path,
                None,
                "the scene has no triangles",
            ));
        }
        model.colour(coloured);
        Ok(model)
    }

    /// The directory mesh files are relative to; an error for a scene that names a prepared
    /// model instead of meshes.
    fn mesh_dir(&self) -> Result<&Path> {
        if self.model.is_some() {
            return Err(Error::format(
                &self.path,
                None,
                "names a prepared model; it has no meshes to load",
            ));
        }
        Ok(self.path.parent().unwrap_or(Path::new(".")))
    }

    /// The scene's camera, or a default one: a generator's own view, else a view fitted to the
    /// model's bounds.
    pub fn camera_or_default(&self, model: &Model) -> Camera {
        self.camera_for(model.bounds)
    }

    /// The scene's camera, or a default one for a model of `bounds` (see `camera_or_default`).
    pub fn camera_for(&self, bounds: Bounds) -> Camera {
        if let Some(c) = self.camera {
            return c;
        }
        if let [spec] = self.meshes.as_slice()
            && spec.translate.is_none()
            && spec.scale.is_none()
            && let Some(g) = spec.generator.as_deref().and_then(Generator::parse)
        {
            let v = g.default_view();
            return Camera {
                position: v.position,
                focal_point: v.focal_point,
                view_up: v.view_up,
                view_angle: v.view_angle,
                parallel_scale: None,
            };
        }
        fitted_camera(bounds)
    }
}

/// Generators are bounded so that a typo does not ask for more memory than any node has.
pub const MAX_GENERATED_TRIANGLES: u64 = 1_000_000_000;

pub fn check_image_size(width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(Error::Invalid(format!(
            "image size {width}x{height} is out of range: each side must be 1..={MAX_IMAGE_SIDE}"
        )));
    }
    Ok(())
}

fn check_color(c: [f32; 3]) -> std::result::Result<(), String> {
    if c.iter().all(|v| v.is_finite() && *v >= 0.0) {
        Ok(())
    } else {
        Err(format!(
            "components must be finite and non-negative, got {c:?}"
        ))
    }
}

/// Scene files are small; beyond this one is not a scene (`/dev/zero`, a stray archive).
pub const MAX_SCENE_BYTES: u64 = 64 << 20;

/// Refuses an input that is not a regular file: a FIFO blocks forever, a device never ends, a
/// directory reads as garbage. `what` names the role in the message.
pub fn check_regular(path: &Path, what: &str) -> Result<()> {
    let m = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !m.is_file() {
        return Err(Error::format(
            path,
            None,
            format!(
                "is {}, not a regular file: a {what} must be a file",
                crate::files::kind_of(&m)
            ),
        ));
    }
    Ok(())
}

/// Reads a whole regular file of at most `max` bytes.
fn read_input(path: &Path, max: u64, what: &str) -> Result<Vec<u8>> {
    use std::io::Read;
    check_regular(path, what)?;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::new();
    file.take(max + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > max {
        return Err(Error::format(
            path,
            None,
            format!("larger than {} MiB: not a {what} file", max >> 20),
        ));
    }
    Ok(bytes)
}

/// Loads a mesh file by its extension (`MESH_FORMATS`), geometry only.
pub fn load_mesh_file(path: &Path) -> Result<Mesh> {
    load_mesh_data(path, &data::Keep::None).map(|(mesh, _)| mesh)
}

/// The mesh file extensions dcrt reads, as messages list them.
pub const MESH_FORMATS: &str = ".obj, .ply, .stl, .vtk, .vtp, .gltf, .glb";

/// Loads a mesh file by its extension, with the data arrays it offers and the values of those
/// `keep` asks for.
pub fn load_mesh_data(path: &Path, keep: &data::Keep) -> Result<(Mesh, data::MeshData)> {
    check_regular(path, "mesh")?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let none = data::MeshData::default();
    match ext.as_deref() {
        Some("obj") => Ok((obj::load_obj(path)?, none)),
        Some("ply") => ply::load_ply_data(path, keep),
        Some("stl") => Ok((stl::load_stl(path)?, none)),
        Some("vtk") => vtk::legacy::load_vtk(path, keep),
        Some("vtp") => vtk::xml::load_vtp(path, keep),
        Some("gltf" | "glb") => gltf::load_gltf(path, keep),
        _ => Err(Error::format(
            path,
            None,
            format!("unknown mesh format: the file name must end in one of {MESH_FORMATS}"),
        )),
    }
}

/// Reads a mesh file in pieces: OBJ and PLY as they are read (`obj::stream_obj`,
/// `ply::stream_ply`), keeping at most `max_vertices` vertices; the other formats are read whole
/// (their meshes are held, and refused above `max_vertices` vertices) and handed on at once.
/// Geometry only.
pub fn stream_mesh_file(path: &Path, max_vertices: u64, piece: &mut mesh::Piece) -> Result<()> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => obj::stream_obj(path, max_vertices, piece),
        Some("ply") => ply::stream_ply(path, max_vertices, piece),
        _ => {
            let mesh = load_mesh_file(path)?;
            if mesh.positions.len() as u64 > max_vertices {
                return Err(Error::format(
                    path,
                    None,
                    format!(
                        "{} vertices: more than the {max_vertices} the memory budget holds \
                         (this format is read whole); raise --memory",
                        mesh.positions.len()
                    ),
                ));
            }
            piece(&mesh.positions, &mesh.triangles)
        }
    }
}

/// Axis-aligned bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds {
            min: [f32::INFINITY; 3],
            max: [f32::NEG_INFINITY; 3],
        }
    }
}

impl Bounds {
    /// Length of the box's diagonal (0 when empty).
    pub fn diagonal(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        (0..3)
            .map(|a| (f64::from(self.max[a]) - f64::from(self.min[a])).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    pub fn grow(&mut self, p: [f32; 3]) {
        for (a, v) in p.into_iter().enumerate() {
            self.min[a] = self.min[a].min(v);
            self.max[a] = self.max[a].max(v);
        }
    }
    pub fn union(&mut self, o: &Bounds) {
        self.grow(o.min);
        self.grow(o.max);
    }
    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.min[a] > self.max[a])
    }
}

/// A mesh entry's `scale`, then `translate`, applied to its triangles in f64.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Placement {
    scale: f64,
    translate: [f64; 3],
}

impl Placement {
    pub(crate) fn of(spec: &MeshSpec) -> Placement {
        Placement {
            scale: spec.scale.unwrap_or(1.0),
            translate: spec.translate.unwrap_or([0.0; 3]),
        }
    }

    /// Triangle `i` of the mesh from `origin`, placed; an error if a coordinate is then not
    /// finite.
    pub(crate) fn triangle(
        &self,
        tri: [[f32; 3]; 3],
        origin: &Path,
        i: u64,
    ) -> Result<[[f32; 3]; 3]> {
        let (s, t) = (self.scale, self.translate);
        let tri = tri.map(|p| std::array::from_fn(|a| (f64::from(p[a]) * s + t[a]) as f32));
        if !tri.iter().flatten().all(|c| c.is_finite()) {
            return Err(Error::format(
                origin,
                Some(format!("triangle {i}")),
                "a coordinate is not finite after scale and translate",
            ));
        }
        Ok(tri)
    }
}

/// All triangles of a scene, unshared, in primitive-id order (meshes in scene order, faces in file
/// order), with the mesh table (each entry's first primitive id, colour and look: a mesh, or a
/// part of a file with its own colour) and, when a mesh is coloured by data, every triangle's
/// attribute words.
#[derive(Clone, Debug, Default)]
pub struct Model {
    pub triangles: Vec<[[f32; 3]; 3]>,
    pub mesh_first: Vec<u32>,
    pub colors: Vec<[f32; 3]>,
    /// One per mesh-table entry; empty means all constant.
    pub looks: Vec<color::Look>,
    pub attributes: Option<color::Attributes>,
    pub bounds: Bounds,
}

impl Model {
    /// Sets the looks and attributes from each mesh's colouring (its mesh-table entries and
    /// colouring, mesh by mesh): ranges settled, three words per triangle when any mesh uses
    /// point data, else one; no attributes when no mesh is coloured by data.
    fn colour(&mut self, meshes: Vec<(std::ops::Range<usize>, Option<color::MeshColors>)>) {
        self.looks = vec![color::Look::Constant; self.colors.len()];
        if meshes.iter().all(|(_, c)| c.is_none()) {
            return;
        }
        let mut pending: Vec<(color::Look, Option<(f32, f32)>)> = meshes
            .iter()
            .map(|(_, c)| match c {
                Some(c) => (c.look.clone(), c.data_range),
                None => (color::Look::Constant, None),
            })
            .collect();
        color::settle_ranges(&mut pending);
        let words = if pending.iter().any(|(l, _)| l.per_corner()) {
            3
        } else {
            1
        };
        let mut data = Vec::with_capacity(self.triangles.len() * words);
        for ((entries, colours), (look, _)) in meshes.into_iter().zip(pending) {
            for l in &mut self.looks[entries.clone()] {
                *l = look.clone();
            }
            match colours {
                Some(c) => c
                    .words
                    .iter()
                    .for_each(|w| data.extend_from_slice(&w[..words])),
                None => {
                    let first = self.mesh_first[entries.start] as usize;
                    let end = self
                        .mesh_first
                        .get(entries.end)
                        .map_or(self.triangles.len(), |&f| f as usize);
                    data.resize(data.len() + (end - first) * words, 0);
                }
            }
        }
        self.attributes = Some(color::Attributes {
            words: words as u32,
            data,
        });
    }

    fn push(
        &mut self,
        mesh: &Mesh,
        spec: &MeshSpec,
        origin: &Path,
        parts: &[data::Part],
    ) -> Result<()> {
        let total = self.triangles.len() as u64 + mesh.triangles.len() as u64;
        if total >= u64::from(u32::MAX) {
            return Err(Error::format(
                origin,
                None,
                "the scene has more than 2^32-1 triangles",
            ));
        }
        let place = Placement::of(spec);
        // The file's parts (with their own colours) are entries of their own unless the scene
        // gives the mesh a colour.
        let first = self.triangles.len() as u32;
        match (spec.color, parts) {
            (None, [p0, ..]) if p0.first == 0 => {
                for p in parts {
                    self.mesh_first.push(first + p.first);
                    self.colors.push(p.color);
                }
            }
            _ => {
                self.mesh_first.push(first);
                self.colors.push(spec.color.unwrap_or(DEFAULT_COLOR));
            }
        }
        self.triangles.reserve(mesh.triangles.len());
        for i in 0..mesh.triangles.len() {
            let tri = place.triangle(mesh.corners(i), origin, i as u64)?;
            for p in &tri {
                self.bounds.grow(*p);
            }
            self.triangles.push(tri);
        }
        Ok(())
    }

    /// The mesh a primitive belongs to.
    pub fn mesh_of(&self, prim: u32) -> usize {
        self.mesh_first.partition_point(|&f| f <= prim) - 1
    }

    /// A model from a bare triangle list, one mesh, default colour (tests and benchmarks).
    pub fn from_triangles(triangles: Vec<[[f32; 3]; 3]>) -> Model {
        let mut bounds = Bounds::default();
        triangles.iter().flatten().for_each(|p| bounds.grow(*p));
        Model {
            triangles,
            mesh_first: vec![0],
            colors: vec![DEFAULT_COLOR],
            bounds,
            ..Model::default()
        }
    }
}

/// A three-quarter view from the front, above, that frames the bounds.
pub fn fitted_camera(b: Bounds) -> Camera {
    let c: [f64; 3] = std::array::from_fn(|a| (f64::from(b.min[a]) + f64::from(b.max[a])) / 2.0);
    let r = (0..3)
        .map(|a| f64::from(b.max[a]) - f64::from(b.min[a]))
        .map(|e| e * e)
        .sum::<f64>()
        .sqrt()
        .max(1e-6)
        / 2.0;
    let view_angle: f64 = 40.0;
    let dist = r / (view_angle.to_radians() / 2.0).sin();
    let dir = glam::DVec3::new(0.45, -1.0, 0.6).normalize() * dist;
    Camera {
        position: [c[0] + dir.x, c[1] + dir.y, c[2] + dir.z],
        focal_point: c,
        view_up: [0.0, 0.0, 1.0],
        view_angle,
        parallel_scale: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Scene> {
        Scene::parse(text, Path::new("test.toml"))
    }

    #[test]
    fn minimal_scene() {
        let s = parse("[[mesh]]\ngenerator = \"rm\"\ntriangles = 1000\n").unwrap();
        assert_eq!((s.width, s.height), (512, 512));
        assert_eq!(s.meshes.len(), 1);
    }

    #[test]
    fn errors_name_the_file_and_problem() {
        let cases = [
            (
                "[image]\nwidth = 0\nheight = 10\n[[mesh]]\ngenerator=\"rm\"",
                "out of range",
            ),
            (
                "[image]\nwidth = 100000\nheight = 10\n[[mesh]]\ngenerator=\"rm\"",
                "out of range",
            ),
            ("[image]\nwidth = -4\nheight = 10\n", "width"),
            ("[image]\nwidth = \"wide\"\nheight = 10\n", "width"),
            ("[[mesh]]\ngenerator = \"rm\"\nshiny = true\n", "shiny"),
            ("[cam]\nx = 1\n", "cam"),
            ("[[mesh]]\ngenerator = \"teapot\"\n", "unknown generator"),
            ("[[mesh]]\ncolor = [1, 0, 0]\n", "needs a `file`"),
            ("", "no [[mesh]]"),
            (
                "[camera]\nposition=[0,0,0]\nfocal_point=[0,0,0]\nview_up=[0,0,1]\nview_angle=30\n[[mesh]]\ngenerator=\"rm\"",
                "same point",
            ),
            (
                "[[mesh]]\ngenerator = \"rm\"\ncolor = [1, -1, 0]\n",
                "color",
            ),
            ("[[mesh]]\ngenerator = \"rm\"\ntriangles = 0\n", "triangles"),
        ];
        for (text, want) in cases {
            let e = parse(text).expect_err(text).to_string();
            assert!(e.contains("test.toml"), "{e}");
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn toml_errors_carry_the_line() {
        let e = parse("[[mesh]]\ngenerator = \"rm\"\ntriangles = [\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line"), "{e}");
    }

    #[test]
    fn mesh_of_finds_ranges() {
        let m = Model {
            mesh_first: vec![0, 5, 5, 9],
            ..Model::default()
        };
        assert_eq!(m.mesh_of(0), 0);
        assert_eq!(m.mesh_of(4), 0);
        assert_eq!(m.mesh_of(5), 2);
        assert_eq!(m.mesh_of(100), 3);
    }
}
