"""A tiny mesh-free zcomp project for hostile-input tests and the fuzz suite: one
floor scene with provided maps, a sphere bundle object and an image object. No
Blender is needed, so a whole `zcomp composite` takes well under a second."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from zcomp_cli.imageio import write_exr, write_png
from zcomp_cli.testing import floor_scene, sphere_object_bundle

W, H = 32, 24


def make_project(root: Path, *, width: int = W, height: int = H) -> Path:
    """Write scenes/, objects/ and a valid jobs.yaml under ``root``; return its path."""
    root = Path(root)
    (root / "scenes").mkdir(parents=True, exist_ok=True)
    (root / "objects").mkdir(parents=True, exist_ok=True)
    sc = floor_scene(width, height, with_box=False)
    write_png(root / "scenes/room.png", sc.image)
    write_exr(root / "scenes/depth.exr", sc.depth)
    write_exr(root / "scenes/normals.exr", sc.normals)
    write_exr(root / "scenes/albedo.exr", sc.albedo)
    centre = sc.world_to_camera([0.0, 0.3, -3.0])  # a ball resting on the floor
    b = sphere_object_bundle(sc.camera, center=centre, radius=0.3, floor_normal=sc.up_cam, supersample=2)
    b.save(root / "objects/ball")
    img = np.zeros((16, 16, 3), np.float32) + np.float32([0.6, 0.2, 0.1])
    mask = np.zeros((16, 16), np.float32)
    mask[3:13, 4:12] = 1.0
    write_png(root / "objects/card.png", img)
    write_png(root / "objects/card_mask.png", mask, srgb_encode=False)
    doc = base_manifest(width, height)
    p = root / "jobs.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def write_manifest(project: Path, doc, name: str = "m.yaml") -> Path:
    """Write ``doc`` (a dict, or YAML text as is) to ``project/name``; return the path."""
    p = Path(project) / name
    p.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc, sort_keys=False))
    return p


def run_composite(manifest, out, *extra):
    """``zcomp -q composite MANIFEST --out OUT ...`` in process; a Python exception other
    than the CLI's exit fails the calling test."""
    from click.testing import CliRunner

    from zcomp_cli.cli import cli

    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(out), *map(str, extra)])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    return r


def textured_quad(folder: Path) -> Path:
    """A textured quad mesh, OBJ -> MTL -> PNG, in ``folder``; returns the OBJ."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_png(folder / "tex.png", np.random.default_rng(0).random((8, 8, 3)).astype(np.float32))
    (folder / "quad.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    (folder / "quad.obj").write_text(
        "mtllib quad.mtl\nv -0.5 0 0\nv 0.5 0 0\nv 0.5 1 0\nv -0.5 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    return folder / "quad.obj"


def base_manifest(width: int = W, height: int = H) -> dict:
    return {
        "version": 1,
        "defaults": {"renderer": "naive"},
        "scenes": {"room": {"image": "scenes/room.png", "fov_deg": 50, "depth": "scenes/depth.exr",
                            "normals": "scenes/normals.exr", "albedo": "scenes/albedo.exr"}},
        "objects": {"ball": {"bundle": "objects/ball"},
                    "card": {"image": "objects/card.png", "mask": "objects/card_mask.png"}},
        "jobs": [
            {"scene": "room", "object": "ball", "pose": {"position": [0.0, -1.2, -3.0]}},
            {"scene": "room", "object": "card", "placement": {"pixel": [width / 2, height * 0.8], "height": 0.4}},
        ],
    }


def default_signals() -> None:
    """``preexec_fn`` for a child the test will signal: SIGINT, SIGTERM and SIGHUP at their
    default dispositions, whatever the test runner inherited (a shell's background job
    ignores SIGINT, ``nohup`` SIGHUP, and zcomp rightly keeps an ignored signal ignored)."""
    import signal

    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)
