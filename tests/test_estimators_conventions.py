"""Model outputs -> zcomp's conventions (estimators/model_outputs.py): normal frames and
ranges, prediction spaces, non-finite values; each against hand-computed values."""

import numpy as np
import pytest

from zcomp_cli.errors import InputError, NumericalError
from zcomp_cli.estimators.model_outputs import (NORMAL_FRAMES, clean_nonfinite, parse_normal_frame,
                                                to_camera_normals, to_linear)


def _px(*v):
    return np.array(v, np.float32).reshape(1, 1, 3)


def test_opengl_frame_is_identity_up_to_length():
    # Marigold: x right, y up, z toward the viewer = zcomp's frame.
    n = to_camera_normals(_px(0.0, 0.0, 1.0))
    np.testing.assert_allclose(n[0, 0], [0, 0, 1])
    n = to_camera_normals(_px(0.3, 0.4, 0.0))  # not unit: renormalised
    np.testing.assert_allclose(n[0, 0], [0.6, 0.8, 0.0], atol=1e-6)


def test_opencv_frame_flips_y_and_z():
    # OpenCV camera: y down, z into the scene. A floor seen from above (its normal points
    # up and toward the camera) is (0, -0.6, -0.8) there and (0, 0.6, 0.8) in zcomp's.
    n = to_camera_normals(_px(0.0, -0.6, -0.8), "opencv")
    np.testing.assert_allclose(n[0, 0], [0.0, 0.6, 0.8], atol=1e-6)
    assert parse_normal_frame("opencv") == NORMAL_FRAMES["opencv"] == parse_normal_frame(["x", "-y", "-z"])


def test_axes_permutation_and_encoded_range():
    # A model storing (y, x, -z) in an RGB image: value 0.5 is 0, 1 is +1, 0 is -1.
    frame = parse_normal_frame(["y", "x", "-z"])  # zcomp x = model y, zcomp y = model x, zcomp z = -model z
    n = to_camera_normals(_px(1.0, 0.5, 0.5), frame, encoded=True)  # model (1, 0, 0)
    np.testing.assert_allclose(n[0, 0], [0, 1, 0], atol=1e-6)
    n = to_camera_normals(_px(0.5, 0.5, 0.0), frame, encoded=True)  # model (0, 0, -1)
    np.testing.assert_allclose(n[0, 0], [0, 0, 1], atol=1e-6)


def test_degenerate_and_nonfinite_normals_become_zero():
    p = np.array([[[0, 0, 0], [np.nan, 0, 1], [np.inf, 0, 0], [0, 0, 2]]], np.float32)
    n = to_camera_normals(p)
    np.testing.assert_array_equal(n[0, :3], 0)
    np.testing.assert_allclose(n[0, 3], [0, 0, 1])
    assert n.dtype == np.float32 and np.isfinite(n).all()


@pytest.mark.parametrize("bad", ["dx", ["x", "x", "z"], ["x", "y"], ["x", "w", "z"], 3])
def test_bad_frames_are_refused(bad):
    with pytest.raises(InputError):
        parse_normal_frame(bad)


def test_prediction_spaces():
    x = np.array([0.0, 0.04, 0.5, 1.0, 1.5, -0.2], np.float32)
    np.testing.assert_allclose(to_linear(x, "gamma"), np.clip(x, 0, 1) ** 2.2, rtol=1e-6)  # Marigold "srgb"
    srgb = to_linear(x, "srgb")
    assert srgb[1] == pytest.approx(0.04 / 12.92, rel=1e-5)  # IEC curve's linear toe
    assert srgb[2] == pytest.approx(((0.5 + 0.055) / 1.055) ** 2.4, rel=1e-5)
    np.testing.assert_array_equal(to_linear(x, "linear"), np.clip(x, 0, 1))
    assert np.isnan(to_linear(np.array([np.nan]), "gamma")[0])  # kept for clean_nonfinite to see
    with pytest.raises(InputError):
        to_linear(x, "log")


def test_clean_nonfinite_fills_from_the_nearest_pixel():
    a = np.arange(100, dtype=np.float32).reshape(10, 10)
    a[4, 4] = np.nan
    out, note = clean_nonfinite(a, "depth")
    assert np.isfinite(out).all() and "1 non-finite" in note
    assert out[4, 4] in (a[3, 4], a[5, 4], a[4, 3], a[4, 5])
    n = np.ones((10, 10, 3), np.float32)
    n[2, 3, 1] = np.inf  # one bad channel makes the pixel bad
    out, note = clean_nonfinite(n, "normals", max_fraction=0.05)
    np.testing.assert_array_equal(out[2, 3], [1, 1, 1])
    assert clean_nonfinite(np.ones((3, 3)), "x")[1] is None


def test_clean_nonfinite_refuses_many():
    a = np.ones((10, 10), np.float32)
    a[:2] = np.nan  # 20 %
    with pytest.raises(NumericalError, match="20.0%.*bf16"):
        clean_nonfinite(a, "normals model", hint="try dtype: bf16")
    with pytest.raises(NumericalError):
        clean_nonfinite(np.full((4, 4), np.nan), "albedo")
