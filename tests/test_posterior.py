"""The posterior over light directions (renderers/physical/posterior.py): normalisation,
known values for a delta-like and a uniform posterior, tempering, and bad input."""

import math

import numpy as np
import pytest

from zcomp_cli.light.posterior import DirectionPosterior, hemisphere_solid_angles
from zcomp_cli.scene.sampling import fibonacci_sphere, hemisphere

UP = np.array([0.0, 0.9, 0.42])
UP = UP / np.linalg.norm(UP)


def _grid(n=400, up=UP):
    d = hemisphere(n, up)
    return d, np.full(len(d), hemisphere_solid_angles(len(d)))


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _peaked(d, om, centre, width_deg, T=1.0):
    """A posterior made of a Gaussian log-likelihood in the angle from ``centre``."""
    ang = np.degrees(np.arccos(np.clip(d @ centre, -1, 1)))
    return DirectionPosterior.from_parts(d, -0.5 * (ang / width_deg) ** 2, np.zeros(len(d)), om, T)


def test_grid_and_solid_angles():
    d, om = _grid()
    assert 300 < len(d) < 500 and np.all(d @ UP > 0)
    assert hemisphere_solid_angles(len(d)) * len(d) == pytest.approx(2 * math.pi)
    assert hemisphere_solid_angles(0) == pytest.approx(2 * math.pi)  # no division by zero


def test_probabilities_sum_to_one_and_ignore_offsets():
    d, om = _grid()
    rng = np.random.default_rng(0)
    lp = rng.normal(scale=3.0, size=len(d))
    om = om * rng.uniform(0.5, 1.5, size=len(d))
    p = DirectionPosterior(d, lp, om)
    assert p.probabilities.shape == (len(d),) and np.all(p.probabilities >= 0)
    assert p.probabilities.sum() == pytest.approx(1.0, abs=1e-12)
    # mass = density x solid angle
    want = np.exp(lp) * om
    np.testing.assert_allclose(p.probabilities, want / want.sum(), rtol=1e-10)
    # a constant added to the log-posterior changes nothing but the normaliser
    q = DirectionPosterior(d, lp + 1234.5, om)
    np.testing.assert_allclose(q.probabilities, p.probabilities, rtol=1e-10)
    assert q.log_normaliser - p.log_normaliser == pytest.approx(1234.5)
    assert p.log_normaliser == pytest.approx(math.log(float(want.sum())))
    # directions are stored unit, whatever length they came in
    r = DirectionPosterior(d * 3.0, lp, om)
    np.testing.assert_allclose(np.linalg.norm(r.dirs, axis=1), 1.0)
    np.testing.assert_allclose(r.probabilities, p.probabilities)


def test_a_delta_like_posterior():
    d, om = _grid()
    k = 123
    lp = np.zeros(len(d))
    lp[k] = 1000.0
    p = DirectionPosterior(d, lp, om)
    np.testing.assert_allclose(p.map_direction, d[k], atol=1e-12)
    np.testing.assert_allclose(p.mean_direction, d[k], atol=1e-9)
    assert np.linalg.norm(p.mean_resultant) == pytest.approx(1.0, abs=1e-9)
    assert p.rms_angle_deg() < 1e-6
    assert p.mass_within(d[k], 1.0) == pytest.approx(1.0, abs=1e-9)
    assert p.mass_within(-d[k], 30.0) < 1e-9
    assert p.rank(d[k]) == 1
    # the density peaks there and is lowest far away
    assert p.log_density(d[k]) > p.log_density(d[(k + 50) % len(d)]) + 5
    assert p.rank(d[(k + 200) % len(d)]) > 1
    info = p.to_info()
    assert info["grid"] == len(d) and info["rms_angle_deg"] < 1e-6
    np.testing.assert_allclose(info["map_direction"], d[k], atol=1e-12)


def test_a_uniform_posterior():
    d, om = _grid(800)
    p = DirectionPosterior(d, np.zeros(len(d)), om)
    np.testing.assert_allclose(p.probabilities, 1.0 / len(d))
    assert _angle_deg(p.mean_direction, UP) < 2.0
    # the resultant of a uniform hemisphere is half its axis
    assert np.linalg.norm(p.mean_resultant) == pytest.approx(0.5, abs=0.02)
    # the density is 1 / (2 pi) per steradian above the horizon
    for x in hemisphere(60, UP, min_elevation_deg=10.0):
        assert abs(p.log_density(x) + math.log(2 * math.pi)) < 0.3
    # and smaller well below it (only the kernels' tails reach there)
    assert p.log_density(-UP) < -math.log(2 * math.pi) - 5
    # the RMS angle about up of a uniform hemisphere: E[theta^2] = int theta^2 sin theta
    # over [0, pi/2] = pi - 2, 61.2 deg; about its mean (within 2 deg of up) the same
    assert p.rms_angle_deg(UP) == pytest.approx(math.degrees(math.sqrt(math.pi - 2)), abs=0.5)
    assert p.rms_angle_deg() == pytest.approx(math.degrees(math.sqrt(math.pi - 2)), abs=1.0)
    assert p.mass_within(UP, 60.0) == pytest.approx(0.5, abs=0.02)  # a cap of 1 - cos 60 = half


def test_the_density_integrates_to_one_over_the_sphere():
    d, om = _grid(200)
    rng = np.random.default_rng(1)
    p = DirectionPosterior(d, rng.normal(scale=2.0, size=len(d)), om)
    S = fibonacci_sphere(6000)
    dens = np.exp([p.log_density(x) for x in S])
    assert float(dens.sum() * 4 * math.pi / len(S)) == pytest.approx(1.0, abs=0.02)


def test_tempering_spreads_the_mass():
    d, om = _grid()
    c = d[int(np.argmax(d @ UP))]
    base = _peaked(d, om, c, 8.0)
    rms = [base.tempered(T).rms_angle_deg() for T in (0.25, 0.5, 1.0, 2.0, 4.0, 16.0)]
    assert all(b > a for a, b in zip(rms, rms[1:])), rms
    masses = [base.tempered(T).mass_within(c, 10.0) for T in (0.5, 1.0, 4.0)]
    assert masses[0] > masses[1] > masses[2]
    # every temperature keeps the most probable direction
    for T in (0.5, 4.0):
        np.testing.assert_allclose(base.tempered(T).map_direction, base.map_direction)
    # a very high temperature: the prior alone (here flat)
    flat = base.tempered(1e9)
    np.testing.assert_allclose(flat.probabilities, 1.0 / len(d), rtol=1e-6)


def test_from_parts_and_tempered_round_trip():
    d, om = _grid()
    rng = np.random.default_rng(2)
    ll, lp = rng.normal(size=len(d)) * 5, rng.normal(size=len(d))
    p = DirectionPosterior.from_parts(d, ll, lp, om, 2.0)
    assert p.temperature == 2.0
    np.testing.assert_allclose(p.log_post, ll / 2.0 + lp)
    q = p.tempered(0.5).tempered(2.0)
    np.testing.assert_allclose(q.log_post, p.log_post)
    np.testing.assert_allclose(q.probabilities, p.probabilities)
    assert q.temperature == 2.0 and np.array_equal(q.loglik, ll) and np.array_equal(q.log_prior, lp)
    with pytest.raises(ValueError, match="log-likelihood"):
        DirectionPosterior(d, ll, om).tempered(2.0)


@pytest.mark.parametrize("case", ["empty", "nan dir", "inf dir", "zero solid angle", "negative solid angle",
                                  "nan solid angle", "short log_post", "short solid angle"])
def test_bad_input_raises(case):
    d, om = _grid(50)
    lp = np.zeros(len(d))
    if case == "empty":
        d, lp, om = np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    elif case == "nan dir":
        d = d.copy()
        d[3, 1] = np.nan
    elif case == "inf dir":
        d = d.copy()
        d[0] = np.inf
    elif case == "zero solid angle":
        om = om.copy()
        om[5] = 0.0
    elif case == "negative solid angle":
        om = -om
    elif case == "nan solid angle":
        om = om.copy()
        om[2] = np.nan
    elif case == "short log_post":
        lp = lp[:-1]
    else:
        om = om[:-1]
    with pytest.raises(ValueError):
        DirectionPosterior(d, lp, om)


def test_all_minus_inf_is_the_flat_posterior():
    d, om = _grid()
    om = om * np.linspace(0.5, 1.5, len(d))
    for lp in (np.full(len(d), -np.inf), np.full(len(d), np.nan)):
        p = DirectionPosterior(d, lp, om)
        assert np.all(np.isfinite(p.log_post))
        np.testing.assert_allclose(p.probabilities, om / om.sum())
    # some -inf (and nan: the same) among finite values: no mass there
    lp = np.zeros(len(d))
    lp[:10] = -np.inf
    lp[10:20] = np.nan
    p = DirectionPosterior(d, lp, om)
    assert not p.probabilities[:20].any() and p.probabilities.sum() == pytest.approx(1.0)
    assert np.isfinite(p.rms_angle_deg()) and np.isfinite(p.log_density(UP))


# -- the posterior drawn as its modes (issue 47) ------------------------------------------------


def _two_bumps(d, om, a, b, mass_a, width_deg=4.0):
    """A posterior of two narrow bumps at ``a`` and ``b`` holding ``mass_a`` and
    ``1 - mass_a`` of the mass (their log densities offset by the log of the masses)."""
    ang_a = np.degrees(np.arccos(np.clip(d @ a, -1, 1)))
    ang_b = np.degrees(np.arccos(np.clip(d @ b, -1, 1)))
    la = math.log(mass_a) - 0.5 * (ang_a / width_deg) ** 2
    lb = math.log(1.0 - mass_a) - 0.5 * (ang_b / width_deg) ** 2
    return DirectionPosterior(d, np.logaddexp(la, lb), om)


def test_modes_of_two_bumps_are_the_bumps_with_their_masses():
    d, om = _grid(4000)
    a = d[np.argmax(d @ np.array([0.5, 0.8, 0.3]))]
    b = d[np.argmax(d @ np.array([-0.6, 0.7, 0.1]))]
    p = _two_bumps(d, om, a, b, 0.7)
    modes = p.modes(max_modes=4, radius_deg=15.0, mass=0.99)
    assert len(modes) == 2
    assert _angle_deg(modes[0].direction, a) < 1.0 and _angle_deg(modes[1].direction, b) < 1.0
    assert modes[0].mass == pytest.approx(0.7, abs=0.01) and modes[1].mass == pytest.approx(0.3, abs=0.01)
    # heaviest first, whichever bump is denser
    q = _two_bumps(d, om, a, b, 0.2)
    m2 = q.modes(max_modes=4, radius_deg=15.0, mass=0.99)
    assert _angle_deg(m2[0].direction, b) < 1.0 and m2[0].mass == pytest.approx(0.8, abs=0.01)


def test_a_sharp_posterior_is_one_mode_and_a_flat_one_is_many_small_ones():
    d, om = _grid(2000)
    c = d[np.argmax(d @ UP)]
    sharp = _peaked(d, om, c, 2.0).modes(max_modes=4, radius_deg=15.0, mass=0.9)
    assert len(sharp) == 1 and sharp[0].mass > 0.99 and _angle_deg(sharp[0].direction, c) < 0.5
    flat = DirectionPosterior(d, np.zeros(len(d)), om).modes(max_modes=4, radius_deg=15.0, mass=0.9)
    assert len(flat) == 4
    cap = 2 * math.pi * (1 - math.cos(math.radians(15.0))) / (2 * math.pi)  # a cap's share of the hemisphere
    for m in flat:
        assert m.mass <= cap * 1.3
    # each mode holds its members' mass, and no direction belongs to two modes
    p_ = DirectionPosterior(d, np.zeros(len(d)), om).probabilities
    for m in flat:
        assert m.mass == pytest.approx(float(p_[m.members].sum()), rel=1e-12)
    assert np.sum([m.members for m in flat], axis=0).max() == 1
    # each mode's direction lies on the hemisphere and the modes do not overlap
    for i, m in enumerate(flat):
        assert m.direction @ UP > 0
        for o in flat[i + 1:]:
            assert _angle_deg(m.peak, o.peak) >= 15.0


def test_modes_stop_when_they_hold_the_mass_asked():
    d, om = _grid(4000)
    a = d[np.argmax(d @ np.array([0.5, 0.8, 0.3]))]
    b = d[np.argmax(d @ np.array([-0.6, 0.7, 0.1]))]
    p = _two_bumps(d, om, a, b, 0.95)
    assert len(p.modes(max_modes=4, radius_deg=15.0, mass=0.9)) == 1
    assert len(p.modes(max_modes=4, radius_deg=15.0, mass=0.99)) == 2
    assert len(p.modes(max_modes=1, radius_deg=15.0, mass=0.99)) == 1


@pytest.mark.parametrize("kw", [dict(max_modes=0, radius_deg=15.0, mass=0.9),
                                dict(max_modes=2, radius_deg=0.0, mass=0.9),
                                dict(max_modes=2, radius_deg=float("nan"), mass=0.9)])
def test_modes_reject_bad_arguments(kw):
    d, om = _grid(200)
    with pytest.raises(ValueError, match="modes"):
        DirectionPosterior(d, np.zeros(len(d)), om).modes(**kw)


def test_the_rest_drawn_as_sky_shades_as_its_suns_would_on_average():
    """``sun_sky_sh``: the radiance SH of a unit sun spread over the posterior's mass.
    Known values: a uniform posterior over the hemisphere shades an upward surface with
    E[cos] = 1/2 and a downward one with nothing; a sharp posterior toward ``d`` shades
    as that sun does (max(0, n . d)), up to the order-2 SH's smoothing of the cosine;
    masks select the mass, and a mask of the wrong length is an error."""
    from zcomp_cli.scene import sh

    up = np.array([0.0, 1.0, 0.0])
    d, om = _grid(6000, up)
    flat = DirectionPosterior(d, np.zeros(len(d)), om)

    def shade(c, n):
        return float(sh.evaluate(sh.shading_coeffs(np.asarray(c)[:, None]), np.asarray(n, float)[None])[0, 0])

    c = flat.sun_sky_sh()
    assert shade(c, up) == pytest.approx(0.5, abs=0.02)
    assert abs(shade(c, -up)) < 0.05
    half = flat.sun_sky_sh(d[:, 0] > 0)  # half the mass: half the shading from above
    assert shade(half, up) == pytest.approx(0.25, abs=0.02)
    assert np.allclose(flat.sun_sky_sh(np.zeros(len(d), bool)), 0.0)
    c0 = d[np.argmax(d @ np.array([0.5, 0.8, 0.3]))]
    sharp = _peaked(d, om, c0, 1.0).sun_sky_sh()
    for n in (c0, up, np.array([1.0, 0.0, 0.0])):
        n = n / np.linalg.norm(n)
        assert shade(sharp, n) == pytest.approx(max(0.0, float(n @ c0)), abs=0.12)
    with pytest.raises(ValueError, match="mask"):
        flat.sun_sky_sh(np.ones(3, bool))


def test_misled_mixes_the_prior_back_in_by_its_chance():
    """``with_misled``: ``(1 - g) p + g q``, each normalised -- the mass far from a sharp
    peak is the prior's share there times g; 0 leaves the posterior as it is; the
    tempered copy keeps g; g outside [0, 1) is an error; -inf in the likelihood is fine."""
    from zcomp_cli.light.posterior import log_integral, with_misled

    d, om = _grid()
    c = hemisphere(1, UP)[0]
    sharp = _peaked(d, om, c, 3.0)
    mixed = DirectionPosterior.from_parts(d, sharp.loglik, sharp.log_prior, om, 1.0, misled=0.2)
    assert mixed.misled == 0.2 and mixed.tempered(2.0).misled == 0.2
    assert math.exp(log_integral(mixed.log_post, om)) == pytest.approx(1.0, abs=1e-9)
    far = np.degrees(np.arccos(np.clip(d @ c, -1, 1))) > 30
    assert mixed.probabilities[far].sum() == pytest.approx(0.2 * om[far].sum() / om.sum(), rel=1e-3)
    assert sharp.probabilities[far].sum() < 1e-6
    # the peak keeps 1 - g of the mass, and the prior's share of its cap besides
    assert mixed.mass_within(c, 10.0) == pytest.approx(0.8 + 0.2 * (1 - math.cos(math.radians(10.0))), abs=0.01)
    assert np.array_equal(with_misled(sharp.log_post, sharp.log_prior, om, 0.0), sharp.log_post)
    # a prior that leans (cos(elevation) ** -1): the misled share follows it, not the uniform
    lp = -np.log(np.maximum(np.sqrt(1 - (d @ UP) ** 2), 1e-3))
    m2 = DirectionPosterior.from_parts(d, sharp.loglik, lp, om, 1.0, misled=0.5)
    q = np.exp(lp) * om / (np.exp(lp) * om).sum()
    assert np.allclose(m2.probabilities[far], 0.5 * q[far], rtol=1e-3, atol=1e-12)
    ll = np.where(far, -np.inf, 0.0)
    assert np.all(np.isfinite(with_misled(ll, np.zeros(len(d)), om, 0.1)))
    for bad in (-0.1, 1.0, 2.0):
        with pytest.raises(ValueError, match="misled"):
            DirectionPosterior.from_parts(d, sharp.loglik, sharp.log_prior, om, 1.0, misled=bad)


def test_informed_is_the_posterior_the_cues_state():
    """``informed`` drops the prior's share ``misled`` (what the search draws and states
    as its doubt): a sharp posterior mixed with the prior is one mode again, and its RMS
    angle the cues' own."""
    d, om = _grid()
    c = hemisphere(1, UP)[0]
    sharp = _peaked(d, om, c, 3.0)
    mixed = DirectionPosterior.from_parts(d, sharp.loglik, sharp.log_prior, om, 1.0, misled=0.25)
    assert mixed.rms_angle_deg() > 20.0 and mixed.modes(4, 15.0, 0.9)[0].mass < 0.8
    inf = mixed.informed
    assert inf.misled == 0.0 and np.allclose(inf.probabilities, sharp.probabilities)
    assert inf.rms_angle_deg() == pytest.approx(sharp.rms_angle_deg())
    modes = inf.modes(4, 15.0, 0.9)
    assert len(modes) == 1 and modes[0].mass > 0.99 and _angle_deg(modes[0].direction, c) < 2.0
    assert sharp.informed is sharp
