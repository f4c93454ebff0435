"""Probes (sources, sky, prefilter), SH, the robust NNLS, and the manifest's light schema."""

import math

import numpy as np
import pytest

from zcomp_cli import equirect
from zcomp_cli.errors import InputError
from zcomp_cli.scene import sh
from zcomp_cli.renderers.physical.gloss import prefilter
from zcomp_cli.renderers.physical.settings import GlossConfig
from zcomp_cli.scene.probe import read_probe, split_probe
from zcomp_cli.light.config import SolverConfig
from zcomp_cli.light.solver import Atom, fit, score_candidates, solve_spd
from zcomp_cli.worldframe import ground_frame, up_from_pitch_roll

SOLVER = SolverConfig()


def _probe(H=256, sun_dir=None, sun_radius_deg=2.0, sun_radiance=2000.0, sky=0.5, frame=None):
    frame = ground_frame((0, 1, 0)) if frame is None else frame
    d = equirect.pixel_directions(H, 2 * H, frame)
    img = np.full((H, 2 * H, 3), sky)
    img[(d @ frame[1]) < 0] = 0.05  # a darker ground
    if sun_dir is not None:
        disc = d @ sun_dir >= math.cos(math.radians(sun_radius_deg))
        img[disc] = sun_radiance
    return img, frame


def test_sh_irradiance_known_values():
    # a uniform sky of radiance 1 shades every surface with 1 (shading = E / pi)
    d = equirect.pixel_directions(64, 128, ground_frame((0, 1, 0))).reshape(-1, 3)
    om = equirect.solid_angles(64, 128).reshape(-1)
    c = sh.project(d, np.ones(len(d)), om)
    n = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    assert np.allclose(sh.evaluate(sh.shading_coeffs(c), n), 1.0, atol=2e-3)
    # the upper hemisphere alone: 1 facing up, 1/2 facing sideways, ~0 facing down
    up = d[:, 1] > 0
    cu = sh.project(d[up], np.ones(up.sum()), om[up])
    s = sh.evaluate(sh.shading_coeffs(cu), n[:2])[:, 0]
    assert abs(s[0] - 1.0) < 0.03 and abs(s[1] - 0.5) < 0.03


def test_probe_source_direction_size_and_power():
    frame = ground_frame(up_from_pitch_roll(-30, 10))
    sun = 0.6 * frame[0] + 0.8 * frame[1]
    sun /= np.linalg.norm(sun)
    img, _ = _probe(256, sun, sun_radius_deg=3.0, frame=frame)
    p = split_probe(img, frame)
    assert len(p.sources) >= 1
    s = p.sources[0]
    assert math.degrees(math.acos(np.clip(s.direction @ sun, -1, 1))) < 0.5
    assert 2.2 < s.radius_deg < 3.8  # a uniform disc of 3 deg, measured by its second moment
    expect = (2000.0 - 0.5) * 2 * math.pi * (1 - math.cos(math.radians(3.0)))
    assert abs(float(s.power.mean()) - expect) / expect < 0.1
    # the sky without the sun: a uniform 0.5 above the horizon shades the ground with 0.5
    up_shade = sh.evaluate(sh.shading_coeffs(p.sky_radiance_sh), frame[1][None])[0]
    assert np.allclose(up_shade, 0.5, atol=0.03)


def test_probe_without_a_source_and_exposure_invariance():
    img, frame = _probe(128, None)
    p = split_probe(img, frame)
    assert p.sources == ()
    sun = np.array([0.0, 0.7, -0.7]) / math.sqrt(0.98)
    a, _ = _probe(128, sun, sun_radius_deg=4.0, frame=frame)
    p1, p2 = split_probe(a, frame), split_probe(a * 37.0, frame)
    assert len(p1.sources) == len(p2.sources)
    assert np.isclose(p1.sources[0].radius_deg, p2.sources[0].radius_deg)
    assert np.allclose(p2.sources[0].power, 37.0 * p1.sources[0].power)


def test_prefilter_preserves_a_uniform_sky_and_blurs_with_roughness():
    img, frame = _probe(64, None, sky=0.5)
    pf = prefilter(img, frame, cfg=GlossConfig())
    r = np.array([[0, 1.0, 0], [0.7, 0.7, 0]])
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    for rough in (0.05, 0.5, 1.0):
        # the support below the horizon as bright as the sky: uniform light everywhere
        out = pf.lookup(r, np.full(2, rough), ground=np.full(3, 0.5))
        assert np.allclose(out, 0.5, atol=0.02)
    # a rough lobe half-way up sees some of a dark support, a sharp one none
    low = pf.lookup(r, np.array([1.0, 1.0]), ground=np.zeros(3))[:, 0]
    assert low[1] < low[0] - 0.02 and np.isclose(pf.lookup(r, np.array([0.05, 0.05]), ground=np.zeros(3))[1, 0],
                                                  0.5, atol=0.02)
    sun = np.array([0.0, 0.8, -0.6])
    img2, _ = _probe(64, sun, sun_radius_deg=6.0, frame=frame)
    pf2 = prefilter(img2, frame, cfg=GlossConfig())
    sharp, broad = (pf2.lookup(sun[None], np.array([x]))[0].mean() for x in (0.05, 1.0))
    assert sharp > 3 * broad


def test_read_probe_refuses_a_probe_without_light(tmp_path):
    from zcomp_cli.imageio import write_exr

    p = tmp_path / "black.exr"
    write_exr(p, np.zeros((8, 16, 3), np.float32))
    with pytest.raises(InputError, match="holds no light"):
        read_probe(p)
    q = tmp_path / "bad.exr"
    img = np.full((8, 16, 3), -1.0, np.float32)
    img[0, 0] = np.nan
    write_exr(q, img)
    with pytest.raises(InputError, match=str(q.name)):
        read_probe(q)


def test_nnls_known_values_outliers_and_exposure_invariance():
    rng = np.random.default_rng(0)
    N = 400
    a = rng.uniform(0.2, 1.0, N)
    b = rng.uniform(0.0, 1.0, N)
    y = 0.3 * a + 1.2 * b
    y_out = y.copy()
    y_out[:40] *= 0.2  # shadows nothing explains
    train = np.arange(N) % 2 == 0
    r = fit([Atom("a", a), Atom("b", b)], y_out, train=train, cfg=SOLVER)
    assert np.allclose([r.weights[0][0], r.weights[1][0]], [0.3, 1.2], atol=0.03)
    r2 = fit([Atom("a", a), Atom("b", b)], 1e-4 * y_out, train=train, cfg=SOLVER)
    assert np.allclose(r2.weights[0], 1e-4 * r.weights[0], rtol=1e-6)
    # a negative weight is refused: the best non-negative fit
    r3 = fit([Atom("a", a), Atom("b", b)], 1.0 * a - 0.5 * b, train=train, cfg=SOLVER)
    assert r3.weights[1][0] == 0.0


def test_an_unseen_shadow_keeps_the_sky_an_exposure_atom_ties_to_its_sun():
    """One exposure over a given sky and a given sun (one atom): in the shadow of
    something the frame does not show a pixel keeps the sky (``Atom.kept``), so those
    pixels tell the unseen shadow apart and the exposure is the lit ones'."""
    rng = np.random.default_rng(3)
    N = 1200
    sky = rng.uniform(0.2, 0.4, N)
    sun = rng.uniform(0.8, 1.2, N)
    shadow = np.arange(N) < 0.45 * N  # near half the pixels: an off-frame wall's shadow
    e = 1.7
    y = e * (sky + np.where(shadow, 0.0, sun)) * rng.normal(1.0, 0.03, N)
    train = np.arange(N) % 2 == 0
    prior = float(np.median(y / (sky + sun)))
    tied = Atom("exposure", sky + sun, prior=prior, direct=True, kept=sky)
    r = fit([tied], y, train=train, cfg=SOLVER)
    assert abs(r.weights[0][0] - e) / e < 0.03, r.weights[0][0]
    assert np.allclose(tied.in_unseen_shadow(), sky) and np.allclose(Atom("s", sky).in_unseen_shadow(), sky)
    assert np.allclose(Atom("d", sun, direct=True).in_unseen_shadow(), 0.0)


def test_prior_decides_only_what_the_pixels_cannot():
    N = 200
    a = np.ones(N)
    y = np.full(N, 2.0)
    # two identical columns: the data fix their sum, the prior their split
    r = fit([Atom("sky", a, prior=1.5), Atom("sun", a.copy(), prior=0.5)], y, ridge=1e-5, cfg=SOLVER)
    assert np.isclose(r.weights[0][0] + r.weights[1][0], 2.0, atol=1e-3)
    assert np.isclose(r.weights[0][0], 1.5, atol=0.05)
    # distinct columns: the pixels decide, whatever the prior says
    b = np.linspace(0, 1, N)
    r = fit([Atom("sky", a, prior=5.0), Atom("sun", b, prior=0.0)], 0.3 + 1.1 * b, ridge=1e-5, cfg=SOLVER)
    assert np.isclose(r.weights[0][0], 0.3, atol=0.02) and np.isclose(r.weights[1][0], 1.1, atol=0.02)


def test_coloured_and_grey_atoms_and_batched_scores():
    N = 300
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 1, N)
    col = np.stack([t, 0.5 * t, 0.25 * t], 1)  # a light of known colour
    grey = rng.uniform(0, 1, N)
    y = 2.0 * col + grey[:, None] * np.array([0.1, 0.2, 0.3])[None]
    r = fit([Atom("fixed", col), Atom("g", grey)], y, cfg=SOLVER)
    assert np.allclose(r.weights[0], 2.0, atol=1e-3)
    assert np.allclose(r.weights[1], [0.1, 0.2, 0.3], atol=1e-3)
    base = np.ones((N, 1))
    cands = np.stack([t, grey, rng.uniform(0, 1, N)], 1)
    lh, lt = score_candidates(base, cands, 0.2 + 0.9 * t, np.arange(N) % 2 == 0)
    assert int(np.argmin(lh)) == 0 and lh[0] < 0.1 * lh[1]


def _parse(value, tmp_path=None):
    from zcomp_cli.pipeline.lightspec import parse_light

    probs = []
    out = parse_light(value, "scenes.s.light", lambda c, k, w, m: probs.append((w, m)),
                      (lambda c, k, w: tmp_path / c[k]) if tmp_path else None)
    return out, probs


def test_batched_spd_solve_known_values_and_a_singular_system():
    """``solve_spd`` (the candidates' normal equations, batched): the exact solution of
    known systems, any size of batch, and ``np.linalg.solve``'s answer where a system is
    not positive definite (no Cholesky factor)."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(64, 30, 5))
    A = np.einsum("kni,knj->kij", X, X)
    x_true = rng.normal(size=(64, 5))
    b = np.einsum("kij,kj->ki", A, x_true)
    assert np.allclose(solve_spd(A, b), x_true, rtol=1e-9, atol=1e-9)
    assert solve_spd(A[:1], b[:1]).shape == (1, 5) and solve_spd(A[:0], b[:0]).shape == (0, 5)
    indefinite = np.array([[[1.0, 0.0], [0.0, -2.0]]])
    assert np.allclose(solve_spd(indefinite, np.array([[1.0, 4.0]])), [[1.0, -2.0]])


def test_light_schema_defaults_and_kinds(tmp_path):
    out, probs = _parse([{"type": "probe", "hdr": "p.exr", "convention": "blender", "rotation_deg": 10},
                         {"azimuth_deg": 30, "elevation_deg": 40},
                         {"type": "lamp", "position": [0, 1, -2], "power": 60}], tmp_path)
    assert not probs
    probe, (sun,), (lamp,) = out.probe, out.suns, out.lamps
    assert probe.convention == "blender" and probe.strength == 1.0
    # what is not given is free (fitted), what is given frozen
    assert sun.angles == (30, 40) and not sun.irradiance.frozen and sun.share is None and not sun.radius_deg.frozen
    assert not lamp.radius_m.frozen and lamp.power.frozen and lamp.power.value == 60.0 and lamp.facing is None
    out, probs = _parse({"direction": [0, 2, 0], "strength": 3})
    assert not probs and out.suns[0].direction.value == (0.0, 1.0, 0.0) and out.suns[0].direction.frozen


@pytest.mark.parametrize("value, where, words", [
    ({"type": "lamp"}, "scenes.s.light", "needs 'position'"),
    ({"type": "lamp", "position": [0, 1]}, "scenes.s.light.position", "3 finite numbers"),
    ({"type": "lamp", "position": [0, 1, 2], "power": -1}, "scenes.s.light.power", "[0, 1e+09]"),
    ({"type": "probe", "hdr": "p.exr", "convention": "upside"}, "scenes.s.light.convention", "unknown probe"),
    ({"type": "spot", "direction": [0, 1, 0]}, "scenes.s.light.type", "unsupported"),
    ({"direction": [0, 1, 0], "strength": 2, "irradiance": 3}, "scenes.s.light.irradiance", "not both"),
    ([{"type": "probe", "hdr": "a.exr"}, {"type": "probe", "hdr": "b.exr"}], "scenes.s.light", "at most one probe"),
    ([{"direction": [0, 1, 0]}] * 9, "scenes.s.light", "at most 8"),
    ([{"type": "probe", "hdr": "a.exr"}, {"direction": [0, 1, 0], "strength": 2}], "scenes.s.light", "share"),
    ({"type": "lamp", "position": [0, 1, 2], "colour": [1, 1, 1]}, "scenes.s.light.colour", "unknown key"),
])
def test_light_schema_errors_name_the_field(value, where, words):
    out, probs = _parse(value)
    assert out is None
    assert any(w == where and words in m for w, m in probs), probs


def test_tilt_needs_a_pitch():
    from zcomp_cli.pipeline.lightspec import parse_tilt

    probs = []
    assert parse_tilt({"pitch_deg": -20, "roll_deg": 3}, "scenes.s", lambda *a: probs.append(a)) == \
        {"pitch_deg": -20.0, "roll_deg": 3.0}
    assert parse_tilt({"roll_deg": 3}, "scenes.s", lambda *a: probs.append(a)) == {}
    assert parse_tilt({"pitch_deg": 95}, "scenes.s", lambda *a: probs.append(a)) == {}
    assert len(probs) == 2
