"""The shipped example (examples/): files exist, agree in size, follow the map
conventions, and its jobs.yaml loads with every object in the frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from zcomp_cli.imageio import read_image, read_map

EX = Path(__file__).resolve().parents[1] / "examples"
ROOM = EX / "scenes" / "room"


def test_example_files_exist():
    for rel in ("jobs.yaml", "README.md", "make_example.py", "scenes/room/image.png", "scenes/room/depth.exr",
                "scenes/room/normals.exr", "scenes/room/albedo.exr", "scenes/room/scene.json",
                "objects/vase.glb", "objects/crate.glb", "refs/vase_pose.exr"):
        assert (EX / rel).is_file(), rel
    total = sum(p.stat().st_size for p in EX.rglob("*") if p.is_file())
    assert total < 5 * 2**20  # small enough to commit


def test_example_maps_are_consistent():
    img = read_image(ROOM / "image.png")
    depth = read_map(ROOM / "depth.exr")
    normals = read_map(ROOM / "normals.exr")
    albedo = read_map(ROOM / "albedo.exr")
    ref = read_image(EX / "refs" / "vase_pose.exr")
    h, w = depth.shape
    assert (w, h) == (512, 384)
    assert img.shape == normals.shape == albedo.shape == ref.shape == (h, w, 3)
    for a in (img, depth, normals, albedo, ref):
        assert np.all(np.isfinite(a))
    assert depth.dtype == normals.dtype == albedo.dtype == np.float32
    valid = depth > 0
    assert valid.mean() > 0.95  # floor and walls fill the view
    np.testing.assert_allclose(np.linalg.norm(normals[valid], axis=-1), 1.0, atol=1e-4)
    assert albedo.min() >= 0 and albedo.max() <= 1
    # Floor normals (bottom rows) point up in the camera frame: +y, toward the camera.
    up = normals[-5:, :, :].reshape(-1, 3).mean(axis=0)
    assert up[1] > 0.9 and up[2] > 0
    # The shadows and lit floor give a real dynamic range.
    lum = img.mean(axis=-1)
    assert np.quantile(lum, 0.95) > 3 * np.quantile(lum, 0.05)


def test_example_depth_matches_the_scene_description():
    from zcomp_cli.benchsuite.scenes import BenchScene, floor_depth

    sc = BenchScene.from_dict(json.loads((ROOM / "scene.json").read_text())["scene"])
    fd = floor_depth(sc)
    depth = read_map(ROOM / "depth.exr")
    assert depth[-1, 256] == pytest.approx(fd[-1, 256], rel=1e-4)


def test_example_textured_object_has_a_texture():
    import trimesh

    scene = trimesh.load(EX / "objects" / "crate.glb", force="scene")
    geom = list(scene.geometry.values())[0]
    assert geom.visual.material.baseColorTexture is not None
    plain = list(trimesh.load(EX / "objects" / "vase.glb", force="scene").geometry.values())[0]
    assert getattr(plain.visual.material, "baseColorTexture", None) is None


def test_example_jobs_load_and_stay_in_frame():
    from zcomp_cli.blender.meshes import load_mesh_info
    from zcomp_cli.camera import Camera
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.placement import pose_from_placement
    from zcomp_cli.pose import transform_points

    m = load_manifest(EX / "jobs.yaml")
    assert 3 <= len(m.jobs) <= 6
    assert any(j.pose is not None for j in m.jobs) and any(j.placement is not None for j in m.jobs)
    assert any(j.reference is not None for j in m.jobs)
    depth = read_map(ROOM / "depth.exr")
    normals = read_map(ROOM / "normals.exr")
    cam = Camera.from_fov(m.scenes["room"].fov_deg, 512, 384)
    for j in m.jobs:
        info = load_mesh_info(m.objects[j.object].mesh)
        pose = j.pose if j.pose is not None else pose_from_placement(j.placement, depth, normals, cam)
        px, z = cam.project(transform_points(pose.object_to_camera(info.bbox_min, info.bbox_max), info.vertices))
        assert np.all(z > 0)
        assert px[:, 0].min() >= 0 and px[:, 0].max() <= 512 and px[:, 1].min() >= 0 and px[:, 1].max() <= 384
        frac = (px[:, 1].max() - px[:, 1].min()) / 384
        assert 0.1 <= frac <= 0.25, (j.name, frac)
