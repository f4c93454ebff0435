"""estimate_scene_maps (precedence, cache) and 2D objects."""

import numpy as np
import pytest

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.camera import Camera
from zcomp_cli.errors import GeometryError, InputError
from zcomp_cli.estimators import estimate_scene_maps
from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, ground_plane_depth
from zcomp_cli.estimators.object2d import object_bundle_from_image

GP = {"proxy": "ground_plane", "camera_height": 1.5, "pitch_deg": -15}


def _img(h=48, w=64, seed=0):
    return np.random.default_rng(seed).uniform(0.05, 1, (h, w, 3)).astype(np.float32)


def test_estimates_all_maps_from_image_alone():
    cam = Camera.from_fov(50, 64, 48)
    est = estimate_scene_maps(_img(), cam, depth_spec=GP)
    assert est.sources == {"depth": "ground_plane", "normals": "ground_plane", "albedo": "retinex"}
    assert est.depth.shape == (48, 64) and est.normals.shape == (48, 64, 3)
    assert est.albedo.shape == est.shading.shape == (48, 64, 3)
    for a in (est.depth, est.normals, est.albedo, est.shading):
        assert a.dtype == np.float32 and np.isfinite(a).all()
    ok = est.albedo > 0.01
    np.testing.assert_allclose((est.albedo * est.shading)[ok], _img()[ok], rtol=1e-4)
    # Explicit normals-from-depth on the proxy agrees with the analytic normals.
    est2 = estimate_scene_maps(_img(), cam, depth_spec=GP, normals_spec={"from": "depth"})
    assert est2.sources["normals"] == "from_depth"
    assert np.median(np.sum(est2.normals * est.normals, -1)) > 0.9999


def test_provided_maps_win():
    cam = Camera.from_fov(50, 64, 48)
    depth = np.full((48, 64), 2.0, np.float32)
    alb = np.full((48, 64, 3), 0.3, np.float32)
    est = estimate_scene_maps(_img(), cam, depth_spec=GP, provided={"depth": depth, "albedo": alb})
    assert est.sources["depth"] == "provided" and est.sources["albedo"] == "provided"
    assert est.depth is depth or np.array_equal(est.depth, depth)
    np.testing.assert_array_equal(est.albedo, alb)
    assert est.sources["normals"] == "from_depth"
    np.testing.assert_allclose(est.normals[10, 10], [0, 0, 1], atol=1e-5)


def test_errors():
    cam = Camera.from_fov(50, 64, 48)
    with pytest.raises(InputError, match="ground_plane"):
        estimate_scene_maps(_img(), cam)  # no depth, no estimator
    with pytest.raises(InputError):
        estimate_scene_maps(_img(), cam, depth_spec={"proxy": "sky"})
    with pytest.raises(InputError):
        estimate_scene_maps(_img(32, 32), cam, depth_spec=GP)
    with pytest.raises(InputError):
        estimate_scene_maps(_img(), cam, depth_spec=GP, albedo_spec={"method": "magic"})


def test_cache_is_keyed_by_content_and_settings(tmp_path):
    cam = Camera.from_fov(50, 64, 48)
    est = estimate_scene_maps(_img(), cam, depth_spec=GP, normals_spec={"from": "depth"},
                              cache_dir=tmp_path)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert len(files) == 2 and files[0].startswith("albedo-") and files[1].startswith("normals-")
    again = estimate_scene_maps(_img(), cam, depth_spec=GP, normals_spec={"from": "depth"},
                                cache_dir=tmp_path)
    np.testing.assert_allclose(again.albedo, est.albedo, atol=1e-6)
    assert len(list(tmp_path.iterdir())) == 2  # hit, nothing new
    estimate_scene_maps(_img(seed=1), cam, depth_spec=GP, cache_dir=tmp_path)
    estimate_scene_maps(_img(), cam, depth_spec=GP, albedo_spec={"lum_threshold": 0.2},
                        cache_dir=tmp_path)
    assert len([p for p in tmp_path.iterdir() if p.name.startswith("albedo-")]) == 3


def _floor(cam):
    return ground_plane_depth(cam, GroundPlaneSpec(1.5, pitch_deg=-15))


@pytest.mark.parametrize("proxy", ["billboard", "cylinder"])
def test_object_from_image_stands_on_the_floor(proxy):
    cam = Camera.from_fov(50, 160, 120)
    d, n = _floor(cam)
    obj = np.zeros((40, 20, 3), np.float32)
    obj[..., 0] = 0.8
    mask = np.zeros((40, 20), np.float32)
    mask[5:35, 4:16] = 1
    b = object_bundle_from_image(obj, mask, cam, (80, 100), 0.5, d, n, proxy=proxy)
    assert isinstance(b, ObjectBundle) and b.meta["object_height_m"] == 0.5
    inside = b.mask > 0.5
    ys, xs = np.nonzero(inside)
    assert abs(ys.max() + 1 - 100) <= 1 and abs(xs.mean() - 80) <= 1.5  # base at the pixel
    P = cam.unproject(np.where(inside, b.depth, 0))
    up = n[100, 80]
    heights = P[inside] @ up + 1.5  # height above the floor
    assert heights.min() > -0.03 and abs(heights.max() - 0.5) < 0.05
    width = np.ptp(P[inside][:, 0])
    assert abs(width - 0.5 * 12 / 30) < 0.04  # aspect ratio kept
    np.testing.assert_allclose(b.albedo[inside][:, 0], 0.8, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(b.normals[inside], axis=-1), 1, atol=1e-4)
    view = -P[inside] / np.linalg.norm(P[inside], axis=-1, keepdims=True)
    assert (np.sum(b.normals[inside] * view, -1) > -1e-3).all()  # no back-facing normal
    fp = b.footprint_depth > 0
    assert fp.sum() > 10
    np.testing.assert_allclose(b.footprint_depth[fp], d[fp], rtol=1e-4)  # on the floor
    yc = int(ys.mean())
    row = np.nonzero(inside[yc])[0]
    assert b.normals[yc, row[0], 0] < -0.5 and b.normals[yc, row[-1], 0] > 0.5  # rounded sides


def test_object_from_image_errors(tmp_path):
    cam = Camera.from_fov(50, 64, 48)
    d, n = _floor(cam)
    img = np.ones((10, 10, 3), np.float32)
    m = np.ones((10, 10), np.float32)
    with pytest.raises(InputError):
        object_bundle_from_image(img, np.zeros((10, 10)), cam, (32, 40), 0.3, d, n)
    with pytest.raises(InputError):
        object_bundle_from_image(img, m, cam, (32, 40), -1, d, n)
    with pytest.raises(InputError):
        object_bundle_from_image(img, m, cam, (32, 40), 0.3, d, n, proxy="sphere")
    with pytest.raises(GeometryError):
        object_bundle_from_image(img, m, cam, (500, 40), 0.3, d, n)
    bad = d.copy()
    bad[40, 32] = np.nan
    with pytest.raises(GeometryError):
        object_bundle_from_image(img, m, cam, (32, 40), 0.3, bad, n)
    b = object_bundle_from_image(img, m, cam, (32, 40), 0.3, d, None)  # normals from depth
    b.save(tmp_path / "b")
    assert ObjectBundle.is_complete(tmp_path / "b")
