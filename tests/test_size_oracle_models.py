"""benchmarks/size_oracle_models.py's photograph-blur model (issue 47): the receivers'
visibility seen through a Gaussian, normalised over the receivers alone."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from size_oracle_models import BLURS_PX, blurred_columns  # noqa: E402


def _receivers(mask):
    ys, xs = np.nonzero(mask)
    return SimpleNamespace(ys=ys, xs=xs)


def test_the_first_column_is_the_visibility_as_it_is_and_a_flat_one_stays_flat():
    mask = np.ones((20, 30), bool)
    mask[5:9, 10:14] = False  # a caster: no receivers there
    rec = _receivers(mask)
    V = np.full(len(rec.ys), 0.37)
    cols = blurred_columns(rec, mask.shape, V)
    assert cols.shape == (len(V), 1 + len(BLURS_PX))
    np.testing.assert_array_equal(cols[:, 0], V)
    # what is not a receiver lends no value: a flat visibility stays flat by the hole
    np.testing.assert_allclose(cols, 0.37, atol=1e-12)


def test_a_hard_edge_softens_more_with_more_blur_and_keeps_its_two_levels():
    mask = np.ones((16, 40), bool)
    rec = _receivers(mask)
    V = (rec.xs >= 20).astype(float)  # shadowed left, lit right
    cols = blurred_columns(rec, mask.shape, V)
    row = rec.ys == 8
    widths = []
    for k in range(cols.shape[1]):
        prof = cols[row, k]
        assert prof[0] == pytest.approx(0.0, abs=1e-3) and prof[-1] == pytest.approx(1.0, abs=1e-3)
        assert np.all(np.diff(prof) >= -1e-12)  # still a monotone edge
        widths.append(int(((prof > 0.05) & (prof < 0.95)).sum()))
    assert widths[0] == 0 and widths == sorted(widths) and widths[-1] >= 6
