"""Ground-plane proxy and normals-from-depth against analytic geometry."""

import math

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError
from zcomp_cli.estimators.ground_plane import (GroundPlaneSpec, floor_mask, ground_plane_depth,
                                               pitch_from_horizon)
from zcomp_cli.estimators.normals_from_depth import normals_from_depth


def _world_floor_depth(cam, h, pitch_deg, roll_deg=0.0):
    """Independent reference: a camera at (0, h, 0) in a Y-up world, rotated by pitch
    about x then roll about its own z, intersecting rays with the plane y = 0."""
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    Rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    R = Rx @ Rz  # camera -> world
    rays_w = cam.pixel_rays() @ R.T
    with np.errstate(divide="ignore"):
        s = np.where(rays_w[..., 1] < 0, -h / rays_w[..., 1], np.inf)
    return s  # the camera-frame ray has z = -1, so s is the z-depth


@pytest.mark.parametrize("pitch,roll", [(-10, 0), (-35, 0), (5, 0), (-20, 8)])
def test_ground_plane_matches_analytic_floor(pitch, roll):
    cam = Camera.from_fov(60, 96, 72)
    spec = GroundPlaneSpec(1.4, pitch_deg=pitch, roll_deg=roll, backdrop_distance_m=50.0)
    d, n = ground_plane_depth(cam, spec)
    ref = _world_floor_depth(cam, 1.4, pitch, roll)
    floor = ref < 50.0
    assert d.dtype == np.float32 and d.shape == (72, 96) and n.shape == (72, 96, 3)
    assert floor.any()
    np.testing.assert_allclose(d[floor], ref[floor], rtol=1e-5)
    assert np.all(d[~floor] == 50.0)
    np.testing.assert_allclose(n[~floor], np.tile([0, 0, 1], ((~floor).sum(), 1)))
    # Floor points lie 1.4 m below the camera along the floor normal.
    P = cam.unproject(d)
    np.testing.assert_allclose((P[floor] * n[floor]).sum(-1), -1.4, rtol=1e-4)


def test_horizon_row_equals_pitch():
    cam = Camera.from_fov(50, 120, 80)
    row = 20.0
    pitch = pitch_from_horizon(cam, row)
    assert pitch < 0  # horizon above the centre => looking down
    a = ground_plane_depth(cam, GroundPlaneSpec(1.0, horizon_row=row))[0]
    b = ground_plane_depth(cam, GroundPlaneSpec(1.0, pitch_deg=pitch))[0]
    np.testing.assert_allclose(a, b, rtol=1e-6)
    # Rows above the horizon are backdrop; the row just below is floor.
    assert np.all(a[: int(row) - 1] == 10.0)
    assert np.all(a[-1] < 10.0)


def test_ground_plane_spec_parsing_and_errors():
    s = GroundPlaneSpec.from_dict({"proxy": "ground_plane", "camera_height": 1.5, "pitch_deg": -10})
    assert s.camera_height_m == 1.5 and s.pitch_deg == -10 and s.backdrop_distance_m == 10.0
    for bad in ({"camera_height": -1, "pitch_deg": 0}, {"camera_height": 1},
                {"camera_height": 1, "pitch_deg": 0, "horizon_row": 3},
                {"camera_height": 1, "pitch_deg": 95}, {"camera_height": "x", "pitch_deg": 0},
                {"camera_height": 1, "pitch_deg": 0, "bogus": 1},
                {"camera_height": float("nan"), "pitch_deg": 0}):
        with pytest.raises(InputError):
            GroundPlaneSpec.from_dict(bad)


def test_normals_from_depth_planes_below_one_degree():
    cam = Camera.from_fov(55, 128, 96)
    spec = GroundPlaneSpec(1.2, pitch_deg=-25, backdrop_distance_m=6.0)
    d, n_true = ground_plane_depth(cam, spec)
    n = normals_from_depth(d, cam)
    assert n.dtype == np.float32 and n.shape == (96, 128, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    ang = np.degrees(np.arccos(np.clip((n * n_true).sum(-1), -1, 1)))
    fl = floor_mask(cam, spec)
    from scipy.ndimage import binary_erosion

    away = binary_erosion(fl, iterations=2) | binary_erosion(~fl, iterations=2)
    assert ang[away].max() < 1.0
    # At the floor/backdrop edge itself the one-sided choice still keeps each side
    # on its own surface for most pixels.
    assert np.median(ang) < 0.1


def test_normals_tilted_plane_and_orientation():
    cam = Camera.from_fov(50, 64, 48)
    # Plane z-depth = a*X + 2, tilted: n ∝ (-a, 0, 1) after orientation toward the camera.
    rays = cam.pixel_rays()
    a = 0.5
    # points t*r with -t = a * t * r_x - 2  =>  t = 2 / (1 + a r_x)
    t = 2.0 / (1.0 + a * rays[..., 0])
    n = normals_from_depth(t.astype(np.float32), cam)
    want = np.array([-a, 0.0, 1.0]) / math.hypot(a, 1)
    ang = np.degrees(np.arccos(np.clip(n @ want, -1, 1)))
    assert ang.max() < 0.5
    assert np.all(n[..., 2] > 0)  # faces the camera


def test_normals_invalid_and_nonfinite_depth():
    cam = Camera.from_fov(50, 32, 24)
    d = np.full((24, 32), 3.0, np.float32)
    d[5, 5] = 0.0
    d[10, 10] = np.nan
    d[12, 12] = np.inf
    d[0:2, :] = 1e4  # HDR-extreme far depth still fine
    n = normals_from_depth(d, cam)
    assert np.isfinite(n).all()
    for y, x in [(5, 5), (10, 10), (12, 12)]:
        assert np.all(n[y, x] == 0)
    np.testing.assert_allclose(n[20, 20], [0, 0, 1], atol=1e-5)
    # A one-pixel sliver in front of a wall faces the camera rather than garbage.
    d2 = np.full((24, 32), 3.0, np.float32)
    d2[:, 16] = 1.0
    n2 = normals_from_depth(d2, cam)
    r = -cam.pixel_rays()[12, 16]
    np.testing.assert_allclose(n2[12, 16], r / np.linalg.norm(r), atol=1e-5)
    with pytest.raises(InputError):
        normals_from_depth(np.ones((5, 5)), cam)
    with pytest.raises(InputError):
        normals_from_depth(d, cam, discontinuity_threshold=0)
