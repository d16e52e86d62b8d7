//! Inputs that used to exhaust time, stack or memory: coincident triangles, sizes past the
//! generators' limits in the bench.

use crate::common::*;

/// 20,000 identical triangles build in well under a second and render: before, PLOC chained
/// them (quadratic build) and the tree was deeper than the GPU's traversal stack.
#[test]
fn identical_triangles_build_shallow_and_render() {
    let dir = TempDir::new("coincident");
    let mut obj = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    obj.push_str(&"f 1 2 3\n".repeat(20_000));
    dir.write("same.obj", obj);
    let scene = dir.write(
        "same.toml",
        "[image]\nwidth = 32\nheight = 32\n[camera]\nposition = [0.3, 0.3, 3]\n\
         focal_point = [0.3, 0.3, 0]\nview_up = [0, 1, 0]\nview_angle = 40\n\
         [[mesh]]\nfile = \"same.obj\"\n",
    );
    let png = dir.path("same.png");
    let out = dcrt(&[&"render", &scene, &"-o", &png]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let img = image::open(&png).unwrap().to_rgb8();
    let centre = img.get_pixel(16, 16);
    assert!(
        centre != img.get_pixel(0, 31),
        "the triangle is not in the image: {err}"
    );
}

/// Each bench with a generated model applies the generators' limit: an absurd `--triangles` is an
/// error naming the option, not an allocation abort.
#[test]
fn bench_refuses_triangles_past_the_generators_limit() {
    for bench in ["rays", "dc", "soak", "shading", "cluster", "figures"] {
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"bench", &bench];
        if bench == "figures" {
            args.push(&"figs-never-written");
        }
        if bench == "soak" {
            args.push(&"--frames");
            args.push(&"20");
        }
        args.push(&"--triangles");
        args.push(&"18446744073709551615");
        let out = dcrt(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{bench}: {err}");
        assert!(
            err.contains("--triangles must be between 1 and 1000000000, got 18446744073709551615"),
            "{bench}: {err}"
        );
    }
}

/// A generator at its documented maximum is refused before it runs, with the size it needs and
/// how to lower it (where the machine has less than the ~240 GiB it would take).
#[test]
fn a_generator_too_large_for_memory_is_refused_with_its_size() {
    if dcrt::render::memory::available().is_none_or(|a| a > 200 << 30) {
        return;
    }
    let dir = TempDir::new("bigmodel");
    let scene = dir.write(
        "big.toml",
        "[[mesh]]\ngenerator = \"rm\"\ntriangles = 1000000000\n",
    );
    let png = dir.path("big.png");
    let out = dcrt(&[&"render", &scene, &"-o", &png]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("generating 1000000000 triangles for") && err.contains("GiB"),
        "{err}"
    );
    assert!(err.contains("lower the generators' `triangles`"), "{err}");
    assert!(!exists(&png));
}

/// The bench's option combinations that cannot be measured are refused, naming the option,
/// before any work: a reference that cannot be split into whole halves, a peer of another bench,
/// a soak too short for a slope, figures without a render rank, a timed frame or a valid cache, a
/// cluster cache with no such mapping, a block file where a model is built from a scene.
#[test]
fn bench_refuses_options_it_cannot_measure() {
    for (args, expect) in [
        (
            &["shading", "--reference-spp", "0"][..],
            "--reference-spp must be a multiple of 8",
        ),
        (&["shading", "--reference-spp", "12"], "got 12"),
        (
            &["rays", "--peer", "mitsuba"],
            "invalid value 'mitsuba' for '--peer",
        ),
        (
            &["shading", "--peer", "embree"],
            "invalid value 'embree' for '--peer",
        ),
        (&["rays", "--runs", "0"], "--runs must be at least 1"),
        (
            &["soak", "--frames", "5"],
            "--frames must be at least 20 for bench soak, got 5",
        ),
        (&["soak"], "--frames <FRAMES>"),
        (
            &["dc", "model.dcb"],
            "bench dc builds its model from a scene",
        ),
        (
            &["dc", "--step", "400"],
            "--step must be between 0 and 360 degrees, got 400",
        ),
        (
            &["dc", "--frames", "1"],
            "--frames must be at least 2 for bench dc",
        ),
        (
            &["fuzz", "--seconds", "0"],
            "--seconds needs a positive number",
        ),
        (
            &["figures", "figs-never-written", "--ranks", "2"],
            "--ranks counts MPI ranks, at least 3",
        ),
        (
            &["figures", "figs-never-written", "--frames", "1"],
            "--frames must be at least 2",
        ),
        (
            &["figures", "figs-never-written", "--caches", "1/0"],
            "--caches: 1/0",
        ),
        (
            &["cluster", "--caches", "none,1/8:fifo"],
            "--caches 1/8:fifo: no cache mapping \"fifo\"",
        ),
        (
            &["cluster", "--caches", "1/8:lru:sometimes"],
            "--caches 1/8:lru:sometimes: no overlap mode \"sometimes\"",
        ),
        (
            &["cluster", "--copy-threads", "1,x"],
            "\"x\" is not a count",
        ),
        // An empty list is taken (it skips the display benchmark): the refusal is the frames'.
        (
            &["cluster", "--copy-threads", "", "--frames", "1"],
            "--frames must be at least 2",
        ),
        // Each bench has only its own options.
        (
            &["rays", "--caches", "1/8"],
            "unexpected argument '--caches'",
        ),
        (
            &["shading", "--generator", "rm"],
            "unexpected argument '--generator'",
        ),
        (
            &["cluster", "--faults", "never"],
            "unexpected argument '--faults'",
        ),
    ] {
        let mut all: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"bench"];
        all.extend(args.iter().map(|a| a as &dyn AsRef<std::ffi::OsStr>));
        let out = dcrt(&all);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}: {err}");
        assert!(err.contains(expect), "{args:?}: {err}");
    }
}
