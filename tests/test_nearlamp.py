"""A lamp near the scene, placed by the falloff of the floor's shading (``nearlamp``),
and the renderer aiming its light at each inserted object."""

import numpy as np
import pytest

from zcomp_cli.renderers.physical import PhysicalRenderer, estimate_lighting
from zcomp_cli.renderers.physical.lighting import LAMP_SOFTNESS_DEG
from zcomp_cli.renderers.physical.nearlamp import LAMP_MIN_FALLOFF, MIN_SUPPORT_PIXELS, fit_near_lamp
from zcomp_cli.testing import floor_scene

from test_physical_shadows import FAST, _angle, _insert

LAMP = ((1.0, 2.5, -4.0), 4.0)  # world position (m), intensity: 0.64 at its foot, ambient 0.3


def _floor(s):
    """(points (N, 3), luminance shading (N,), up (3,)) of the scene's floor pixels."""
    n = s.normals.reshape(-1, 3)
    floor = (s.depth.reshape(-1) > 0) & (n @ s.up_cam > 0.99)
    return s.camera.unproject(s.depth).reshape(-1, 3)[floor], s.shading.reshape(-1, 3)[floor, 0], s.up_cam


def _lamp_scene(**kw):
    return floor_scene(128, 96, light_intensity=0.0, ambient=0.3, lamp=LAMP, **kw)


def test_lamp_placed_by_the_falloff():
    s = _lamp_scene()
    P, y, up = _floor(s)
    fit = fit_near_lamp(P, y, up)
    truth = np.asarray(s.meta["lamp_cam"])
    assert fit is not None and fit.found and fit.falloff > LAMP_MIN_FALLOFF
    # the distances are sampled at 0.8-1.25x steps around the coarse grid's best
    assert np.linalg.norm(fit.position - truth) < 0.15 * np.linalg.norm(truth - fit.aim)
    obj = s.world_to_camera([0.3, 0.0, -3.0])
    want = (truth - obj) / np.linalg.norm(truth - obj)
    assert _angle(fit.direction_at(obj), want) < 5.0
    assert fit.ambient == pytest.approx(0.3, abs=0.05)


def test_a_sun_lit_floor_has_no_lamp():
    s = floor_scene(128, 96, light_dir=(0.5, 1.0, 0.3), ambient=0.3)
    fit = fit_near_lamp(*_floor(s))
    assert fit is None or not fit.found


def test_the_fit_does_not_depend_on_the_depth_scale_or_the_exposure():
    # an estimator's relative depth: the same scene 10x larger is the same light
    P, y, up = _floor(_lamp_scene())
    a, b = fit_near_lamp(P, y, up), fit_near_lamp(10.0 * P, y, up)
    assert b.found and np.allclose(b.position, 10.0 * a.position, rtol=1e-6, atol=1e-6)
    # nor on the exposure: an HDR photograph 1e6 times brighter (or darker) is the same light
    for k in (1e6, 1e-6):
        c = fit_near_lamp(P, k * y, up)
        assert c.found and np.allclose(c.position, a.position, atol=1e-6) and c.falloff == pytest.approx(a.falloff)


def test_bad_values_are_dropped_and_degenerate_input_gives_none():
    P, y, up = _floor(_lamp_scene())
    ref = fit_near_lamp(P, y, up)
    y2, P2 = y.copy(), P.copy()
    y2[::10], y2[1::10], y2[2::10] = np.nan, np.inf, -1.0
    P2[3::10] = np.nan
    bad = fit_near_lamp(P2, y2, up)
    assert bad.found and _angle(bad.position - bad.aim, ref.position - ref.aim) < 3.0
    assert fit_near_lamp(P[: MIN_SUPPORT_PIXELS - 1], y[: MIN_SUPPORT_PIXELS - 1], up) is None
    assert fit_near_lamp(np.zeros_like(P), y, up) is None  # every point at the camera
    same = fit_near_lamp(np.repeat(P[:1], len(P), 0), y, up)  # one point: nothing to fit
    assert same is None or not same.found
    flat = fit_near_lamp(P, np.full(len(y), 0.5), up)  # no falloff at all
    assert flat is None or not flat.found
    assert fit_near_lamp(P, np.zeros(len(y)), up) is None  # no light


def test_the_estimate_reads_a_lamp_and_draws_its_shadow():
    s = _lamp_scene(with_box=True, box_center=(-0.4, -3.2))
    e = estimate_lighting(s.depth, s.normals, s.shading, s.depth > 0, s.camera, **FAST)
    assert e.fallback is None and e.direction_source.startswith("a lamp near the scene")
    truth = np.asarray(s.meta["lamp_cam"])
    assert np.linalg.norm(e.lamp_position - truth) < 0.15 * np.linalg.norm(truth - e.lamp_aim)
    # the split of ambient and lamp is the falloff fit's, at the support's centre
    v = truth - e.lamp_aim
    true_share = 0.3 / (0.3 + LAMP[1] * max(v @ s.up_cam, 0.0) / np.linalg.norm(v) ** 3)
    assert e.share_source.startswith("the lamp's falloff") and abs(e.ambient_share - true_share) < 0.05
    assert e.softness_deg == LAMP_SOFTNESS_DEG  # not measured: the lamp's size is unknown


def test_the_renderer_aims_the_lamp_at_each_object():
    # two objects on either side of the lamp's foot: each one's light comes from the
    # lamp as it sees it (directions 40+ deg apart), not from the scene's centre
    s = _lamp_scene()
    truth = np.asarray(s.meta["lamp_cam"])
    got = []
    for x in (-0.9, 1.2):
        bg, comp, sel, mask = _insert(s, [x, 0.3, -3.2])
        out = PhysicalRenderer().render([bg, comp], seed=1)
        light = out.info["light"]
        assert "aimed at the object" in light["direction_source"]
        c = s.world_to_camera([x, 0.3, -3.2])
        want = (truth - c) / np.linalg.norm(truth - c)
        got.append((np.asarray(light["direction"]), want))
    for d, want in got:
        assert _angle(d, want) < 10.0  # its visible points' mean: in front of its centre
    assert _angle(got[0][0], got[1][0]) > 30.0
    assert all(np.isfinite(i).all() for i in out.images)


def test_a_falloff_the_shadows_contradict_is_set_aside():
    # a sun casts the box's shadow; the floor also brightens toward a point far from the
    # sun's direction (a highlight's glow, no shadows of its own): the shadows decide
    from test_physical_shadows import SUN

    s = floor_scene(128, 96, with_box=True, light_dir=SUN, ambient=0.3, box_center=(-0.4, -3.2))
    glow = np.array([-1.5, 2.5, -5.0])  # world: far left, behind
    P = s.camera.unproject(s.depth) @ s.cam_to_world.T + s.camera_origin
    v = glow - P
    g = np.maximum(v[..., 1], 0) / np.linalg.norm(v, axis=-1) ** 3 * 2.5 ** 2
    shading = s.shading + (1.5 * g * (s.depth > 0) * (s.normals @ s.up_cam > 0.99))[..., None]
    floor = (s.depth > 0) & (s.normals @ s.up_cam > 0.99)
    fit = fit_near_lamp(s.camera.unproject(s.depth)[floor], shading[floor][:, 0], s.up_cam)
    assert fit.found  # the glow alone reads as a lamp
    e = estimate_lighting(s.depth, s.normals, shading, s.depth > 0, s.camera, **FAST)
    assert "set aside" in e.direction_source and e.lamp_position is None
    assert _angle(e.direction, s.light_dir_cam) < 10.0


def test_the_lamp_is_aimed_at_the_posed_meshs_centre():
    # with the posed mesh, its bounding box's centre is the object's: exact
    import dataclasses

    from test_physical_shadows import _sphere_mesh

    s = _lamp_scene()
    truth = np.asarray(s.meta["lamp_cam"])
    centre_w = [-0.9, 0.3, -3.2]
    bg, comp, sel, mask = _insert(s, centre_w)
    c = s.world_to_camera(centre_w)
    out = PhysicalRenderer().render([bg, dataclasses.replace(comp, occluder=_sphere_mesh(c, 0.3))], seed=1)
    light = out.info["light"]
    est = PhysicalRenderer().estimate(bg)
    # the direction from the fitted lamp to the sphere's centre, and the strength scaled
    # by the squared distance ratio to the support's centre
    want = (est.lamp_position - c) / np.linalg.norm(est.lamp_position - c)
    assert _angle(np.asarray(light["direction"]), want) < 1e-3
    gain = (np.linalg.norm(est.lamp_position - est.lamp_aim) / np.linalg.norm(est.lamp_position - c)) ** 2
    assert np.allclose(light["intensity"], np.asarray(est.intensity) * np.clip(gain, 0.25, 4.0))
    assert _angle(want, truth - c) < 5.0


def _checker(P, s, dark=0.15, bright=0.6, size=0.5):
    """(N,) checker albedo of camera-frame floor points P of scene s."""
    W = P @ s.cam_to_world.T + s.camera_origin
    return np.where((np.floor(W[:, 0] / size) + np.floor(W[:, 2] / size)) % 2 == 0, dark, bright)


def test_a_lamp_multiplies_the_albedo_a_glossy_glow_adds_to_it():
    from zcomp_cli.renderers.physical.nearlamp import LAMP_MAX_GLOSS_INDEX, gloss_index

    s = _lamp_scene()
    P, y, up = _floor(s)
    a = _checker(P, s)
    lamp = fit_near_lamp(P, y, up, albedo=a)  # the lamp's light on a checker floor
    assert lamp.found and abs(lamp.gloss_index) < 0.1
    # the same falloff as a reflection: image = albedo * flat shading + glow, so image
    # over albedo carries glow / albedo
    glow = y - y.min()
    gloss = fit_near_lamp(P, 0.3 + glow / a * 0.15, up, albedo=a)
    assert gloss.falloff >= LAMP_MIN_FALLOFF and gloss.gloss_index > LAMP_MAX_GLOSS_INDEX
    assert not gloss.found
    # no contrast, too few pixels, or a falloff missing on one class
    assert np.isnan(fit_near_lamp(P, y, up, albedo=np.full(len(y), 0.4)).gloss_index)
    g = lamp.support_shading(P) - lamp.ambient
    assert np.isnan(gloss_index(g[:60], y[:60], a[:60]))
    y_dark_flat = np.where(a < 0.3, 0.5, y)
    assert gloss_index(g, y_dark_flat, a) == np.inf
    with pytest.raises(ValueError, match="albedo has 3 values"):
        fit_near_lamp(P, y, up, albedo=np.ones(3))


def test_the_estimate_tells_a_glossy_glow_from_a_lamp_by_the_albedo():
    # a sky-lit checker floor whose glossy glow peaks under the lamp's place: read as a
    # lamp without the albedo, as gloss with it
    lit = _lamp_scene()
    s = floor_scene(128, 96, light_intensity=0.0, ambient=0.3)
    P = s.camera.unproject(s.depth).reshape(-1, 3)
    floor = (s.depth.reshape(-1) > 0) & (s.normals.reshape(-1, 3) @ s.up_cam > 0.99)
    a = np.where(floor, _checker(P, s), 0.5)
    glow = lit.shading[..., 0].reshape(-1) - 0.3  # the lamp's term, as a reflection
    shading = (0.3 + np.where(floor, 0.15 * glow / a, 0.0)).reshape(s.depth.shape)
    shading = np.repeat(shading[..., None], 3, -1)
    albedo = np.repeat(a.reshape(s.depth.shape)[..., None], 3, -1)
    blind = estimate_lighting(s.depth, s.normals, shading, s.depth > 0, s.camera, **FAST)
    assert blind.direction_source.startswith("a lamp near the scene")
    e = estimate_lighting(s.depth, s.normals, shading, s.depth > 0, s.camera, albedo=albedo, **FAST)
    assert e.lamp_position is None and not e.direction_source.startswith("a lamp")
