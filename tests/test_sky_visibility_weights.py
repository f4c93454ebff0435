"""The sky's visible share weighed by the sky's own map (issue 48): a wall that hides the
brightest part of a probe hides as much of its light as that part brings, which an
order-2 SH spread over the hemisphere does not tell; pooled sums before the division."""

import math

import numpy as np
import pytest

from zcomp_cli import equirect
from zcomp_cli.scene.planes import Wall, walls_block
from zcomp_cli.scene.config import ProbeConfig
from zcomp_cli.scene.probe import split_probe
from zcomp_cli.scene.skyvis import hemisphere_directions, weighted_visibility
from zcomp_cli.worldframe import ground_frame

UP = np.array([0.0, 1.0, 0.0])
# the band stays in the sky (a split may take a bright band for a broad source)
NO_SOURCES = ProbeConfig(max_sources=0)


def _courtyard(H=128):
    """A dim sky of 0.2 with a broad bright band (2.0) low toward -x (below 35 deg),
    below the horizon 0: the sky of a courtyard whose sunlit facade is behind a wall."""
    frame = ground_frame(UP)
    d = equirect.pixel_directions(H, 2 * H, frame)
    img = np.full((H, 2 * H, 3), 0.2)
    elev = np.degrees(np.arcsin(np.clip(d @ UP, -1, 1)))
    band = (d[..., 0] < -0.3) & (elev < 35.0)
    img[band] = 2.0
    img[elev < 0] = 0.0
    return img, frame, d


def _truth(img, d, blocked_dir):
    """Brute force over the map: the share of an up-facing point's irradiance that
    ``blocked_dir`` (directions (..., 3) -> bool) leaves."""
    om = equirect.solid_angles(*img.shape[:2])
    cos = np.maximum(d @ UP, 0.0)
    w = img[..., 0] * cos * om
    return float((w * ~blocked_dir(d)).sum() / w.sum())


def test_sky_radiance_at_reads_the_map_and_is_dark_below_the_horizon():
    img, frame, _ = _courtyard()
    p = split_probe(img, frame, cfg=NO_SOURCES)
    assert p.sources == ()
    low_left = np.array([-math.cos(math.radians(15)), math.sin(math.radians(15)), 0.0])
    high = np.array([0.3, 0.95, 0.0]) / np.linalg.norm([0.3, 0.95, 0.0])
    L = p.sky_radiance_at(np.stack([low_left, high, -UP]))
    assert L.shape == (3, 3)
    assert np.allclose(L[0], 2.0, rtol=0.05) and np.allclose(L[1], 0.2, rtol=0.05) and np.allclose(L[2], 0.0)
    # any leading shape
    assert p.sky_radiance_at(np.tile(high, (2, 4, 1))).shape == (2, 4, 3)


def test_a_wall_hiding_the_bright_sky_hides_its_share_of_the_light():
    img, frame, d_map = _courtyard()
    p = split_probe(img, frame, cfg=NO_SOURCES)
    wall = Wall(normal=np.array([1.0, 0.0, 0.0]), offset=-3.0, top=3.0, ground=-1.0, up=UP)
    point = np.array([0.0, -1.0, -3.0])  # on the ground, 3 m from the wall
    blocked = lambda dd: walls_block([wall], np.broadcast_to(point, dd.reshape(-1, 3).shape),
                                     dd.reshape(-1, 3))[0].reshape(dd.shape[:-1])
    truth = _truth(img, d_map, blocked)
    n = 4000
    dirs = np.stack(hemisphere_directions(np.tile(UP, (n, 1)), np.random.default_rng(0).random(n), 16))
    vis = (~blocked(dirs)).astype(np.float64)
    pooled = lambda w: (lambda s: s[:, :3].sum(0) / s[:, 3:].sum(0))(weighted_visibility(dirs, vis, w, sums=True))
    by_map = pooled(p.sky_radiance_at)
    by_sh = pooled(p.sky_radiance_sh)
    assert 0.2 < truth < 0.6, truth  # the wall hides most of this sky's light
    assert np.allclose(by_map, truth, atol=0.03), (by_map, truth)
    # the order-2 SH spreads the band over the hemisphere: the wall seems to hide less
    assert by_sh.mean() > truth + 0.1, (by_sh, truth)


def test_pooled_sums_are_the_share_and_a_few_samples_alone_are_biased():
    img, frame, d_map = _courtyard()
    p = split_probe(img, frame, cfg=NO_SOURCES)
    # hidden: one side, at every elevation (the sampler's elevations are stratified
    # rings turned per point, so the test's edge runs along the turning)
    hidden = lambda dd: dd[..., 0] < -0.3
    # the truth at the map the weights read (its bilinear edges are the weights')
    truth = _truth(p.sky_map, equirect.pixel_directions(*p.sky_map.shape[:2], frame), hidden)

    def samples(k, n, seed):
        dirs = np.stack(hemisphere_directions(np.tile(UP, (n, 1)), np.random.default_rng(seed).random(n), k))
        return dirs, (~hidden(dirs)).astype(np.float64)

    s = weighted_visibility(*samples(32, 2000, 1), p.sky_radiance_at, sums=True)
    assert s.shape == (2000, 6)
    assert abs(s[:, 0].sum() / s[:, 3].sum() - truth) < 0.03, (s[:, 0].sum() / s[:, 3].sum(), truth)
    # a pixel's 4 directions alone: its share, then averaged, is pulled toward 1 (a
    # point that drew no bright direction reports it all seen); the same samples'
    # pooled sums are not
    dirs, vis = samples(4, 20000, 2)
    share = weighted_visibility(dirs, vis, p.sky_radiance_at)
    s4 = weighted_visibility(dirs, vis, p.sky_radiance_at, sums=True)
    ok = s4[:, 3] > 0
    assert np.allclose(share[ok], s4[ok, :3] / s4[ok, 3:], rtol=1e-12)
    assert share[:, 0].mean() > s4[:, 0].sum() / s4[:, 3].sum() + 0.1


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0])
def test_a_weight_function_returning_non_finite_or_negative_values_is_safe(bad):
    dirs = np.tile(UP, (4, 3, 1))
    vis = np.ones((4, 3))
    out = weighted_visibility(dirs, vis, lambda dd: np.full((len(dd), 3), bad))
    assert np.all(np.isfinite(out)) and np.allclose(out, 1.0)  # the sky sends nothing: all seen
