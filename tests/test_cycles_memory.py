"""The cycles renderer's memory (issue 50, defect 6): it meshed the whole frame's depth
(in zcomp and again in Blender, ~1 KB a pixel) though Cycles traces only a window.
A large frame is now meshed at full resolution around the window and coarsely
elsewhere, and a job's working size is budgeted by what its renderer costs a pixel."""

from __future__ import annotations

import tracemalloc
from types import SimpleNamespace

import numpy as np

from zcomp_cli.renderers.cycles import scene as sc
from zcomp_cli.testing import floor_scene


def _model(up):
    return SimpleNamespace(up=np.asarray(up, np.float64), walls=(),
                           albedo_offset=lambda points, normals, albedo: np.zeros((np.size(albedo) // 3, 3)))


def _arrays(s, box):
    from zcomp_cli.scene.depthmesh import has_geometry

    valid = has_geometry(s.depth.astype(np.float64), s.normals.astype(np.float64))
    tracemalloc.start()
    out = sc.scene_arrays(s.depth, s.normals, s.albedo, valid, s.camera, _model(s.up_cam), box)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, peak


def test_a_large_frame_is_meshed_finely_only_around_the_window():
    s = floor_scene(1600, 1200, with_box=True)
    box = (700, 700, 900, 900)  # a 200 x 200 window
    whole, peak_whole = _arrays(s, None)
    part, peak_part = _arrays(s, box)
    assert len(part["vertices"]) < 0.25 * len(whole["vertices"])
    assert peak_part < 0.4 * peak_whole, (peak_part, peak_whole)
    # inside the window, the very vertices of the whole frame's mesh (the same rays, depths)
    x0, y0, x1, y1 = box
    P = s.camera.unproject(s.depth)[y0:y1, x0:x1].reshape(-1, 3)
    have = {tuple(v) for v in np.round(part["vertices"].astype(np.float64), 4)}
    assert all(tuple(v) in have for v in np.round(P.astype(np.float32).astype(np.float64), 4)[::97])
    # and the coarse rest spans the frame as the whole mesh does
    lo, hi = part["vertices"].min(0), part["vertices"].max(0)
    wlo, whi = whole["vertices"].min(0), whole["vertices"].max(0)
    assert np.allclose(lo, wlo, atol=0.2 * np.abs(wlo).max()) and np.allclose(hi, whi, atol=0.2 * np.abs(whi).max())


def test_a_small_frame_is_meshed_whole_as_before():
    s = floor_scene(320, 240, with_box=True)
    whole, _ = _arrays(s, None)
    part, _ = _arrays(s, (100, 100, 150, 150))
    for k in ("vertices", "faces", "colors"):
        np.testing.assert_array_equal(whole[k], part[k])


def test_a_scene_too_large_for_the_cycles_renderer_is_refused(tmp_path, monkeypatch):
    """The pixel budget is set for 0.3 KB a pixel; the cycles renderer costs about 1:
    a working size within the budget for the physical renderer is refused for cycles,
    naming the scene, before anything is written."""
    from hostile_project import make_project, run_composite

    make_project(tmp_path)  # 32 x 24 = 768 pixels
    monkeypatch.setenv("ZCOMP_MAX_PIXELS", "1000")
    out = tmp_path / "out"
    r = run_composite(tmp_path / "jobs.yaml", out, "--renderer", "cycles")
    assert r.exit_code == 2 and "scene 'room'" in r.output and "cycles" in r.output, r.output
    assert not out.exists()
    assert run_composite(tmp_path / "jobs.yaml", out).exit_code == 0  # naive: within its budget
