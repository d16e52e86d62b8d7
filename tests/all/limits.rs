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

/// The bench applies the generators' limit: an absurd `--triangles` is an error naming the
/// option, not an allocation abort.
#[test]
fn bench_refuses_triangles_past_the_generators_limit() {
    let out = dcrt(&[&"bench", &"--triangles", &"18446744073709551615"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("--triangles must be between 1 and 1000000000, got 18446744073709551615"),
        "{err}"
    );
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
/// before any work: a reference that cannot be split into whole halves, a peer with the wrong
/// benchmark, a soak too short for a slope, figures without a render rank, a timed frame or a
/// valid cache, a cluster cache with no such mapping.
#[test]
fn bench_refuses_options_it_cannot_measure() {
    for (args, expect) in [
        (
            &["--shading", "--reference-spp", "0"][..],
            "--reference-spp must be a multiple of 8",
        ),
        (&["--shading", "--reference-spp", "12"], "got 12"),
        (&["--peer", "mitsuba"], "--peer mitsuba needs --shading"),
        (
            &["--peer", "embree", "--shading"],
            "--peer embree measures primary rays",
        ),
        (&["--soak", "5"], "--soak needs at least 20 frames, got 5"),
        (
            &["--figures", "figs-never-written", "--ranks", "2"],
            "--ranks counts MPI ranks, at least 3",
        ),
        (
            &["--figures", "figs-never-written", "--frames", "1"],
            "--frames must be at least 2",
        ),
        (
            &[
                "--figures",
                "figs-never-written",
                "--ranks",
                "3",
                "--caches",
                "1/0",
            ],
            "--caches: 1/0",
        ),
        (
            &["--cluster", "--cluster-caches", "none,1/8:fifo"],
            "--cluster-caches 1/8:fifo: no cache mapping \"fifo\"",
        ),
        (
            &["--cluster", "--cluster-caches", "1/8:lru:sometimes"],
            "--cluster-caches 1/8:lru:sometimes: no overlap mode \"sometimes\"",
        ),
        (
            &["--cluster", "--copy-threads", "1,x"],
            "\"x\" is not a count",
        ),
        // An empty list is taken (it skips the display benchmark): the refusal is the frames'.
        (
            &["--cluster", "--copy-threads", "", "--frames", "1"],
            "--frames must be at least 2",
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
