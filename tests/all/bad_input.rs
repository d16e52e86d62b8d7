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
        format!("{CAMERA}[[mesh]]\nfile = \"x.stl\"\n"),
    );
    d.write("x.stl", "solid");
    fails(&d, &s, &[], &["x.stl", "unknown mesh format"]);
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
    let s = d.write(
        "ok.toml",
        format!("{CAMERA}[[mesh]]\ngenerator = \"rm\"\ntriangles = 1000\n"),
    );
    fails(&d, &s, &["--width", "0"], &["out of range"]);
    fails(
        &d,
        &s,
        &["--width", "100000", "--height", "100000"],
        &["out of range"],
    );
    fails(&d, &s, &["--step-budget", "70000"], &["--step-budget"]);
    fails(&d, &s, &["--aov", "depth"], &["--exr"]);
    let missing_dir = d.path("no/such/dir/x.exr");
    let m = missing_dir.to_str().unwrap();
    fails(&d, &s, &["--exr", m], &["does not exist"]);
    // Cluster options are checked in one process too.
    fails(&d, &s, &["--copy-threads", "0"], &["--copy-threads"]);
    fails(&d, &s, &["--tile", "0"], &["--tile"]);
    fails(&d, &s, &["--timeout", "0"], &["--timeout"]);
    fails(&d, &s, &["--display-bench"], &["mpirun"]);
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
}
