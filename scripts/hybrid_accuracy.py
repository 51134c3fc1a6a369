#!/usr/bin/env python3
"""The layered method's multiple scattering against the path tracer (docs/accuracy.md).

For a scene with a layered material whose "multiple_scattering" is "diffusion", render:
  reference  --method pathtrace, every scattering order (the layers exactly)
  single     --method layered with "multiple_scattering": "none" (seed 001 alone)
  diffusion  --method diffusion on the object with its core material (layers removed)
  diffusion_layers  --method diffusion on the layered material (each voxel the mean of its
             layers' and core's coefficients, every scattering order)
  hybrid     --method layered as the scene says
and print `nacre compare --json` of each against the reference.

usage: scripts/hybrid_accuracy.py SCENE.json [--nacre build/release/nacre] [--out DIR]
       [--pt-seconds 90] [--spp 4096] [--seed 1] [--reuse-reference]
"""
import argparse, json, os, subprocess, sys

ap = argparse.ArgumentParser()
ap.add_argument("scene")
ap.add_argument("--nacre", default="build/release/nacre")
ap.add_argument("--out", default="/tmp/nacre_hybrid")
ap.add_argument("--pt-seconds", type=float, default=90)
ap.add_argument("--spp", type=int, default=4096)
ap.add_argument("--seed", type=int, default=1)
ap.add_argument("--reuse-reference", action="store_true")
a = ap.parse_args()
os.makedirs(a.out, exist_ok=True)
base = os.path.splitext(os.path.basename(a.scene))[0]
src_dir = os.path.dirname(os.path.abspath(a.scene))
scene = json.load(open(a.scene))
for m in scene["materials"].values():
    if "depth_map" in m:
        m["depth_map"] = os.path.join(src_dir, m["depth_map"])


def variant(name, edit):
    s = json.loads(json.dumps(scene))
    for m in s["materials"].values():
        if "multiple_scattering" in m or "layers" in m:
            edit(m)
    path = os.path.join(a.out, "%s.%s.json" % (base, name))
    json.dump(s, open(path, "w"), indent=1)
    return path


def none(m):
    m["multiple_scattering"] = "none"


def core(m):
    for k in ("layers", "depth_map", "multiple_scattering"):
        m.pop(k, None)
    if m.get("preset") == "fish":  # the preset's core (scene.c, seed 001 table 1), without its layers
        del m["preset"]
        m.update({"type": "translucent", "sigma_a": [0.5, 0.5, 0.5], "sigma_s": [1, 1, 2], "g": 0.8,
                  "eta": 1.33})


runs = {
    "reference": (variant("reference", lambda m: None),
                  ["--method", "pathtrace", "--spp", str(a.spp), "--seed", str(a.seed),
                   "--time-limit", str(a.pt_seconds)]),
    "single": (variant("single", none), ["--method", "layered"]),
    "diffusion": (variant("diffusion", core), ["--method", "diffusion"]),
    "diffusion_layers": (variant("reference", lambda m: None), ["--method", "diffusion"]),
    "hybrid": (variant("hybrid", lambda m: None), ["--method", "layered"]),
}
images = {}
for name, (path, args) in runs.items():
    images[name] = os.path.join(a.out, "%s.%s.exr" % (base, name))
    if name == "reference" and a.reuse_reference and os.path.exists(images[name]):
        continue
    subprocess.run([a.nacre, "render", path, "-o", images[name], "--exr-float"] + args, check=True)
print("%-16s %12s %10s %10s %10s %10s" % ("image", "mean_rel_err", "rmse", "rel_mse", "lit_ratio_g", "dark_ratio_g"))
for name in ("single", "diffusion", "diffusion_layers", "hybrid"):
    r = subprocess.run([a.nacre, "compare", images[name], images["reference"], "--json"],
                       capture_output=True, text=True)
    c = json.loads(r.stdout)
    print("%-16s %12.4f %10.5f %10.5f %10.3f %10.3f" % (name, c["mean_rel_err"], c["rmse"], c["rel_mse"],
                                                      c["lit_ratio"][1], c["dark_ratio"][1]))
