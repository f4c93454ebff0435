"""benchmarks/audit_light.py's pieces (issue 47): the stated cones and the strata."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from audit_light import cone_deg, hpd_mass, stratum  # noqa: E402

from zcomp_cli.light.posterior import DirectionPosterior, hemisphere_solid_angles  # noqa: E402
from zcomp_cli.scene.sampling import hemisphere  # noqa: E402


def test_the_stated_cones_of_a_uniform_posterior_hold_their_share_of_the_hemisphere():
    up = np.array([0.0, 1.0, 0.0])
    d = hemisphere(6000, up)
    post = DirectionPosterior(d, np.zeros(len(d)), np.full(len(d), hemisphere_solid_angles(len(d))))
    # about the zenith (the mean of a uniform hemisphere): a cap of half-angle a holds 1 - cos a
    for q in (0.5, 0.68, 0.9):
        assert cone_deg(post, q) == pytest.approx(math.degrees(math.acos(1.0 - q)), abs=1.5)
    # nested, and a cone holding everything reaches the horizon
    assert cone_deg(post, 0.5) < cone_deg(post, 0.68) < cone_deg(post, 0.9) <= cone_deg(post, 1.0) <= 90.0


def test_a_sharp_posteriors_cones_are_narrow():
    up = np.array([0.0, 1.0, 0.0])
    d = hemisphere(6000, up)
    ang = np.degrees(np.arccos(np.clip(d @ up, -1, 1)))
    post = DirectionPosterior(d, -0.5 * (ang / 3.0) ** 2, np.full(len(d), hemisphere_solid_angles(len(d))))
    assert cone_deg(post, 0.9) < 10.0


def test_the_highest_density_set_reaching_a_direction():
    """A sharp posterior about the zenith (a 2-D Gaussian of 5 deg): the set denser than a
    direction 5 deg off holds about 1 - exp(-1/2) of the mass; a bimodal one: a mode's peak is
    inside the 50 % set, where the cone about the mean (between the modes) must reach
    past both to hold it."""
    up = np.array([0.0, 1.0, 0.0])
    d = hemisphere(3000, up)
    om = np.full(len(d), hemisphere_solid_angles(len(d)))
    ang = np.degrees(np.arccos(np.clip(d @ up, -1, 1)))
    post = DirectionPosterior(d, -0.5 * (ang / 5.0) ** 2, om)
    i = int(np.argmin(np.abs(ang - 5.0)))  # a grid direction about 5 deg off
    assert hpd_mass(post, d[i]) == pytest.approx(1.0 - math.exp(-0.5 * (ang[i] / 5.0) ** 2), abs=0.04)
    assert hpd_mass(post, up) < 0.05
    assert hpd_mass(post, np.array([1.0, 0.05, 0.0])) > 0.99  # near the horizon: outside nearly all of it
    a, b = (np.array([math.sin(t), math.cos(t), 0.0]) for t in (math.radians(40), math.radians(-40)))
    ang_a, ang_b = (np.degrees(np.arccos(np.clip(d @ v, -1, 1))) for v in (a, b))
    two = DirectionPosterior(d, np.logaddexp(-0.5 * (ang_a / 5.0) ** 2, -0.5 * (ang_b / 5.0) ** 2), om)
    assert hpd_mass(two, a) < 0.1
    assert cone_deg(two, 0.5) > 35.0


@pytest.mark.parametrize("row,want", [({"shown": True, "truth": "AREA"}, "shadows shown"),
                                      ({"shown": False, "truth": "AREA"}, "lamp"),
                                      ({"shown": False, "truth": "SUN"}, "bare floor"),
                                      ({"shown": False, "truth": "HDR-sun"}, "bare floor")])
def test_strata(row, want):
    assert stratum(row) == want


def test_the_summary_states_the_drawn_skys_share_beside_the_truth():
    """The sky's share as drawn (all its lobes against the suns: what a full shadow keeps)
    beside the truth's, its median gap and its sign (a drawn sky above the truth: pale
    shadows); a model with lamps does not state it."""
    from audit_light import summarise

    base = {"truth": "SUN", "shown": False, "err_deg": 5.0, "spread_deg": 10.0, "split_est": 0.5,
            "split_read": True, "seconds": 0.5}
    rows = [{**base, "split_true": 0.4, "split_drawn": 0.7}, {**base, "split_true": 0.6, "split_drawn": 0.65},
            {**base, "split_true": 0.5, "split_drawn": 0.4}, {**base, "split_true": 0.5, "split_drawn": math.nan}]
    text = summarise(rows)
    line = [x for x in text.splitlines() if x.startswith("the sky's share as drawn")]
    assert len(line) == 1
    assert "n=3" in line[0] and "median |drawn - truth| 0.100" in line[0] and "median drawn - truth +0.050" in line[0]
