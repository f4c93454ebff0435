"""The object's glossy reflection of its surroundings (``renderers/physical/reflect.py``):
the GGX-sampled rays weighed so that their mean is the light the layer reflects, at any
angle; known values from brute-force integration of ``gloss.ggx_direct``."""

import math

import numpy as np
import pytest

from zcomp_cli.equirect import pixel_directions, solid_angles
from zcomp_cli.renderers.physical.gloss import DIELECTRIC_F0, ggx_direct
from zcomp_cli.renderers.physical.reflect import lobe_weights
from zcomp_cli.scene.gather import ggx_directions
from zcomp_cli.worldframe import ground_frame

UP = np.array([0.0, 0.0, 1.0])


def _sky(d):
    """A sky brighter toward the grazing side of the mirror direction (red) and low (green)."""
    return np.stack([1 + 6 * np.clip(-d[..., 0], 0, 1) ** 4, 1 + 2 * (1 - d[..., 2]), np.ones(d.shape[:-1])], -1)


def _truth(v, rough, f0, fresnel):
    d = pixel_directions(512, 1024, ground_frame(UP)).reshape(-1, 3)
    om = solid_angles(512, 1024).reshape(-1)
    keep = d @ UP > 0
    d, om = d[keep], om[keep]
    f = ggx_direct(np.tile(UP, (len(d), 1)), np.tile(v, (len(d), 1)), d, np.full(len(d), rough),
                   np.full((len(d), 3), f0), fresnel=fresnel)
    return (f * _sky(d) * om[:, None]).sum(0) / (f * om[:, None]).sum(0)


@pytest.mark.parametrize("ndv,rough", [(0.2, 0.4), (0.5, 0.6), (0.9, 0.3)])
def test_the_rays_mean_is_the_light_the_layer_reflects(ndv, rough):
    """Known values: the weighted mean of 4096 GGX rays equals int L f (n.l) / int f (n.l)
    over the sky within 0.5 %, a dielectric and a metal alike; the n.l weights of
    Karis's prefilter (n = v) were 5-22 % low on the bright side here."""
    v = np.array([math.sqrt(1 - ndv * ndv), 0.0, ndv])
    a = np.array([rough * rough])
    dirs, nl = ggx_directions(UP[None], v[None], a, 4096, np.array([0.37]))
    for layers, f0, fresnel in ((None, DIELECTRIC_F0, "dielectric"),
                                ((np.ones(1), np.full((1, 3), 0.9)), 0.9, "schlick")):
        w, g, vh, nh = lobe_weights(UP[None], v[None], dirs, a, nl, layers)
        assert w.shape == (4096, 1, 3) and g.shape == vh.shape == nh.shape == (4096, 1)
        est = (w * _sky(dirs)).sum(0)[0] / w.sum(0)[0]
        np.testing.assert_allclose(est, _truth(v, rough, f0, fresnel), rtol=5e-3)
    old = (nl[..., None] * _sky(dirs)).sum(0)[0] / nl.sum(0)[0]
    if ndv < 0.6:
        assert old[0] < 0.9 * _truth(v, rough, DIELECTRIC_F0, "dielectric")[0]


def test_rays_below_the_surface_weigh_nothing_and_degenerate_input_stays_finite():
    v = np.array([[1.0, 0.0, 1e-9], [0.0, 0.0, 1.0]])
    n = np.array([UP, UP])
    a = np.array([1e-3, 1.0])
    dirs, nl = ggx_directions(n, v, a, 16, np.array([0.1, 0.9]))
    w, g, _, _ = lobe_weights(n, v, dirs, a, nl)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert np.all(w[nl <= 0] == 0)
