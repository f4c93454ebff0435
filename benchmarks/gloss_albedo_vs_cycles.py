"""The physical renderer's glossy layer against Cycles' Principled BSDF: the specular
directional albedo of a dielectric, measured.

Cycles renders an orthographic sphere of a black Principled BSDF (so only its specular
layer reflects) under a uniform white world of radiance 1, one bounce: each pixel's
radiance is the layer's directional albedo toward the camera at that pixel's n.v. The
script bins the pixels by n.v and prints, per roughness, Cycles' mean beside
``gloss.specular_albedo`` (the exact dielectric Fresnel with the multiple-scattering
energy) and beside the earlier model (Schlick's Fresnel, one scattering), at the same
pixels. ``--json`` writes the table that ``tests/test_gloss.py`` holds the renderer to.

    python benchmarks/gloss_albedo_vs_cycles.py --json docs/gloss_albedo_vs_cycles.json

bpy runs in a child process (this script with ``--render``), fed by its arguments.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

SIZE = 128  # pixels across the sphere's image
BANDS = ((0.15, 0.3), (0.3, 0.5), (0.5, 0.7), (0.7, 0.85), (0.85, 1.0))  # n.v bins
EDGE = 0.97  # pixels within this squared radius (the silhouette's anti-aliased ring left out)


def _render(out: Path, roughness: list[float], samples: int) -> None:
    """(child process) one EXR per roughness of the sphere's red channel -> ``out``/albedo.json."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_denoising = False
    sc.cycles.max_bounces = 1
    sc.cycles.seed = 1
    sc.render.resolution_x = sc.render.resolution_y = SIZE
    sc.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("white")
    sc.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[0].default_value = (1.0, 1.0, 1.0, 1.0)
    world.node_tree.nodes["Background"].inputs[1].default_value = 1.0
    bpy.ops.mesh.primitive_uv_sphere_add(segments=256, ring_count=128, radius=1.0)
    ob = bpy.context.object
    bpy.ops.object.shade_smooth()
    mat = bpy.data.materials.new("black")
    mat.use_nodes = True
    ob.data.materials.append(mat)
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    cam = bpy.data.cameras.new("ortho")
    cam.type = "ORTHO"
    cam.ortho_scale = 2.0
    co = bpy.data.objects.new("ortho", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    co.location = (0.0, -5.0, 0.0)
    co.rotation_euler = (np.pi / 2, 0.0, 0.0)
    sc.render.image_settings.file_format = "OPEN_EXR"
    res = {}
    for r in roughness:
        bsdf.inputs["Roughness"].default_value = r
        sc.render.filepath = str(out / f"r{r}.exr")
        bpy.ops.render.render(write_still=True)
        img = bpy.data.images.load(sc.render.filepath)
        res[repr(r)] = np.array(img.pixels[:], np.float64).reshape(SIZE, SIZE, 4)[..., 0].tolist()
    (out / "albedo.json").write_text(json.dumps({"blender": bpy.app.version_string, "images": res}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--roughness", default="0.2,0.4,0.6,0.85", help="comma-separated Principled roughness values")
    ap.add_argument("--samples", type=int, default=256, help="Cycles samples per pixel")
    ap.add_argument("--json", type=Path, help="write the table here")
    ap.add_argument("--render", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    rough = [float(x) for x in a.roughness.split(",")]
    if a.render is not None:
        _render(a.render, rough, a.samples)
        return 0

    from zcomp_cli.renderers.physical.gloss import DIELECTRIC_F0, env_brdf, specular_albedo

    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, __file__, "--render", tmp, "--roughness", a.roughness,
                        "--samples", str(a.samples)], check=True, stdout=subprocess.DEVNULL)
        got = json.loads((Path(tmp) / "albedo.json").read_text())
    c = (np.arange(SIZE) + 0.5) / SIZE * 2.0 - 1.0
    X, Y = np.meshgrid(c, c)
    rr = X * X + Y * Y
    ndv = np.sqrt(np.clip(1.0 - rr, 0.0, 1.0))
    rows = []
    print(f"Cycles {got['blender']}, {a.samples} samples: dielectric specular albedo by n.v band "
          "(cycles | zcomp | earlier: Schlick, one scattering)")
    for r in rough:
        img = np.array(got["images"][repr(r)])
        for lo, hi in BANDS:
            m = (rr < EDGE) & (ndv >= lo) & (ndv < hi)
            k = int(m.sum())
            ours = specular_albedo(np.full(k, r), ndv[m], np.full((k, 1), DIELECTRIC_F0), fresnel="dielectric")
            a_s, b_s = env_brdf(np.full(k, r), ndv[m], fresnel="schlick")
            row = {"roughness": r, "ndv_lo": lo, "ndv_hi": hi, "pixels": k, "cycles": float(img[m].mean()),
                   "zcomp": float(ours.mean()), "earlier": float((DIELECTRIC_F0 * a_s + b_s).mean())}
            rows.append(row)
            print(f"  roughness {r:.2f}  n.v {lo:.2f}-{hi:.2f}: {row['cycles']:.4f} | {row['zcomp']:.4f} "
                  f"({row['zcomp'] / row['cycles'] - 1:+.1%}) | {row['earlier']:.4f} "
                  f"({row['earlier'] / row['cycles'] - 1:+.1%})")
    if a.json is not None:
        a.json.write_text(json.dumps({"blender": got["blender"], "samples": a.samples, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
