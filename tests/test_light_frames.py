"""World up, the ground frame and the probe conventions (worldframe, equirect)."""

import math

import numpy as np
import pytest

from zcomp_cli import equirect
from zcomp_cli.worldframe import (angles_from_direction, direction_from_angles, ground_frame, pitch_roll_from_up,
                                  up_from_pitch_roll)


def test_up_from_pitch_roll_known_values():
    assert np.allclose(up_from_pitch_roll(0, 0), [0, 1, 0])
    # looking down 30 deg: world up tilts toward the viewer (+z)
    assert np.allclose(up_from_pitch_roll(-30, 0), [0, math.cos(math.radians(30)), math.sin(math.radians(30))])
    # rolled counter-clockwise: the horizon drops on the right, up leans to the right
    u = up_from_pitch_roll(0, 20)
    assert u[0] > 0 and np.isclose(np.linalg.norm(u), 1)
    for p, r in ((-35.0, 12.0), (10.0, -25.0), (-80.0, 0.0)):
        assert np.allclose(pitch_roll_from_up(up_from_pitch_roll(p, r)), (p, r), atol=1e-9)


@pytest.mark.parametrize("up", [(0, 1, 0), up_from_pitch_roll(-30, 10), up_from_pitch_roll(-89.9, 0),
                                up_from_pitch_roll(40, -15)])
def test_ground_frame_is_right_handed_and_forward_is_the_view(up):
    r, u, f = ground_frame(up)
    assert np.allclose(np.stack([r, u, f]) @ np.stack([r, u, f]).T, np.eye(3), atol=1e-9)
    assert np.allclose(np.cross(f, u), r)
    assert f[2] <= 1e-9 or abs(u[2]) > 0.99  # forward looks away from the viewer
    assert r[0] > 0  # the camera's right stays on the right


def test_azimuth_elevation_round_trip_and_meaning():
    up = up_from_pitch_roll(-25, 5)
    r, u, f = ground_frame(up)
    assert np.allclose(direction_from_angles(0, 0, up), r)
    assert np.allclose(direction_from_angles(90, 0, up), f)
    assert np.allclose(direction_from_angles(37, 90, up), u)
    for az, el in ((10.0, 20.0), (135.0, 45.0), (300.0, 70.0)):
        assert np.allclose(angles_from_direction(direction_from_angles(az, el, up), up), (az, el), atol=1e-9)


def _skylibs_world2latlong(x, y, z):
    # lvsn/skylibs envmap/projections.py, world2latlong (+x right, +y up, +z toward the camera)
    u = 1 + (1 / np.pi) * np.arctan2(x, -z)
    v = (1 / np.pi) * np.arccos(y)
    return u / 2, v


def test_skylibs_convention_is_zcomps_on_known_values():
    frame = ground_frame((0, 1, 0))  # a level camera: skylibs' frame is the camera's
    H, W = 16, 32
    d = equirect.pixel_directions(H, W, frame, "skylibs")
    u, v = _skylibs_world2latlong(d[..., 0], d[..., 1], d[..., 2])
    uu = (np.arange(W) + 0.5) / W
    vv = (np.arange(H) + 0.5) / H
    assert np.allclose(u % 1.0, uu[None].repeat(H, 0) % 1.0, atol=1e-9)
    assert np.allclose(v, vv[:, None].repeat(W, 1), atol=1e-9)
    assert np.allclose(equirect.pixel_directions(H, W, frame, "zcomp"), d)


def test_zcomp_convention_known_columns():
    frame = ground_frame((0, 1, 0))
    H, W = 8, 16
    d = equirect.pixel_directions(H, W, frame, "zcomp", rotation_deg=0.0)
    mid = d[H // 2 - 1:H // 2 + 1, W // 2 - 1:W // 2 + 1].mean((0, 1))
    assert np.allclose(mid / np.linalg.norm(mid), [0, 0, -1], atol=1e-9)  # forward
    # a quarter turn to the right of the centre column looks right (+x)
    q = d[H // 2 - 1:H // 2 + 1, 3 * W // 4 - 1:3 * W // 4 + 1].mean((0, 1))
    assert np.allclose(q / np.linalg.norm(q), [1, 0, 0], atol=1e-9)
    assert np.allclose(d[0].mean(0) / np.linalg.norm(d[0].mean(0)), [0, 1, 0])  # row 0 is up
    # rotation turns the probe toward the right: what was forward is now at azimuth +90
    dr = equirect.pixel_directions(H, W, frame, "zcomp", rotation_deg=90.0)
    m = dr[H // 2 - 1:H // 2 + 1, W // 2 - 1:W // 2 + 1].mean((0, 1))
    assert np.allclose(m / np.linalg.norm(m), [1, 0, 0], atol=1e-9)


def test_blender_convention_against_its_formula():
    # Blender's world mapping: u = 0.5 - atan2(d.y, d.x) / 2 pi, v_from_bottom = 0.5 +
    # asin(d.z) / pi, world +Z up. A camera with Z rotation psi looks along
    # (-sin psi, cos psi, 0) on the ground.
    psi = 30.0
    fwd_w = np.array([-math.sin(math.radians(psi)), math.cos(math.radians(psi)), 0.0])
    right_w = np.cross(fwd_w, [0, 0, 1.0])
    frame = ground_frame((0, 1, 0))
    H, W = 16, 32
    d = equirect.pixel_directions(H, W, frame, "blender", rotation_deg=psi)
    r, u, f = frame
    # camera-frame direction -> Blender world: (right, up, forward) -> (right_w, +Z, fwd_w)
    dw = (d @ r)[..., None] * right_w + (d @ u)[..., None] * np.array([0, 0, 1.0]) + (d @ f)[..., None] * fwd_w
    ub = (0.5 - np.arctan2(dw[..., 1], dw[..., 0]) / (2 * np.pi)) % 1.0
    vb = 0.5 + np.arcsin(np.clip(dw[..., 2], -1, 1)) / np.pi
    uu = (np.arange(W) + 0.5) / W
    vv = 1.0 - (np.arange(H) + 0.5) / H
    assert np.allclose(ub, uu[None].repeat(H, 0), atol=1e-9)
    assert np.allclose(vb, vv[:, None].repeat(W, 1), atol=1e-9)


def test_mirrored_and_round_trip():
    frame = ground_frame(up_from_pitch_roll(-20, 8))
    for conv in equirect.CONVENTIONS:
        d = equirect.pixel_directions(8, 16, frame, conv, rotation_deg=37.0)
        for i, j in ((1, 2), (4, 9), (6, 15)):
            u, v = equirect.direction_to_uv(d[i, j], frame, conv, rotation_deg=37.0)
            assert np.isclose(u, (j + 0.5) / 16) and np.isclose(v, (i + 0.5) / 8)
    a = equirect.pixel_directions(8, 16, frame, "zcomp")
    b = equirect.pixel_directions(8, 16, frame, "mirrored")
    assert np.allclose(a, b[:, ::-1])


def test_solid_angles_sum_to_the_sphere():
    assert np.isclose(equirect.solid_angles(33, 64).sum(), 4 * np.pi)


def test_bad_arguments():
    with pytest.raises(ValueError):
        equirect.pixel_directions(4, 8, ground_frame((0, 1, 0)), "upside-down")
    with pytest.raises(ValueError):
        equirect.pixel_directions(0, 8, ground_frame((0, 1, 0)))
    with pytest.raises(ValueError):
        ground_frame((0, 0, 0))
    with pytest.raises(ValueError):
        ground_frame((np.nan, 1, 0))
