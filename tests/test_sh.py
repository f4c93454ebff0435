"""Real spherical harmonics of order 2 (renderers/physical/sh.py)."""

import numpy as np
import pytest

from zcomp_cli.scene import sh


def test_the_quadratic_form_is_the_basis_expansion():
    """``a + w.b + w^T A w`` equals ``basis(w) @ c`` for any coefficients and any
    vectors (unit or not: the nine functions are polynomials)."""
    rng = np.random.default_rng(3)
    c = rng.normal(size=(9, 3))
    w = rng.normal(size=(500, 3))
    a, b, A = sh.quadratic_form(c)
    got = a[None] + w @ b + np.einsum("kj,jlc,kl->kc", w, A, w)
    assert np.allclose(got, sh.basis(w) @ c, atol=1e-12)
    assert a.shape == (3,) and b.shape == (3, 3) and A.shape == (3, 3, 3)
    assert np.allclose(A, A.transpose(1, 0, 2))


def test_a_uniform_radiance_is_its_constant():
    a, b, A = sh.quadratic_form(np.eye(9, 1)[:, :1] * 2.0)
    assert a == pytest.approx([0.282095 * 2.0]) and not b.any() and not A.any()
