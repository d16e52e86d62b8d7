//! glTF 2.0 loading (`.gltf` with external or embedded buffers, and binary `.glb`): the
//! triangles of the default scene's meshes, each placed by its node's world transform, with the
//! base colour of each primitive's material as a part colour, and every vertex attribute but
//! `POSITION` as a point array (`COLOR_0` as linear colours, multiplied by the base colour as
//! glTF defines it; `_NAME` application attributes as values to colour by).
//!
//! The `gltf` crate parses and validates the JSON and the GLB container (its errors give the JSON
//! path of what is wrong); accessors are read here, every byte range checked first, so that a
//! damaged file is an error naming the mesh, primitive and accessor rather than a panic. Not
//! read: textures (a base colour texture is ignored), morph targets and skins (the rest pose is
//! drawn), cameras and lights, and compressed geometry (Draco, meshopt: refused by the crate as
//! unsupported required extensions). Points and lines are skipped.

use crate::error::{Error, Result};
use crate::scene::data::{ArrayInfo, Assoc, Encoding, Keep, MeshData, Part, Values};
use crate::scene::mesh::Mesh;
use base64::Engine;
use gltf::Semantic;
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use std::path::Path;

/// Reads the glTF or GLB file at `path`.
pub fn load_gltf(path: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_gltf(&bytes, path, keep)
}

/// Parses glTF or GLB bytes; `origin` names the file in errors and anchors relative buffer URIs.
pub fn parse_gltf(bytes: &[u8], origin: &Path, keep: &Keep) -> Result<(Mesh, MeshData)> {
    check_position_accessors(bytes, origin)?;
    let doc = gltf::Gltf::from_slice(bytes).map_err(|e| {
        let msg = match e {
            gltf::Error::Validation(list) => {
                let items: Vec<String> = list
                    .iter()
                    .take(8)
                    .map(|(path, err)| format!("{path}: {err}"))
                    .collect();
                format!("invalid glTF: {}", items.join("; "))
            }
            e => format!("not a glTF 2.0 file: {e}"),
        };
        Error::format(origin, None, msg)
    })?;
    let buffers = load_buffers(&doc, origin)?;
    let mut r = Reader {
        doc: &doc,
        buffers: &buffers,
        origin,
        keep,
        out: (Mesh::default(), MeshData::default()),
        names: Vec::new(),
        partial: Vec::new(),
    };
    r.list_arrays();
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        // Without scenes, every node that is nobody's child.
        None => {
            let mut child = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    child[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !child[n.index()]).collect()
        }
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut stack: Vec<(gltf::Node, glam::DMat4)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, glam::DMat4::IDENTITY))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(Error::format(
                origin,
                Some(format!("node {}", node.index())),
                "appears twice in the scene's hierarchy (glTF nodes form trees)",
            ));
        }
        let m = node.transform().matrix();
        let local = glam::DMat4::from_cols_array_2d(&m.map(|c| c.map(f64::from)));
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            r.mesh(&mesh, &world, node.index())?;
        }
        for c in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push((c, world));
        }
    }
    Ok(r.out)
}

/// gltf-json 1.4's validation reads the accessor of every primitive's POSITION without checking
/// that it exists (a panic on a damaged file): those indices are checked here first. Anything
/// else wrong is left to the crate's validation.
fn check_position_accessors(bytes: &[u8], origin: &Path) -> Result<()> {
    let json = match gltf::Glb::from_slice(bytes) {
        Ok(glb) => glb.json.into_owned(),
        Err(_) => bytes.to_vec(),
    };
    // Lossy: the crate skips the strings it ignores without checking their UTF-8, so a file
    // with a damaged name must still be checked.
    let Ok(j) = serde_json::from_str::<serde_json::Value>(&String::from_utf8_lossy(&json)) else {
        return Ok(());
    };
    let accessors = j["accessors"].as_array().map_or(0, Vec::len) as u64;
    for (m, mesh) in j["meshes"].as_array().into_iter().flatten().enumerate() {
        for (p, prim) in mesh["primitives"]
            .as_array()
            .into_iter()
            .flatten()
            .enumerate()
        {
            let pos = &prim["attributes"]["POSITION"];
            if !pos.is_null() && pos.as_u64().is_none_or(|i| i >= accessors) {
                return Err(Error::format(
                    origin,
                    Some(format!("mesh {m} primitive {p}")),
                    format!("POSITION names accessor {pos}, the file has {accessors}"),
                ));
            }
        }
    }
    Ok(())
}

/// Each buffer's bytes: the GLB's binary chunk, a `data:` URI, or a file beside the glTF.
fn load_buffers(doc: &gltf::Gltf, origin: &Path) -> Result<Vec<Vec<u8>>> {
    let mut out = Vec::new();
    for b in doc.buffers() {
        let at = || Some(format!("buffer {}", b.index()));
        let data = match b.source() {
            gltf::buffer::Source::Bin => doc.blob.clone().ok_or_else(|| {
                Error::format(
                    origin,
                    at(),
                    "refers to a GLB binary chunk the file does not have",
                )
            })?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                let (_, payload) = uri
                    .split_once(";base64,")
                    .ok_or_else(|| Error::format(origin, at(), "a data URI that is not base64"))?;
                base64::engine::general_purpose::STANDARD
                    .decode(payload)
                    .map_err(|e| {
                        Error::format(origin, at(), format!("damaged base64 data URI: {e}"))
                    })?
            }
            gltf::buffer::Source::Uri(uri) => {
                if uri.contains("://") {
                    return Err(Error::format(
                        origin,
                        at(),
                        format!("'{uri}' is not a local file"),
                    ));
                }
                let path = origin.parent().unwrap_or(Path::new(".")).join(uri);
                std::fs::read(&path)
                    .map_err(|e| Error::format(origin, at(), format!("{}: {e}", path.display())))?
            }
        };
        if data.len() < b.length() {
            return Err(Error::format(
                origin,
                at(),
                format!(
                    "holds {} bytes, its byteLength is {}",
                    data.len(),
                    b.length()
                ),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

/// The glTF name of an attribute.
fn semantic_name(s: &Semantic) -> String {
    match s {
        Semantic::Extras(n) => format!("_{n}"),
        Semantic::Positions => "POSITION".into(),
        Semantic::Normals => "NORMAL".into(),
        Semantic::Tangents => "TANGENT".into(),
        Semantic::Colors(k) => format!("COLOR_{k}"),
        Semantic::TexCoords(k) => format!("TEXCOORD_{k}"),
        Semantic::Joints(k) => format!("JOINTS_{k}"),
        Semantic::Weights(k) => format!("WEIGHTS_{k}"),
    }
}

fn type_name(t: DataType) -> &'static str {
    match t {
        DataType::I8 => "int8",
        DataType::U8 => "uint8",
        DataType::I16 => "int16",
        DataType::U16 => "uint16",
        DataType::U32 => "uint32",
        DataType::F32 => "float32",
    }
}

/// Most elements an accessor without a buffer view (all zeros but its sparse values) may have.
const MAX_ZERO_ELEMENTS: usize = 1 << 24;

struct Reader<'a> {
    doc: &'a gltf::Gltf,
    buffers: &'a [Vec<u8>],
    origin: &'a Path,
    keep: &'a Keep,
    out: (Mesh, MeshData),
    /// Array names by index into `out.1.arrays`.
    names: Vec<String>,
    /// Arrays found missing from some primitive: listed, but not kept for `Keep::All`.
    partial: Vec<bool>,
}

/// The primitives dcrt draws.
fn drawn(p: &gltf::Primitive) -> bool {
    matches!(
        p.mode(),
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    )
}

impl Reader<'_> {
    /// Lists every vertex attribute of the drawn primitives (but POSITION) as a point array.
    fn list_arrays(&mut self) {
        for m in self.doc.meshes() {
            for p in m.primitives().filter(drawn) {
                for (s, a) in p.attributes() {
                    let name = semantic_name(&s);
                    if s == Semantic::Positions || self.names.contains(&name) {
                        continue;
                    }
                    let color = matches!(s, Semantic::Colors(0)).then_some(Encoding::Linear);
                    self.out.1.offer(ArrayInfo {
                        name: name.clone(),
                        assoc: Assoc::Point,
                        components: a.dimensions().multiplicity(),
                        ty: type_name(a.data_type()).into(),
                        color,
                    });
                    self.names.push(name);
                    self.partial.push(false);
                }
            }
        }
    }

    fn mesh(&mut self, mesh: &gltf::Mesh, world: &glam::DMat4, node: usize) -> Result<()> {
        for p in mesh.primitives().filter(drawn) {
            let at = format!(
                "mesh {} primitive {} (node {node})",
                mesh.index(),
                p.index()
            );
            let origin = self.origin;
            let fail = |m: String| Error::format(origin, Some(at.clone()), m);
            let pos = p
                .get(&Semantic::Positions)
                .ok_or_else(|| fail("has no POSITION attribute".into()))?;
            let positions = self
                .read(&pos, 3)
                .map_err(|m| fail(format!("POSITION: {m}")))?;
            let base = self.out.0.positions.len() as u64;
            let n = positions.len() as u64 / 3;
            if base + n > u64::from(u32::MAX) {
                return Err(fail("more than 2^32-1 vertices".into()));
            }
            for (v, c) in positions.chunks_exact(3).enumerate() {
                let q = world.transform_point3(glam::DVec3::new(c[0], c[1], c[2]));
                let q = [q.x as f32, q.y as f32, q.z as f32];
                if !q.iter().all(|x| x.is_finite()) {
                    return Err(fail(format!(
                        "vertex {v}: position is not finite once placed: {q:?}"
                    )));
                }
                self.out.0.positions.push(q);
            }
            let indices: Vec<u64> = match p.indices() {
                Some(a) if a.data_type() == DataType::F32 || a.normalized() => {
                    return Err(fail(format!(
                        "indices must be unsigned integers (accessor {} is not)",
                        a.index()
                    )));
                }
                Some(a) => self
                    .read(&a, 1)
                    .map_err(|m| fail(format!("indices: {m}")))?
                    .into_iter()
                    .map(|i| i as u64)
                    .collect(),
                None => (0..n).collect(),
            };
            if let Some((k, &i)) = indices.iter().enumerate().find(|(_, i)| **i >= n) {
                return Err(fail(format!(
                    "index {k}: vertex {i} out of range ({n} vertices)"
                )));
            }
            let first = self.out.0.triangles.len() as u32;
            let g = |i: u64| (base + i) as u32;
            let tris = &mut self.out.0.triangles;
            match p.mode() {
                Mode::Triangles => {
                    if !indices.len().is_multiple_of(3) {
                        return Err(fail(format!(
                            "{} indices are not whole triangles",
                            indices.len()
                        )));
                    }
                    tris.extend(indices.chunks_exact(3).map(|t| [g(t[0]), g(t[1]), g(t[2])]));
                }
                // As the glTF specification orders them.
                Mode::TriangleStrip => {
                    for i in 0..indices.len().saturating_sub(2) {
                        let (a, b, c) =
                            (indices[i], indices[i + 1 + i % 2], indices[i + 2 - i % 2]);
                        tris.push([g(a), g(b), g(c)]);
                    }
                }
                _ => {
                    for i in 1..indices.len().saturating_sub(1) {
                        tris.push([g(indices[i]), g(indices[i + 1]), g(indices[0])]);
                    }
                }
            }
            if tris.len() as u64 >= u64::from(u32::MAX) {
                return Err(fail("more than 2^32-1 triangles".into()));
            }
            let c = p.material().pbr_metallic_roughness().base_color_factor();
            let color = [c[0], c[1], c[2]];
            if !color.iter().all(|x| x.is_finite() && *x >= 0.0) {
                return Err(fail(format!("material base colour {c:?} is not a colour")));
            }
            let parts = &mut self.out.1.parts;
            if parts.last().is_none_or(|l| l.color != color) && tris.len() as u32 > first {
                parts.push(Part { first, color });
            }
            self.arrays(&p, n, color).map_err(fail)?;
        }
        Ok(())
    }

    /// Appends this primitive's values of every kept array.
    fn arrays(
        &mut self,
        p: &gltf::Primitive,
        n: u64,
        tint: [f32; 3],
    ) -> std::result::Result<(), String> {
        for i in 0..self.names.len() {
            let name = self.names[i].clone();
            if !self.keep.wants(&name, Assoc::Point) {
                continue;
            }
            let info = self.out.1.arrays[i].clone();
            if self.partial[i] {
                continue;
            }
            let Some(a) = p
                .attributes()
                .find(|(s, _)| semantic_name(s) == name)
                .map(|(_, a)| a)
            else {
                // Listing everything, an array not on every primitive is only listed.
                if *self.keep == Keep::All {
                    self.partial[i] = true;
                    self.out.1.kept.retain(|(k, _)| *k != i);
                    continue;
                }
                return Err(format!(
                    "has no attribute {name}, which other primitives have"
                ));
            };
            let comps = a.dimensions().multiplicity();
            if comps != info.components {
                return Err(format!(
                    "{name} has {comps} components, elsewhere {}",
                    info.components
                ));
            }
            let mut v = self.read(&a, comps).map_err(|m| format!("{name}: {m}"))?;
            if v.len() as u64 != n * comps as u64 {
                return Err(format!(
                    "{name} has {} values for {n} vertices",
                    v.len() / comps
                ));
            }
            if info.color.is_some() {
                for t in v.chunks_exact_mut(comps) {
                    for k in 0..3.min(comps) {
                        t[k] *= f64::from(tint[k]);
                    }
                }
            }
            let kept = &mut self.out.1.kept;
            let values = match kept.iter_mut().find(|(k, _)| *k == i) {
                Some((_, v)) => v,
                None => {
                    kept.push((i, Values::new(comps)));
                    &mut kept.last_mut().expect("just pushed").1
                }
            };
            values.data.extend(v.into_iter().map(|x| x as f32));
        }
        Ok(())
    }

    /// An accessor's values as f64, `comps` per element (normalized integers scaled to [0, 1]
    /// or [-1, 1]), sparse substitutions applied; every byte range checked first.
    fn read(&self, a: &gltf::Accessor, comps: usize) -> std::result::Result<Vec<f64>, String> {
        let at = format!("accessor {}", a.index());
        let dims = a.dimensions();
        if matches!(dims, Dimensions::Mat2 | Dimensions::Mat3 | Dimensions::Mat4) {
            return Err(format!("{at} holds matrices"));
        }
        let got = dims.multiplicity();
        if got != comps {
            return Err(format!("{at} has {got} components, {comps} expected"));
        }
        let t = a.data_type();
        let size = t.size();
        let count = a.count();
        let norm = a.normalized();
        let decode = |b: &[u8]| -> f64 {
            let v = match t {
                DataType::I8 => f64::from(b[0] as i8),
                DataType::U8 => f64::from(b[0]),
                DataType::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                DataType::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                DataType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                DataType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            };
            if !norm {
                return v;
            }
            match t {
                DataType::I8 => (v / 127.0).max(-1.0),
                DataType::U8 => v / 255.0,
                DataType::I16 => (v / 32767.0).max(-1.0),
                DataType::U16 => v / 65535.0,
                DataType::U32 => v / 4294967295.0,
                DataType::F32 => v,
            }
        };
        let elem = size * got;
        // Checked before anything is allocated: the count is the file's word.
        let view = match a.view() {
            Some(view) => {
                let stride = view.stride().unwrap_or(elem);
                let data = self.view_bytes(&view)?;
                let start = a.offset();
                if stride < elem {
                    return Err(format!(
                        "{at}: byteStride {stride} is below its element size {elem}"
                    ));
                }
                let end = count
                    .checked_sub(1)
                    .and_then(|c| c.checked_mul(stride))
                    .and_then(|x| x.checked_add(start))
                    .and_then(|x| x.checked_add(elem));
                match end {
                    Some(e) if e <= data.len() => {}
                    _ => {
                        return Err(format!(
                            "{at}: {count} elements from byte {start} run past its buffer view ({} bytes)",
                            data.len()
                        ));
                    }
                }
                Some((data, start, stride))
            }
            // Zeros (and sparse values): nothing in the file bounds the count.
            None if count > MAX_ZERO_ELEMENTS => {
                return Err(format!(
                    "{at}: {count} elements without a buffer view (at most {MAX_ZERO_ELEMENTS})"
                ));
            }
            None => None,
        };
        let mut out = vec![0f64; count * comps];
        let mut fill = |k: usize, b: &[u8]| {
            for c in 0..comps {
                out[k * comps + c] = decode(&b[c * size..]);
            }
        };
        if let Some((data, start, stride)) = view {
            for k in 0..count {
                fill(k, &data[start + k * stride..]);
            }
        }
        if let Some(sp) = a.sparse() {
            let n = sp.count();
            let (iv, vv) = (sp.indices(), sp.values());
            let isz = iv.index_type().size();
            let idata = self.view_bytes(&iv.view())?;
            let vdata = self.view_bytes(&vv.view())?;
            let fits = |d: &[u8], off: usize, each: usize| {
                n.checked_mul(each)
                    .and_then(|x| x.checked_add(off))
                    .is_some_and(|e| e <= d.len())
            };
            if !fits(idata, iv.offset(), isz) || !fits(vdata, vv.offset(), elem) {
                return Err(format!("{at}: its sparse data runs past its buffer views"));
            }
            for s in 0..n {
                let b = &idata[iv.offset() + s * isz..];
                let k = match isz {
                    1 => usize::from(b[0]),
                    2 => usize::from(u16::from_le_bytes([b[0], b[1]])),
                    _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
                };
                if k >= count {
                    return Err(format!(
                        "{at}: sparse index {k} is past its {count} elements"
                    ));
                }
                fill(k, &vdata[vv.offset() + s * elem..]);
            }
        }
        Ok(out)
    }

    /// A buffer view's bytes, checked against its buffer.
    fn view_bytes(&self, v: &gltf::buffer::View) -> std::result::Result<&[u8], String> {
        let buf = &self.buffers[v.buffer().index()];
        v.offset()
            .checked_add(v.length())
            .filter(|&e| e <= buf.len().min(v.buffer().length()))
            .map(|e| &buf[v.offset()..e])
            .ok_or_else(|| {
                format!(
                    "buffer view {} ({} bytes from byte {}) runs past buffer {} ({} bytes)",
                    v.index(),
                    v.length(),
                    v.offset(),
                    v.buffer().index(),
                    v.buffer().length()
                )
            })
    }
}

/// A GLB file of a JSON chunk and a binary chunk, each padded to 4 bytes (the glTF 2.0 binary
/// container, as the loader reads it; the fuzzer and the tests make GLB files with it).
pub fn glb_container(mut json: Vec<u8>, mut bin: Vec<u8>) -> Vec<u8> {
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut out = Vec::with_capacity(28 + json.len() + bin.len());
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A glTF file built in code: two triangles (a quad) in one primitive and one triangle in
    /// another, each with its material; a `_PRESSURE` attribute and `COLOR_0`. `patch` edits the
    /// JSON before it is written.
    pub fn quad_gltf(patch: &dyn Fn(&mut serde_json::Value)) -> Vec<u8> {
        let mut bin = Vec::new();
        let f32s = |bin: &mut Vec<u8>, v: &[f32]| {
            v.iter()
                .for_each(|x| bin.extend_from_slice(&x.to_le_bytes()))
        };
        // Primitive 0: 4 vertices, 6 u16 indices; primitive 1: 3 vertices, no indices.
        f32s(&mut bin, &[0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.]); // 0: 48 bytes
        for i in [0u16, 1, 2, 0, 2, 3] {
            bin.extend_from_slice(&i.to_le_bytes()); // 48: 12 bytes
        }
        f32s(&mut bin, &[10., 20., 30., 40.]); // 60: pressure, 16 bytes
        bin.extend_from_slice(&[
            255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 255,
        ]); // 76: COLOR_0 u8 normalized VEC4
        f32s(&mut bin, &[2., 0., 0., 3., 0., 0., 2., 1., 0.]); // 92: 36 bytes
        f32s(&mut bin, &[50., 60., 70.]); // 128: 12 bytes
        bin.extend_from_slice(&[255, 0, 0, 255, 255, 0, 0, 255, 255, 0, 0, 255]); // 140
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        );
        let view =
            |o: usize, l: usize| serde_json::json!({"buffer": 0, "byteOffset": o, "byteLength": l});
        let acc = |v: usize, ty: &str, ct: u32, n: usize, norm: bool| {
            let mut a =
                serde_json::json!({"bufferView": v, "type": ty, "componentType": ct, "count": n});
            if norm {
                a["normalized"] = true.into();
            }
            a
        };
        let mut j = serde_json::json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "translation": [0.0, 0.0, 5.0], "children": [1]},
                      {"mesh": 1, "scale": [1.0, 2.0, 1.0]}],
            "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0]}},
                          {"pbrMetallicRoughness": {"baseColorFactor": [1.0, 0.2, 0.1, 1.0]}}],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": 0, "_PRESSURE": 2, "COLOR_0": 3}, "indices": 1, "material": 0}]},
                {"primitives": [{"attributes": {"POSITION": 4, "_PRESSURE": 5, "COLOR_0": 6}, "material": 1}]}
            ],
            "buffers": [{"byteLength": bin.len(), "uri": uri}],
            "bufferViews": [view(0, 48), view(48, 12), view(60, 16), view(76, 16), view(92, 36), view(128, 12), view(140, 12)],
            "accessors": [
                acc(0, "VEC3", 5126, 4, false), acc(1, "SCALAR", 5123, 6, false), acc(2, "SCALAR", 5126, 4, false),
                acc(3, "VEC4", 5121, 4, true), acc(4, "VEC3", 5126, 3, false), acc(5, "SCALAR", 5126, 3, false),
                acc(6, "VEC4", 5121, 3, true)
            ]
        });
        // The validator wants min and max on POSITION accessors.
        for k in [0, 4] {
            j["accessors"][k]["min"] = serde_json::json!([0.0, 0.0, 0.0]);
            j["accessors"][k]["max"] = serde_json::json!([3.0, 1.0, 0.0]);
        }
        patch(&mut j);
        serde_json::to_vec(&j).unwrap()
    }

    pub fn parse(bytes: &[u8]) -> Result<(Mesh, MeshData)> {
        parse_gltf(bytes, Path::new("t.gltf"), &Keep::All)
    }

    fn assert_err(bytes: &[u8], place: &str, what: &str) {
        let e = parse(bytes).expect_err(what).to_string();
        assert!(
            e.contains("t.gltf") && e.contains(place) && e.contains(what),
            "{e}"
        );
    }

    /// The same file as GLB: the JSON chunk, then the buffer as the binary chunk.
    pub fn glb_of(gltf: &[u8]) -> Vec<u8> {
        let mut j: serde_json::Value = serde_json::from_slice(gltf).unwrap();
        let uri = j["buffers"][0]["uri"].as_str().unwrap().to_string();
        let bin = base64::engine::general_purpose::STANDARD
            .decode(uri.split_once(";base64,").unwrap().1)
            .unwrap();
        j["buffers"][0].as_object_mut().unwrap().remove("uri");
        glb_container(serde_json::to_vec(&j).unwrap(), bin)
    }

    #[test]
    fn meshes_nodes_colours_and_attributes() {
        let gltf = quad_gltf(&|_| {});
        for bytes in [gltf.clone(), glb_of(&gltf)] {
            let (m, d) = parse(&bytes).unwrap();
            assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [4, 5, 6]]);
            // Node 0 moves by z = 5; its child scales y by 2 as well.
            assert_eq!(m.positions[2], [1.0, 1.0, 5.0]);
            assert_eq!(m.positions[6], [2.0, 2.0, 5.0]);
            assert_eq!(
                d.parts,
                vec![
                    Part {
                        first: 0,
                        color: [0.5, 0.5, 0.5]
                    },
                    Part {
                        first: 2,
                        color: [1.0, 0.2, 0.1]
                    }
                ]
            );
            let names: Vec<String> = d.arrays.iter().map(|a| a.to_string()).collect();
            assert_eq!(
                names,
                [
                    "_PRESSURE (point data, 1 x float32)",
                    "COLOR_0 (point data, 4 x uint8, colours)"
                ]
            );
            assert_eq!(
                d.values(0).unwrap().data,
                vec![10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0]
            );
            // COLOR_0 times the base colour: vertex 4 is red times (1, 0.2, 0.1).
            let c = &d.values(1).unwrap().data;
            assert_eq!(c[..4], [0.5, 0.0, 0.0, 1.0]);
            assert_eq!(c[16..20], [1.0, 0.0, 0.0, 1.0]);
        }
    }

    #[test]
    fn damaged_files_name_what_is_wrong() {
        let with = |f: &dyn Fn(&mut serde_json::Value)| quad_gltf(f);
        assert_err(b"{not json", "", "not a glTF 2.0 file");
        assert_err(b"glTF\x02\x00\x00\x00garbage", "", "not a glTF 2.0 file");
        assert_err(
            &with(&|j| j["accessors"][1]["count"] = 7.into()),
            "mesh 0 primitive 0",
            "indices: accessor 1: 7 elements from byte 0 run past",
        );
        assert_err(
            &with(&|j| j["meshes"][0]["primitives"][0]["indices"] = 2.into()),
            "mesh 0 primitive 0",
            "indices must be unsigned integers",
        );
        assert_err(
            &with(&|j| j["bufferViews"][2]["byteLength"] = 400.into()),
            "mesh 0 primitive 0",
            "buffer view 2 (400 bytes from byte 60) runs past buffer 0",
        );
        assert_err(
            &with(&|j| j["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 9.into()),
            "mesh 0 primitive 0",
            "POSITION names accessor 9, the file has 7",
        );
        assert_err(
            &with(&|j| j["nodes"][1]["children"] = serde_json::json!([0])),
            "node 0",
            "appears twice",
        );
        assert_err(
            &with(&|j| j["nodes"][0]["scale"] = serde_json::json!([3e38, 1.0, 1.0])),
            "mesh 1 primitive 0 (node 1)",
            "vertex 0: position is not finite once placed",
        );
        assert_err(
            &with(&|j| j["buffers"][0]["uri"] = "missing.bin".into()),
            "missing.bin",
            "No such file",
        );
        assert_err(
            &with(&|j| j["extensionsRequired"] = serde_json::json!(["KHR_draco_mesh_compression"])),
            "",
            "extensionsRequired",
        );
        let no_pressure = with(&|j| {
            j["meshes"][1]["primitives"][0]["attributes"]
                .as_object_mut()
                .unwrap()
                .remove("_PRESSURE");
        });
        let pressure = Keep::One {
            name: "_PRESSURE".into(),
            assoc: Assoc::Point,
        };
        let e = parse_gltf(&no_pressure, Path::new("t.gltf"), &pressure)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("mesh 1 primitive 0") && e.contains("has no attribute _PRESSURE"),
            "{e}"
        );
        // Listing everything, it is listed and not kept.
        let (_, d) = parse(&no_pressure).unwrap();
        assert_eq!((d.arrays.len(), d.kept.len()), (2, 1));
        // Only asked for arrays are required everywhere.
        let keep = Keep::One {
            name: "COLOR_0".into(),
            assoc: Assoc::Point,
        };
        assert!(parse_gltf(&no_pressure, Path::new("t.gltf"), &keep).is_ok());
    }

    /// Found by `dcrt bench fuzz`: a huge accessor count allocated its values before
    /// its bytes were checked (an abort for want of 96 GiB), and an ignored key with invalid
    /// UTF-8 hid a POSITION index from the check before gltf-json's validation (a panic).
    #[test]
    fn fuzzing_findings_are_errors() {
        let huge = |view: bool| {
            quad_gltf(&|j| {
                j["accessors"][2]["count"] = 4294967295u32.into();
                if !view {
                    // Zeros but for sparse values: no buffer view bounds the count.
                    j["accessors"][2]
                        .as_object_mut()
                        .unwrap()
                        .remove("bufferView");
                    j["accessors"][2]["sparse"] = serde_json::json!({"count": 1,
                        "indices": {"bufferView": 1, "componentType": 5123},
                        "values": {"bufferView": 2}});
                }
            })
        };
        assert_err(
            &huge(true),
            "mesh 0 primitive 0",
            "accessor 2: 4294967295 elements from byte 0 run past its buffer view (16 bytes)",
        );
        assert_err(
            &huge(false),
            "mesh 0 primitive 0",
            "accessor 2: 4294967295 elements without a buffer view (at most 16777216)",
        );
        let mut b = quad_gltf(&|_| {});
        let at = |b: &[u8], what: &[u8]| b.windows(what.len()).position(|w| w == what).unwrap();
        let k = at(&b, b"\"accessors\"");
        b[k + 6] = b'1';
        let k = at(&b, b"VEC3");
        b[k + 3] = 0xb1;
        assert_err(
            &b,
            "mesh 0 primitive 0",
            "POSITION names accessor 0, the file has 0",
        );
    }

    #[test]
    fn random_input_never_panics() {
        let mut seed = 0x005e_ed0f_617f_u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let gltf = quad_gltf(&|_| {});
        let valid = [gltf.clone(), glb_of(&gltf)];
        for round in 0..2000 {
            let mut b = valid[round % 2].clone();
            for _ in 0..1 + next() % 4 {
                let i = next() as usize % b.len();
                b[i] = match next() % 3 {
                    0 => next() as u8,
                    1 => b"0123456789,:[]{}\"-."[next() as usize % 19],
                    _ => b[i].wrapping_add(1),
                };
            }
            if next() % 3 == 0 {
                b.truncate(next() as usize % (b.len() + 1));
            }
            if let Ok((m, _)) = parse(&b) {
                m.validate(Path::new("fuzz.gltf")).unwrap();
            }
        }
    }
}
