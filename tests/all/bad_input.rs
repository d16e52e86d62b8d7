//! Bad input gets a clear error naming the file and the place, a non-zero exit, and no output.

use crate::common::*;

const CAMERA: &str = "[camera]\nposition = [0, -3, 0]\nfocal_point = [0, 0, 0]\n\
                      view_up = [0, 0, 1]\nview_angle = 40\n[image]\nwidth = 16\nheight = 16\n";

fn scene_with_mesh(dir: &TempDir, mesh_name: &str, mesh: &[u8]) -> std::path::PathBuf {
    dir.write(mesh_name, mesh);
    dir.write(
        "scene.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"{mesh_name}\"\n"),
    )
}

/// Runs `dcrt render` and checks the failure: exit code, every `needles` in stderr, no output.
fn fails(dir: &TempDir, scene: &std::path::Path, extra: &[&str], needles: &[&str]) {
    let out = dir.path("out.png");
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"render", &scene, &"-o", &out];
    for e in extra {
        args.push(e);
    }
    let r = dcrt(&args);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success(), "should fail: {err}");
    assert_eq!(
        r.status.code(),
        Some(1),
        "a clean error exit, not a panic: {err}"
    );
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}:\n{err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(!exists(&out), "no output is written on failure");
}

const PLY_HEADER: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                          property float y\nproperty float z\nelement face 1\n\
                          property list uchar int vertex_indices\nend_header\n";

#[test]
fn missing_and_unreadable_files() {
    let d = TempDir::new("missing");
    fails(
        &d,
        &d.path("nope.toml"),
        &[],
        &["nope.toml", "No such file"],
    );
    // A directory where a file should be cannot be read.
    std::fs::create_dir_all(d.path("dir.toml")).unwrap();
    fails(&d, &d.path("dir.toml"), &[], &["dir.toml"]);
    let s = d.write(
        "scene.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"gone.ply\"\n"),
    );
    fails(&d, &s, &[], &["gone.ply", "No such file"]);
    let s = d.write(
        "scene2.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"x.xyz\"\n"),
    );
    d.write("x.xyz", "solid");
    fails(
        &d,
        &s,
        &[],
        &["x.xyz", "unknown mesh format", ".vtp, .gltf, .glb"],
    );
}

#[test]
fn broken_mesh_files() {
    let d = TempDir::new("broken");
    // Truncated binary PLY: the header promises 3 vertices, the data holds 1.
    let mut ply = PLY_HEADER
        .replace("ascii", "binary_little_endian")
        .into_bytes();
    ply.extend(bytemuck::cast_slice::<f32, u8>(&[0.0, 0.0, 0.0]));
    let s = scene_with_mesh(&d, "trunc.ply", &ply);
    fails(&d, &s, &[], &["trunc.ply", "vertex"]);
    // Garbage.
    let s = scene_with_mesh(&d, "junk.obj", b"\x00\xff\xfe garbage\n\x01\x02");
    fails(&d, &s, &[], &["junk.obj", "line 1"]);
    let s = scene_with_mesh(&d, "junk.ply", b"\x00\xff\xfe garbage\n\x01\x02");
    fails(&d, &s, &[], &["junk.ply"]);
    // Counts that do not match the data: 3 vertices promised, 2 given before the face.
    let text = format!("{PLY_HEADER}0 0 0\n1 0 0\n3 0 1 2\n");
    let s = scene_with_mesh(&d, "count.ply", text.as_bytes());
    fails(&d, &s, &[], &["count.ply"]);
    // Extra data after the last element.
    let text = format!("{PLY_HEADER}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n");
    let s = scene_with_mesh(&d, "extra.ply", text.as_bytes());
    fails(&d, &s, &[], &["extra.ply"]);
    // A face index out of range.
    let s = scene_with_mesh(&d, "range.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
    fails(&d, &s, &[], &["range.obj", "line 4"]);
}

#[test]
fn non_finite_coordinates() {
    let d = TempDir::new("nan");
    let s = scene_with_mesh(&d, "nan.obj", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
    fails(&d, &s, &[], &["nan.obj", "line 2"]);
    let s = scene_with_mesh(&d, "inf.obj", b"v 0 0 0\nv 1 0 0\nv 0 1e39 0\nf 1 2 3\n");
    fails(&d, &s, &[], &["inf.obj", "line 3"]);
    let text = format!("{PLY_HEADER}0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n");
    let s = scene_with_mesh(&d, "inf.ply", text.as_bytes());
    fails(&d, &s, &[], &["inf.ply", "vertex 1"]);
    // Finite in the file, infinite once scaled.
    d.write("ok.obj", "v 0 0 0\nv 1 0 0\nv 0 1e30 0\nf 1 2 3\n");
    let s = d.write(
        "scaled.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"ok.obj\"\nscale = 1e10\n"),
    );
    fails(&d, &s, &[], &["ok.obj", "not finite"]);
}

#[test]
fn scenes_without_triangles() {
    let d = TempDir::new("empty");
    let s = scene_with_mesh(&d, "points.obj", b"v 0 0 0\nv 1 0 0\n");
    fails(&d, &s, &[], &["points.obj", "the mesh has no triangles"]);
    // `faces` is not the `face` element: a mesh without faces, named.
    let ply = PLY_HEADER.replace("element face 1", "element faces 1");
    let s = scene_with_mesh(
        &d,
        "faces.ply",
        format!("{ply}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").as_bytes(),
    );
    fails(&d, &s, &[], &["faces.ply"]);
    let s = d.write("nomesh.toml", CAMERA);
    fails(&d, &s, &[], &["nomesh.toml", "no [[mesh]]"]);
}

#[test]
fn bad_scene_files() {
    let d = TempDir::new("toml");
    let cases = [
        (
            "unknown.toml",
            format!("{CAMERA}[[mesh]]\ngenerator = \"rm\"\nshiny = 1\n"),
            "shiny",
        ),
        (
            "type.toml",
            format!("{CAMERA}[[mesh]]\ngenerator = \"rm\"\ntriangles = \"many\"\n"),
            "triangles",
        ),
        (
            "syntax.toml",
            "[camera\nposition = 1\n".to_string(),
            "line 1",
        ),
        (
            "zero.toml",
            CAMERA.replace("width = 16", "width = 0") + "[[mesh]]\ngenerator = \"rm\"\n",
            "out of range",
        ),
        (
            "huge.toml",
            CAMERA.replace("width = 16", "width = 1000000") + "[[mesh]]\ngenerator = \"rm\"\n",
            "out of range",
        ),
        (
            "cam.toml",
            CAMERA.replace("view_angle = 40", "view_angle = 200")
                + "[[mesh]]\ngenerator = \"rm\"\n",
            "view_angle",
        ),
    ];
    for (name, text, needle) in cases {
        let s = d.write(name, text);
        fails(&d, &s, &[], &[name, needle]);
    }
}

#[test]
fn bad_command_line_values() {
    let d = TempDir::new("cli");
    let s = small_scene(&d);
    fails(&d, &s, &["--width", "0"], &["out of range"]);
    fails(
        &d,
        &s,
        &["--width", "100000", "--height", "100000"],
        &["out of range"],
    );
    fails(&d, &s, &["--step-budget", "70000"], &["--step-budget"]);
    for cost in ["0", "-1", "nan", "inf", "1e9"] {
        fails(
            &d,
            &s,
            &["--bvh-node-cost", cost],
            &["--bvh-node-cost", "node cost"],
        );
    }
    fails(&d, &s, &["--aov", "depth"], &["--exr"]);
    let missing_dir = d.path("no/such/dir/x.exr");
    let m = missing_dir.to_str().unwrap();
    fails(&d, &s, &["--exr", m], &["does not exist"]);
    // Cluster options are checked in one process too.
    fails(&d, &s, &["--copy-threads", "0"], &["--copy-threads"]);
    fails(&d, &s, &["--tile", "0"], &["--tile"]);
    fails(&d, &s, &["--timeout", "0"], &["--timeout"]);
}

/// `ok.toml` in `d`: a 1,000-triangle generated scene.
fn small_scene(d: &TempDir) -> std::path::PathBuf {
    d.write(
        "ok.toml",
        format!("{CAMERA}[[mesh]]\ngenerator = \"rm\"\ntriangles = 1000\n"),
    )
}

/// A block file holds its tree and blocks: build options given with it are refused, not ignored.
#[test]
fn build_options_with_a_block_file_are_refused() {
    let d = TempDir::new("dcb-build");
    let s = small_scene(&d);
    let dcb = d.path("model.dcb");
    let r = dcrt(&[&"prepare", &s, &"-o", &dcb, &"-q"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    for extra in [
        ["--bvh-node-cost", "1"],
        ["--bvh-preset", "medium"],
        ["--block-size", "4096"],
    ] {
        fails(&d, &dcb, &extra, &["model.dcb", extra[0], "dcrt prepare"]);
    }
    // The defaults, given or not, are what the file was built with.
    let out = d.path("ok.png");
    let r = dcrt(&[&"render", &dcb, &"-o", &out, &"--bvh-node-cost", &"3"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

#[test]
fn scene_values_are_strict() {
    let d = TempDir::new("strict");
    d.write("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let mesh = "[[mesh]]\nfile = \"tri.obj\"\n";
    let cases = [
        (
            "pos4.toml",
            CAMERA.replace("[0, -3, 0]", "[0, -6, 2, 99]"),
            "got 4",
        ),
        (
            "far.toml",
            CAMERA.replace("[0, -3, 0]", "[0, -3, 1e39]"),
            "32-bit",
        ),
        (
            "sun4.toml",
            format!("{CAMERA}[render]\nsun = [1, 1, 1, 1]\n"),
            "got 4",
        ),
        (
            "light4.toml",
            format!("{CAMERA}[[light]]\ntype = \"directional\"\ndirection = [0, 0, -1, 0]\n"),
            "got 4",
        ),
        (
            "color4.toml",
            format!("{CAMERA}[[mesh]]\nfile = \"tri.obj\"\ncolor = [1, 0, 0, 1]\n"),
            "got 4",
        ),
        (
            "bg2.toml",
            CAMERA.replace("height = 16\n", "height = 16\nbackground = [0, 0]\n"),
            "got 2",
        ),
        (
            "model.toml",
            "model = \"\"\n".to_string(),
            "model: the path is empty",
        ),
    ];
    for (name, text, needle) in cases {
        let text = if text.contains("[[mesh]]") || text.contains("model") {
            text
        } else {
            format!("{text}{mesh}")
        };
        let s = d.write(name, text);
        fails(&d, &s, &[], &[name, needle]);
    }
}

#[test]
fn obj_typos_are_errors() {
    let d = TempDir::new("objtypo");
    let v = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n";
    let s = scene_with_mesh(&d, "typo.obj", format!("{v}f 1 2 3\nF 1 3 4\n").as_bytes());
    fails(&d, &s, &[], &["typo.obj", "line 6", "'F'"]);
    let s = scene_with_mesh(&d, "corner.obj", format!("{v}f 1/x/y 2 4\n").as_bytes());
    fails(&d, &s, &[], &["corner.obj", "line 5", "1/x/y"]);
}

#[test]
fn inputs_must_be_regular_files_of_bounded_size() {
    let d = TempDir::new("special");
    fails(
        &d,
        std::path::Path::new("/dev/zero"),
        &[],
        &["/dev/zero", "character device"],
    );
    std::fs::create_dir_all(d.path("dir.toml")).unwrap();
    fails(
        &d,
        &d.path("dir.toml"),
        &[],
        &["dir.toml", "is a directory"],
    );
    // A FIFO as a mesh would block the loader forever.
    let fifo = d.path("pipe.obj");
    let r = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(r.success());
    let s = d.write(
        "fifo.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"pipe.obj\"\n"),
    );
    fails(&d, &s, &[], &["pipe.obj", "a FIFO"]);
    // A scene past the size cap, sparse so that it costs no disk.
    let big = d.path("big.toml");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(65 << 20)
        .unwrap();
    fails(&d, &big, &[], &["big.toml", "larger than 64 MiB"]);
    // A directory or a scene where the model should be says what it is.
    let m = d.write("m.toml", "model = \"dir.toml\"\n");
    fails(&d, &m, &[], &["dir.toml", "is a directory"]);
    let s = d.write("s.toml", format!("{CAMERA}[[mesh]]\ngenerator = \"rm\"\n"));
    let m = d.write("m2.toml", "model = \"s.toml\"\n");
    fails(&d, &m, &[], &["s.toml", "it is text (a scene?)"]);
    let _ = s;
}

#[test]
fn messages_say_their_cause_once() {
    let d = TempDir::new("messages");
    let r = dcrt(&[&"render", &d.path("nope.toml"), &"-o", &d.path("o.png")]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.matches("No such file").count(), 1, "{err}");
    // The same through every loader and command: a missing mesh, a glTF's missing buffer file,
    // `prepare`, `info FILE`.
    d.write(
        "b.gltf",
        gltf(&|j| j["buffers"][0]["uri"] = "gone.bin".into()),
    );
    for mesh in ["gone.vtp", "gone.stl", "b.gltf"] {
        let s = d.write("m.toml", format!("{CAMERA}[[mesh]]\nfile = \"{mesh}\"\n"));
        for (cmd, out) in [("render", "o.png"), ("prepare", "o.dcb")] {
            let out = d.path(out);
            let r = dcrt(&[&cmd, &s, &"-o", &out]);
            let err = String::from_utf8_lossy(&r.stderr);
            assert_eq!(
                err.matches("No such file").count(),
                1,
                "{cmd} {mesh}: {err}"
            );
            let named = if mesh == "b.gltf" { "gone.bin" } else { mesh };
            assert!(err.contains(named), "{err}");
        }
    }
    let r = dcrt(&[&"info", &d.path("gone.vtk")]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.matches("No such file").count(), 1, "{err}");
    assert!(err.contains("gone.vtk"), "{err}");
    let s = d.write(
        "u.toml",
        b"[camera]\nposition = [0, 0, 1]\n# \xff\n".as_slice(),
    );
    fails(&d, &s, &[], &["u.toml", "line 3", "UTF-8"]);
    let ply = d.write("bumpy.ply", PLY_HEADER);
    fails(
        &d,
        &ply,
        &[],
        &[
            "bumpy.ply",
            "expected a scene (.toml) or a block file (.dcb)",
        ],
    );
    let s = d.write(
        "g.toml",
        format!("{CAMERA}[[mesh]]\ngenerator = \"rm\"\ntriangles = 1000\n"),
    );
    fails(
        &d,
        &s,
        &["--virtual-ranks", "0"],
        &["--virtual-ranks must be at least 1"],
    );
    fails(
        &d,
        &s,
        &["--virtual-ranks", "2", "--rank", "2"],
        &["--rank 2 is out of range"],
    );
    // Replicated blocks mean something only beside a cache: not silently ignored without one.
    fails(
        &d,
        &s,
        &["--replicate-blocks", "nodes"],
        &["--replicate-blocks nodes needs a distributed cache"],
    );
    // So are a cache's size and mapping.
    fails(
        &d,
        &s,
        &["--cache", "1/4"],
        &["--cache 1/4 needs a distributed cache"],
    );
    fails(
        &d,
        &s,
        &["--cache-map", "lru"],
        &["--cache-map needs a distributed cache"],
    );
}

/// A small legacy VTK file: two triangles, point array "p", cell array "c".
const VTK: &str = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 4 float\n\
                   0 0 0 1 0 0 1 1 0 0 1 0\nPOLYGONS 2 8\n3 0 1 2\n3 0 2 3\n\
                   POINT_DATA 4\nSCALARS p float\nLOOKUP_TABLE default\n0 1 2 3\n\
                   CELL_DATA 2\nSCALARS c int\nLOOKUP_TABLE default\n5 6\n";

/// A small XML PolyData file: the same two triangles and arrays.
const VTP: &str = r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
<PolyData><Piece NumberOfPoints="4" NumberOfPolys="2">
<PointData><DataArray type="Float32" Name="p" format="ascii">0 1 2 3</DataArray></PointData>
<CellData><DataArray type="Int32" Name="c" format="ascii">5 6</DataArray></CellData>
<Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 1 1 0 0 1 0</DataArray></Points>
<Polys><DataArray type="Int32" Name="connectivity" format="ascii">0 1 2 0 2 3</DataArray>
<DataArray type="Int32" Name="offsets" format="ascii">3 6</DataArray></Polys>
</Piece></PolyData></VTKFile>
"#;

/// A binary STL of two triangles.
fn stl(nan: bool) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&2u32.to_le_bytes());
    for t in [
        [0.0f32, 0., 0., 1., 0., 0., 1., 1., 0.],
        [0., 0., 0., 1., 1., 0., 0., 1., 0.],
    ] {
        b.extend_from_slice(&[0u8; 12]);
        for (k, v) in t.iter().enumerate() {
            let v = if nan && k == 4 { f32::NAN } else { *v };
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&[0u8; 2]);
    }
    b
}

/// A glTF file of the same two triangles, buffer inlined, with a `_P` attribute.
fn gltf(edit: &dyn Fn(&mut serde_json::Value)) -> Vec<u8> {
    use base64::Engine;
    let mut bin = Vec::new();
    for v in [
        0.0f32, 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0., 0., 1., 2., 3.,
    ] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    let mut j = serde_json::json!({
        "asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "_P": 1}, "indices": 2}]}],
        "buffers": [{"byteLength": bin.len(), "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 16},
                        {"buffer": 0, "byteOffset": 64, "byteLength": 12}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}]
    });
    edit(&mut j);
    serde_json::to_vec(&j).unwrap()
}

/// Every new loader, through the command line: truncated, garbage, wrong counts, out-of-range
/// indices, non-finite coordinates, arrays of the wrong length and mismatched types each give an
/// error naming the file and the element or line, exit 1 and no output.
#[test]
fn broken_stl_vtk_vtp_gltf_files() {
    let d = TempDir::new("broken-formats");
    let cases: Vec<(&str, Vec<u8>, Vec<&str>)> = vec![
        // STL
        (
            "trunc.stl",
            stl(false)[..150].to_vec(),
            vec!["declares 2 triangles (184 bytes) where the file has 150"],
        ),
        (
            "junk.stl",
            b"\x00\xff garbage".to_vec(),
            vec!["not an STL file"],
        ),
        ("nan.stl", stl(true), vec!["triangle 0", "not finite"]),
        (
            "count.stl",
            b"solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\n"
                .to_vec(),
            vec!["line 6", "a facet has 2 vertices"],
        ),
        // legacy VTK
        (
            "trunc.vtk",
            VTK.as_bytes()[..VTK.find("3 0 2 3").unwrap()].to_vec(),
            vec!["POLYGONS: integer 4 of 8", "file ends after 4 of 8 values"],
        ),
        (
            "junk.vtk",
            b"\x00\xff garbage\n".to_vec(),
            vec!["line 1", "not a legacy VTK file"],
        ),
        (
            "count.vtk",
            VTK.replace("POLYGONS 2 8", "POLYGONS 3 8").into_bytes(),
            vec!["holds 2 whole cells, the header says 3"],
        ),
        (
            "range.vtk",
            VTK.replace("3 0 2 3", "3 0 2 7").into_bytes(),
            vec!["POLYGONS: cell 1", "point index 7 out of range (4 points)"],
        ),
        (
            "nan.vtk",
            VTK.replace("1 1 0 0 1 0", "1 nan 0 0 1 0").into_bytes(),
            vec!["POINTS: point 2 (line 6)", "not finite"],
        ),
        (
            "length.vtk",
            VTK.replace("0 1 2 3\nCELL", "0 1 2\nCELL").into_bytes(),
            vec!["point 'p'", "expected a float32 value, found 'CELL_DATA'"],
        ),
        (
            "type.vtk",
            VTK.replace("5 6\n", "5 6.5\n").into_bytes(),
            vec!["cell 'c': cell 1", "expected a int32 value, found '6.5'"],
        ),
        // XML PolyData
        (
            "trunc.vtp",
            VTP.as_bytes()[..200].to_vec(),
            vec!["not well-formed XML"],
        ),
        ("junk.vtp", b"\x00\xff garbage".to_vec(), vec!["line 1"]),
        (
            "count.vtp",
            VTP.replace("NumberOfPolys=\"2\"", "NumberOfPolys=\"3\"")
                .into_bytes(),
            vec!["Piece 0: Polys offsets", "2 values where 3 tuples"],
        ),
        (
            "range.vtp",
            VTP.replace("0 1 2 0 2 3", "0 1 2 0 2 9").into_bytes(),
            vec!["Polys cell 1", "point index 9 out of range"],
        ),
        (
            "nan.vtp",
            VTP.replace("1 1 0 0 1 0", "1 nan 0 0 1 0").into_bytes(),
            vec!["Piece 0: Points", "point 2: coordinate is not finite"],
        ),
        (
            "length.vtp",
            VTP.replace(">0 1 2 3<", ">0 1 2<").into_bytes(),
            vec!["point array 'p'", "3 values where 4 tuples of 1 need 4"],
        ),
        (
            "type.vtp",
            VTP.replace("type=\"Int32\" Name=\"c\"", "type=\"Float16\" Name=\"c\"")
                .into_bytes(),
            vec!["cell array 'c'", "unsupported type 'Float16'"],
        ),
        // glTF
        (
            "trunc.gltf",
            gltf(&|_| {})[..300].to_vec(),
            vec!["not a glTF 2.0 file"],
        ),
        (
            "junk.glb",
            b"glTF\x02\x00\x00\x00\xff\xff".to_vec(),
            vec!["not a glTF 2.0 file"],
        ),
        (
            "count.gltf",
            gltf(&|j| j["accessors"][0]["count"] = 9.into()),
            vec![
                "mesh 0 primitive 0",
                "POSITION: accessor 0: 9 elements from byte 0 run past its buffer view (48 bytes)",
            ],
        ),
        (
            "range.gltf",
            gltf(&|j| j["accessors"][2]["count"] = 5.into()),
            vec!["mesh 0 primitive 0", "5 indices are not whole triangles"],
        ),
        (
            "nan.gltf",
            gltf(&|j| j["nodes"][0]["scale"] = serde_json::json!([4e38, 1, 1])),
            vec!["mesh 0 primitive 0 (node 0)", "not finite"],
        ),
        (
            "length.gltf",
            gltf(&|j| j["accessors"][1]["count"] = 3.into()),
            vec!["mesh 0 primitive 0", "_P has 3 values for 4 vertices"],
        ),
        (
            "type.gltf",
            gltf(&|j| j["accessors"][2]["componentType"] = 5126.into()),
            vec!["mesh 0 primitive 0", "indices must be unsigned integers"],
        ),
    ];
    for (name, bytes, needles) in cases {
        d.write(name, &bytes);
        // Coloured by the point array, so that arrays are read and checked.
        let by = if name.ends_with("gltf") { "_P" } else { "p" };
        let colour =
            if name.ends_with("stl") || name.starts_with("junk") || name.starts_with("trunc") {
                String::new()
            } else {
                format!("color_by = \"{by}\"\n")
            };
        let s = d.write(
            "s.toml",
            format!("{CAMERA}[[mesh]]\nfile = \"{name}\"\n{colour}"),
        );
        eprintln!("case {name}");
        let mut all = vec![name];
        all.extend(needles);
        fails(&d, &s, &[], &all);
    }
}

/// Colouring mistakes: an unknown array (the message lists the ones there are), cell data asked
/// as point data and back, a colour array given a colormap, an unknown colormap, a bad range, the
/// keys without `color_by`, a generator, non-finite values.
#[test]
fn colour_by_mistakes() {
    let d = TempDir::new("color-mistakes");
    d.write("m.vtk", VTK);
    d.write("n.vtk", VTK.replace("0 1 2 3\nCELL", "0 nan 2 3\nCELL"));
    d.write(
        "rgb.vtk",
        VTK.replace(
            "SCALARS c int\nLOOKUP_TABLE default\n5 6",
            "COLOR_SCALARS c 3\n1 0 0 0 1 0",
        ),
    );
    let cases: Vec<(&str, Vec<&str>)> = vec![
        (
            "file = \"m.vtk\"\ncolor_by = \"pressure\"",
            vec![
                "m.vtk",
                "color_by 'pressure': no point array of that name; point arrays: p; cell arrays: c",
            ],
        ),
        (
            "file = \"m.vtk\"\ncolor_by = \"c\"",
            vec!["m.vtk", "'c' is cell data: add cell = true"],
        ),
        (
            "file = \"m.vtk\"\ncolor_by = \"p\"\ncell = true",
            vec!["m.vtk", "'p' is point data: remove cell = true"],
        ),
        (
            "file = \"rgb.vtk\"\ncolor_by = \"c\"\ncell = true\ncolormap = \"viridis\"",
            vec!["rgb.vtk", "the array holds colours"],
        ),
        (
            "file = \"m.vtk\"\ncolor_by = \"p\"\ncolormap = \"jet\"",
            vec![
                "s.toml",
                "unknown variant `jet`",
                "cool-to-warm",
                "rainbow-uniform",
            ],
        ),
        (
            "file = \"m.vtk\"\ncolor_by = \"p\"\nrange = [2, 1]",
            vec!["s.toml", "[2, 1] is empty"],
        ),
        (
            "file = \"m.vtk\"\ncolor_by = \"p\"\nrange = [0, 1, 2]",
            vec!["s.toml", "expected 2 numbers, got 3"],
        ),
        (
            "file = \"m.vtk\"\ncolormap = \"viridis\"",
            vec!["s.toml", "mesh 1", "go with `color_by`"],
        ),
        (
            "generator = \"rm\"\ncolor_by = \"p\"",
            vec!["s.toml", "generated meshes have no data arrays"],
        ),
        (
            "file = \"n.vtk\"\ncolor_by = \"p\"",
            vec!["n.vtk", "array 'p': point 1 is NaN"],
        ),
    ];
    for (mesh, needles) in cases {
        let s = d.write("s.toml", format!("{CAMERA}[[mesh]]\n{mesh}\n"));
        fails(&d, &s, &[], &needles);
    }
}

/// No adapter with what the kernels need (here: only the GL backend searched, which offers none
/// on this machine): an error naming the needs and the adapters found, a non-zero exit, no
/// output. `--adapter` with a name nothing matches lists the adapters there are.
#[test]
fn no_usable_adapter_is_a_clear_error() {
    let d = TempDir::new("adapter");
    let s = d.write(
        "scene.toml",
        format!("{CAMERA}[[mesh]]\nfile = \"t.ply\"\n"),
    );
    d.write(
        "t.ply",
        format!("{PLY_HEADER}0 0 0\n1 0 0\n0 0 1\n3 0 1 2\n"),
    );
    let out = d.path("out.png");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_dcrt"))
        .args([
            "render".as_ref(),
            s.as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
        ])
        .env("WGPU_BACKEND", "gl")
        .env_remove("WGPU_ADAPTER_NAME")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    for n in ["compute shaders", "subgroup operations", "found: "] {
        assert!(err.contains(n), "stderr lacks {n:?}:\n{err}");
    }
    assert!(!exists(&out), "no output is written on failure");
    fails(
        &d,
        &s,
        &["--adapter", "no-such-adapter"],
        &["no adapter named like 'no-such-adapter'", "available: "],
    );
}
