"""Make the shipped example: a room rendered once with Blender/Cycles, two objects, jobs.

    .venv/bin/python examples/make_example.py [--samples 128] [--out examples]

Writes (all small files, committed to the repository):

* ``scenes/room/image.png`` (sRGB), ``depth.exr``, ``normals.exr``, ``albedo.exr``
  (float32, zip), ``scene.json``: a floor with a back wall and a left wall, lit by
  Blender's bundled ``courtyard`` HDR map and a sun lamp casting crisp shadows, with a
  box already standing in the room (its shadow is light evidence);
* ``objects/vase.glb`` (untextured, linear base colour) and ``objects/crate.glb``
  (checker base-colour texture), made with trimesh;
* ``jobs.yaml``: four jobs (``pose:`` and ``placement:`` forms);
* ``refs/vase_pose.exr`` + ``.png``: the ground truth of the first job, rendered by
  Cycles with the object in the scene (same samples and seed as the background).

Deterministic: no random numbers; rerunning reproduces the files (up to Cycles noise
across Blender versions).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from zcomp_cli.benchsuite.generate import exposure_scale
from zcomp_cli.benchsuite.objects import ObjectRecipe, write_object_glb
from zcomp_cli.benchsuite.render import render_scenes
from zcomp_cli.benchsuite.scenes import BenchScene, Box, Lamp, Material, Wall, scene_for_blender
from zcomp_cli.blender.meshes import load_mesh_info
from zcomp_cli.imageio import write_exr, write_json_atomic, write_png, write_text_atomic
from zcomp_cli.pose import Pose, euler_deg_to_matrix, transform_points

WIDTH, HEIGHT = 512, 384
SEED = 7

ROOM = BenchScene(
    width=WIDTH, height=HEIGHT, fov_deg=55.0, camera_height=1.4, pitch_deg=22.0,
    hdr="courtyard", hdr_rotation_deg=60.0, hdr_strength=0.8,
    floor=Material(color=(0.42, 0.30, 0.20), roughness=0.55, checker_color=(0.30, 0.20, 0.13), checker_size=0.5),
    walls=(Wall("back", 5.0, Material((0.70, 0.68, 0.62), 0.9)),
           Wall("left", 2.6, Material((0.55, 0.62, 0.70), 0.9))),
    boxes=(Box(x=1.1, z=-3.6, size=(0.45, 0.55, 0.45), yaw_deg=25.0, material=Material((0.65, 0.12, 0.08), 0.5)),),
    lamps=(Lamp("SUN", direction=(0.55, -0.75, -0.35), strength=3.0, angle_deg=3.0),),
)

OBJECTS = {
    "vase": ObjectRecipe("vase", color=(0.10, 0.25, 0.55), roughness=0.35, aspect=0.55),
    "crate": ObjectRecipe("box", color=(0.80, 0.62, 0.30), color2=(0.25, 0.12, 0.05), texture="checker",
                          roughness=0.7, aspect=1.0),
}

# Poses given in the scene frame (Y up, floor at y = -camera_height): (x, z, yaw, height).
POSE_JOBS = [("vase", -0.45, -2.7, 0.0, 0.45), ("crate", 0.35, -2.2, 30.0, 0.25)]
# Placement jobs: (object, pixel [x, y], yaw, height) -- the base point is the floor
# point seen through the pixel.
PLACEMENT_JOBS = [("crate", (150, 330), -20.0, 0.25), ("vase", (330, 250), 0.0, 0.4)]


def pose_in_camera(scene: BenchScene, x: float, z: float, yaw: float, height: float) -> Pose:
    R = scene.scene_to_camera
    base = R @ np.array([x, -scene.camera_height, z])
    return Pose(position=tuple(base), rotation=R @ euler_deg_to_matrix(0.0, yaw, 0.0), height=height)


def check_in_frame(scene: BenchScene, info, pose: Pose, what: str) -> tuple[float, float]:
    """Raise if the object leaves the frame; return its top and bottom image rows."""
    cam = scene.camera
    pts = transform_points(pose.object_to_camera(info.bbox_min, info.bbox_max), info.vertices)
    px, depth = cam.project(pts)
    if np.any(depth <= 0) or px[:, 0].min() < 0 or px[:, 0].max() > cam.width or \
            px[:, 1].min() < 0 or px[:, 1].max() > cam.height:
        raise SystemExit(f"{what}: object leaves the frame")
    return float(px[:, 1].min()), float(px[:, 1].max())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent))
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--no-denoise", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out)

    # 1. objects
    infos = {}
    for name, recipe in OBJECTS.items():
        path = write_object_glb(recipe, out / "objects" / f"{name}.glb")
        infos[name] = load_mesh_info(path)

    # 2. jobs (checked to stay in the frame at 10-25% of its height)
    jobs = []
    poses = []
    for name, x, z, yaw, h in POSE_JOBS:
        pose = pose_in_camera(ROOM, x, z, yaw, h)
        top, bottom = check_in_frame(ROOM, infos[name], pose, name)
        print(f"{name}: pose job, {100 * (bottom - top) / HEIGHT:.0f}% of the frame height")
        d = pose.to_dict()
        jobs.append({"scene": "room", "object": name,
                     "pose": {"position": [round(v, 5) for v in d["position"]],
                              "quaternion": [round(v, 7) for v in d["quaternion"]], "height": h}})
        poses.append((name, pose))
    for name, pixel, yaw, h in PLACEMENT_JOBS:
        jobs.append({"scene": "room", "object": name,
                     "placement": {"pixel": list(pixel), "yaw_deg": yaw, "height": h}})
    jobs[0]["reference"] = "refs/vase_pose.exr"

    # 3. render the background and the ground truth of the first job
    desc = scene_for_blender(ROOM)
    common = {"samples": args.samples, "seed": SEED, "denoise": not args.no_denoise, "max_bounces": 8,
              "scene": desc}
    name0, pose0 = poses[0]
    info0 = infos[name0]
    tmp = out / ".render_tmp"
    items = [{"id": "bg", "out_dir": str(tmp / "bg"), "object": None, **common},
             {"id": "gt", "out_dir": str(tmp / "gt"), **common,
              "object": {"mesh": str(info0.path), "format": info0.format,
                         "mesh_to_camera": pose0.object_to_camera(info0.bbox_min, info0.bbox_max).tolist()}}]
    maps = render_scenes(items, on_event=lambda ev: print(ev.get("event"), ev.get("id", ""), flush=True))
    bg, gt = maps["bg"], maps["gt"]
    scale = exposure_scale(bg.image, 0.8)

    sdir = out / "scenes" / "room"
    write_png(sdir / "image.png", bg.image * scale)
    write_exr(sdir / "depth.exr", bg.depth)
    write_exr(sdir / "normals.exr", bg.normals)
    write_exr(sdir / "albedo.exr", bg.albedo)
    write_json_atomic(sdir / "scene.json", {"scene": ROOM.to_dict(), "exposure": scale, "seed": SEED,
                                            "samples": args.samples, "K": ROOM.camera.K.tolist()})
    # The reference in half float: it is compared, not computed with, and stays small.
    write_exr(out / "refs" / "vase_pose.exr", gt.image * scale, half=True)
    write_png(out / "refs" / "vase_pose.png", gt.image * scale)
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)

    # 4. the manifest
    import yaml

    doc = {"version": 1,
           "defaults": {"renderer": "physical", "resolution": [WIDTH, HEIGHT], "shading_radius": 1.0, "seed": 469},
           "scenes": {"room": {"image": "scenes/room/image.png", "fov_deg": ROOM.fov_deg,
                               "depth": "scenes/room/depth.exr", "normals": "scenes/room/normals.exr",
                               "albedo": "scenes/room/albedo.exr"}},
           "objects": {name: {"mesh": f"objects/{name}.glb"} for name in OBJECTS},
           "jobs": jobs}
    header = ("# The shipped example (made by examples/make_example.py): `zcomp composite examples/jobs.yaml`.\n"
              "# Poses are in the camera frame (x right, y up, looking along -z), metres.\n")
    write_text_atomic(out / "jobs.yaml", header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
    print(f"exposure {scale:.4g}; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
