"""Real spherical harmonics up to order 2 (9 functions): radiance in, irradiance out.

Ramamoorthi and Hanrahan, "An Efficient Representation for Irradiance Environment
Maps" (SIGGRAPH 2001): the irradiance of a Lambertian surface of normal n under a
distant radiance L is ``E(n) = sum_lm A_l L_lm Y_lm(n)`` with ``A_0 = pi``,
``A_1 = 2 pi / 3``, ``A_2 = pi / 4``; order 2 holds the irradiance within a few percent
for any L (the cosine lobe has almost no energy beyond it).

zcomp's shading is ``image / albedo`` = E / pi for a Lambertian surface, so
``shading_sh`` returns the coefficients of E / pi: a sky of uniform radiance L shades
every orientation with L.

Arrays: directions and normals (N, 3) camera-frame unit vectors, float64; radiance
(N, C) linear; coefficients (9, C).
"""

from __future__ import annotations

import numpy as np

N_COEFFS = 9
# Ramamoorthi-Hanrahan cosine-lobe factors per band, over pi (shading = E / pi)
_A_OVER_PI = np.array([1.0, 2.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0, 0.25, 0.25, 0.25, 0.25, 0.25])


def basis(dirs: np.ndarray) -> np.ndarray:
    """(N, 9) real SH Y_00, Y_1-1, Y_10, Y_11, Y_2-2, Y_2-1, Y_20, Y_21, Y_22 of unit
    vectors (N, 3) (the usual x, y, z axes of whatever frame the vectors are in); a
    transposed view of (9, N) rows (each function written whole: a third of the time of
    stacking columns)."""
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = np.empty((N_COEFFS, len(d)))
    out[0] = 0.282095
    np.multiply(0.488603, y, out=out[1])
    np.multiply(0.488603, z, out=out[2])
    np.multiply(0.488603, x, out=out[3])
    out[4] = 1.092548 * x * y
    out[5] = 1.092548 * y * z
    out[6] = 0.315392 * (3 * z * z - 1)
    out[7] = 1.092548 * x * z
    out[8] = 0.546274 * (x * x - y * y)
    return out.T


def quadratic_form(coeffs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The order-2 expansion ``basis(w) @ coeffs`` (9, C) as a polynomial of ``w``:
    ``(a (C,), b (3, C), A (3, 3, C))`` with ``basis(w) @ coeffs = a + w @ b + w^T A w``
    for every vector ``w`` (the nine functions are polynomials of degree 2 in x, y, z).
    Evaluated this way over many directions at once, nothing of size (N, 9) is built.
    The coefficients are read off ``basis`` itself (at 0, the axes and their pairwise
    sums and differences), so its constants stand in one place."""
    c = np.asarray(coeffs, np.float64).reshape(N_COEFFS, -1)
    e = np.eye(3)
    f = lambda w: basis(w) @ c  # noqa: E731  (rows: the polynomial at each vector)
    a = f(np.zeros((1, 3)))[0]
    plus, minus = f(e), f(-e)
    b = 0.5 * (plus - minus)
    A = np.zeros((3, 3, c.shape[1]))
    for i in range(3):
        A[i, i] = 0.5 * (plus[i] + minus[i]) - a
        for j in range(i + 1, 3):
            # f(e_i + e_j) - f(e_i - e_j) = 2 b_j + 4 A_ij
            d = f((e[i] + e[j])[None])[0] - f((e[i] - e[j])[None])[0]
            A[i, j] = A[j, i] = 0.25 * (d - 2.0 * b[j])
    return a, b, A


def project(dirs: np.ndarray, radiance: np.ndarray, solid_angle: np.ndarray) -> np.ndarray:
    """(9, C) SH coefficients of a radiance sampled at ``dirs`` (N, 3), ``radiance``
    (N, C) or (N,), each sample covering ``solid_angle`` (N,) sr."""
    L = np.asarray(radiance, np.float64)
    L = L[:, None] if L.ndim == 1 else L
    w = np.asarray(solid_angle, np.float64)[:, None]
    return basis(dirs).T @ (L * w)


def shading_coeffs(radiance_sh: np.ndarray) -> np.ndarray:
    """(9, C) coefficients of the shading (E / pi) from radiance coefficients (9, C)."""
    return np.asarray(radiance_sh, np.float64) * _A_OVER_PI[:, None]


def evaluate(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, C) value of SH ``coeffs`` (9, C) at unit ``normals`` (N, 3)."""
    return basis(normals) @ np.asarray(coeffs, np.float64)


def directional_radiance(direction, shading) -> np.ndarray:
    """(9, C) radiance coefficients of a delta light toward unit ``direction`` (3,) that
    shades a surface facing it with ``shading`` (C,) (its irradiance over pi: the
    delta's integral is pi x shading)."""
    p = np.atleast_1d(np.asarray(shading, np.float64))
    return basis(np.asarray(direction, np.float64)[None])[0][:, None] * (np.pi * p)[None, :]


__all__ = ["N_COEFFS", "basis", "project", "shading_coeffs", "evaluate", "directional_radiance"]
