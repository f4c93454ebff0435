"""The share of the sky the scene's depth mesh leaves each support pixel
(scene/skyvis.py ``mesh_sky_view``, ``support_sky_view``): against the view factor of a
long wall, on an open floor, on the lattice's spread against every pixel traced."""

import numpy as np
import pytest

from zcomp_cli.scene.depthmesh import build_depth_mesh
from zcomp_cli.scene.frame import scene_up
from zcomp_cli.scene.skyvis import mesh_sky_view, support_sky_view
from zcomp_cli.testing import floor_scene

W, H = 160, 120
WALL_H, WALL_Z = 1.5, -5.0
# a wall 1.5 m high across the frame (30 m long), 5 m ahead, its top edge seen
WALL = [((0.0, WALL_Z), (30.0, WALL_H, 0.3))]


def _mesh(**kw):
    s = floor_scene(W, H, pitch_deg=-10.0, **kw)
    up, _ = scene_up(None, s.normals, s.depth > 0)
    return s, build_depth_mesh(s.depth, s.normals, s.camera, up)


def _hidden_by_rectangle(p, x0, x1, height, face, n=400):
    """The cosine-weighted share of the upper hemisphere of the world point ``p`` (on the
    floor, y = 0) that the rectangle ``x0 <= x <= x1``, ``0 <= y <= height`` in the
    plane ``z = face`` hides: a midpoint rule on the disc (Nusselt's analogue)."""
    r = (np.arange(n) + 0.5) / n
    ph = (np.arange(4 * n) + 0.5) / (4 * n) * 2 * np.pi
    rr, pp = np.meshgrid(np.sqrt(r), ph, indexing="ij")
    d = np.stack([rr * np.cos(pp), np.sqrt(1 - rr ** 2), rr * np.sin(pp)], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (face - p[2]) / d[..., 2]
    hx, hy = p[0] + t * d[..., 0], t * d[..., 1]
    return float(((t > 0) & (hx >= x0) & (hx <= x1) & (hy <= height)).mean())


@pytest.mark.parametrize("x", [0.1, 0.5, 1.0, 2.0])
def test_the_share_before_a_wall_is_its_view_factor(x):
    # a patch of floor x in front of the wall sees all the sky but what the wall's part
    # in the frame hides (the mesh holds what the frame shows: no walls beyond it are
    # given here); for x << the wall's width, the long wall's (1 - x / sqrt(x^2 + H^2)) / 2
    s, m = _mesh(occluders=WALL)
    face = WALL_Z + 0.15  # (the box's face toward the camera)
    wall = (s.depth > 0) & (np.abs(s.normals @ m.up) < 0.2)
    wx = (m.points[wall] @ s.cam_to_world.T + s.camera_origin)[:, 0]
    world = np.array([0.0, 0.0, face + x])
    p = (world - s.camera_origin) @ s.cam_to_world  # camera frame
    v = mesh_sky_view(p[None], m.up, m.caster(), directions=1024, bias_rel=1e-3)[0]
    want = 1.0 - _hidden_by_rectangle(world, wx.min(), wx.max(), WALL_H, face)
    assert abs(v - want) < 0.01, (v, want)
    if x <= 0.5:
        assert abs(v - (1.0 - 0.5 * (1.0 - x / np.hypot(x, WALL_H)))) < 0.015


def test_an_open_floor_sees_the_whole_sky():
    s, m = _mesh()
    v = support_sky_view(m.points, m.support, m.up, m.caster(), directions=256, stride=2, bias_rel=1e-3)
    assert v.shape == (H, W) and (v == 1.0).all()
    assert mesh_sky_view(np.zeros((0, 3)), m.up, m.caster(), directions=8, bias_rel=1e-3).shape == (0,)


def test_the_lattices_spread_is_the_share_traced_at_every_pixel():
    s, m = _mesh(occluders=WALL)
    c = m.caster()
    v = support_sky_view(m.points, m.support, m.up, c, directions=256, stride=2, bias_rel=1e-3)
    full = np.ones((H, W))
    full[m.support] = mesh_sky_view(m.points[m.support], m.up, c, directions=256, bias_rel=1e-3)
    assert (v[~m.support] == 1.0).all() and v.min() >= 0.0
    d = np.abs(v - full)[m.support]
    assert float(np.percentile(d, 99)) < 0.05 and float(d.max()) < 0.08
    assert float(full[m.support].min()) < 0.7  # (the wall's foot: the shares do vary)
