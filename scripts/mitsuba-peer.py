"""Mitsuba 3 peer of `dcrt bench shading` (run through mitsuba-peer.sh).

DIR/scene.json, written by dcrt, gives the image size, the camera as dcrt's ray generation uses it
(origin, forward, and the right and up vectors that span the image plane at unit distance), the
meshes (binary PLY, unshared vertices) with their albedo, the sky radiance, dcrt's max_depth and
rr_depth, a seed and the list of spp. For each spp this writes DIR/mitsuba-<spp>.f32 (linear RGB,
f32 little-endian, rows from the top) and prints one JSON line on stdout.

Timed: the render alone (mi.render and evaluation of its result), after an untimed render at the
same spp that compiles the kernels; scene loading and the conversion to bytes are not timed.
Renders of more than 2^24 samples run in passes of equal spp with their own seeds, averaged
(with a box filter this is the same estimator as one render), and the time is their sum.
"""

import array
import json
import math
import os
import sys
import time

import drjit as dr
import mitsuba as mi

MAX_SAMPLES_PER_PASS = 1 << 24


def fail(msg):
    print(f"mitsuba-peer: {msg}", file=sys.stderr)
    sys.exit(1)


def vec(v, name):
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
        fail(f"scene.json: {name} must be three numbers, got {v!r}")
    return [float(x) for x in v]


def norm(v):
    return math.sqrt(sum(x * x for x in v))


def main():
    if len(sys.argv) != 2:
        fail("usage: mitsuba-peer.py DIR")
    d = sys.argv[1]
    try:
        with open(os.path.join(d, "scene.json")) as f:
            s = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"{d}/scene.json: {e}")
    w, h = int(s["width"]), int(s["height"])
    cam = s["camera"]
    origin, forward = vec(cam["origin"], "camera.origin"), vec(cam["forward"], "camera.forward")
    right, up = vec(cam["right"], "camera.right"), vec(cam["up"], "camera.up")
    # dcrt: d = normalize(forward + sx * right + sy * up), sx, sy in [-1, 1], y down the image.
    # That is a pinhole whose vertical half-angle is atan(|up|), with |right| / |up| the aspect.
    if abs(norm(right) / norm(up) - w / h) > 1e-4 * (w / h):
        fail(f"camera: |right| / |up| = {norm(right) / norm(up)} is not width / height = {w / h}")
    fov_y = math.degrees(2.0 * math.atan(norm(up)))
    # dcrt's max_depth D allows D bounces after the camera hit, D + 1 segments; Mitsuba's
    # max_depth counts segments. dcrt's Russian roulette at bounce k >= rr_depth decides the ray
    # after the k-th bounce's hit, which Mitsuba applies at its depth k + 1.
    max_depth, rr_depth = int(s["max_depth"]) + 1, int(s["rr_depth"]) + 1

    mi.set_variant("llvm_ad_rgb")
    t = mi.ScalarTransform4f().look_at(
        origin=origin, target=[o + f for o, f in zip(origin, forward)], up=up
    )
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": rr_depth},
        "sensor": {
            "type": "perspective",
            "fov": fov_y,
            "fov_axis": "y",
            "near_clip": 1e-4,
            "far_clip": 1e7,
            "to_world": t,
            "film": {
                "type": "hdrfilm",
                "width": w,
                "height": h,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
                "component_format": "float32",
            },
            "sampler": {"type": "independent", "sample_count": 1},
        },
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": vec(s["sky"], "sky")}},
    }
    for i, m in enumerate(s["meshes"]):
        scene[f"mesh{i}"] = {
            "type": "ply",
            "filename": os.path.join(d, m["file"]),
            "face_normals": True,
            # dcrt's surfaces reflect on both sides (the normal faces the incoming ray).
            "bsdf": {
                "type": "twosided",
                "bsdf": {
                    "type": "diffuse",
                    "reflectance": {"type": "rgb", "value": vec(m["albedo"], "albedo")},
                },
            },
        }
    t0 = time.perf_counter()
    try:
        scene = mi.load_dict(scene)
    except Exception as e:  # Mitsuba raises plain RuntimeErrors
        fail(f"loading the scene: {e}")
    load_s = time.perf_counter() - t0

    def render(spp, seed):
        passes = max(1, math.ceil(spp * w * h / MAX_SAMPLES_PER_PASS))
        while spp % passes:
            passes += 1
        acc, secs = None, 0.0
        for p in range(passes):
            t0 = time.perf_counter()
            img = mi.render(scene, spp=spp // passes, seed=seed * 4096 + p)
            dr.eval(img)
            dr.sync_thread()
            secs += time.perf_counter() - t0
            acc = img if acc is None else acc + img
        acc = acc / passes
        dr.eval(acc)
        return acc, secs, passes

    seed = int(s.get("seed", 0))
    renders = []
    for k, spp in enumerate(s["spp"]):
        spp = int(spp)
        render(spp, seed + 7919 * (k + 1))  # compiles the kernels of this spp
        img, secs, passes = render(spp, seed + k)
        if tuple(img.shape) != (h, w, 3):
            fail(f"render at {spp} spp has shape {img.shape}, expected ({h}, {w}, 3)")
        name = f"mitsuba-{spp}.f32"
        with open(os.path.join(d, name), "wb") as f:
            array.array("f", img.array).tofile(f)
        renders.append({"spp": spp, "seconds": secs, "passes": passes, "file": name})
    print(
        json.dumps(
            {
                "mitsuba": mi.__version__,
                "variant": mi.variant(),
                "max_depth": max_depth,
                "rr_depth": rr_depth,
                "fov_y": fov_y,
                "threads": dr.thread_count(),
                "load_seconds": load_s,
                "timed": "mi.render and its evaluation, after an untimed render at the same spp",
                "renders": renders,
            }
        )
    )


main()
