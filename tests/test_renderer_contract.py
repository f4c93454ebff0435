"""One contract, every renderer (the diffusers ``PipelineTesterMixin`` way).

Each entry of ``renderers.registry.RENDERERS`` is checked here, the renderers of
installed plugins (the ``zcomp.renderers`` entry point group) included: a built-in
renderer needs a row in ``CONTRACT`` (else ``test_every_renderer_is_covered`` fails); a
plugin brings its own settings (``RendererEntry.contract_settings``, ``contract_exact``).
The contract:

* deterministic for a seed;
* one (H, W, 3) float32 finite image per request;
* a request's output does not depend on its neighbours: rendering [a, b] gives the same
  images as rendering [a] and [b] (order and batching change nothing), and
  ``render_jobs`` equals one ``render`` per job;
* where the shading is known, an analytic renderer reproduces the background
  (albedo x shading) exactly; a learned one only approximates it (the compositor's ratio
  of its two passes cancels that), so the check is skipped for it.
"""

from __future__ import annotations

import numpy as np
import pytest

from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers import get_renderer
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.renderers.registry import RENDERERS
from zcomp_cli.testing import floor_scene, insert_bundle, sphere_object_bundle

W, H = 48, 36


def _requests(scene_key: str, sphere_x: float):
    """Background and composite requests of one job on an analytic lit floor."""
    s = floor_scene(W, H, light_dir=(0.6, 1.0, 0.3), ambient=0.3)
    b = sphere_object_bundle(s.camera, s.world_to_camera([sphere_x, 0.3, -2.6]), 0.3, (0.7, 0.6, 0.5),
                             floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    ys, xs = np.nonzero(sel)
    known = np.ones((H, W), bool)
    known[max(0, ys.min() - 3):ys.max() + 5, max(0, xs.min() - 6):xs.max() + 6] = False
    roi = (0, 0, W, H)
    bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, roi=roi,
                       image=s.image, scene_key=scene_key)
    comp = RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, roi=roi, image=s.image,
                         scene_key=scene_key)
    return [bg, comp]


def _zerocomp_settings(tmp_path_factory):
    from zerocomp_dummy import save_dummy

    ckpt, base = save_dummy(tmp_path_factory.mktemp("zc"), 11)
    return {"controlnet": str(ckpt), "base": str(base), "steps": 2, "resolution": 32}


# renderer -> (settings factory, reproduces the known background exactly)
CONTRACT = {
    "physical": (lambda f: {"n_light_candidates": 32}, True),
    "naive": (lambda f: {}, True),
    # Blender's path tracer, a few samples: the background it reproduces is the known
    # shading itself (it path traces only the unknown pixels)
    "cycles": (lambda f: {"samples": 4, "denoise": False}, True),
    "zerocomp": (_zerocomp_settings, False),
}


def _contract(name):
    """(settings factory, exact) of a renderer: its CONTRACT row, or a plugin's own."""
    if name in CONTRACT:
        return CONTRACT[name]
    entry = RENDERERS[name]
    return (lambda f: dict(entry.contract_settings)), entry.contract_exact


def test_every_renderer_is_covered():
    assert set(CONTRACT) == set(RENDERERS.builtin)
    assert all(n in CONTRACT or RENDERERS[n].source != "zcomp" for n in RENDERERS)


# The tiny diffusion model takes seconds per call on a CPU: its rows are slow tests.
# Cycles runs Blender (the ``blender`` mark).
_MARKS = {"zerocomp": pytest.mark.slow, "cycles": pytest.mark.blender}


@pytest.fixture(scope="module", params=[pytest.param(n, marks=_MARKS[n]) if n in _MARKS else n
                                        for n in sorted(RENDERERS)])
def renderer_case(request, tmp_path_factory):
    name = request.param
    make_settings, exact = _contract(name)
    settings = make_settings(tmp_path_factory)
    return name, settings, exact


def _fresh(name, settings):
    return get_renderer(name, **settings)


def test_shapes_dtype_finite(renderer_case):
    name, settings, _ = renderer_case
    out = _fresh(name, settings).render(_requests("a", 0.3), seed=3)
    assert len(out.images) == 2
    for im in out.images:
        assert im.shape == (H, W, 3) and im.dtype == np.float32 and np.isfinite(im).all()
    assert isinstance(out.info, dict) and isinstance(out.timings, dict)


def test_deterministic_for_a_seed(renderer_case):
    name, settings, _ = renderer_case
    reqs = _requests("a", 0.3)
    a = _fresh(name, settings).render(reqs, seed=11).images
    b = _fresh(name, settings).render(reqs, seed=11).images
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_each_output_depends_only_on_its_request(renderer_case):
    name, settings, _ = renderer_case
    bg, comp = _requests("a", 0.3)
    r = _fresh(name, settings)
    both = r.render([bg, comp], seed=5).images
    swapped = r.render([comp, bg], seed=5).images
    np.testing.assert_allclose(both[0], swapped[1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(both[1], swapped[0], rtol=1e-5, atol=1e-6)


def test_render_jobs_equals_one_render_per_job(renderer_case):
    name, settings, _ = renderer_case
    job_a, job_b = _requests("a", 0.3), _requests("b", -0.2)
    batched = _fresh(name, settings).render_jobs([job_a, job_b], [5, 9])
    single = [_fresh(name, settings).render(job_a, seed=5), _fresh(name, settings).render(job_b, seed=9)]
    for bo, so in zip(batched, single):
        for x, y in zip(bo.images, so.images):
            np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError):
        _fresh(name, settings).render_jobs([job_a], [1, 2])


def test_known_shading_reproduces_the_background(renderer_case):
    name, settings, exact = renderer_case
    if not exact:
        pytest.skip(f"{name} is learned: it approximates the known background")
    bg, comp = _requests("a", 0.3)
    out = _fresh(name, settings).render([bg, comp], seed=1).images
    for req, im in zip((bg, comp), out):
        k = req.known
        np.testing.assert_allclose(im[k], (req.maps.albedo * req.shading)[k], rtol=1e-5, atol=1e-6)
