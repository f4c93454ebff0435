"""Shading model: low-order SH ambient + directional lights, each with a cone (softness)."""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED


def sh_basis(normals: np.ndarray) -> np.ndarray:
    """Order-1 real SH basis (unnormalised): (N, 3) normals -> (N, 4) [1, nx, ny, nz]."""
    n = np.asarray(normals, np.float64)
    return np.concatenate([np.ones((len(n), 1)), n], axis=1)


def _orthonormal(l: np.ndarray):
    a = np.array([1.0, 0, 0]) if abs(l[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(l, a)
    u /= np.linalg.norm(u)
    return u, np.cross(l, u)


def cone_directions(light_dir, radius_deg: float, k: int, seed: int = DEFAULT_SEED) -> np.ndarray:
    """K unit directions spread uniformly (in solid angle) over a cone of half-angle
    ``radius_deg`` around ``light_dir`` (Fibonacci spiral, rotated by ``seed``).
    radius 0 or k <= 1 gives just the axis. Returns (K, 3) float64."""
    l = np.asarray(light_dir, np.float64)
    l = l / np.linalg.norm(l)
    if radius_deg <= 0 or k <= 1:
        return l[None]
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi)
    i = np.arange(k) + 0.5
    cos_max = np.cos(np.deg2rad(radius_deg))
    cz = 1 - (1 - cos_max) * i / k
    sz = np.sqrt(np.maximum(0, 1 - cz * cz))
    ph = phase + i * np.pi * (3 - np.sqrt(5))
    u, v = _orthonormal(l)
    d = cz[:, None] * l + sz[:, None] * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def direct_term(points, normals, dirs, depth, camera, visibility_fn, **march) -> np.ndarray:
    """Mean over cone directions of max(0, n.l_k) V(p, l_k): (N,) float64. Accumulated in a
    fixed order per pixel so results do not depend on which pixels are processed."""
    acc = np.zeros(len(points))
    for lk in dirs:
        ndl = np.maximum(0.0, normals @ lk)
        live = ndl > 0
        v = np.zeros(len(points))
        if live.any():
            v[live] = visibility_fn(points[live], normals[live], lk, depth, camera, **march)
        acc += ndl * v
    return acc / len(dirs)


def shade(normals: np.ndarray, direct: np.ndarray, ambient_sh: np.ndarray,
          intensity: np.ndarray) -> np.ndarray:
    """shading (N, 3) = max(0, SH_ambient(n)) + I * direct, linear RGB."""
    amb = np.maximum(sh_basis(normals) @ ambient_sh, 0.0)
    return amb + direct[:, None] * np.asarray(intensity)[None, :]
