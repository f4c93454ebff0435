"""Tests of the embedded physical renderer on analytic synthetic scenes."""

import numpy as np
import pytest

from zcomp_cli.errors import InputError, UsageError
from zcomp_cli.renderers import get_renderer
from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.renderers.physical import PhysicalRenderer
from zcomp_cli.scene.config import MarchConfig
from zcomp_cli.scene.march import march_visibility, sample_depth
from zcomp_cli.testing import floor_scene, insert_bundle, light_context, sphere_object_bundle

LIGHT = (0.7, 1.0, 0.2)  # world, toward the light: from the right, above


def _angle(a, b):
    return np.rad2deg(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


@pytest.fixture(scope="module")
def boxed():
    return floor_scene(112, 84, with_box=True, light_dir=LIGHT, ambient=0.3, box_center=(-0.4, -3.2),
                       sky_occlusion=True)


@pytest.fixture(scope="module")
def inserted(boxed):
    s = boxed
    c = s.world_to_camera([0.4, 0.3, -2.6])
    b = sphere_object_bundle(s.camera, c, 0.3, (0.7, 0.7, 0.7), floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    # shading mask: object footprint dilated generously (shadow region included)
    ys, xs = np.nonzero(sel)
    mask = np.zeros(sel.shape, bool)
    mask[max(0, ys.min() - 6):ys.max() + 10, max(0, xs.min() - 16):xs.max() + 16] = True
    known = ~mask
    bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera,
                       scene_key="boxed")
    comp = RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, scene_key="boxed")
    r = PhysicalRenderer()
    out = r.render([bg, comp], seed=7)
    return dict(scene=s, bundle=b, sel=sel, mask=mask, bg=bg, comp=comp, out=out, center=c)


def test_synthetic_scene_conventions(boxed):
    s = boxed
    assert s.depth.dtype == np.float32 and s.depth.shape == (84, 112)
    valid = s.depth > 0
    assert np.allclose(np.linalg.norm(s.normals[valid], axis=-1), 1, atol=1e-5)
    # floor normal seen from a camera pitched down 25 deg: (0, cos25, sin25)
    assert np.allclose(s.up_cam, [0, np.cos(np.deg2rad(25)), np.sin(np.deg2rad(25))])
    assert (s.visibility < 1).sum() > 20  # the box casts a shadow
    assert np.allclose(s.image, s.albedo * s.shading)


def test_render_outputs(inserted):
    out = inserted["out"]
    s = inserted["scene"]
    assert len(out.images) == 2
    for img in out.images:
        assert img.shape == (84, 112, 3) and img.dtype == np.float32
        assert np.all(np.isfinite(img))
    known = ~inserted["mask"]
    if out.shading_mask is not None:  # grown along the object's shadow: a superset
        assert out.shading_mask.shape == known.shape and not (out.shading_mask < ~known).any()
        known &= ~out.shading_mask
    # known region reproduced exactly (albedo * known shading)
    assert known.any()
    assert np.array_equal(out.images[0][known], (s.albedo * s.shading).astype(np.float32)[known])
    assert {"estimate", "synthesis"} <= set(out.timings)
    assert "direction" in out.info["light"] and out.info["fallback"] is None


def test_background_pass_reproduces_background(inserted):
    s, out = inserted["scene"], inserted["out"]
    m = inserted["mask"] & (s.visibility > 0)
    err = np.abs(out.images[0][m] - s.image[m]).mean() / s.image[m].mean()
    assert err < 0.08


def test_object_shading_and_cast_shadow(inserted):
    s, out, sel = inserted["scene"], inserted["out"], inserted["sel"]
    bg, comp = out.images
    l = s.light_dir_cam
    n = inserted["comp"].maps.normals
    lum = comp.mean(-1)
    facing = sel & (n @ l > 0.5)
    away = sel & (n @ l < -0.2)
    assert facing.sum() > 5 and away.sum() > 5
    assert lum[facing].mean() > 1.5 * lum[away].mean()
    # cast shadow: floor pixels inside the mask, not the object, darker in comp than bg
    ratio = np.where(inserted["mask"] & ~sel, comp.mean(-1) / np.maximum(bg.mean(-1), 1e-6), 1)
    shadow = ratio < 0.7
    assert shadow.sum() > 10
    # the shadow lies on the side away from the light: light from +x => shadow at -x
    ys, xs = np.nonzero(shadow)
    _, xo = np.nonzero(sel)
    assert xs.mean() < xo.mean()
    # R ~ 1 where the object has little influence: far right of the mask, on the light's
    # side (it hides a few percent of the sky there at most)
    cols = np.nonzero(inserted["mask"].any(0))[0]
    right = inserted["mask"].copy()
    right[:, : cols.max() - 3] = False
    assert np.allclose(comp[right], bg[right], rtol=0.03)


@pytest.mark.slow
def test_determinism_and_cache(inserted):
    r = PhysicalRenderer()
    a = r.render([inserted["bg"], inserted["comp"]], seed=7)
    b = PhysicalRenderer().render([inserted["bg"], inserted["comp"]], seed=7)
    for x, y, z in zip(a.images, b.images, inserted["out"].images):
        assert np.array_equal(x, y) and np.array_equal(x, z)


def test_roi_matches_full_frame(inserted):
    bg, comp = inserted["bg"], inserted["comp"]
    ys, xs = np.nonzero(inserted["mask"])
    roi = (int(xs.min()) + 3, int(ys.min()) + 2, int(xs.max()) - 5, int(ys.max()) - 1)
    reqs = [RenderRequest(r.maps, r.shading, r.known, r.camera, roi=roi, scene_key="boxed") for r in (bg, comp)]
    out = PhysicalRenderer().render(reqs, seed=7)
    x0, y0, x1, y1 = roi
    full = inserted["out"].images[1]
    assert np.array_equal(out.images[1][y0:y1, x0:x1], full[y0:y1, x0:x1])
    assert np.all(np.isfinite(out.images[1]))


def _req(s, known, **over):
    maps = SceneMaps(over.get("depth", s.depth), over.get("normals", s.normals),
                     over.get("albedo", s.albedo))
    return RenderRequest(maps, over.get("shading", s.shading), known, s.camera)


def test_bad_values_stay_finite():
    s = floor_scene(48, 36, with_box=True, light_dir=LIGHT)
    known = np.ones(s.depth.shape, bool)
    known[10:25, 10:30] = False
    depth = s.depth.copy()
    depth[12, 12] = np.nan
    depth[13, 13] = np.inf
    normals = s.normals.copy()
    normals[14, 14] = np.nan
    shading = s.shading.copy()
    shading[0:5, 0:5] = 1e4
    shading[30, 30] = np.nan
    albedo = s.albedo.copy()
    albedo[15:18, 15:18] = 0
    albedo[19, 19] = np.inf
    out = PhysicalRenderer().render([_req(s, known, depth=depth, normals=normals,
                                          shading=shading, albedo=albedo)])
    img = out.images[0]
    assert np.all(np.isfinite(img))
    assert np.all(img[15:18, 15:18] == 0)


def test_one_pixel_and_empty_masks():
    s = floor_scene(40, 30, with_box=True, light_dir=LIGHT)
    known = np.ones(s.depth.shape, bool)
    out = PhysicalRenderer().render([_req(s, known)])
    assert np.array_equal(out.images[0], (s.albedo * s.shading).astype(np.float32))
    known[20, 20] = False
    out = PhysicalRenderer().render([_req(s, known)])
    assert np.all(np.isfinite(out.images[0])) and out.images[0][20, 20].sum() > 0


def test_settings_and_errors():
    with pytest.raises(UsageError):
        PhysicalRenderer(bogus=1)
    with pytest.raises(UsageError):
        PhysicalRenderer(march_steps=0)
    r = get_renderer("physical", shadow_softness=5.0)
    assert r.settings()["light"]["shadow_softness"] == 5.0 and r.settings()["name"] == "physical"
    s = floor_scene(20, 16)
    bad = RenderRequest(SceneMaps(s.depth[:5], s.normals, s.albedo), s.shading,
                        np.ones((16, 20), bool), s.camera)
    with pytest.raises(InputError):
        PhysicalRenderer().render([bad])


def test_visibility_primitives():
    d = np.full((10, 10), 2.0)
    assert np.allclose(sample_depth(d, np.array([5.0, 0.1]), np.array([5.0, 9.9])), 2.0)
    d[:, :5] = 0
    assert sample_depth(d, np.array([2.0]), np.array([5.0]))[0] == 0
    assert len(march_visibility(np.zeros((0, 3)), np.zeros((0, 3)), np.array([0, 1.0, 0]),
                                d, floor_scene(10, 10).camera, cfg=MarchConfig(), steps=8)) == 0


def _march_one(p, n, l, jit, depth, camera, cfg, steps):
    """One ray marched step by step, every step (the definition ``march_visibility``
    keeps): (visible, first hit's distance, its texel), nearest texels."""
    H, W = depth.shape
    z0 = max(-p[2], 1e-6)
    start = p + n * (cfg.march_bias_rel * z0)
    dmax = cfg.march_range_rel * z0
    for k in range(1, steps + 1):
        r = min(max(k + (jit - 0.5), 0.25), steps) / steps
        t = dmax * (r * r)
        q = start + l * t
        qz = -q[2]
        if not qz > 1e-6:
            continue
        x, y = camera.fx * q[0] / qz + camera.cx, -camera.fy * q[1] / qz + camera.cy
        if not (0 <= x < W and 0 <= y < H):
            continue
        ds = depth[int(y), int(x)]
        if ds > 0 and cfg.march_bias_rel * qz < qz - ds < cfg.march_thickness_rel * qz:
            return 0.0, t, (int(y), int(x))
    return 1.0, np.inf, (-1, -1)


def test_a_batch_of_rays_marches_as_each_ray_alone():
    """``march_visibility`` drops a ray from its batch once it has met an occluder, or has
    been in the frame and left it: each ray's visibility, first hit's distance and texel
    are the ones it gets marched alone, every step -- rays that hit the box, leave the
    frame lit, head back toward the camera, or start outside the frame (their start
    lifted off an edge pixel) and come in."""
    s = floor_scene(64, 48, with_box=True, box_center=(0.0, -3.0))
    ys, xs = np.nonzero(s.depth > 0)
    pick = np.linspace(0, len(ys) - 1, 300).astype(int)
    P = s.camera.ray(xs[pick] + 0.5, ys[pick] + 0.5) * s.depth[ys[pick], xs[pick]][:, None]
    N = s.normals[ys[pick], xs[pick]].astype(np.float64)
    rng = np.random.default_rng(2)
    L = np.where(rng.uniform(size=(len(P), 1)) < 0.2, [[0.1, 0.2, 1.0]], [[-0.4, 0.5, -0.7]])  # some toward the camera
    L = L + 0.3 * rng.normal(size=L.shape)
    # floor points on the frame's left edge, lifted out of it, their rays toward the box
    edge = np.nonzero((s.depth[:, 0] > 0))[0][::4]
    Pe = s.camera.ray(np.full(len(edge), 0.5), edge + 0.5) * s.depth[edge, 0][:, None]
    P, N = np.concatenate([P, Pe]), np.concatenate([N, np.tile([-1.0, 0.0, 0.0], (len(edge), 1))])
    L = np.concatenate([L, np.tile([1.0, 0.25, -0.3], (len(edge), 1))])
    L /= np.linalg.norm(L, axis=1, keepdims=True)
    jit = rng.uniform(size=len(P))
    cfg = MarchConfig()
    vis, dist, tex = march_visibility(P, N, L, s.depth, s.camera, cfg=cfg, steps=24, jitter=jit,
                                      return_distance=True, return_texel=True, nearest=True)
    want = [_march_one(P[i], N[i], L[i], jit[i], s.depth, s.camera, cfg, 24) for i in range(len(P))]
    assert np.array_equal(vis, [w[0] for w in want])
    assert np.array_equal(dist, [w[1] for w in want])
    assert np.array_equal(tex, np.array([w[2] for w in want]))
    assert 0.1 < vis.mean() < 0.9  # both kinds of ray are there
    lifted = np.arange(len(P) - len(edge), len(P))
    z0 = np.maximum(-P[lifted, 2], 1e-6)
    start = P[lifted] + N[lifted] * (cfg.march_bias_rel * z0)[:, None]
    assert np.all(s.camera.project(start)[0][:, 0] < 0)  # they start outside the frame
    assert (vis[lifted] == 0).any()  # and some come in and meet the box


def test_long_shadow_grows_the_shading_mask():
    """Under a low sun the object's shadow runs past a tight shading mask: the renderer
    re-shades along it (``RenderOutput.shading_mask``) instead of cutting it, the grown
    pixels lie on the light's far side, and the composite darkens them."""
    from zcomp_cli.compositing.compositor import composite

    light = (1.0, 0.45, 0.0)  # from the right, ~24 deg above the floor: a shadow ~2x the height
    s = floor_scene(112, 84, light_dir=light, ambient=0.3)
    c = s.world_to_camera([0.0, 0.3, -2.8])
    b = sphere_object_bundle(s.camera, c, 0.3, (0.7, 0.7, 0.7), floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    ys, xs = np.nonzero(sel)
    mask = np.zeros(sel.shape, bool)
    mask[ys.min() - 2:ys.max() + 4, xs.min() - 3:xs.max() + 4] = True  # tight: the shadow leaves it
    known = ~mask
    spec = light_context({"direction": [float(v) for v in s.light_dir_cam], "angular_radius_deg": 1.0,
                          "strength": 2.0})
    reqs = [RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, light=spec),
            RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, light=spec)]
    out = PhysicalRenderer().render(reqs, seed=1)
    assert out.shading_mask is not None
    grown = out.shading_mask & ~mask
    assert grown.sum() > 20
    gy, gx = np.nonzero(grown)
    assert np.median(gx) < xs.min()  # on the far side of the light (to the left of the object)
    res = composite(s.image, out.images[0], out.images[1], out.shading_mask, sel.astype(np.float32))
    ratio = (res.image.mean(-1) / np.maximum(s.image.mean(-1), 1e-6))[grown]
    # the shadow continues past the requested mask (the rest of the grown band is the
    # margin for its penumbra and the compositor's blur)
    assert (ratio < 0.7).mean() > 0.3 and np.percentile(ratio, 10) < 0.65
    # without a cast shadow to extend (the contact-shadow fallback), nothing grows
    bare = PhysicalRenderer().render([RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known,
                                                    s.camera)] * 2, seed=1)
    assert bare.shading_mask is None or not (bare.shading_mask & ~mask).any()
