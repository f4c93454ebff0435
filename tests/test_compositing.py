"""Equations 1-5 of DESIGN.md section 2, with known values and stability cases."""

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.compositing import (
    align_depth,
    apply_alignment,
    blur_weight,
    colour_balance,
    composite,
    composite_intrinsics,
    occlusion_mask,
    shading_from_image,
    shading_mask,
    shadow_ratio,
)
from zcomp_cli.compositing.compositor import gaussian_kernel1d
from zcomp_cli.maps import SceneMaps


# ---------------------------------------------------------------- depth alignment
def _plane_depth(h=40, w=50, base=2.0, slope=0.02):
    rows = np.arange(h, dtype=np.float64)[:, None]
    return np.broadcast_to(base + slope * rows, (h, w)).copy()


def test_align_depth_recovers_affine():
    fp = np.zeros((40, 50))
    fp[20:30, 10:30] = _plane_depth()[20:30, 10:30]
    bg = 1.5 * _plane_depth() + 0.3
    al = align_depth(bg, fp)
    assert al.mode == "affine"
    assert al.a == pytest.approx(1.5, abs=1e-6)
    assert al.b == pytest.approx(0.3, abs=1e-6)
    assert al.n_pixels == 200
    out = apply_alignment(fp, al)
    np.testing.assert_allclose(out[20:30, 10:30], bg[20:30, 10:30], atol=1e-5)
    assert np.all(out[fp == 0] == 0)


def test_align_depth_constant_footprint_falls_back_to_shift():
    fp = np.zeros((20, 20))
    fp[5:15, 5:15] = 3.0
    bg = np.full((20, 20), 3.4)
    al = align_depth(bg, fp)
    assert al.mode == "shift" and al.a == 1.0
    assert al.b == pytest.approx(0.4)
    assert "constant" in al.fallback


def test_align_depth_insane_scale_falls_back():
    fp = np.zeros((40, 50))
    fp[10:30, 10:30] = _plane_depth()[10:30, 10:30]
    bg = 10.0 * _plane_depth()
    al = align_depth(bg, fp)
    assert al.mode == "shift" and "outside" in al.fallback


@pytest.mark.parametrize("bad", [0.0, np.nan, np.inf, -1.0])
def test_align_depth_too_few_pixels(bad):
    fp = np.zeros((10, 10))
    fp[2:4, 2:4] = 1.0
    bg = np.full((10, 10), bad)
    al = align_depth(bg, fp)
    assert al.mode == "none" and al.a == 1.0 and al.b == 0.0 and al.n_pixels == 0
    assert "valid footprint" in al.fallback


def test_align_depth_robust_to_outliers():
    fp = np.zeros((40, 50))
    fp[10:30, 10:40] = _plane_depth()[10:30, 10:40]
    bg = _plane_depth() * 1.2 - 0.1
    bg[10:12, 10:40] = 50.0  # a depth edge crossing the footprint
    al = align_depth(bg, fp)
    assert al.mode == "affine" and al.a == pytest.approx(1.2, abs=1e-3)


# ---------------------------------------------------------------- eq. 1
def test_occlusion_cuts_object_behind_background():
    mask = np.ones((4, 4), np.float32)
    obj = np.full((4, 4), 3.0, np.float32)
    bg = np.full((4, 4), 5.0, np.float32)
    bg[0, 0] = 1.0  # nearer background: occludes
    bg[1, 1] = np.nan  # unknown background never occludes
    m = occlusion_mask(mask, obj, bg)
    assert m[0, 0] == 0 and m[1, 1] == 1 and m[2, 2] == 1


def test_composite_intrinsics_values():
    h, w = 3, 3
    bg = SceneMaps(np.full((h, w), 5.0, np.float32), np.tile(np.float32([0, 1, 0]), (h, w, 1)),
                   np.full((h, w, 3), 0.2, np.float32))
    obj = SceneMaps(np.full((h, w), 2.0, np.float32), np.tile(np.float32([0, 0, 1]), (h, w, 1)),
                    np.full((h, w, 3), 0.8, np.float32))
    m = np.array([[0, 0.3, 0.7], [1, 1, 0], [0, 0, 0]], np.float32)
    c = composite_intrinsics(bg, obj, m)
    assert c.depth[0, 1] == 5.0 and c.depth[0, 2] == 2.0  # hard geometry at 0.5
    np.testing.assert_allclose(c.normals[0, 2], [0, 0, 1])
    np.testing.assert_allclose(c.albedo[0, 1], 0.3 * 0.8 + 0.7 * 0.2, rtol=1e-6)
    assert c.roughness is None


# ---------------------------------------------------------------- eq. 3
def _floor_and_box(W=64, H=48):
    """Floor at y = -1 seen by a level camera; a small box-like object standing on it."""
    cam = Camera.from_fov(60, W, H)
    rays = cam.pixel_rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rays[..., 1] < -1e-6, -1.0 / rays[..., 1], 0.0)
    bg = np.where((t > 0) & (t < 50), t, 0.0).astype(np.float32)  # z-depth = t (rays have z=-1)
    obj_depth = np.zeros_like(bg)
    obj_mask = np.zeros_like(bg)
    # a fronto-parallel square at z = -4 spanning y in [-1, -0.5], x in [-0.25, 0.25]
    z = 4.0
    X = rays[..., 0] * z
    Y = rays[..., 1] * z
    inside = (np.abs(X) <= 0.25) & (Y >= -1) & (Y <= -0.5)
    obj_depth[inside] = z
    obj_mask[inside] = 1
    return cam, bg, obj_depth, obj_mask


def test_shading_mask_radius_and_never_above():
    cam, bg, od, om = _floor_and_box()
    res = shading_mask(bg, od, om, cam, radius_scale=1.0)
    s = res.mask
    assert res.object_extent_m == pytest.approx(0.5, abs=0.08)  # pixel-centre sampling
    assert s[om > 0].all()  # object pixels masked
    # never above: in the object's columns, rows above its top are unmasked
    cols = np.flatnonzero(om.any(0))
    top = np.flatnonzero(om[:, cols[0]])[0]
    assert not s[:top, cols].any()
    # a floor point within d is masked; a far floor point is not
    pts = cam.unproject(bg)
    obj_pts = cam.unproject(od)[om > 0]
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(obj_pts).query(np.nan_to_num(pts.reshape(-1, 3), nan=1e9))
    dist = dist.reshape(bg.shape)
    floor = (bg > 0) & (om == 0)
    # brute force agrees except right at the radius and above the object
    above = np.zeros_like(s)
    above[:top, cols] = True
    expected = floor & (dist <= res.radius_m) & ~above
    agree = (s[floor] == expected[floor]).mean()
    assert agree > 0.99
    assert not s[floor & (dist > res.radius_m * 1.05)].any()


def test_shading_mask_never_masks_a_wall_above_the_object():
    """A wall 0.1 m behind the object: its points above the object are well within the
    radius, yet the object cannot shade them, so they stay known. (Without the rule
    every wall pixel in the object's columns up to ~d above its top would be masked.)"""
    cam, bg, od, om = _floor_and_box()
    rays = cam.pixel_rays()
    wall_z = 4.1
    wall = (rays[..., 1] * wall_z >= -1.0) & (bg == 0) | (bg > wall_z)
    bg = np.where(wall, wall_z, bg).astype(np.float32)
    res = shading_mask(bg, od, om, cam, radius_scale=1.0)
    cols = np.flatnonzero(om.any(0))
    top = min(np.flatnonzero(om[:, c])[0] for c in cols)
    wall_above = np.zeros_like(res.mask)
    wall_above[:top, cols] = True
    wall_above &= wall
    # the wall right above the object is within d of it...
    pts = cam.unproject(bg)[wall_above]
    obj_pts = cam.unproject(od)[om > 0]
    from scipy.spatial import cKDTree

    near = cKDTree(obj_pts).query(pts)[0] <= res.radius_m
    assert near.sum() >= 10
    # ...and yet never masked; beside the object (other columns) the wall within d is.
    assert not res.mask[wall_above].any()
    beside = wall & ~res.mask
    assert res.mask[wall & ~wall_above & (om == 0)].any()
    assert beside.any()


def test_shading_mask_lambda_zero_only_object():
    cam, bg, od, om = _floor_and_box()
    s = shading_mask(bg, od, om, cam, radius_scale=0.0).mask
    np.testing.assert_array_equal(s, om > 0)


def test_shading_mask_empty_object():
    cam, bg, od, om = _floor_and_box()
    res = shading_mask(bg, od * 0, om * 0, cam)
    assert not res.mask.any()


def test_shading_mask_checks_inputs():
    cam, bg, od, om = _floor_and_box()
    with pytest.raises(ValueError):
        shading_mask(bg[:-1], od, om, cam)
    with pytest.raises(ValueError):
        shading_mask(bg, od, om, cam, radius_scale=-1)


# ---------------------------------------------------------------- shading
def test_shading_from_image_guards():
    img = np.array([[[0.5, 0.0, np.nan], [1e4, np.inf, 0.2]]], np.float32)
    alb = np.array([[[0.5, 0.0, 0.5], [1.0, 0.5, np.nan]]], np.float32)
    s = shading_from_image(img, alb)
    assert np.all(np.isfinite(s))
    assert s[0, 0, 0] == pytest.approx(1.0)
    assert s[0, 0, 1] == pytest.approx(1e-5)  # 0 / max(0, eps) -> clamp to eps
    assert s[0, 1, 0] == pytest.approx(1e3)  # clamped
    with pytest.raises(ValueError):
        shading_from_image(img[..., :2], alb[..., :2])


# ---------------------------------------------------------------- eq. 4-5
def test_shadow_ratio_known_values():
    fb = np.full((2, 2, 3), 0.5, np.float32)
    fc = fb.copy()
    fc[0, 0] = 0.25
    fc[0, 1] = 1.0  # brighter -> clamped to 1
    s = np.array([[True, True], [False, True]])
    R = shadow_ratio(fc, fb, s, eps=0.0)
    assert R[0, 0] == pytest.approx(0.5)
    assert R[0, 1] == 1.0 and R[1, 0] == 1.0 and R[1, 1] == 1.0


def test_shadow_ratio_black_background_is_one():
    z = np.zeros((3, 3, 3), np.float32)
    assert np.all(shadow_ratio(z, z, np.ones((3, 3), bool)) == 1.0)


def test_shadow_ratio_rejects_nan():
    a = np.zeros((2, 2, 3), np.float32)
    b = a.copy()
    b[0, 0, 0] = np.nan
    with pytest.raises(ValueError):
        shadow_ratio(b, a, np.ones((2, 2), bool))


def test_blur_weight_kernel_and_support():
    k = gaussian_kernel1d()
    assert k.shape == (15,) and k.sum() == pytest.approx(1.0)
    assert k[7] == k.max()
    s = np.zeros((41, 41), bool)
    s[20, 20] = True
    w = blur_weight(s)
    assert w[20, 20] == pytest.approx(k[7] ** 2, rel=1e-5)
    assert w[20, 27] > 0 and w[20, 28] == 0  # 15x15 support: 7 pixels each side
    full = blur_weight(np.ones((41, 41), bool))
    assert full[20, 20] == pytest.approx(1.0, abs=1e-6)


def test_colour_balance_guards():
    xb = np.full((4, 4, 3), [0.2, 0.4, 0.0], np.float32)
    fb = np.full((4, 4, 3), [0.1, 0.4, 0.0], np.float32)
    C, note = colour_balance(xb, fb, np.ones((4, 4), bool))
    np.testing.assert_allclose(C, [2.0, 1.0, 1.0])
    assert "near-zero" in note
    C, note = colour_balance(xb, fb, np.zeros((4, 4), bool))
    np.testing.assert_array_equal(C, [1, 1, 1])
    C, note = colour_balance(xb * 100, fb, np.ones((4, 4), bool))
    assert C.max() == 4.0 and "clamped" in note


def test_composite_outside_blurred_mask_is_bit_identical():
    rng = np.random.default_rng(0)
    h, w = 48, 64
    xb = (rng.random((h, w, 3)) * 3).astype(np.float32)  # HDR-ish
    fb = xb * 1.0
    fc = xb * 0.5
    s = np.zeros((h, w), bool)
    s[20:30, 20:30] = True
    m = np.zeros((h, w), np.float32)
    m[22:26, 22:26] = 1.0
    res = composite(xb, fb, fc, s, m)
    outside = res.weight == 0
    assert outside.sum() > 0.8 * h * w
    assert np.array_equal(res.image[outside], xb[outside])
    # inside the mask, off the object: darkened by R = 0.5 (w ~ 1 in the core)
    np.testing.assert_allclose(res.image[25, 28], xb[25, 28] * (1 - res.weight[25, 28] * 0.5), rtol=1e-3)  # eps in R
    # object pixels take C * f(comp); C = 1 here since f_bg == x_bg
    np.testing.assert_allclose(res.image[23, 23], fc[23, 23], rtol=1e-5)


@pytest.mark.parametrize("scale", [0.0, 1e-8, 1.0, 1e4])
def test_composite_extremes_finite(scale):
    h, w = 20, 20
    xb = np.full((h, w, 3), scale, np.float32)
    fb = xb.copy()
    fc = xb * 0.3
    s = np.zeros((h, w), bool)
    s[5:15, 5:15] = True
    m = np.zeros((h, w), np.float32)
    m[8:10, 8:10] = 0.5
    res = composite(xb, fb, fc, s, m)
    assert np.all(np.isfinite(res.image))
    assert res.image.dtype == np.float32


def test_composite_takes_the_object_from_its_own_layer_at_a_partly_covered_pixel():
    """``f_object`` (``RenderOutput.object_layers``): a pixel the object covers by m is m
    of the object's own radiance and 1 - m of the surface behind it, the surface's shadow
    ratio read from ``f_comp`` (the surface there). Without it ``f_comp`` is both, and a
    renderer's anti-aliased edge (m obj + (1 - m) surface) puts the surface in twice: the
    one-pixel fringe of issue 48."""
    h, w = 16, 16
    xb = np.full((h, w, 3), 0.2, np.float32)  # a dim floor
    fb = xb.copy()
    obj = np.array([0.8, 0.6, 0.4], np.float32)  # a bright object
    s = np.zeros((h, w), bool)
    s[2:14, 2:14] = True
    m = np.zeros((h, w), np.float32)
    m[6:10, 6:10] = 1.0
    m[6:10, 10] = 0.5  # the object's right edge covers half of each pixel
    f_object = np.zeros((h, w, 3), np.float32)
    f_object[m > 0] = obj
    surface = fb.copy()  # the floor behind the object, unshadowed here
    res = composite(xb, fb, surface, s, m, f_object=f_object)
    np.testing.assert_allclose(res.image[7, 10], 0.5 * obj + 0.5 * xb[7, 10], rtol=1e-5)
    np.testing.assert_allclose(res.image[7, 7], obj, rtol=1e-5)
    # the old contract, the edge's mixed radiance as the image: the floor counted twice
    mixed = surface.copy()
    mixed[m > 0] = m[m > 0, None] * obj + (1 - m[m > 0, None]) * surface[m > 0]
    old = composite(xb, fb, mixed, s, m)
    # (m of the mixed radiance: the object's own share m^2, the floor's m (1 - m) + (1 - m) R')
    assert float(np.abs(old.image[7, 10] - res.image[7, 10]).max()) > 0.1
