"""zcomp_cli.metrics.light_spheres: the light rendered on a diffuse and a matte-silver
sphere, and the relative scale-invariant RMSE between two lights' renders."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from zcomp_cli.errors import InputError
from zcomp_cli.metrics.light_spheres import (
    DIFFUSE_ALBEDO,
    light_sphere_error,
    parse_light,
    render_spheres,
    si_rmse,
    sphere_geometry,
)
from zcomp_cli.scene import sh

SIZE = 64


def sun(direction, irradiance=(1.0, 1.0, 1.0), radius_deg=0.5) -> dict:
    return {"kind": "sun", "direction_camera": list(direction), "angular_radius_deg": radius_deg,
            "irradiance_rgb": list(irradiance)}


def sky(level=0.2, ground=(0.1, 0.1, 0.1)) -> dict:
    """A sky of uniform radiance ``level`` over the upper hemisphere (+y; the lower one
    is the ground's, ``lightmodel.Sky``): its SH projection, exact to order 2 (a
    hemisphere's band-2 coefficients are 0): Y00 x 2 pi, Y1-1 (y) x pi."""
    b = sh.basis(np.array([[0.0, 1.0, 0.0]]))[0]
    c = np.zeros((9, 3))
    c[0] = level * b[0] * 2.0 * math.pi
    c[1] = level * b[1] * math.pi
    return {"kind": "sky", "radiance_sh_rgb": c.tolist(), "ground_radiance_rgb": list(ground)}


def lamp(position, intensity=(2.0, 2.0, 2.0), radius_m=0.1, facing=None) -> dict:
    return {"kind": "lamp", "position_camera": list(position), "intensity_rgb_at_1m": list(intensity),
            "radius_m": radius_m, "facing_camera": facing}


def light(*items, up=(0.0, 1.0, 0.0)) -> dict:
    return {"up_camera": list(up), "lights": list(items)}


def scaled(lt: dict, k: float) -> dict:
    """Every strength of ``lt`` times ``k``."""
    out = copy.deepcopy(lt)
    for it in out["lights"]:
        for key in ("irradiance_rgb", "intensity_rgb_at_1m", "radiance_sh_rgb", "ground_radiance_rgb"):
            if key in it:
                it[key] = (k * np.asarray(it[key], float)).tolist()
    return out


# -- geometry and rendering ---------------------------------------------------------------
def test_sphere_geometry_faces_camera_and_is_unit():
    n, mask = sphere_geometry(SIZE)
    assert n.shape == (SIZE, SIZE, 3) and mask.shape == (SIZE, SIZE)
    assert np.allclose(np.linalg.norm(n[mask], axis=1), 1.0)
    assert (n[mask][:, 2] >= 0).all()
    c = SIZE // 2
    assert n[c, c, 2] > 0.99
    assert n[0, c, 1] > 0.5 or not mask[0, c]  # row 0 is the top (+y)
    assert n[c, 2, 0] < -0.5 and n[c, SIZE - 3, 0] > 0.5  # column 0 is the left (-x)
    assert not mask[0, 0]
    assert abs(mask.mean() - math.pi / 4) < 0.02


def test_sun_at_camera_lights_centre_brightest_and_falls_off_as_cosine():
    out = render_spheres(light(sun([0.0, 0.0, 1.0])), size=SIZE)
    d, mask = out["diffuse"], out["mask"]
    n, _ = sphere_geometry(SIZE)
    lum = d.mean(-1)
    c = SIZE // 2
    assert lum[c - 1:c + 1, c - 1:c + 1].min() >= lum[mask].max() - 1e-9
    # Lambert: albedo x irradiance x cos, cos = n.z
    assert np.allclose(d[mask], DIFFUSE_ALBEDO * n[mask][:, 2:3] * np.ones(3), atol=1e-9)
    # along the horizontal diameter, the falloff toward the limb
    row = lum[c, c:]
    assert np.all(np.diff(row[mask[c, c:]]) < 0)
    assert (d[~mask] == 0).all() and (out["silver"][~mask] == 0).all()
    # the silver highlight is at the centre too (mirror of +z is +z)
    s = out["silver"].mean(-1)
    iy, ix = np.unravel_index(np.argmax(s), s.shape)
    assert abs(iy - c) <= 1 and abs(ix - c) <= 1


def test_sun_from_right_lights_right_half():
    out = render_spheres(light(sun([1.0, 0.0, 0.0])), size=SIZE)
    lum = out["diffuse"].mean(-1)
    assert lum[:, :SIZE // 2].max() == 0.0
    assert lum[:, SIZE // 2:].max() > 0.5


def test_uniform_sky_shades_diffuse_sphere_evenly():
    out = render_spheres(light(sky(0.3, ground=(0.3, 0.3, 0.3))), size=SIZE)
    d = out["diffuse"][out["mask"]]
    # a uniform radiance L above and a ground of radiance L below shade every normal with L
    assert np.allclose(d, DIFFUSE_ALBEDO * 0.3, rtol=1e-4)
    # the sky alone: L (1 + n.up) / 2
    n, mask = sphere_geometry(SIZE)
    top = render_spheres(light(sky(0.3, ground=(0.0, 0.0, 0.0))), size=SIZE)["diffuse"][mask]
    assert np.allclose(top, DIFFUSE_ALBEDO * 0.3 * 0.5 * (1.0 + n[mask][:, 1:2]), atol=1e-4)
    assert (out["silver"][out["mask"]] > 0).all()


def test_lamp_is_seen_from_center():
    # the lamp right of the centre lights the spheres' right halves, wherever the camera is
    out = render_spheres(light(lamp([3.0, 0.0, -5.0])), center=[0.0, 0.0, -5.0], size=SIZE)
    lum = out["diffuse"].mean(-1)
    assert lum[:, :SIZE // 2].max() == 0.0 and lum.max() > 0
    # inverse square: at 3 m, a facing surface gets intensity / 9, times the cosine
    n, mask = sphere_geometry(SIZE)
    assert np.allclose(lum[mask], DIFFUSE_ALBEDO * 2.0 / 9.0 * np.maximum(n[mask][:, 0], 0.0), atol=1e-12)
    # a panel facing away from the spheres lights nothing
    away = render_spheres(light(lamp([3.0, 0.0, -5.0], facing=[1.0, 0.0, 0.0])), center=[0.0, 0.0, -5.0], size=SIZE)
    assert away["diffuse"].max() == 0.0


# -- the score ----------------------------------------------------------------------------
def test_si_rmse_values():
    rng = np.random.default_rng(0)
    a = rng.random((8, 8, 3))
    assert si_rmse(a, a) == 0.0
    assert si_rmse(3.0 * a, a) < 1e-12
    assert si_rmse(np.zeros_like(a), a) == 1.0
    assert si_rmse(a, np.zeros_like(a)) == 1.0
    assert si_rmse(np.zeros_like(a), np.zeros_like(a)) == 0.0
    b = rng.random((8, 8, 3))
    v = si_rmse(a, b)
    assert 0.0 < v < 1.0
    # it is the sine of the angle between the two images as vectors: symmetric
    assert math.isclose(v, si_rmse(b, a), rel_tol=1e-9)
    cos = float(a.ravel() @ b.ravel()) / (np.linalg.norm(a) * np.linalg.norm(b))
    assert math.isclose(v, math.sqrt(1 - cos * cos), rel_tol=1e-9)
    # huge but finite values do not overflow
    assert si_rmse(1e300 * a, a) < 1e-9
    m = np.zeros((8, 8), bool)
    m[:4] = True
    c = a.copy()
    c[4:] = 0
    assert si_rmse(c, a, m) == 0.0


def test_si_rmse_bad_input_raises():
    a = np.ones((4, 4, 3))
    with pytest.raises(InputError):
        si_rmse(a, np.ones((4, 5, 3)))
    with pytest.raises(InputError):
        si_rmse(np.ones((4, 4)), np.ones((4, 4)))
    with pytest.raises(InputError):
        si_rmse(a, np.full((4, 4, 3), np.nan))
    with pytest.raises(InputError):
        si_rmse(a, a, np.zeros((4, 4)))


def test_identical_lights_score_zero():
    lt = light(sun([0.3, 0.8, 0.5], (1.0, 0.9, 0.7)), sky(0.2), lamp([-1.0, 1.0, -2.0]))
    r = light_sphere_error(lt, copy.deepcopy(lt), center=[0.0, -0.5, -3.0])
    assert r == {"diffuse": 0.0, "silver": 0.0, "mean": 0.0}


def test_scale_invariance_doubling_strength_scores_zero():
    lt = light(sun([0.3, 0.8, 0.5], (1.0, 0.9, 0.7)), sky(0.2), lamp([-1.0, 1.0, -2.0]))
    r = light_sphere_error(scaled(lt, 2.0), lt, center=[0.0, -0.5, -3.0])
    assert r["diffuse"] < 1e-9 and r["silver"] < 1e-9


def test_opposite_light_scores_large():
    a = light(sun([0.6, 0.6, 0.5]), sky(0.05))
    b = light(sun([-0.6, 0.6, 0.5]), sky(0.05))
    r = light_sphere_error(a, b)
    assert r["diffuse"] > 0.5 and r["silver"] > 0.8
    # a nearer direction scores better, on both spheres
    near = light_sphere_error(light(sun([0.5, 0.6, 0.6]), sky(0.05)), a)
    assert near["diffuse"] < r["diffuse"] and near["silver"] < r["silver"]
    # a colour error alone counts
    col = light_sphere_error(light(sun([0.6, 0.6, 0.5], (1.0, 0.5, 0.5)), sky(0.05)), a)
    assert col["diffuse"] > 0.05


def test_real_report_light_round_trips():
    """A light as LightModel.to_info writes it scores 0 against itself."""
    from zcomp_cli.scene.lightmodel import Lamp, LightModel, Sky, Sun

    c = np.zeros((9, 3))
    c[0] = 0.5
    c[2] = 0.2
    m = LightModel(suns=(Sun(direction=[0.2, 0.9, 0.3], radius_deg=1.0, irradiance=[1.0, 1.0, 1.0]),),
                   lamps=(Lamp(position=[1.0, 1.5, -3.0], radius_m=0.2, intensity=[4.0, 4.0, 4.0],
                               facing=[0.0, -1.0, 0.0]),),
                   sky=Sky(radiance_sh=c, ground=[0.2, 0.2, 0.2], up=[0.0, 1.0, 0.0]))
    info = m.to_info()
    out = render_spheres(info, center=[0.0, 0.0, -3.0])
    assert out["diffuse"].max() > 0 and out["silver"].max() > 0
    assert light_sphere_error(info, info, center=[0.0, 0.0, -3.0])["mean"] == 0.0


# -- degenerate and bad input -------------------------------------------------------------
def test_degenerate_lights_stay_finite():
    nothing = light()
    zero_sky = light(sky(0.0, ground=(0.0, 0.0, 0.0)))
    nan_sun = light(sun([float("nan"), 1.0, 0.0], (float("nan"), 1.0, 1.0)))
    zero_dir = light(sun([0.0, 0.0, 0.0]))
    nan_sky = light({"kind": "sky", "radiance_sh_rgb": np.full((9, 3), np.nan).tolist(),
                     "ground_radiance_rgb": [float("inf")] * 3})
    inf_sun = light(sun([0.0, 1.0, 0.0], (float("inf"), 1.0, 1.0)))
    lamp_at_centre = light(lamp([0.0, 0.0, -2.0]))
    no_up = {"lights": [sun([0.0, 0.0, 1.0]), sky(0.1)]}
    good = light(sun([0.0, 0.0, 1.0]), sky(0.1))
    cases = [nothing, zero_sky, nan_sun, zero_dir, nan_sky, inf_sun, lamp_at_centre, no_up, good]
    for a in cases:
        out = render_spheres(a, center=[0.0, 0.0, -2.0], size=16)
        assert np.isfinite(out["diffuse"]).all() and np.isfinite(out["silver"]).all()
        for b in cases:
            r = light_sphere_error(a, b, center=[0.0, 0.0, -2.0], size=16)
            assert all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in r.values()), (a, b, r)
    assert light_sphere_error(nothing, nothing, size=16)["mean"] == 0.0
    assert light_sphere_error(nothing, good, size=16) == {"diffuse": 1.0, "silver": 1.0, "mean": 1.0}


@pytest.mark.parametrize("bad, match", [
    ([], "must be a dict"),
    ({}, "no 'lights' list"),
    ({"lights": "sun"}, "no 'lights' list"),
    ({"lights": [{"kind": "laser"}]}, "unknown light kind"),
    ({"lights": [3]}, "must be a dict"),
    ({"lights": [{"kind": "sun", "direction_camera": [0, 1], "irradiance_rgb": [1, 1, 1]}]}, "shape"),
    ({"lights": [{"kind": "sun", "irradiance_rgb": [1, 1, 1]}]}, "missing 'direction_camera'"),
    ({"lights": [{"kind": "sky", "radiance_sh_rgb": [[1, 1, 1]] * 4}]}, r"\(9, 3\)"),
    ({"lights": [{"kind": "lamp", "position_camera": [0, 1, 0], "intensity_rgb_at_1m": "bright"}]}, "not numeric"),
    ({"lights": [sun([0, 1, 0], radius_deg="wide")]}, "must be a number"),
    ({"up_camera": [0, 1], "lights": []}, "up_camera"),
])
def test_bad_light_raises_clear_error(bad, match):
    with pytest.raises(InputError, match=match):
        parse_light(bad)
    with pytest.raises(InputError):
        light_sphere_error(bad, light(sky()))


def test_bad_center_and_size_raise():
    with pytest.raises(InputError, match="center"):
        render_spheres(light(sky()), center=[0.0, 1.0])
    with pytest.raises(InputError, match="center"):
        render_spheres(light(sky()), center=[0.0, float("nan"), 1.0])
    with pytest.raises(InputError, match="size"):
        render_spheres(light(sky()), size=1)
