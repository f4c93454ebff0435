"""Retinex albedo scored against exact albedo on analytic floor scenes."""

import numpy as np
import pytest

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError
from zcomp_cli.estimators.albedo import retinex_albedo, scale_invariant_error
from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, ground_plane_depth


def floor_scene(seed, W=160, H=120):
    """A tiled floor (random tile colours) and a backdrop, lit by a point light with
    inverse-square falloff and a little ambient: exact albedo and grey shading."""
    rng = np.random.default_rng(seed)
    cam = Camera.from_fov(55, W, H)
    spec = GroundPlaneSpec(1.2, pitch_deg=-float(rng.uniform(10, 30)), backdrop_distance_m=6.0)
    d, n = ground_plane_depth(cam, spec)
    P = cam.unproject(d).astype(np.float64)
    tile = float(rng.uniform(0.25, 0.6))
    colours = rng.uniform(0.08, 0.9, (5, 3))
    floor = d < 6.0
    idx = ((np.floor(P[..., 0] / tile) + np.floor(P[..., 2] / tile)) % 4).astype(int)
    idx[~floor] = 4
    alb = colours[idx]
    light = np.array([rng.uniform(-1, 1), 1.5, -rng.uniform(1, 3)])
    L = light - P
    r2 = (L ** 2).sum(-1)
    cosine = np.clip((n * L).sum(-1) / np.sqrt(r2), 0, None)
    shading = 4.0 * cosine / r2 + 0.05
    img = (alb * shading[..., None]).astype(np.float32)
    return img, alb.astype(np.float32), shading


def test_retinex_beats_trivial_baseline_on_synthetic_floors():
    ours, trivial = [], []
    for seed in range(4):
        img, alb, _ = floor_scene(seed)
        a, s = retinex_albedo(img)
        assert a.shape == img.shape and a.dtype == np.float32
        assert a.min() >= 0 and a.max() <= 1
        ours.append(scale_invariant_error(a, alb))
        trivial.append(scale_invariant_error(img, alb))
    ours, trivial = np.mean(ours), np.mean(trivial)
    print(f"scale-invariant albedo error: retinex {ours:.4f}, albedo=image {trivial:.4f}")
    assert ours < 0.25 * trivial
    assert ours < 0.03


def test_shading_is_one_colour_and_reconstructs_image():
    img, _, _ = floor_scene(7)
    img = img * 50.0  # HDR exposure: the decomposition is exposure-invariant
    a, s = retinex_albedo(img)
    # one colour over the frame (the plate's white balance) times a grey shading
    ratio = s / s[..., 1:2]
    np.testing.assert_allclose(ratio, np.broadcast_to(ratio[:1, :1], ratio.shape), rtol=1e-4)
    ok = (a.max(-1) < 0.999) & (a.min(-1) > 0.01)
    np.testing.assert_allclose((a * s)[ok], img[ok], rtol=1e-3, atol=1e-6)
    a1, _ = retinex_albedo(img / 50.0)
    np.testing.assert_allclose(a, a1, atol=1e-4)
    lum = a @ np.array([0.299, 0.587, 0.114])
    assert abs(np.percentile(lum, 95) - 0.8) < 0.05
    a0, s0 = retinex_albedo(img, white_balance=False)  # Retinex alone: grey shading
    np.testing.assert_allclose(s0[..., 0], s0[..., 1])
    np.testing.assert_allclose(s0[..., 0], s0[..., 2])


def test_a_coloured_light_goes_to_the_shading_not_the_albedo():
    """Tiles of random colours under a warm light (a tungsten cast): the plate's white
    balance puts the cast in the shading; Retinex alone leaves all of it in the albedo."""
    from zcomp_cli.estimators.white_balance import angular_error_deg

    warm = np.array([1.45, 0.95, 0.55])
    with_wb, grey, alb_wb, alb_grey = [], [], [], []
    for seed in range(6):
        img, alb, _ = floor_scene(seed)
        lit = (img * warm).astype(np.float32)
        a, s = retinex_albedo(lit)
        a0, s0 = retinex_albedo(lit, white_balance=False)
        with_wb.append(angular_error_deg(s.reshape(-1, 3).mean(0), warm))
        grey.append(angular_error_deg(s0.reshape(-1, 3).mean(0), warm))
        ok = alb.min(-1) > 0.1
        alb_wb.append(np.median([angular_error_deg(x, y) for x, y in zip(a[ok][::37], alb[ok][::37])]))
        alb_grey.append(np.median([angular_error_deg(x, y) for x, y in zip(a0[ok][::37], alb[ok][::37])]))
    print(f"light colour error: white-balanced {np.mean(with_wb):.1f} deg, grey {np.mean(grey):.1f} deg; "
          f"albedo colour error {np.mean(alb_wb):.1f} vs {np.mean(alb_grey):.1f} deg")
    assert np.mean(grey) == pytest.approx(angular_error_deg(warm, np.ones(3)), abs=1.0)  # the whole cast
    assert np.mean(with_wb) < 0.5 * np.mean(grey)
    assert np.mean(alb_wb) < 0.5 * np.mean(alb_grey)


def test_retinex_degenerate_inputs():
    a, s = retinex_albedo(np.zeros((8, 8, 3), np.float32))
    assert np.isfinite(a).all() and np.isfinite(s).all() and (s > 0).all()
    img = np.random.default_rng(0).uniform(0, 1, (16, 16, 3)).astype(np.float32)
    img[3, 3] = np.nan
    img[4, 4] = np.inf
    img[5, 5] = 1e4
    a, s = retinex_albedo(img)
    assert np.isfinite(a).all() and np.isfinite(s).all()
    with pytest.raises(InputError):
        retinex_albedo(np.zeros((8, 8)))
    with pytest.raises(InputError):
        retinex_albedo(img, percentile_value=2.0)
    for wb in (True, False):  # one saturated channel: the white balance stays finite and positive
        red = np.zeros((16, 16, 3), np.float32)
        red[..., 0] = np.linspace(0.1, 3e4, 256).reshape(16, 16)
        a, s = retinex_albedo(red, white_balance=wb)
        assert np.isfinite(a).all() and np.isfinite(s).all() and (s > 0).all()


def test_scale_invariant_error_properties():
    r = np.random.default_rng(1).uniform(0.1, 1, (10, 10, 3))
    assert scale_invariant_error(3.0 * r, r) == pytest.approx(0.0, abs=1e-12)
    assert scale_invariant_error(np.zeros_like(r), r) == pytest.approx(1.0)
    with pytest.raises(InputError):
        scale_invariant_error(r, np.zeros_like(r))
