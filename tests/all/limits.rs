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
