"""A lamp near or inside the object (issue 50, defect 2): the lamp's shadow map
(``scene.objectshadow.mesh_shadow_point``) sized its grid from the samples' gnomonic tangents,
which reach ~1e5 on triangles crossing the lamp's plane (a lamp 1 cm beside a 0.3 m box
peaked at 11 GB, 5 cm beside it asked for 907 GiB). The grid now covers only the field
the receivers need, samples at or behind the lamp's plane are dropped, and its cells are
budgeted like an image.

Each case runs in a child process under an address-space limit, so that the unbounded
grid fails fast (MemoryError) instead of taking the machine's memory."""

from __future__ import annotations

import json
import resource
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
LIMIT_BYTES = 3 << 30  # the child's address space: far above a bounded grid, far below the old asks

CHILD = r"""
import json, sys, tracemalloc
import numpy as np
import trimesh
from zcomp_cli.posed_mesh import PosedMesh
from zcomp_cli.scene import objectshadow as meshshadow

case = json.loads(sys.argv[1])
box = trimesh.creation.box(extents=[0.3, 0.3, 0.3])
box.apply_translation([0.0, -1.0 + 0.15, -3.0])  # standing on the floor y = -1, 3 m away
mesh = PosedMesh(np.asarray(box.vertices, np.float64), np.asarray(box.faces, np.int64))
lamp = np.array(case["lamp"], np.float64)
xs, zs = np.meshgrid(np.linspace(-2, 2, 128), np.linspace(-5, -1.5, 96))
P = np.stack([xs.ravel(), np.full(xs.size, -1.0), zs.ravel()], 1)  # the floor, 128 x 96 receivers
N = np.tile([0.0, 1.0, 0.0], (len(P), 1))
probe = np.array(case["probe"], np.float64)
tracemalloc.start()
vis, t = meshshadow.mesh_shadow_point(mesh, np.vstack([P, probe]), np.vstack([N, np.tile([0.0, 1.0, 0.0], (len(probe), 1))]), lamp)
peak = tracemalloc.get_traced_memory()[1]
print(json.dumps({"peak": peak, "probe_vis": vis[len(P):].tolist(), "shadowed": float(1 - vis[:len(P)].mean())}))
"""


def _run(lamp, probe) -> dict:
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT_BYTES, LIMIT_BYTES))

    r = subprocess.run([sys.executable, "-c", CHILD, json.dumps({"lamp": lamp, "probe": probe})],
                       capture_output=True, text=True, preexec_fn=limit, env={"PYTHONPATH": str(SRC)})
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("gap", [0.01, 0.05])
def test_a_lamp_beside_the_box_takes_bounded_memory(gap):
    """The lamp at the box's height, ``gap`` metres right of its side: the floor left of
    the box (away from the lamp) is shadowed, the floor right of the lamp is lit."""
    x1 = 0.15
    got = _run([x1 + gap, -1.0 + 0.15, -3.0], [[-0.4, -1.0, -3.0], [0.8, -1.0, -3.0]])
    assert got["peak"] < 400e6, got["peak"]
    assert got["probe_vis"] == [0.0, 1.0]


def test_a_lamp_inside_the_box_shadows_the_floor_it_faces():
    """A lamp in a closed lampshade: every floor point in front of it is in shadow."""
    got = _run([0.0, -1.0 + 0.2, -3.0], [[-0.4, -1.0, -2.5], [0.4, -1.0, -3.5]])
    assert got["peak"] < 400e6, got["peak"]
    assert got["probe_vis"] == [0.0, 0.0]
