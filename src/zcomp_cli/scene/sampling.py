"""Deterministic direction sets: the sphere's candidates and a light's cone.

Shared by the light fit and the renderer (no module of ``physical/`` imports another's
internals for them).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def length(v: np.ndarray) -> np.ndarray:
    """(...) the Euclidean length of vectors ``v`` (..., 3): the sums ``np.linalg.norm``
    forms, in the same order (the same values), without its generic path, a third of
    its time on a frame of normals."""
    v = np.asarray(v)
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...) the dot products of vectors ``a`` and ``b`` (..., 3) (broadcast): the sum
    ``(a * b).sum(-1)`` forms, in the same order (the same values), without a reduction
    over an axis of 3 (several times the time)."""
    a, b = np.asarray(a), np.asarray(b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors spread evenly over the sphere (a Fibonacci spiral
    about +z); deterministic."""
    i = np.arange(int(n)) + 0.5
    z = 1 - 2 * i / int(n)
    r = np.sqrt(np.maximum(0, 1 - z * z))
    ph = i * GOLDEN_ANGLE
    return np.stack([r * np.cos(ph), r * np.sin(ph), z], 1)


def hemisphere(n: int, up, min_elevation_deg: float = 0.0) -> np.ndarray:
    """The directions of ``fibonacci_sphere(2 n)`` above ``min_elevation_deg`` over the
    plane of normal ``up``: about n of them."""
    c = fibonacci_sphere(2 * int(n))
    return c[c @ np.asarray(up, np.float64) > np.sin(np.deg2rad(min_elevation_deg))]


def spacing_deg(n_sphere: int) -> float:
    """Typical angle (degrees) between neighbours of ``fibonacci_sphere(n_sphere)``."""
    return float(np.degrees(np.sqrt(4 * np.pi / max(int(n_sphere), 1))))


def orthonormal(l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit ``l`` (3,) to a right-handed basis."""
    l = np.asarray(l, np.float64)
    a = np.array([1.0, 0, 0]) if abs(l[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(l, a)
    u /= np.linalg.norm(u)
    return u, np.cross(l, u)


def cone_directions(light_dir, radius_deg: float, k: int, seed: int = DEFAULT_SEED) -> np.ndarray:
    """K unit directions spread uniformly (in solid angle) over a cone of half-angle
    ``radius_deg`` around ``light_dir`` (a Fibonacci spiral, turned by ``seed``).
    Radius 0 or k <= 1 gives the axis alone. Returns (K, 3) float64."""
    l = np.asarray(light_dir, np.float64)
    l = l / np.linalg.norm(l)
    if radius_deg <= 0 or k <= 1:
        return l[None]
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    i = np.arange(k) + 0.5
    cos_max = np.cos(np.deg2rad(radius_deg))
    cz = 1 - (1 - cos_max) * i / k
    sz = np.sqrt(np.maximum(0, 1 - cz * cz))
    ph = phase + i * GOLDEN_ANGLE
    u, v = orthonormal(l)
    d = cz[:, None] * l + sz[:, None] * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def fine_spiral(center, radius_deg: float, k: int = 40, up=None) -> np.ndarray:
    """``center`` and ``k`` directions around it within ``radius_deg`` (above the plane
    of normal ``up`` when given): the refinement of a coarse search's best."""
    c = np.asarray(center, np.float64)
    f = cone_directions(c, radius_deg, k, seed=0)
    if up is not None:
        f = f[f @ np.asarray(up, np.float64) > 0.02]
    return np.concatenate([c[None], f])


def pixel_jitter(ys: np.ndarray, xs: np.ndarray, salt: int = 0) -> np.ndarray:
    """Deterministic per-pixel value in [0, 1) from integer pixel coordinates (a 4x4
    ordered-dither matrix, shifted by ``salt``): neighbours get well-spread offsets,
    and the same pixel always gets the same one (ROI-independent)."""
    bayer = np.array([[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]], np.float64)
    return ((bayer[(ys + salt) % 4, (xs + 3 * salt) % 4] + 0.5) / 16.0)


def orthonormal_rows(n: np.ndarray):
    """Two unit vectors orthogonal to each row of ``n`` (N, 3) and to each other."""
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    u = np.cross(n, a)
    u /= np.maximum(length(u), 1e-12)[:, None]
    return u, np.cross(n, u)


def disc_samples(k: int, jitter: np.ndarray) -> np.ndarray:
    """(k, N, 2) points on the unit disc, ``k`` stratified in area (sunflower spiral), the
    spiral turned by ``jitter`` (N,) in [0, 1) per point."""
    i = np.arange(k)[:, None]
    r = np.sqrt((i + 0.5) / k)
    ph = 2 * np.pi * (i * 0.618034 + np.asarray(jitter, np.float64)[None])
    return np.stack([r * np.cos(ph), r * np.sin(ph)], -1)


__all__ = ["length", "dot", "fibonacci_sphere", "hemisphere", "spacing_deg", "orthonormal", "cone_directions", "fine_spiral",
           "pixel_jitter", "orthonormal_rows", "disc_samples"]
