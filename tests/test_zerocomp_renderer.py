import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import K_from_fov
from zcomp_cli.errors import InputError, UsageError, WeightsError
from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.renderers.zerocomp.conditioning import build_conditioning, crop_box, official_shading

from zerocomp_dummy import H, W, random_request as _request, save_dummy


def test_conditioning_channels_by_hand():
    r = _request()
    c = build_conditioning(r, 11, 24, box=(4, 0, 28, 24))  # 24x24 crop -> no resize
    sl = (slice(0, 24), slice(4, 28))
    np.testing.assert_allclose(c[0], r.maps.depth[sl], rtol=1e-6)
    n = r.maps.normals[sl]
    np.testing.assert_allclose(c[1], n[..., 0] * 0.5 + 0.5, atol=1e-6)
    np.testing.assert_allclose(c[3], n[..., 2] * 0.5 + 0.5, atol=1e-6)  # no flip (DESIGN §4)
    np.testing.assert_allclose(c[4:7].transpose(1, 2, 0), r.maps.albedo[sl], atol=1e-6)
    k = r.known[sl]
    assert np.all(c[10][k] == 1) and np.all(c[10][~k] == -1)
    assert np.all(c[7:10][:, ~k] == -1)
    img = r.shading * r.maps.albedo
    expect = np.clip(np.clip(img, 0, 1) ** (1 / 2.2) / r.maps.albedo, 1e-5, 1e3)[sl]
    np.testing.assert_allclose(c[7:10].transpose(1, 2, 0)[k], expect[k], rtol=1e-5)
    c10 = build_conditioning(r, 10, 24, box=(4, 0, 28, 24))
    np.testing.assert_array_equal(c10, c[1:])
    assert build_conditioning(r, 11, 16).shape == (11, 16, 16)


def test_conditioning_13_and_errors():
    c = build_conditioning(_request(rough=True), 13, 16)
    assert np.allclose(c[11], 0.3) and np.allclose(c[12], 0.7)
    with pytest.raises(InputError):
        build_conditioning(_request(), 13, 16)
    with pytest.raises(InputError):
        build_conditioning(_request(), 12, 16)


def test_official_shading_extremes():
    img = np.array([[[1e4, np.nan, np.inf]]], np.float32)
    alb = np.array([[[0.0, 0.5, 1e-9]]], np.float32)
    s = official_shading(img, alb)
    assert np.isfinite(s).all() and s.min() >= np.float32(1e-5) and s.max() <= np.float32(1e3)


def test_crop_box():
    assert crop_box(None, (H, W), 0.5) == (4, 0, 28, 24)  # official centre crop, not squashed
    b = crop_box((10, 8, 20, 16), (H, W), 0.5)
    assert b[2] - b[0] == b[3] - b[1] == 20 and 0 <= b[0] and b[2] <= W and b[3] <= H
    # a roi longer than the short side is never cut: the window is padded past the frame
    assert crop_box((0, 0, W, H), (H, W), 1.0) == (0, -4, 32, 28)


def test_missing_weights_lists_files(tmp_path, monkeypatch):
    from zcomp_cli.renderers.zerocomp import ZeroCompRenderer

    monkeypatch.delenv("ZCOMP_CONTROLNET", raising=False)
    monkeypatch.delenv("ZCOMP_SD_BASE", raising=False)
    r = ZeroCompRenderer(tmp_path / "ck", tmp_path / "base", device="cpu")
    with pytest.raises(WeightsError) as e:
        r.render([_request()])
    msg = str(e.value)
    assert "config.json" in msg and "unet" in msg and "scheduler_config.json" in msg
    with pytest.raises(UsageError):
        ZeroCompRenderer(steps=0)


@pytest.fixture(scope="module")
def dummy(tmp_path_factory):
    root = tmp_path_factory.mktemp("zc")
    return {ch: save_dummy(root, ch) for ch in (11, 13)}


def _renderer(dummy, ch=11, **kw):
    from zcomp_cli.renderers.zerocomp import ZeroCompRenderer

    ck, base = dummy[ch]
    return ZeroCompRenderer(ck, base, steps=2, device="cpu", resolution=16, **kw)


def test_end_to_end_deterministic_and_batched(dummy):
    r = _renderer(dummy)
    reqs = [_request(0), _request(1)]
    a = r.render(reqs, seed=469)
    assert len(a.images) == 2 and a.images[0].shape == (H, W, 3) and a.images[0].dtype == np.float32
    assert all(np.isfinite(i).all() and i.min() >= 0 for i in a.images)
    assert not np.allclose(a.images[0], a.images[1])  # conditioning matters
    b = r.render(reqs, seed=469)
    np.testing.assert_array_equal(a.images[0], b.images[0])
    c = r.render(reqs, seed=1)
    assert not np.allclose(a.images[0], c.images[0])
    sep = [r.render([q], seed=469).images[0] for q in reqs]
    for x, y in zip(a.images, sep):
        np.testing.assert_allclose(x, y, atol=1e-4)
    assert r._models is not None and r.models() is r._models  # cached


def test_crop_mode_pastes_outside(dummy):
    r = _renderer(dummy, crop=True, context_margin=0.2)
    req = _request(0)
    res = r.render([req])
    out = res.images[0]
    x0, y0, x1, y1 = res.info["box"]
    assert (x1 - x0) < W
    outside = np.ones((H, W), bool)
    outside[y0:y1, x0:x1] = False
    np.testing.assert_allclose(out[outside], (req.maps.albedo * req.shading)[outside], rtol=1e-6)


def test_13_channel_checkpoint_uses_roughness(dummy):
    r = _renderer(dummy, ch=13)
    a = r.render([_request(0, rough=True)]).images[0]
    q = _request(0, rough=True)
    q.maps.roughness = np.full((H, W), 0.9, np.float32)
    b = r.render([q]).images[0]
    assert not np.allclose(a, b)
    with pytest.raises(InputError):
        r.render([_request(0)])


def test_env_fallback(dummy, monkeypatch):
    from zcomp_cli.renderers import get_renderer

    ck, base = dummy[11]
    monkeypatch.setenv("ZCOMP_CONTROLNET", str(ck))
    monkeypatch.setenv("ZCOMP_SD_BASE", str(base))
    r = get_renderer("zerocomp", steps=1, device="cpu", resolution=16)
    assert r.render([_request()]).images[0].shape == (H, W, 3)


def test_dtype_policy_and_finite_guard():
    import torch

    from zcomp_cli.errors import NumericalError
    from zcomp_cli.renderers.zerocomp.dtype import check_finite, resolve_dtype

    assert resolve_dtype("auto", "cpu") == torch.float32
    assert resolve_dtype("bf16", "cpu") == torch.bfloat16
    with pytest.raises(UsageError):
        resolve_dtype("int8", "cpu")
    with pytest.raises(NumericalError):
        check_finite(torch.tensor([1.0, float("nan")]), "test")


def test_conditioning_nonfinite_inputs_become_finite():
    r = _request()
    r.maps.depth[0, 0] = np.nan
    r.maps.normals[1, 1] = np.inf
    r.shading[2, 2] = np.nan
    r.maps.albedo[3, 3] = 0.0
    c = build_conditioning(r, 11, 16)
    assert np.isfinite(c).all()


def test_empty_prompt_ids():
    from zcomp_cli.renderers.zerocomp.pipeline import empty_prompt_ids

    ids = empty_prompt_ids()
    assert ids.shape == (1, 77) and ids[0, 0] == 49406 and ids[0, 1] == 49407 and (ids[0, 2:] == 0).all()


def _job_requests(seed, h, w, roi):
    """A job's two passes (background, composite) on an h x w frame."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(h, w, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    bg = SceneMaps(depth=rng.uniform(0.5, 5, (h, w)).astype(np.float32), normals=n,
                   albedo=rng.uniform(0.1, 0.9, (h, w, 3)).astype(np.float32))
    comp = SceneMaps(depth=bg.depth.copy(), normals=bg.normals.copy(), albedo=bg.albedo.copy())
    x0, y0, x1, y1 = roi
    comp.albedo[y0:y1, x0:x1] = 0.7
    known = np.ones((h, w), bool)
    known[y0:y1, x0:x1] = False
    shading = rng.uniform(0.2, 2.0, (h, w, 3)).astype(np.float32)
    cam = Camera(K_from_fov(50, w, h), w, h)
    return [RenderRequest(m, shading, known, cam, roi=roi) for m in (bg, comp)]


@pytest.mark.slow
def test_batched_jobs_equal_jobs_alone(dummy):
    # three jobs (different frame sizes, windows and seeds) in one render_jobs call, one job
    # per GPU call (2 passes): job 0 has a third pass, so job 1's passes straddle two
    # chunks. Each job must equal the same job rendered alone, and its unbatched passes.
    jobs = [_job_requests(0, 24, 32, (10, 8, 20, 16)), _job_requests(1, 40, 24, (2, 20, 14, 38)),
            _job_requests(2, 16, 16, (4, 4, 9, 9))]
    jobs[0].append(_job_requests(5, 24, 32, (10, 8, 20, 16))[1])
    seeds = [469, 469, 7]
    r = _renderer(dummy, batch_size=1)
    together = r.render_jobs(jobs, seeds)
    assert len(together) == 3 and together[0].info["chunks"] == 4
    big = _renderer(dummy, batch_size=8).render_jobs(jobs, seeds)  # all 7 passes in one call
    assert big[0].info["chunks"] == 1
    for k, (j, sd) in enumerate(zip(jobs, seeds)):
        alone = r.render(j, seed=sd).images
        unbatched = [r.render([q], seed=sd).images[0] for q in j]
        assert len(together[k].images) == len(j) and len(together[k].info["requests"]) == len(j)
        for p in range(len(j)):
            got = together[k].images[p]
            assert got.shape == j[p].maps.shape + (3,)
            for other in (alone[p], unbatched[p], big[k].images[p]):
                np.testing.assert_allclose(got, other, atol=2e-6, rtol=0)
    # the seed matters: job 2 with seed 469 differs
    assert not np.allclose(r.render(jobs[2], seed=469).images[0], together[2].images[0])
    # a job's passes share one noise: identical inputs give identical outputs
    same = _job_requests(3, 24, 32, (10, 8, 20, 16))[0]
    out = r.render([same, same]).images
    np.testing.assert_array_equal(out[0], out[1])
    # the window is reported per request
    for j, o in zip(jobs, together):
        for q, rep in zip(j, o.info["requests"]):
            b = rep["box"]
            assert b[2] - b[0] == b[3] - b[1] == min(q.maps.shape)
            assert rep["roi_in_window"] == 1.0 and rep["padded_px"] == 0


def test_fp16_autocast_runs_and_matches_fp32(dummy):
    reqs = _job_requests(0, 24, 32, (10, 8, 20, 16))
    a = _renderer(dummy).render(reqs).images
    b = _renderer(dummy, dtype="fp16-autocast").render(reqs).images
    assert all(np.isfinite(x).all() for x in b)
    np.testing.assert_allclose(a[1], b[1], atol=0.05)


def test_renderer_option_errors():
    from zcomp_cli.renderers.zerocomp import ZeroCompRenderer

    with pytest.raises(UsageError):
        ZeroCompRenderer(batch_size=0)
    with pytest.raises(UsageError):
        ZeroCompRenderer(window="squash")
    with pytest.raises(UsageError):
        ZeroCompRenderer(crop=True, window="center")
    assert ZeroCompRenderer(crop=True).window == "roi"
