"""The plate's white balance (estimators.white_balance): known values, the norm's
orders, what is not counted, errors."""

import math

import numpy as np
import pytest

from zcomp_cli.conventions import luminance
from zcomp_cli.errors import InputError
from zcomp_cli.estimators.white_balance import angular_error_deg, plate_illuminant


def _unit(c):
    c = np.asarray(c, np.float64)
    return c / float(luminance(c[None])[0])


@pytest.mark.parametrize("p", [1, 2, 6, math.inf])
@pytest.mark.parametrize("edges", [False, True])
def test_a_grey_scene_under_a_coloured_light_gives_the_light(p, edges):
    rng = np.random.default_rng(3)
    grey = rng.uniform(0.05, 1.0, (24, 32, 1))  # grey surfaces of any brightness
    light = np.array([1.3, 1.0, 0.4])
    got = plate_illuminant(grey * light * 1e4, p=p, edges=edges)  # HDR level: read the same
    np.testing.assert_allclose(got, _unit(light), rtol=1e-9)
    assert float(luminance(got[None])[0]) == pytest.approx(1.0)


def test_known_values_of_the_norm():
    img = np.zeros((1, 2, 3))
    img[0, 0] = [1.0, 0.0, 0.0]
    img[0, 1] = [0.0, 1.0, 0.0]
    # grey-world: the mean (0.5, 0.5, 0); the maximum: (1, 1, 0)
    np.testing.assert_allclose(plate_illuminant(img, p=1), _unit([0.5, 0.5, 0.0]))
    np.testing.assert_allclose(plate_illuminant(img, p=math.inf), _unit([1.0, 1.0, 0.0]))
    bright = img.copy()
    bright[0, 1] = [0.0, 0.5, 0.0]
    # p = 2: sqrt(mean(x^2)) per channel: (sqrt(0.5), sqrt(0.125), 0)
    np.testing.assert_allclose(plate_illuminant(bright, p=2), _unit([math.sqrt(0.5), math.sqrt(0.125), 0.0]))


def test_what_is_not_counted():
    img = np.full((8, 8, 3), [0.2, 0.4, 0.6])
    want = plate_illuminant(img, p=2)
    bad = img.copy()
    bad[0, 0] = [np.nan, 1.0, 1.0]
    bad[1, 1] = [np.inf, 0.0, 0.0]
    bad[2, 2] = [-5.0, 1.0, 1.0]
    np.testing.assert_allclose(plate_illuminant(bad, p=2), want)
    sky = img.copy()
    sky[:2] = [0.0, 0.0, 50.0]
    valid = np.ones((8, 8), bool)
    valid[:2] = False
    np.testing.assert_allclose(plate_illuminant(sky, p=2, valid=valid), want)
    assert angular_error_deg(plate_illuminant(sky, p=2), want) > 20  # counted, the sky's blue wins
    # nothing to read: grey
    np.testing.assert_array_equal(plate_illuminant(np.zeros((4, 4, 3)), p=2), np.ones(3))
    np.testing.assert_array_equal(plate_illuminant(img, p=2, valid=np.zeros((8, 8), bool)), np.ones(3))
    np.testing.assert_array_equal(plate_illuminant(np.full((4, 4, 3), np.nan), p=1, edges=True), np.ones(3))
    # extremes: float32's largest and smallest normal values read the same colour
    for level in (3e38, 1e-37):
        np.testing.assert_allclose(plate_illuminant((img * level).astype(np.float32), p=6), plate_illuminant(img, p=6),
                                   rtol=1e-5)


def test_errors():
    img = np.ones((4, 4, 3))
    with pytest.raises(InputError, match="expected an"):
        plate_illuminant(np.ones((4, 4)), p=2)
    for p in (0.5, 0, -1, float("nan"), "2"):
        with pytest.raises(InputError, match="p must be"):
            plate_illuminant(img, p=p)
    with pytest.raises(InputError, match="valid"):
        plate_illuminant(img, p=2, valid=np.ones((3, 4), bool))


def test_angular_error():
    assert angular_error_deg([1, 0, 0], [0, 1, 0]) == pytest.approx(90.0)
    assert angular_error_deg([1, 2, 3], [10, 20, 30]) == pytest.approx(0.0, abs=1e-6)
    assert angular_error_deg([1, 1, 0], [1, 0, 0]) == pytest.approx(45.0)
    with pytest.raises(InputError):
        angular_error_deg([0, 0, 0], [1, 1, 1])
    with pytest.raises(InputError):
        angular_error_deg([1, 1], [1, 1, 1])
