"""A sun's and a lamp's disc as samples (``Sun.disc``, ``Lamp.disc``) and the highlight
summed over them (``gloss.ggx_light``): the samples lie on the light, their mean is the
whole light, and a broad light's highlight falls where its disc's mirror image does,
against a brute-force sum over the disc."""

import math

import numpy as np
import pytest

from zcomp_cli.renderers.physical.gloss import ggx_direct, ggx_light, principled_layers
from zcomp_cli.scene.lightmodel import Lamp, Sun, disc_shading
from zcomp_cli.scene.sampling import disc_samples

UP = np.array([0.0, 1.0, 0.0])


def _floor(n=41, half=1.5, y=-1.0, z=-3.0):
    """(n, 3) points along a line of a floor at height ``y`` (camera frame, y up)."""
    x = np.linspace(-half, half, n)
    return np.stack([x, np.full(n, y), np.full(n, z)], 1)


LIGHTS = [Sun(direction=[0.3, 0.6, -0.5], radius_deg=10.0, irradiance=[1.0, 0.8, 0.6]),
          Lamp(position=[0.4, 2.0, -3.5], radius_m=0.6, intensity=[2.0, 2.0, 2.0]),
          Lamp(position=[0.4, 2.0, -3.5], radius_m=0.6, intensity=[2.0, 2.0, 2.0], facing=[0.5, -1.0, 0.2])]


@pytest.mark.parametrize("light", LIGHTS, ids=["sun", "sphere", "panel"])
def test_the_disc_lies_on_the_light_and_its_centre_is_the_light(light):
    P = _floor()
    k = 32
    d, t, E = light.disc(P, disc_samples(k, np.linspace(0, 1, len(P), endpoint=False)))
    assert d.shape == (k, len(P), 3) and t.shape == (k, len(P)) and E.shape == (k, len(P), 3)
    assert np.allclose(np.linalg.norm(d, axis=-1), 1.0)
    L, dist, E0 = light.toward(P)
    cos_max = np.cos(np.arctan(light.tan_radius(P if light.varies else None)))
    # every sample within the light's angular radius of its centre (a panel's disc,
    # tilted, looks narrower, never wider)
    assert np.all(np.einsum("knc,nc->kn", d, L) >= np.broadcast_to(cos_max, (len(P),)) - 1e-9)
    if light.varies:
        q = P[None] + t[..., None] * d  # the samples themselves
        assert np.allclose(np.linalg.norm(q - light.position, axis=-1).max(), light.radius_m, rtol=0.05)
        assert np.all(np.linalg.norm(q - light.position, axis=-1) <= light.radius_m + 1e-9)
    else:
        assert np.all(np.isinf(t))
    # offsets of zero: the light's centre, as ``toward`` gives it
    dc, tc, Ec = light.disc(P, np.zeros((1, len(P), 2)))
    assert np.allclose(dc[0], L) and np.allclose(Ec[0], E0)
    assert np.allclose(tc[0], dist) if light.varies else np.all(np.isinf(tc))


def test_a_small_lamps_disc_gives_its_centres_shading():
    lamp = Lamp(position=[0.0, 3.0, -3.0], radius_m=0.01, intensity=[1.0, 1.0, 1.0], facing=[0.0, -1.0, 0.0])
    P = _floor()
    n = np.tile(UP, (len(P), 1))
    d, _, E = lamp.disc(P, disc_samples(16, np.zeros(len(P))))
    L, _, E0 = lamp.toward(P)
    mean = (np.einsum("knc,nc->kn", d, n)[..., None] * E).mean(0)
    assert np.allclose(mean, (L * n).sum(1)[:, None] * E0, rtol=1e-2)


def _glossy_floor(m=25):
    """(m * m, 3) points of a floor one metre below the camera, the lights' highlights on it."""
    x, z = np.meshgrid(np.linspace(-1.5, 1.5, m), np.linspace(-0.3, -4.0, m))
    return np.stack([x.ravel(), np.full(m * m, -1.0), z.ravel()], 1)


def _highlight(light, k, rough=0.2, widened=False):
    """(M,) the highlight of ``light`` on a glossy floor seen from the camera at the
    origin: ``ggx_light`` over ``k`` samples of its disc (one at its centre with the
    whole radius if ``widened``)."""
    P = _glossy_floor()
    n = np.tile(UP, (len(P), 1))
    v = -P / np.linalg.norm(P, axis=1, keepdims=True)
    r = np.full(len(P), rough)
    layers = principled_layers(np.zeros(len(P)), None)
    tan = np.asarray(light.tan_radius(P) if light.varies else light.tan_radius(None), np.float64)
    if widened:
        d, _, E = light.disc(P, np.zeros((1, len(P), 2)))
        return ggx_light(n, v, r, layers, d, E, tan)[:, 0]
    off = disc_samples(k, np.linspace(0, 1, len(P), endpoint=False))
    d, _, E = light.disc(P, off)
    return ggx_light(n, v, r, layers, d, E, tan / math.sqrt(k))[:, 0]


@pytest.mark.parametrize("light", LIGHTS, ids=["sun", "sphere", "panel"])
def test_the_summed_highlight_matches_a_brute_force_sum_over_the_disc(light):
    truth = _highlight(light, 1024)  # a sharp sample per 1/1024 of the disc
    few, sampled, many = (_highlight(light, k) for k in (4, 16, 64))
    widened = _highlight(light, 1, widened=True)
    err = lambda a: float(np.abs(a - truth).sum() / truth.sum())
    # the samples' pattern is noise the film filter averages; it shrinks as they grow
    assert err(many) < err(sampled) < err(few)
    assert err(many) < 0.2
    # the widened lobe at the centre misplaces and reshapes the highlight: 16 samples
    # do better by more than half (measured: 0.29-0.33 against 0.95-1.05)
    assert err(sampled) < 0.5 * err(widened)
    assert many.sum() == pytest.approx(truth.sum(), rel=0.1)


def test_one_centre_sample_is_the_widened_lobe():
    lamp = LIGHTS[1]
    P = _floor()
    n = np.tile(UP, (len(P), 1))
    v = -P / np.linalg.norm(P, axis=1, keepdims=True)
    r = np.full(len(P), 0.3)
    layers = principled_layers(np.zeros(len(P)), None)
    d, _, E = lamp.disc(P, np.zeros((1, len(P), 2)))
    L, _, E0 = lamp.toward(P)
    tan = lamp.tan_radius(P)
    want = np.pi * E0 * ggx_direct(n, v, L, r, layers[0][1], tan, fresnel="dielectric")
    assert np.allclose(ggx_light(n, v, r, layers, d, E, tan), want)


def test_degenerate_lights_stay_finite():
    P = np.array([[0.0, 0.0, -2.0], [0.0, 2.0, -3.0]])  # the second point at the lamp itself
    lamp = Lamp(position=[0.0, 2.0, -3.0], radius_m=0.0, intensity=[1.0, 1.0, 1.0], facing=[0.0, -1.0, 0.0])
    d, t, E = lamp.disc(P, disc_samples(8, np.zeros(2)))
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(E)) and np.all(t >= 0)
    n = np.tile(UP, (2, 1))
    v = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    out = ggx_light(n, v, np.array([0.0, np.nan]), principled_layers(np.zeros(2), None), d, E, 0.0)
    assert np.all(np.isfinite(out)) and np.all(out >= 0)


@pytest.mark.parametrize("light", LIGHTS[:2], ids=["sun", "sphere"])
def test_a_sun_or_sphere_lights_a_surface_facing_it_as_its_centre_does(light):
    P = _floor()
    L, _, E0 = light.toward(P)
    off = disc_samples(16, np.linspace(0, 1, len(P), endpoint=False))
    assert np.allclose(disc_shading(light, P, L, off), E0, rtol=1e-9)


def test_a_panel_below_its_centre_gets_the_discs_integral():
    h, a = 1.5, 0.6
    lamp = Lamp(position=[0.0, h, -3.0], radius_m=a, intensity=[1.0, 1.0, 1.0], facing=[0.0, -1.0, 0.0])
    P = np.array([[0.0, 0.0, -3.0]])
    n = np.array([UP])
    got = disc_shading(lamp, P, n, disc_samples(4096, np.zeros(1)))[0, 0]
    # a Lambertian disc of radius a, h below its centre: 4 I / (h^2 + a^2), where a
    # point gives 4 I / h^2
    assert got == pytest.approx(4.0 / (h * h + a * a), rel=2e-3)


def test_a_broad_sun_still_shines_past_the_terminator():
    sun = Sun(direction=[1.0, 0.0, 0.0], radius_deg=10.0, irradiance=[1.0, 1.0, 1.0])
    P = np.zeros((3, 3))
    # normals at the terminator, 5 degrees past it, 15 degrees past it
    ang = np.deg2rad([0.0, -5.0, -15.0])
    n = np.stack([np.sin(ang), np.cos(ang), np.zeros(3)], 1)
    got = disc_shading(sun, P, n, disc_samples(256, np.zeros(3)))[:, 0]
    centre = np.maximum((n @ sun.direction), 0.0)
    assert np.all(centre[:2] <= 1e-12) and got[0] > 0.02 and 0 < got[1] < got[0]
    assert got[2] == 0.0  # past the whole disc
    # half of the disc is above the terminator, its mean height there tan(r) 4 / 3 pi
    assert got[0] == pytest.approx(0.5 * math.tan(math.radians(10.0)) * 4 / (3 * math.pi), rel=0.05)


def _normals(m, seed=0):
    """(m, 3) unit normals spread over the sphere (some facing a light, some grazing it,
    some turned away)."""
    v = np.random.default_rng(seed).normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("light", LIGHTS, ids=["sun", "sphere", "panel"])
def test_disc_shading_samples_only_where_the_horizon_cuts_the_disc(light):
    P = np.repeat(_floor(9), 40, 0)
    n = _normals(len(P))
    jit = np.linspace(0, 1, len(P), endpoint=False)
    k = 64
    asked = []

    def offsets(i):
        asked.append(np.asarray(i))
        return disc_samples(k, jit[i])

    got = disc_shading(light, P, n, offsets)
    assert np.allclose(got, disc_shading(light, P, n, disc_samples(k, jit)), rtol=0, atol=1e-12)
    # brute force: every point over many samples of its disc
    d, _, E = light.disc(P, disc_samples(4096, jit))
    ref = (np.maximum(np.einsum("knc,nc->kn", d, n), 0.0)[..., None] * E).mean(0)
    assert np.allclose(got, ref, rtol=2e-3, atol=2e-3 * float(np.abs(ref).max()))
    L, _, E0 = light.toward(P)
    cos = np.einsum("nc,nc->n", L, n)
    cut = np.zeros(len(P), bool)
    cut[np.concatenate(asked)] = True
    if getattr(light, "facing", None) is not None:  # a panel's profile is not symmetric: every point sampled
        assert cut.all()
        return
    # the points asked for are those whose horizon passes through the disc; the others
    # get their centre's cosine exactly
    assert 0 < cut.sum() < len(P)
    assert np.array_equal(got[~cut], np.maximum(cos[~cut], 0.0)[:, None] * E0[~cut])
    assert np.all(np.abs(cos[cut]) < 0.5)  # (the lights span at most 30 deg here)


def test_disc_shading_of_a_light_without_size_is_its_centres():
    sun = Sun(direction=[0.3, 0.6, -0.5], radius_deg=0.0, irradiance=[1.0, 1.0, 1.0])
    P, n = _floor(), _normals(41, seed=1)

    def never(i):
        raise AssertionError("a light without size has nothing to sample")

    out = disc_shading(sun, P, n, never)
    # (to the rounding: a matrix product and an einsum may round the last bit apart, as
    # they do on some CPUs)
    np.testing.assert_allclose(out, np.maximum(n @ sun.direction, 0.0)[:, None] * sun.irradiance[None],
                               rtol=0, atol=1e-14)
