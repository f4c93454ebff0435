"""The support beyond the frame, as the object's rays read it (``reflect``).

A ray from the object that meets the floor outside the frame reads what the floor
reflects of the light there (``support_reflectance`` times ``LightModel.open_shading``),
so that under a lamp the floor beyond the frame falls off with its distance as the floor
in the frame does. Measured first on seed 3301's lamp cases: the object's bounce was
1.2-2 times Cycles' with the frame's median floor radiance standing for the floor beyond
it (docs/calibration-record.md).
"""

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.renderers.physical.reflect import Surroundings, _met, support_reflectance
from zcomp_cli.renderers.physical.settings import TransportConfig
from zcomp_cli.scene import gather
from zcomp_cli.scene.config import MarchConfig
from zcomp_cli.scene.lightmodel import Lamp, LightModel, Sky
from zcomp_cli.scene.skyvis import hemisphere_directions

UP = np.array([0.0, 1.0, 0.0])
TRIM = TransportConfig().support_trim
FLOOR_Y = -1.0


def _model(ground=(0.0, 0.0, 0.0)):
    sky = np.zeros((9, 3))
    sky[0] = 0.05  # a dim uniform sky
    lamp = Lamp(position=[0.3, 0.2, -5.0], radius_m=0.1, intensity=[2.0, 1.5, 1.0])
    return LightModel(sky=Sky(radiance_sh=sky, ground=np.asarray(ground, float), up=UP), lamps=(lamp,),
                      anchor=np.array([0.0, FLOOR_Y, -5.0]))


def _floor_scene(cam: Camera, model: LightModel, checker: bool = True):
    """(depth, points, normals, image, albedo, floor mask) of a Lambertian floor at
    y = FLOOR_Y seen by a level camera, nothing above the horizon (depth 0)."""
    H, W = cam.height, cam.width
    ys, xs = np.mgrid[0:H, 0:W]
    ray = cam.ray(xs.ravel() + 0.5, ys.ravel() + 0.5).reshape(H, W, 3)  # z = -1
    floor = ray[..., 1] < -1e-3
    d = np.where(floor, FLOOR_Y / np.where(floor, ray[..., 1], -1.0), 0.0)
    P = ray * d[..., None]
    n = np.broadcast_to(UP, (H, W, 3)).copy()
    alb = np.full((H, W, 3), 0.6)
    if checker:
        dark = ((np.floor(P[..., 0] / 0.5) + np.floor(P[..., 2] / 0.5)) % 2).astype(bool)
        alb[dark] = 0.15
    E = model.open_shading(P.reshape(-1, 3), UP).reshape(H, W, 3)
    img = np.where(floor[..., None], alb * E, 0.0)
    return d, P, n, img, alb, floor


def test_open_shading_is_the_lamps_and_the_skys_at_n_l():
    model = _model()
    q = np.array([[0.3, FLOOR_Y, -5.0], [2.3, FLOOR_Y, -5.0]])
    E = model.open_shading(q, UP)
    sky = model.sky.shading(UP[None])[0]
    # under the lamp: 1.2 m straight below it
    np.testing.assert_allclose(E[0], sky + np.array([2.0, 1.5, 1.0]) / 1.2 ** 2, rtol=1e-9)
    # 2 m aside: the inverse square and the cosine
    r2 = 1.2 ** 2 + 2.0 ** 2
    np.testing.assert_allclose(E[1], sky + np.array([2.0, 1.5, 1.0]) * (1.2 / np.sqrt(r2)) / r2, rtol=1e-9)
    # a surface facing away from every light gets none of theirs
    assert np.all(model.open_shading(q, -UP) <= model.sky.shading(-UP[None])[0] + 1e-12)


def test_the_support_reflects_its_mean_albedo_under_a_lamp():
    cam = Camera.from_fov(70.0, 48, 48)
    model = _model()
    d, P, n, img, alb, floor = _floor_scene(cam, model)
    got = support_reflectance(P, n, img, floor, model, TRIM)
    # the shading falls off 10-fold across the floor; what it reflects is its albedo's
    # mean (trimmed: the checker's tones are not quite half and half here)
    np.testing.assert_allclose(got, alb[floor].mean(0), rtol=0.01)
    assert abs(got[0] - 0.15) > 0.1 and abs(got[0] - 0.6) > 0.1  # not one of its tones
    # a few broken pixels and a bright prop among the floor's do not move it far
    img2 = img.copy()
    img2[floor.nonzero()[0][:5], floor.nonzero()[1][:5]] = np.nan
    got2 = support_reflectance(P, n, img2, floor, model, TRIM)
    assert np.all(np.isfinite(got2))
    np.testing.assert_allclose(got2, alb[floor].mean(0), rtol=0.02)


def test_no_support_or_no_light_says_so():
    cam = Camera.from_fov(70.0, 16, 16)
    model = _model()
    d, P, n, img, alb, floor = _floor_scene(cam, model, checker=False)
    assert support_reflectance(P, n, img, np.zeros_like(floor), model, TRIM) is None
    dark = LightModel(sky=Sky(radiance_sh=np.zeros((9, 3)), ground=np.zeros(3), up=UP), anchor=model.anchor)
    assert support_reflectance(P, n, img, floor, dark, TRIM) is None


@pytest.mark.parametrize("measured", [True, False])
def test_a_ray_reads_the_floor_beyond_the_frame_as_the_frame_would_show_it(measured):
    """The same rays from a point above a plain floor, seen by a wide camera (the floor
    they meet is in its frame: the photograph's texel) and a narrow one (beyond its
    frame): each ray brings the same radiance. Without the support's measure (the frame's median
    floor radiance for every point beyond it, as before), the rays near the lamp and far
    from it disagree with the frame by a factor of several."""
    model_w = _model()
    wide, narrow = Camera.from_fov(110.0, 384, 384), Camera.from_fov(20.0, 64, 64)
    dw, Pw, nw, imgw, _, floor_w = _floor_scene(wide, model_w, checker=False)
    model = _model(ground=np.median(imgw[floor_w], 0))  # what the light fit measures
    dn, Pn, nn, imgn, _, floor_n = _floor_scene(narrow, model, checker=False)
    P = np.array([[0.2, FLOOR_Y + 0.4, -5.3]])
    nv = -UP[None]
    dirs = np.stack(hemisphere_directions(nv, np.array([0.37]), 64))
    ys = xs = np.array([0])
    march = MarchConfig()

    def read(cam, d, P_, n_, img, floor):
        sup = support_reflectance(P_, n_, img, floor, model, TRIM) if measured else None
        s = Surroundings(img, np.zeros_like(img), np.zeros(d.shape, bool), sup)
        L, _ = _met(model, cam, d, P, nv, dirs, ys, xs, 16, None, None, s, march)
        seen = gather.trace(P, nv, dirs, d, cam, cfg=march, steps=16, jitter=np.zeros(1), support=(model.anchor, UP))
        return L[:, 0], seen.kind[:, 0], seen.texel[:, 0, 0] >= 0

    Lw, kw, in_w = read(wide, dw, Pw, nw, imgw, floor_w)
    Ln, kn, _ = read(narrow, dn, Pn, nn, imgn, floor_n)
    # (in the wide frame the march meets the floor's texels, or the plane at a texel)
    both = np.isin(kw, (gather.SCENE, gather.SUPPORT)) & in_w & (kn == gather.BEYOND)
    assert both.sum() >= 20
    if measured:
        # (over the rays: the march meets a texel near the point, not at it)
        assert abs(Ln[both].mean() / Lw[both].mean() - 1.0) < 0.03
        # the falloff is kept: the rays meeting the floor nearest the lamp read the most
        q = P[0] + dirs[both, 0] * ((P[0, 1] - FLOOR_Y) / -dirs[both, 0, 1])[:, None]
        near = np.linalg.norm(q - model.lamps[0].position, axis=1)
        assert np.corrcoef(near, Ln[both].mean(1))[0, 1] < -0.5
    else:
        # the frame's median floor, far from the lamp, for the floor beside the lamp
        assert Ln[both].mean() / Lw[both].mean() < 0.5


def test_a_glint_on_the_floor_does_not_light_the_floor_beyond_the_frame():
    """HDR extremes: 2 % of the floor's pixels 1000 times as bright (the sun's glint
    toward the camera in an HDR photograph), a few at inf or NaN: what the support
    reflects stays within 2 % of its albedo's mean (the plain mean: 23 times it)."""
    cam = Camera.from_fov(70.0, 48, 48)
    model = _model()
    d, P, n, img, alb, floor = _floor_scene(cam, model)
    rng = np.random.default_rng(3)
    ys, xs = np.nonzero(floor)
    pick = rng.choice(len(ys), size=max(1, len(ys) // 50), replace=False)
    img2 = img.copy()
    img2[ys[pick], xs[pick]] *= 1000.0
    img2[ys[:3], xs[:3]] = np.inf
    img2[ys[3:6], xs[3:6]] = np.nan
    got = support_reflectance(P, n, img2, floor, model, TRIM)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, alb[floor].mean(0), rtol=0.02)
