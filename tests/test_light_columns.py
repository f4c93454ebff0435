"""The light fit's columns and candidate scores (light/atoms.py, light/solver.py): the
batched forms give each lamp, pixel and candidate what it has alone, and known values."""

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.light import atoms as at
from zcomp_cli.light.solver import _huber_loss, candidate_losses, huber_weights
from zcomp_cli.scene.config import MarchConfig
from zcomp_cli.scene.raycast import RayCaster, embree_available

# a box 0.4 m wide standing on the floor y = 0, 2 m in front of the camera
BOX_V = np.array([[x, y, z] for x in (-0.2, 0.2) for y in (0.0, 0.4) for z in (-2.2, -1.8)], np.float64)
_QUADS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
BOX_F = np.array([t for a, b, c, d in _QUADS for t in ((a, b, c), (a, c, d))], np.int64)


def _floor(n_side: int, caster=None) -> at.FitPixels:
    """Fit pixels on the floor y = 0 around the box (n_side^2 of them), normals up."""
    g = np.linspace(-1.2, 1.2, n_side)
    X, Z = np.meshgrid(g, g - 2.0)
    P = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    N = len(P)
    return at.FitPixels(points=P, normals=np.tile([0.0, 1.0, 0.0], (N, 1)), ys=np.arange(N), xs=np.arange(N),
                        albedo=np.full((N, 3), 0.5), train=np.arange(N) % 2 == 0, support=np.ones(N, bool),
                        depth=np.ones((4, 4)), camera=Camera.from_fov(4, 4, 60.0), up=np.array([0.0, 1.0, 0.0]),
                        march=MarchConfig(), bias_rel=1e-3, blocks=4, caster=caster)


LAMPS = np.array([[0.5, 1.5, -2.5], [-1.0, 0.8, -1.5], [0.0, 3.0, -2.0], [0.3, -0.5, -2.0]])  # the last below


def test_unshadowed_lamp_columns_are_the_inverse_square_law():
    fp = _floor(23)  # 529 pixels: more than one block of pixels
    assert len(fp) > at._PIXEL_BLOCK
    got = at.lamp_columns(fp, LAMPS)
    v = LAMPS[None] - fp.points[:, None]
    r = np.linalg.norm(v, axis=2)
    want = np.maximum(v[..., 1], 0.0) / r ** 3  # n = +y
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert (got[:, 3] == 0).all()  # a lamp below the floor lights none of it


@pytest.mark.skipif(not embree_available(), reason="embreex is not installed")
@pytest.mark.parametrize("radius_m,samples", [(0.0, 1), (0.3, 8)])
def test_shadowed_lamp_columns_of_many_lamps_are_each_lamps_own(radius_m, samples):
    fp = _floor(15, RayCaster(BOX_V, BOX_F))
    together = at.lamp_columns(fp, LAMPS, steps=16, radius_m=radius_m, cone_samples=samples)
    alone = np.concatenate([at.lamp_columns(fp, q[None], steps=16, radius_m=radius_m, cone_samples=samples)
                            for q in LAMPS], 1)
    np.testing.assert_array_equal(together, alone)
    free = at.lamp_columns(fp, LAMPS)
    shadowed = together[:, :3] < free[:, :3] * 0.999
    assert shadowed.any() and not shadowed.all()  # the box's shadow, and the lit floor
    if radius_m == 0:  # a point lamp: the column is the free one where the lamp is seen, else 0
        assert np.all((together == 0) | np.isclose(together, free, rtol=1e-12))


@pytest.mark.skipif(not embree_available(), reason="embreex is not installed")
def test_lamp_visibility_of_many_lamps_is_each_lamps_own():
    from zcomp_cli.light.shadowcast import Receivers, lamp_visibility

    fp = _floor(15)
    n = len(fp)
    rec = Receivers(ys=fp.ys, xs=fp.xs, origins=fp.ray_origins(), distance=np.linalg.norm(fp.points, axis=1),
                    ratio=np.ones(n), weight=np.ones(n), blocks=4, sigma=0.1, log_shading=np.zeros(n),
                    basis=np.ones((n, 1)))
    caster = RayCaster(BOX_V, BOX_F)
    together = lamp_visibility(caster, rec, LAMPS[:3])
    alone = np.concatenate([lamp_visibility(caster, rec, q[None]) for q in LAMPS[:3]], 1)
    np.testing.assert_array_equal(together, alone)
    assert together.shape == (n, 3) and 0 < together.mean() < 1


def test_huber_loss_known_values():
    a = np.array([0.0, 0.5, 1.0, 2.0, 4.0, np.inf])
    np.testing.assert_array_equal(_huber_loss(a, 1.0), [0.0, 0.125, 0.5, 1.5, 3.5, np.inf])
    np.testing.assert_array_equal(_huber_loss(a[:5], 0.0), np.zeros(5))  # no quadratic zone
    rng = np.random.default_rng(0)
    r = rng.normal(size=1000) * 10.0 ** rng.integers(-8, 8, 1000)
    for c in (1e-3, 0.37, 2.5):  # the two branches of the definition, to the bit
        ref = np.where(np.abs(r) <= c, 0.5 * r * r, c * (np.abs(r) - 0.5 * c))
        np.testing.assert_array_equal(huber_weights(r, c, 1.0)[1], ref)
        np.testing.assert_array_equal(_huber_loss(np.abs(r), c, overwrite=True), ref)  # in place: the same bits


def test_candidate_losses_of_some_rows_are_those_rows():
    rng = np.random.default_rng(2)
    N, K = 300, 17
    B = np.abs(rng.normal(size=(N, 4)))
    C = np.abs(rng.normal(size=(N, K)))
    y = B @ [0.3, 0.2, 0.1, 0.4] + 0.7 * C[:, 5] + rng.normal(0, 0.01, N)
    y[::37] += 3.0  # outliers: Huber's linear zone
    train = rng.random(N) < 0.6
    full = candidate_losses(B, C, y, train)
    rows = ~train
    np.testing.assert_array_equal(candidate_losses(B, C, y, train, rows=rows), full[rows])
    assert full.shape == (N, K) and np.argmin(full[rows].mean(0)) == 5
