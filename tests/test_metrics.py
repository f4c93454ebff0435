"""Pixel metrics and the FLIP wrapper: known values, invariants, validation."""

import numpy as np
import pytest

from zcomp_cli.errors import InputError
from zcomp_cli.metrics import image_metrics as im
from zcomp_cli.metrics.flip import flip, flip_error_map


@pytest.fixture
def pair():
    rng = np.random.default_rng(0)
    ref = rng.random((24, 32, 3))
    pred = np.clip(ref + rng.normal(0, 0.05, ref.shape), 0, 1)
    return pred, ref


def test_psnr_of_known_mse():
    ref = np.zeros((8, 8, 3))
    pred = np.full((8, 8, 3), 0.1)  # MSE = 0.01 -> 20 dB
    assert im.psnr(pred, ref) == pytest.approx(20.0, abs=1e-9)
    assert im.rmse(pred, ref) == pytest.approx(0.1)
    assert im.mae(pred, ref) == pytest.approx(0.1)


def test_identical_images_give_perfect_scores(pair):
    _, ref = pair
    assert im.psnr(ref, ref) == float("inf")
    assert im.rmse(ref, ref) == 0.0
    assert im.si_rmse(ref, ref) == pytest.approx(0.0, abs=1e-12)
    assert im.mae(ref, ref) == 0.0
    assert im.ssim(ref, ref) == pytest.approx(1.0)
    assert flip(ref.astype(np.float32), ref.astype(np.float32)) == pytest.approx(0.0, abs=1e-7)


def test_si_rmse_invariant_to_global_scale(pair):
    pred, ref = pair
    base = im.si_rmse(pred, ref)
    for s in (0.01, 0.5, 3.0, 1e4):
        assert im.si_rmse(pred * s, ref) == pytest.approx(base, rel=1e-9)
    assert base <= im.rmse(pred, ref) + 1e-12
    # A scaled copy of the reference is a perfect match up to scale.
    assert im.si_rmse(ref * 7.0, ref) == pytest.approx(0.0, abs=1e-12)


def test_si_rmse_zero_prediction_is_finite():
    ref = np.full((4, 4, 3), 0.5)
    v = im.si_rmse(np.zeros_like(ref), ref)
    assert np.isfinite(v) and v == pytest.approx(0.5)
    assert im.si_rmse(np.full_like(ref, 1e-30), ref) == pytest.approx(0.5)


def test_ssim_equals_scikit_image(pair):
    from skimage.metrics import structural_similarity

    pred, ref = pair
    want = structural_similarity(pred, ref, channel_axis=-1, data_range=1.0)
    assert im.ssim(pred, ref) == pytest.approx(want, abs=1e-12)
    # A full mask gives the unmasked value (SSIM border excluded in both).
    assert im.ssim(pred, ref, np.ones(ref.shape[:2])) == pytest.approx(want, abs=1e-12)


def test_mask_restricts_region():
    ref = np.zeros((10, 10, 3))
    pred = ref.copy()
    pred[:, 5:] = 0.5
    left = np.zeros((10, 10), bool)
    left[:, :5] = True
    assert im.mae(pred, ref, left) == 0.0
    assert im.mae(pred, ref, ~left) == pytest.approx(0.5)
    assert im.psnr(pred, ref, left) == float("inf")
    with pytest.raises(InputError, match="no pixel"):
        im.mae(pred, ref, np.zeros((10, 10)))
    with pytest.raises(InputError, match="mask"):
        im.mae(pred, ref, np.ones((9, 10)))


def test_hdr_extremes_stay_finite():
    ref = np.full((8, 8, 3), 1e4)
    pred = ref * 1.01
    assert np.isfinite(im.psnr(pred, ref)) and im.psnr(pred, ref) < 0
    assert im.si_rmse(pred, ref) == pytest.approx(0.0, abs=1e-6)
    assert np.isfinite(im.ssim(pred, ref))


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_rejected(pair, bad):
    pred, ref = pair
    pred = pred.copy()
    pred[0, 0, 0] = bad
    for fn in (im.psnr, im.rmse, im.si_rmse, im.ssim, im.mae):
        with pytest.raises(InputError, match="non-finite"):
            fn(pred, ref)
    with pytest.raises(InputError, match="non-finite"):
        flip(pred, ref)


def test_shape_errors(pair):
    pred, ref = pair
    with pytest.raises(InputError, match="size mismatch"):
        im.psnr(pred[:-1], ref)
    with pytest.raises(InputError, match="H x W x 3"):
        im.psnr(pred[..., 0], ref[..., 0])
    with pytest.raises(InputError, match="at least 7x7"):
        im.ssim(pred[:5, :5], ref[:5, :5])


def test_flip_equals_flip_evaluator(pair):
    import flip_evaluator

    pred, ref = (a.astype(np.float32) for a in pair)
    _, want, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref), np.ascontiguousarray(pred), "LDR")
    assert flip(pred, ref) == pytest.approx(want, rel=1e-5)
    # Non-contiguous float64 input is converted, not misread.
    got = flip(np.asfortranarray(pred.astype(np.float64)), ref[:, :, :].astype(np.float64))
    assert got == pytest.approx(want, rel=1e-5)


def test_flip_hdr_mode_and_mask(pair):
    import flip_evaluator

    pred, ref = (a.astype(np.float32) * 5.0 for a in pair)
    _, want, _ = flip_evaluator.evaluate(ref, pred, "HDR")
    assert flip(pred, ref, mode="HDR") == pytest.approx(want, rel=1e-5)
    emap = flip_error_map(pred, ref, mode="HDR")
    m = np.zeros(ref.shape[:2])
    m[:10] = 1
    assert flip(pred, ref, m, mode="HDR") == pytest.approx(emap[:10].mean(), rel=1e-6)


def test_flip_validates_before_calling(pair):
    pred, ref = pair
    with pytest.raises(InputError, match="sRGB-encoded"):
        flip(pred * 2.0, ref)
    with pytest.raises(InputError, match="non-negative"):
        flip(pred - 0.5, ref, mode="HDR")
    with pytest.raises(InputError, match="H x W x 3"):
        flip(np.dstack([pred, pred[..., :1]]), np.dstack([ref, ref[..., :1]]))
    with pytest.raises(InputError, match="mode"):
        flip(pred, ref, mode="XDR")
    with pytest.raises(InputError, match="size mismatch"):
        flip(pred[:-2], ref)
