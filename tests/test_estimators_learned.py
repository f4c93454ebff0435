"""Learned depth: a tiny random DPT saved locally runs end to end; disparity alignment."""

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError, WeightsError
from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, floor_mask, ground_plane_depth
from zcomp_cli.estimators.learned import (check_model_dir, disparity_to_depth, learned_depth,
                                          output_kind)


def test_missing_files_named(tmp_path):
    with pytest.raises(WeightsError) as e:
        check_model_dir(tmp_path)
    msg = str(e.value)
    assert "config.json" in msg and "model.safetensors" in msg and "preprocessor_config.json" in msg


def test_tiny_dpt_end_to_end_with_ground_plane(tiny_dpt):
    cam = Camera.from_fov(50, 48, 36)
    img = np.random.default_rng(0).uniform(0, 1, (36, 48, 3)).astype(np.float32)
    spec = GroundPlaneSpec(1.5, pitch_deg=-20)
    proxy, _ = ground_plane_depth(cam, spec)
    res = learned_depth(img, cam, tiny_dpt, proxy_depth=proxy, proxy_mask=floor_mask(cam, spec))
    assert res.kind == "disparity"
    assert res.depth.shape == (36, 48) and res.depth.dtype == np.float32
    assert np.isfinite(res.depth).all() and (res.depth >= 0).all()
    assert res.raw.shape == (36, 48)
    # The same through the scene API, with caching.
    from zcomp_cli.estimators import estimate_scene_maps

    est = estimate_scene_maps(img, cam, depth_spec={"model": str(tiny_dpt), "median_depth": 2.0})
    assert est.sources["depth"] == f"learned:{tiny_dpt}"
    assert est.sources["normals"] == "from_depth"
    assert np.isfinite(est.normals).all()


def test_output_kind():
    class C:
        model_type = "zoedepth"

    class D:
        model_type = "depth_anything"
        depth_estimation_type = "metric"

    class E:
        model_type = "dpt"

    assert output_kind(C()) == "metric" and output_kind(D()) == "metric"
    assert output_kind(E()) == "disparity"


def test_disparity_fit_recovers_metric_depth():
    cam = Camera.from_fov(60, 80, 60)
    spec = GroundPlaneSpec(1.3, pitch_deg=-25, backdrop_distance_m=8.0)
    true, _ = ground_plane_depth(cam, spec)
    disp = 7.0 / true + 0.3  # affine-invariant disparity of the true depth
    depth, how = disparity_to_depth(disp, proxy_depth=true, proxy_mask=floor_mask(cam, spec))
    np.testing.assert_allclose(depth, true, rtol=1e-4)
    assert "ground plane" in how
    # The fit survives outliers (an object standing on the floor).
    disp2 = disp.copy()
    disp2[40:50, 30:40] *= 3
    depth2, _ = disparity_to_depth(disp2, proxy_depth=true, proxy_mask=floor_mask(cam, spec))
    np.testing.assert_allclose(depth2[55:, :], true[55:, :], rtol=1e-3)


def test_disparity_median_fallback_and_errors():
    disp = np.array([[1.0, 2.0], [4.0, 0.0]])
    depth, _ = disparity_to_depth(disp, median_depth_m=3.0)
    assert depth[1, 1] == 0  # zero disparity: invalid, not infinite
    assert np.median(depth[depth > 0]) == pytest.approx(3.0)
    assert depth[0, 0] > depth[0, 1] > depth[1, 0]  # larger disparity = nearer
    with pytest.raises(InputError):
        disparity_to_depth(np.zeros((3, 3)))
    with pytest.raises(InputError):
        disparity_to_depth(disp, median_depth_m=-1)


def test_metric_override_and_cache(tiny_dpt, tmp_path):
    cam = Camera.from_fov(50, 40, 30)
    img = np.random.default_rng(2).uniform(0, 1, (30, 40, 3)).astype(np.float32)
    res = learned_depth(img, cam, tiny_dpt, output="metric")
    assert res.kind == "metric"
    np.testing.assert_array_equal(res.depth, np.where(res.raw > 0, res.raw, 0))
    with pytest.raises(InputError):
        learned_depth(img, cam, tiny_dpt, output="inverse")
    with pytest.raises(InputError):
        learned_depth(img[:10], cam, tiny_dpt)
    from zcomp_cli.estimators import estimate_scene_maps

    spec = {"model": str(tiny_dpt), "output": "metric"}
    a = estimate_scene_maps(img, cam, depth_spec=spec, cache_dir=tmp_path)
    assert any(p.name.startswith("depth-") for p in tmp_path.iterdir())
    b = estimate_scene_maps(img, cam, depth_spec=spec, cache_dir=tmp_path)
    np.testing.assert_allclose(a.depth, b.depth, rtol=1e-6)
    with pytest.raises(InputError):
        estimate_scene_maps(img, cam, depth_spec={"model": str(tiny_dpt), "median_depth": "far"})
    with pytest.raises(WeightsError):
        estimate_scene_maps(img, cam, depth_spec={"model": str(tmp_path / "absent")})
