"""The object's glossy reflection (``renderers/physical/gloss.py``): the GGX BRDF of a sun
or lamp, the split-sum sky, the layering of diffuse beneath specular, and a shadowed
light leaving no highlight."""

import math

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.equirect import pixel_directions, solid_angles
from zcomp_cli.renderers.physical.gloss import env_brdf, ggx_direct, specular_albedo
from zcomp_cli.worldframe import ground_frame

UP = np.array([0.0, 0.0, 1.0])


def _hemisphere(h=256, w=512):
    frame = ground_frame(UP)
    d = pixel_directions(h, w, frame).reshape(-1, 3)
    om = solid_angles(h, w).reshape(-1)
    keep = d @ UP > 0
    return d[keep], om[keep]


def _view(ndv):
    return np.array([math.sqrt(1 - ndv * ndv), 0.0, ndv])


@pytest.mark.parametrize("rough", [0.3, 0.5, 0.8])
@pytest.mark.parametrize("ndv", [0.3, 0.7, 1.0])
@pytest.mark.parametrize("f0", [1.0, 0.04])
def test_the_brdf_integrates_to_the_environment_albedo(rough, ndv, f0):
    """Known values: the hemisphere integral of f (n.l) is the directional albedo
    ``F0 A + B`` that the sky's reflection uses (the two paths of the gloss agree), at
    most 1 (single scattering). The old analytic fit for mobile was 0.1-0.16 below it
    at F0 = 1."""
    d, om = _hemisphere()
    n = len(d)
    f = ggx_direct(np.tile(UP, (n, 1)), np.tile(_view(ndv), (n, 1)), d, np.full(n, rough), np.full((n, 1), f0))
    albedo = float((f[:, 0] * om).sum())
    a, b = env_brdf(np.array([rough]), np.array([ndv]))
    assert 0.0 < albedo <= 1.0 + 1e-3
    assert albedo == pytest.approx(float(f0 * a[0] + b[0]), abs=0.01)


def test_reciprocity_and_the_horizon():
    rng = np.random.default_rng(3)
    n = np.tile(UP, (200, 1))
    v = rng.normal(size=(200, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    l = rng.normal(size=(200, 3))
    l[:, 2] = np.abs(l[:, 2])
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    r = rng.uniform(0.1, 1.0, 200)
    f0 = np.full((200, 3), 0.04)
    # f(v, l) = f(l, v): ggx_direct is f (n.l)
    a = ggx_direct(n, v, l, r, f0)[:, 0] / l[:, 2]
    b = ggx_direct(n, l, v, r, f0)[:, 0] / v[:, 2]
    np.testing.assert_allclose(a, b, rtol=1e-9)
    below = l * np.array([1, 1, -1])
    assert np.all(ggx_direct(n, v, below, r, f0) == 0)


def test_the_highlight_peaks_at_the_mirror_direction_and_a_disc_widens_it():
    v = _view(0.6)
    mirror = 2 * 0.6 * UP - v
    ang = np.deg2rad(np.linspace(-30, 30, 61))
    th = math.atan2(mirror[2], mirror[0])  # the light swept through the mirror direction
    l = np.stack([np.cos(th + ang), np.zeros_like(ang), np.sin(th + ang)], 1)
    n = np.tile(UP, (len(l), 1))
    vv = np.tile(v, (len(l), 1))
    sharp = ggx_direct(n, vv, l, np.full(len(l), 0.2), np.full((len(l), 1), 0.04))[:, 0]
    wide = ggx_direct(n, vv, l, np.full(len(l), 0.2), np.full((len(l), 1), 0.04), tan_radius=math.tan(math.radians(10)))[:, 0]
    assert int(np.argmax(sharp)) == 30
    assert wide[30] < sharp[30]  # the same energy spread wider
    assert wide[5] > sharp[5]


def test_degenerate_inputs_stay_finite():
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    v = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1e-9], [0.0, 0.0, 1.0]])
    l = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 1e-9], [0.0, 0.0, 1.0]])
    r = np.array([0.0, np.nan, 0.5])
    out = ggx_direct(n, v, l, r, np.full((3, 3), 0.04))
    assert np.all(np.isfinite(out)) and np.all(out >= 0)
    assert np.all(out[2] == 0)  # no normal: no reflection
    e = specular_albedo(np.array([0.0, 1.0, np.nan]), np.array([0.0, 1.0, 0.5]), np.full((3, 1), 0.04))
    assert np.all((e >= 0) & (e <= 1))


def test_a_shadowed_light_leaves_no_highlight_and_the_diffuse_keeps_the_rest():
    from zcomp_cli.scene.lightmodel import LightModel, Sky, Sun
    from zcomp_cli.renderers.physical.renderer import PhysicalRenderer

    cam = Camera.from_fov(50.0, 8, 8)
    up = np.array([0.0, 1.0, 0.0])
    sun_dir = np.array([0.0, 0.6, 0.8])
    sun = Sun(direction=sun_dir, radius_deg=2.0, irradiance=np.array([1.0, 1.0, 1.0]))
    model = LightModel(sky=Sky(radiance_sh=np.zeros((9, 3)), ground=np.zeros(3), up=up), suns=(sun,))
    ys, xs = np.array([4]), np.array([4])
    d = np.full((8, 8), 2.0)
    # the normal halfway between the viewer and the sun: the highlight's centre
    P = cam.ray(xs + 0.5, ys + 0.5) * 2.0
    v = -P[0] / np.linalg.norm(P[0])
    nv = (v + sun_dir) / np.linalg.norm(v + sun_dir)
    light = model.suns[0]
    L, _, E = light.toward(P)
    r = PhysicalRenderer()
    args = (model, cam, d, nv[None], ys, xs, np.ones(1), np.full((8, 8, 3), 0.5),
            np.full((8, 8), 0.3), np.zeros((8, 8)), np.ones((1, 3)))
    lit_seen, keep = r._glossy(*args, lit=[(light, L, E, np.ones(1))])
    lit_hidden, _ = r._glossy(*args, lit=[(light, L, E, np.zeros(1))])
    assert lit_seen[0, 0] > 0.05
    assert np.all(lit_hidden == 0)
    # a dielectric's diffuse keeps one minus its specular albedo; a metal none
    assert 0.9 < keep[0] < 1.0
    _, keep_metal = r._glossy(*args[:9], np.ones((8, 8)), args[10], lit=[])
    assert keep_metal[0] == 0
