"""Depth and normals that agree (estimators/consistency.py) and the alignment of relative
depth (estimators/depth_alignment.py), on analytic scenes."""

import math

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError
from zcomp_cli.estimators.consistency import agreement, angle_deg, continuous_depth, fit_shift_to_normals
from zcomp_cli.estimators.depth_alignment import (align_relative_depth, ground_plane_fit,
                                                  relative_to_depth)
from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, floor_mask, ground_plane_depth


def _rot_x(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _floor_and_wall(cam):
    """A floor 1.2 m below the camera (pitch -25 deg) and a wall 4 m away: exact depth
    and normals."""
    d, n = ground_plane_depth(cam, GroundPlaneSpec(1.2, pitch_deg=-25, backdrop_distance_m=4.0))
    return d.astype(np.float64), n


def test_agreement_is_zero_on_exact_geometry_and_sees_a_tilt():
    cam = Camera.from_fov(60, 96, 72)
    d, n = _floor_and_wall(cam)
    a = agreement(d, n, cam)
    assert a.pixels > 0.8 * d.size  # only the floor/wall crease and the border are left out
    assert a.median_deg < 0.5 and a.frac_over == 0.0
    tilted = (n.reshape(-1, 3) @ _rot_x(30).T).reshape(n.shape)  # normals 30 deg off everywhere
    b = agreement(d, tilted, cam)
    assert b.median_deg == pytest.approx(30.0, abs=0.5)
    assert b.angle_deg.shape == d.shape and np.isnan(b.angle_deg[~continuous_depth(d)]).all()
    assert "30.0 deg" in b.describe() or "median 30" in b.describe()


def test_angle_deg_known_values_and_degenerate():
    a = np.array([[[1, 0, 0], [0, 0, 1], [0, 0, 0]]], float)
    b = np.array([[[0, 1, 0], [0, 0, -1], [0, 0, 1]]], float)
    ang = angle_deg(a, b)
    assert ang[0, 0] == pytest.approx(90) and ang[0, 1] == pytest.approx(180) and np.isnan(ang[0, 2])


def test_agreement_without_pixels():
    cam = Camera.from_fov(50, 8, 6)
    a = agreement(np.zeros((6, 8)), np.zeros((6, 8, 3)), cam)
    assert a.pixels == 0 and math.isnan(a.median_deg)
    with pytest.raises(InputError):
        agreement(np.ones((6, 8)), np.zeros((6, 8, 2)), cam)


@pytest.mark.parametrize("kind", ["disparity", "affine"])
def test_fit_shift_recovers_the_geometry(kind):
    cam = Camera.from_fov(60, 96, 72)
    d, n = _floor_and_wall(cam)
    # What a relative model would give: an unknown scale and shift of disparity or depth.
    rel = 0.37 / d + 0.8 if kind == "disparity" else 0.21 * d - 0.15
    shift, best, before = fit_shift_to_normals(rel, kind, n, cam)
    assert best < 1.0 < before  # the default shift bends the floor; the fitted one does not
    depth, how = align_relative_depth(rel, kind, median_depth_m=float(np.median(d)), shift=shift)
    np.testing.assert_allclose(depth / d, 1.0, atol=0.03)  # metric once the median is right
    assert "fitted" in how


def test_affine_depth_ground_plane_fit_and_fallback():
    cam = Camera.from_fov(60, 80, 60)
    spec = GroundPlaneSpec(1.3, pitch_deg=-25, backdrop_distance_m=8.0)
    true, _ = ground_plane_depth(cam, spec)
    p = (true - 1.0) / 7.0  # Marigold-like: affine depth, near ~ 0
    depth, how = ground_plane_fit(p, "affine", true, floor_mask(cam, spec))
    np.testing.assert_allclose(depth, true, rtol=1e-4)
    assert how.startswith("depth = 7")
    # No proxy, no normals: the shift is assumed (far/near ratio 4 between 2nd and 98th
    # percentiles) and said so.
    depth, how = align_relative_depth(p, "affine", median_depth_m=3.0)
    lo, hi = np.percentile(depth[depth > 0], [2, 98])
    assert hi / lo == pytest.approx(4.0, rel=0.02) and np.median(depth) == pytest.approx(3.0, rel=1e-3)
    assert "assumed" in how
    assert ground_plane_fit(np.ones_like(p), "affine", true) is None  # flat prediction: no fit


def test_relative_to_depth_invalid_values():
    r = np.array([[0.0, -1.0, np.nan, 2.0]])
    np.testing.assert_array_equal(relative_to_depth(r, "disparity"), [[0, 0, 0, 0.5]])
    np.testing.assert_array_equal(relative_to_depth(r, "affine", shift=0.5), [[0.5, 0, 0, 2.5]])
    with pytest.raises(InputError):
        relative_to_depth(r, "inverse")


def test_scene_agreement_on_the_floor_sees_a_wrong_pitch():
    """Normals given beside a ground-plane proxy: the floor's agreement measures the
    ground-plane keys themselves (here a pitch 10 deg off)."""
    from zcomp_cli.estimators import estimate_scene_maps

    cam = Camera.from_fov(60, 96, 72)
    _, true_n = ground_plane_depth(cam, GroundPlaneSpec(1.2, pitch_deg=-25))
    img = np.full((72, 96, 3), 0.4, np.float32)
    right = estimate_scene_maps(img, cam, depth_spec={"camera_height": 1.2, "pitch_deg": -25},
                                provided={"normals": true_n})
    wrong = estimate_scene_maps(img, cam, depth_spec={"camera_height": 1.2, "pitch_deg": -35},
                                provided={"normals": true_n})
    assert right.fits["agreement_floor"]["median_deg"] < 0.5
    assert wrong.fits["agreement_floor"]["median_deg"] == pytest.approx(10.0, abs=0.5)
    assert right.sources["normals"] == "provided" and right.agreement.shape == (72, 96)
