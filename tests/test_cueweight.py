"""Each cue's weight from the case's own blocks (light/cueweight.py): shapes, errors,
known values, and the two behaviours it exists for -- blocks that agree keep a cue's
weight, blocks that disagree take it away -- with the scorer's per-block terms summing to
the likelihoods the search uses."""

import math

import numpy as np
import pytest

from zcomp_cli.light import cueweight as cw
from zcomp_cli.light.config import SearchConfig
from zcomp_cli.light.posterior import log_integral
from zcomp_cli.scene.sampling import hemisphere


CFG = SearchConfig()
K_LO, K_HI = CFG.weight_range


def _grid(n=256):
    dirs = hemisphere(n, np.array([0.0, 1.0, 0.0]), 2.0)
    return dirs, np.zeros(len(dirs)), np.full(len(dirs), 2 * math.pi / len(dirs))


def _peaked(dirs, toward, sharpness):
    """(K,) a log-likelihood peaked at ``toward``."""
    t = np.asarray(toward, np.float64)
    return sharpness * (dirs @ (t / np.linalg.norm(t)) - 1.0)


def test_block_ids_number_the_blocks_present():
    ys = np.array([0, 0, 5, 9, 9])
    xs = np.array([0, 9, 0, 9, 1])
    ids, n = cw.block_ids(ys, xs, (10, 10), 2)
    assert n == 4 and ids.shape == (5,)
    assert ids[2] == ids[4]  # (5, 0) and (9, 1): the lower left block
    assert len({ids[0], ids[1], ids[2], ids[3]}) == 4
    with pytest.raises(ValueError, match="blocks"):
        cw.block_ids(ys, xs, (10, 10), 0)


def test_block_sums_sum_each_blocks_rows():
    v = np.arange(12, dtype=float).reshape(4, 3)
    out = cw.block_sums(v, np.array([1, 0, 1, 0]), 2)
    assert np.allclose(out, [[3 + 9, 4 + 10, 5 + 11], [0 + 6, 1 + 7, 2 + 8]])
    assert np.allclose(out.sum(0), v.sum(0))
    with pytest.raises(ValueError, match="agree"):
        cw.block_sums(v, np.array([0, 1]), 2)


def test_blocks_that_agree_keep_the_cues_weight():
    """Every block sees the same sharp peak: resampled, the best direction never moves,
    so the cue keeps its full weight, and the coverage is met."""
    dirs, lp, om = _grid()
    one = _peaked(dirs, (0.5, 1.0, 0.2), 3.0)
    LL = np.stack([one * (1.0 + 0.05 * i) for i in range(20)])
    w = cw.cue_weight(LL, lp, om, dirs, CFG)
    assert w.k == pytest.approx(K_HI) and w.coverage >= CFG.weight_level and w.blocks == 20


def test_blocks_that_disagree_take_the_weight_away():
    """Each block peaked toward its own random direction, summing to a confident-looking
    peak: resampled, the best direction wanders, and the weight falls far below 1."""
    dirs, lp, om = _grid()
    rng = np.random.default_rng(3)
    LL = np.stack([_peaked(dirs, dirs[rng.integers(len(dirs))], 20.0) for _ in range(24)])
    w = cw.cue_weight(LL, lp, om, dirs, CFG)
    assert w.k < 0.1 and w.coverage >= CFG.weight_level
    # the same blocks agreeing get more weight than disagreeing: the weight orders them
    agree = cw.cue_weight(np.stack([LL.sum(0) / 24] * 24), lp, om, dirs, CFG)
    assert agree.k > 10 * w.k


def test_the_weight_is_deterministic_and_checks_its_input():
    dirs, lp, om = _grid(64)
    rng = np.random.default_rng(0)
    LL = rng.normal(size=(10, len(dirs)))
    assert cw.cue_weight(LL, lp, om, dirs, CFG, seed=4) == cw.cue_weight(LL, lp, om, dirs, CFG, seed=4)
    # one block: nothing to resample -- the floor
    assert cw.cue_weight(LL[:1], lp, om, dirs, CFG).k == K_LO
    # NaN in a block's terms: the floor, not a NaN weight
    bad = LL.copy()
    bad[2, 5] = np.nan
    assert cw.cue_weight(bad, lp, om, dirs, CFG).k == K_LO
    with pytest.raises(ValueError, match="agree"):
        cw.cue_weight(LL[:, :-1], lp, om, dirs, CFG)
    with pytest.raises(ValueError, match="positive"):
        cw.cue_weight(LL, lp, np.zeros_like(om), dirs, CFG)


def test_the_gate_mixes_a_cues_density_with_the_uniform():
    dirs, _, om = _grid()
    ll = _peaked(dirs, (0.5, 1.0, 0.2), 50.0)
    z = log_integral(ll, om)
    # a density: it integrates to 1 over the hemisphere, gated or not
    for gate in (0.0, 0.1, 0.5):
        g = cw.gated(ll, gate, z)
        assert float(np.exp(g) @ om) == pytest.approx(1.0, rel=1e-9)
    g = cw.gated(ll, 0.1, z)
    assert np.all(np.diff(g[np.argsort(ll)]) >= 0)  # the order kept
    # never below the uniform's share; the peak keeps (1 - gate) of its density
    assert g.min() >= math.log(0.1 / (2 * math.pi)) - 1e-12
    assert g.max() == pytest.approx(math.log(0.9 * math.exp(ll.max() - z) + 0.1 / (2 * math.pi)), rel=1e-12)
    # two sharp cues that disagree: each peak survives (at the other's gate); ungated,
    # the product is sure of a direction neither cue chose
    other = _peaked(dirs, (-0.6, 0.5, -0.3), 50.0)
    zo = log_integral(other, om)
    both = cw.gated(ll, 0.1, z) + cw.gated(other, 0.1, zo)
    i_a, i_b = int(np.argmax(ll)), int(np.argmax(other))
    p = np.exp(both - both.max()) * om
    p /= p.sum()
    near = lambda i: (dirs @ dirs[i]) > math.cos(math.radians(15))
    assert p[near(i_a)].sum() > 0.3 and p[near(i_b)].sum() > 0.3
    bare = np.exp((ll - z) + (other - zo) - ((ll - z) + (other - zo)).max()) * om
    bare /= bare.sum()
    assert bare[near(i_a)].sum() + bare[near(i_b)].sum() < 0.2
    # HDR-sized log-likelihoods overflow nothing
    assert np.all(np.isfinite(cw.gated(np.array([-1e300, 1e3]), 0.1, 0.0)))
    with pytest.raises(ValueError, match="gate"):
        cw.gated(ll, 1.0, z)


def test_the_per_block_terms_sum_to_the_likelihoods():
    """The shadow fit's and the photometric fit's per-block shares sum to what the
    search scores, so the weight reads the same likelihood it weighs."""
    from zcomp_cli.light.shadowcast import ShadowFit
    from zcomp_cli.light.solver import candidate_losses, score_candidates

    rng = np.random.default_rng(1)
    sf = ShadowFit(resid=rng.normal(size=(50, 7)), weight=rng.uniform(0.1, 2, 50), ratio=np.ones(7), blocks=9,
                   sigma_min=0.01)
    ids = rng.integers(0, 6, 50)
    ll, blocks = sf.block_loglik(0.3, ids, 6)
    assert np.array_equal(ll, sf.loglik(0.3))
    assert np.allclose(blocks.sum(0), ll)
    B = rng.uniform(0.5, 1.0, (80, 3))
    C = rng.uniform(0.0, 1.0, (80, 5))
    y = B @ [0.3, 0.2, 0.1] + 0.4 * C[:, 2] + 0.01 * rng.normal(size=80)
    train = np.arange(80) % 3 != 0
    loss = candidate_losses(B, C, y, train)
    lh, lt = score_candidates(B, C, y, train)
    assert loss.shape == (80, 5)
    assert np.allclose(loss[~train].mean(0), lh) and np.allclose(loss[train].mean(0), lt)
    assert int(np.argmin(lh)) == 2


def test_the_search_keeps_what_a_refit_needs_and_weighs_its_cues_when_asked():
    """The search's unweighted scores (``Search.scored``) give back its own posterior
    through ``weighted_marginal`` -- what ``fit_light_constants.py`` refits offline -- and
    with the weights applied and a gate (off by default: the calibration's choice) the
    fit runs through and reports them applied."""
    import dataclasses

    from zcomp_cli.light import search as sr
    from zcomp_cli.light.config import DEFAULT_LIGHT
    from zcomp_cli.light.posterior import DirectionPosterior
    from zcomp_cli.light.prepare import prepare
    from zcomp_cli.scene.frame import scene_up
    from zcomp_cli.testing import estimate_light, floor_scene

    s = floor_scene(120, 90, light_dir=(0.7, 1.0, 0.2), with_box=True, box_center=(-0.4, -3.2), ambient=0.3,
                    sky_occlusion=True)
    known = s.depth > 0
    up, uf = scene_up(None, s.normals, known)
    cfg = DEFAULT_LIGHT
    pp = prepare(s.depth, s.normals, s.shading, known, s.albedo, s.camera, up, cfg)
    res, _ = sr.search(pp, cfg)
    post = res.posterior
    marg, _ = sr.weighted_marginal(res.scored, (dataclasses.replace(res.weights[0], k=1.0),
                                                dataclasses.replace(res.weights[1], k=1.0)),
                                   cfg.search.gate, cfg.search.temperature, res.log_opt_prior, post.solid_angle)
    again = DirectionPosterior.from_parts(post.dirs, marg, post.log_prior, post.solid_angle, cfg.search.temperature,
                                          cfg.search.misled)
    assert np.allclose(again.probabilities, post.probabilities, atol=1e-12)
    assert all(0 < w.k <= 1 for w in res.weights)
    on = dataclasses.replace(cfg, search=dataclasses.replace(cfg.search, cue_weights=True, gate=0.1))
    m = estimate_light(s.depth, s.normals, s.shading, known, s.albedo, s.camera, up=up, up_from=uf, cfg=on)
    assert np.all(np.isfinite(m.key_direction)) and abs(float(np.linalg.norm(m.key_direction)) - 1.0) < 1e-9
    assert m.fit.cue_weights["shadow"]["applied"] and m.fit.cue_weights["photometric"]["applied"]
    assert m.fit.modes and not cfg.search.cue_weights
    # a light whose direction is given (no search): the weights measured off the
    # search's coarse grid where they are to be applied, not scored where nothing uses them
    _, sc = sr.search_scorer(pp, on)
    sc.ensure_weights()
    assert all(np.isfinite(w.coverage) and w.blocks >= 2 for w in sc.weights)
    _, sc = sr.search_scorer(pp, cfg)
    sc.ensure_weights()
    assert all(w.k == 1.0 and w.blocks == 0 for w in sc.weights)
