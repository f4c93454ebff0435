"""Known-value tests of the convention conversions (DESIGN.md section 3)."""

import numpy as np
import pytest

from zcomp_cli.conventions import (
    K_from_fov,
    blender_depth_to_z_depth,
    camera_normals_to_conditioning,
    conditioning_to_camera_normals,
    fov_from_K,
    linear_to_srgb,
    luminance,
    normalize,
    ray_distance_to_z_depth,
    srgb_to_linear,
    valid_depth_mask,
    world_to_camera_normals,
    z_depth_to_ray_distance,
)


# -- sRGB ------------------------------------------------------------------------------
def test_srgb_known_values():
    x = np.array([0.0, 0.04045, 0.5, 1.0], dtype=np.float32)
    want = np.array([0.0, 0.04045 / 12.92, 0.21404114, 1.0], dtype=np.float32)
    np.testing.assert_allclose(srgb_to_linear(x), want, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(linear_to_srgb(np.float32(0.21404114)), 0.5, atol=1e-6)
    # 8-bit mid grey 128 -> 0.2158605 linear
    np.testing.assert_allclose(srgb_to_linear(np.float32(128 / 255)), 0.2158605, atol=1e-6)


def test_srgb_round_trip_and_dtype():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    y = linear_to_srgb(srgb_to_linear(x))
    assert y.dtype == np.float32
    np.testing.assert_allclose(y, x, atol=2e-6)
    # the linear segment near black is continuous with the power segment
    a = srgb_to_linear(np.float32(0.04045 - 1e-6))
    b = srgb_to_linear(np.float32(0.04045 + 1e-6))
    assert abs(float(a) - float(b)) < 1e-6


def test_srgb_extremes_nan_inf_hdr():
    out = linear_to_srgb(np.array([np.nan, np.inf, -np.inf, 1e4, -1.0], dtype=np.float32))
    np.testing.assert_allclose(out, [0.0, 1.0, 0.0, 1.0, 0.0], atol=1e-6)
    assert np.all(np.isfinite(srgb_to_linear(np.array([2.0, -3.0, 1e4]))))
    np.testing.assert_allclose(srgb_to_linear(np.array([2.0, -3.0])), [1.0, 0.0])


def test_integer_input_is_promoted():
    assert srgb_to_linear(np.array([0, 1])).dtype.kind == "f"


# -- K <-> FOV --------------------------------------------------------------------------
def test_K_from_fov_known():
    K = K_from_fov(90.0, 64, 48)
    np.testing.assert_allclose(K, [[32, 0, 32], [0, 32, 24], [0, 0, 1]], atol=1e-12)
    K60 = K_from_fov(60.0, 512, 512)
    np.testing.assert_allclose(K60[0, 0], 256 / np.tan(np.radians(30)), rtol=1e-12)
    assert fov_from_K(K60, 512) == pytest.approx(60.0, abs=1e-9)


@pytest.mark.parametrize("fov,w,h", [(0.0, 4, 4), (180.0, 4, 4), (np.nan, 4, 4), (50.0, 0, 4), (50.0, 4, -1)])
def test_K_from_fov_rejects(fov, w, h):
    with pytest.raises(ValueError):
        K_from_fov(fov, w, h)


def test_K_from_fov_tiny_and_huge_angles_finite():
    assert np.all(np.isfinite(K_from_fov(1e-6, 64, 64)))
    assert K_from_fov(179.999, 64, 64)[0, 0] > 0


# -- depth ------------------------------------------------------------------------------
def test_blender_depth_empty_and_invalid_become_zero():
    z = np.array([[2.5, 1e10], [np.nan, -1.0], [np.inf, 1e4]], dtype=np.float32)
    out = blender_depth_to_z_depth(z)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[2.5, 0.0], [0.0, 0.0], [0.0, 1e4]])
    np.testing.assert_array_equal(valid_depth_mask(out), [[True, False], [False, False], [False, True]])


def test_ray_distance_z_depth_known_values():
    K = K_from_fov(90.0, 2, 2)  # fx = 1, cx = cy = 1: pixel centres at +-0.5 from axis
    # every pixel centre of this 2x2 image has direction (+-0.5, +-0.5, -1)
    dist = np.full((2, 2), 3.0, dtype=np.float32)
    z = ray_distance_to_z_depth(dist, K)
    np.testing.assert_allclose(z, 3.0 / np.sqrt(1.5), rtol=1e-6)
    np.testing.assert_allclose(z_depth_to_ray_distance(z, K), dist, rtol=1e-6)
    # centre pixel of an odd image lies on the axis: distance == depth
    K3 = K_from_fov(50.0, 3, 3)
    np.testing.assert_allclose(ray_distance_to_z_depth(np.full((3, 3), 2.0), K3)[1, 1], 2.0, rtol=1e-6)
    # invalid stays 0
    d = np.array([[0.0, np.nan], [np.inf, 1.0]], dtype=np.float32)
    out = ray_distance_to_z_depth(d, K)
    assert out[0, 0] == 0 and out[0, 1] == 0 and out[1, 0] == 0 and out[1, 1] > 0


# -- normals ----------------------------------------------------------------------------
def test_world_to_camera_normals_identity_is_noop():
    n = normalize(np.random.default_rng(0).normal(size=(8, 8, 3)))
    np.testing.assert_allclose(world_to_camera_normals(n, np.eye(4)), n, atol=1e-6)


def test_world_to_camera_normals_rotated_camera():
    # camera turned 90 degrees to the left (about world +y): it now looks along world -x.
    c, s = 0.0, 1.0
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    M = np.eye(4)
    M[:3, :3] = R
    # a wall facing world +x faces this camera -> (0, 0, 1) in the camera frame
    out = world_to_camera_normals(np.array([1.0, 0.0, 0.0]), M)
    np.testing.assert_allclose(out, [0, 0, 1], atol=1e-6)
    # world up stays camera up
    np.testing.assert_allclose(world_to_camera_normals(np.array([0.0, 1.0, 0.0]), M), [0, 1, 0], atol=1e-6)
    # a scaled camera matrix gives the same rotation
    M2 = M.copy()
    M2[:3, :3] *= 3.0
    np.testing.assert_allclose(world_to_camera_normals(np.array([1.0, 0.0, 0.0]), M2), [0, 0, 1], atol=1e-6)


def test_normalize_zero_nan_and_huge():
    v = np.array([[0, 0, 0], [np.nan, 1, 0], [1e4, 0, 0], [0, 3, 4]], dtype=np.float32)
    out = normalize(v)
    np.testing.assert_allclose(out, [[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0.6, 0.8]], atol=1e-6)


def test_conditioning_normals_no_flip():
    # DESIGN §4: plain n * 0.5 + 0.5 of OpenGL camera normals; camera-facing -> blue = 1
    out = camera_normals_to_conditioning(np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(out, [0.5, 0.5, 1.0])
    out = camera_normals_to_conditioning(np.array([1.0, -1.0, 0.0]))
    np.testing.assert_allclose(out, [1.0, 0.0, 0.5])
    # a floor seen by a level camera faces up: +y -> green = 1
    np.testing.assert_allclose(camera_normals_to_conditioning(np.array([0.0, 1.0, 0.0])), [0.5, 1.0, 0.5])
    back = conditioning_to_camera_normals(np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 0.5]]))
    np.testing.assert_allclose(back, [[0, 0, 1], [0, 0, 0]], atol=1e-6)


def test_luminance_rec601_and_shape_check():
    assert luminance(np.array([1.0, 1.0, 1.0], dtype=np.float32)) == pytest.approx(1.0, abs=1e-6)
    assert luminance(np.array([0.0, 1.0, 0.0], dtype=np.float32)) == pytest.approx(0.587, abs=1e-6)
    with pytest.raises(ValueError):
        luminance(np.zeros((2, 2)))
