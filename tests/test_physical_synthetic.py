"""Tests of the analytic scenes in zcomp_cli.testing."""

import numpy as np
import pytest

from zcomp_cli.errors import InputError
from zcomp_cli.testing import floor_scene, insert_bundle, sphere_object_bundle


def test_floor_depth_is_exact():
    s = floor_scene(64, 48, camera_height=1.5, pitch_deg=-30)
    pts = s.camera.unproject(s.depth).reshape(-1, 3)
    world = pts[np.isfinite(pts[:, 0])] @ s.cam_to_world.T + s.camera_origin
    assert np.allclose(world[:, 1], 0.0, atol=1e-4)  # every valid pixel lies on y = 0
    assert np.allclose(s.shading[s.depth > 0], s.ambient + s.light_intensity
                       * max(0, s.up_cam @ s.light_dir_cam), atol=1e-5)


def test_horizon_sky_is_invalid():
    s = floor_scene(32, 32, pitch_deg=0)
    assert np.all(s.depth[:16] == 0) and np.all(s.depth[16:] > 0)
    assert np.all(s.normals[:16] == 0)


def test_sphere_bundle():
    s = floor_scene(64, 48)
    c = s.world_to_camera([0.0, 0.25, -2.5])
    b = sphere_object_bundle(s.camera, c, 0.25, (0.2, 0.4, 0.6), floor_normal=s.up_cam)
    assert b.meta["object_height_m"] == 0.5
    assert 0 <= b.mask.min() and b.mask.max() == 1.0
    assert ((b.mask > 0) & (b.mask < 1)).sum() > 0  # anti-aliased edge
    inside = b.mask == 1
    assert np.allclose(np.linalg.norm(b.normals[inside], axis=-1), 1, atol=1e-5)
    # nearest depth is the sphere front: |c| - r along the central ray, roughly
    assert abs(b.depth[inside].min() - (np.linalg.norm(c) - 0.25) * (-c[2] / np.linalg.norm(c))) < 0.05
    fp = b.footprint_depth > 0
    assert fp.sum() > 0
    pts = s.camera.unproject(np.where(fp, b.footprint_depth, 0)).reshape(-1, 3)
    world = pts[np.isfinite(pts[:, 0])] @ s.cam_to_world.T + s.camera_origin
    assert np.allclose(world[:, 1], 0.0, atol=1e-4)  # footprint on the floor
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    assert np.all(d[sel] < s.depth[sel]) and np.allclose(a[sel], (0.2, 0.4, 0.6))
    with pytest.raises(InputError):
        sphere_object_bundle(s.camera, c, -1.0)
    with pytest.raises(InputError):
        sphere_object_bundle(s.camera, [np.nan, 0, -2], 0.2)
