"""Shadow metrics (darkened region vs the background): IoU and darkness error."""

import numpy as np
import pytest

from zcomp_cli.errors import InputError
from zcomp_cli.metrics.shadow import darkened_region, shadow_bias, shadow_darkness, shadow_iou


def _img(val=0.5, h=20, w=30):
    return np.full((h, w, 3), val, np.float32)


def test_identical_shadows_score_perfectly():
    bg = _img()
    a = bg.copy()
    a[5:10, 5:15] *= 0.3
    assert shadow_iou(a, a, bg) == 1.0
    assert shadow_darkness(a, a, bg) == 0.0


def test_partial_overlap_and_darkness():
    bg = _img()
    ref = bg.copy()
    ref[5:10, 0:10] *= 0.25  # 50 px, ratio 0.25
    pred = bg.copy()
    pred[5:10, 5:15] *= 0.85  # 50 px, ratio 0.85, 25 px overlap
    assert shadow_iou(pred, ref, bg) == pytest.approx(25 / 75)
    # union 75 px: |0.85-0.25| on 25, |1-0.25| on 25, |0.85-1| on 25
    assert shadow_darkness(pred, ref, bg) == pytest.approx((0.6 + 0.75 + 0.15) / 3, abs=1e-6)
    # signed, over ref's 50 px only: 0.85-0.25 on 25, 1-0.25 on 25 (pred too pale); none: nan
    assert shadow_bias(pred, ref, bg) == pytest.approx((0.6 + 0.75) / 2, abs=1e-6)
    assert shadow_bias(ref, pred, bg) == pytest.approx((-0.6 + 0.15) / 2, abs=1e-6)  # over pred's 50 px
    assert np.isnan(shadow_bias(pred, bg, bg))


def test_threshold_object_mask_and_black_background():
    bg = _img()
    bg[0, 0] = 0.0
    img = bg.copy()
    img[1, 1] *= 0.95  # 5 % darker: not a shadow
    img[2, 2] *= 0.5
    img[3, 3] *= 0.5
    om = np.zeros(bg.shape[:2])
    om[3, 3] = 1
    reg = darkened_region(img, bg, om)
    assert reg.sum() == 1 and reg[2, 2]
    # neither image darkens anything: perfect agreement, no darkness error
    assert shadow_iou(bg, bg, bg) == 1.0 and shadow_darkness(bg, bg, bg) == 0.0
    with pytest.raises(InputError):
        shadow_iou(img[:5], img, bg)


def test_non_finite_inputs_stay_finite():
    bg = _img()
    img = bg.copy()
    img[0, 0] = np.nan
    img[1, 1] = np.inf
    assert np.isfinite(shadow_darkness(img, bg, bg))
