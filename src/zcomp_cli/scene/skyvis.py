"""The sky seen from points over the depth map, in screen space (the sky's visibility).

A few cosine-distributed directions per point, turned per pixel (``sampling.pixel_jitter``:
neighbours take well-spread turns, which a blur averages), each marched through the
depth map (``march``) up to ``MarchConfig.sky_range_rel`` of the point's depth. The light
fit's sky atoms and the physical renderer's synthesis read the same samples, weighted
by the sky's radiance (``weighted_visibility``): a wall hides the bright sky behind it,
not the dark one.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.scene.config import MarchConfig
from zcomp_cli.scene.march import march_visibility
from zcomp_cli.scene.sampling import length, pixel_jitter


def hemisphere_directions(normals: np.ndarray, jitter: np.ndarray, k: int) -> list[np.ndarray]:
    """k cosine-distributed directions around each normal, rotated by ``jitter``."""
    n = normals
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    u = np.cross(n, a)
    u /= np.maximum(length(u), 1e-12)[:, None]
    v = np.cross(n, u)
    out = []
    for i in range(k):
        s = (i + 0.5) / k
        rr = np.sqrt(s)  # cosine-weighted: radius on the unit disc
        ph = 2 * np.pi * (i * 0.618034 + jitter)
        ct = np.sqrt(max(1 - rr * rr, 0.0))
        d = ct * n + rr * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
        out.append(d / np.maximum(length(d), 1e-12)[:, None])
    return out


def sky_samples(points: np.ndarray, normals: np.ndarray, ys: np.ndarray, xs: np.ndarray,
                depth: np.ndarray, camera: Camera, *, cfg: MarchConfig,
                occluder_mask: np.ndarray | None = None, walls=()):
    """The sky seen from (N,) camera-frame points over the depth map (screen space, like
    the direct shadow), in ``k = cfg.sky_directions`` cosine-distributed directions turned
    per pixel, each marched ``cfg.sky_steps`` times up to ``cfg.sky_range_rel`` of the
    depth: (directions (k, N, 3), visibility (k, N) in {0, 1}). ``occluder_mask``: (H, W)
    bool, the texels that may occlude (None: all); ``walls`` (``planes.Wall``) beyond the
    frame occlude at any distance. Noisy by design: filter what is made of it."""
    k = cfg.sky_directions
    if len(points) == 0:
        return np.zeros((k, 0, 3)), np.zeros((k, 0))
    jit = pixel_jitter(ys, xs, salt=1)
    dirs = hemisphere_directions(normals, jit, k)
    vis = [march_visibility(points, normals, d, depth, camera, cfg=cfg, steps=cfg.sky_steps, max_distance_rel="sky",
                            jitter=pixel_jitter(ys, xs, salt=i + 2),
                            nearest=True, occluder_mask=occluder_mask, walls=walls)
           for i, d in enumerate(dirs)]
    return np.stack(dirs), np.stack(vis)


def weighted_visibility(dirs: np.ndarray, vis: np.ndarray, radiance, *, sums: bool = False) -> np.ndarray:
    """The visible share of a sky from the samples of ``sky_samples``: sum_k L(w_k) V_k /
    sum_k L(w_k) (cosine-distributed samples, so this is the irradiance's share): (N, C)
    in [0, 1]; 1 where the sky sends nothing. ``radiance``: the sky's SH radiance
    (9, C), or a function of unit directions (M, 3) -> radiance (M, C) (a probe's map,
    ``probe.ProbeLights.sky_radiance_at``): each direction weighs as much as the sky is
    bright there (a weight not finite or negative: none). ``sums``: (N, 2C) the sums sum_k L V and sum_k L instead, for a caller
    that pools neighbours before dividing (a share from a few samples, where one
    bright direction decides it, is biased; a ratio of pooled sums is not)."""
    from zcomp_cli.scene import sh

    K, N = vis.shape
    if callable(radiance):
        L = np.asarray(radiance(dirs.reshape(-1, 3)), np.float64)
        L = np.maximum(np.nan_to_num(L, nan=0.0, posinf=0.0, neginf=0.0), 0.0).reshape(K, N, -1)
    else:
        L = np.maximum(sh.basis(dirs.reshape(-1, 3)) @ np.asarray(radiance, np.float64), 0.0).reshape(K, N, -1)
    num = (L * vis[..., None]).sum(0)
    den = L.sum(0)
    if sums:
        return np.concatenate([num, den], 1)
    return np.where(den > 1e-12, num / np.maximum(den, 1e-300), 1.0)


def mesh_sky_view(points: np.ndarray, up, caster, *, directions: int, bias_rel: float) -> np.ndarray:
    """The share of a uniform sky's irradiance that reaches each of (N,) points of the
    support (camera frame, facing ``up``) past the scene's depth mesh (``caster``:
    ``raycast.RayCaster``, the walls beyond the frame included): (N,) in [0, 1], 1 where
    nothing stands around it. ``directions`` cosine-distributed directions about ``up``,
    the same for every point (a smooth share; a pixel's own turn would need a blur);
    each ray starts ``bias_rel`` of its point's depth above the support."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    if len(P) == 0:
        return np.ones(0)
    up = np.asarray(up, np.float64)
    up = up / max(float(np.linalg.norm(up)), 1e-12)
    dirs = np.stack(hemisphere_directions(up[None], np.zeros(1), int(directions)))[:, 0]
    origins = P + up[None] * (float(bias_rel) * np.maximum(-P[:, 2], 1e-6))[:, None]
    hidden = caster.occluded_grid(origins, dirs)
    return 1.0 - hidden.mean(0)


def support_sky_view(points: np.ndarray, support: np.ndarray, up, caster, *, directions: int, stride: int,
                     bias_rel: float) -> np.ndarray:
    """(h, w) the share of a uniform sky each pixel of the support sees past the scene's
    depth mesh (``mesh_sky_view``), 1 off the support: traced at the support's pixels on
    a ``stride`` x ``stride`` lattice and spread between them by a normalised bilinear
    resize (the share varies over a wall's height, many pixels; ``points`` (h, w, 3)
    camera frame, ``support`` (h, w) bool)."""
    import cv2

    support = np.asarray(support, bool)
    h, w = support.shape
    out = np.ones((h, w))
    if not support.any():
        return out
    st = max(1, int(stride))
    ys = np.arange(st // 2, h, st)
    xs = np.arange(st // 2, w, st)
    sub = support[np.ix_(ys, xs)]
    if not sub.any():  # a support thinner than the lattice: its own pixels
        out[support] = mesh_sky_view(points[support], up, caster, directions=directions, bias_rel=bias_rel)
        return out
    P = np.asarray(points, np.float64)[np.ix_(ys, xs)][sub]
    coarse = np.zeros(sub.shape)
    coarse[sub] = mesh_sky_view(P, up, caster, directions=directions, bias_rel=bias_rel)
    # the lattice's cells resized to the full grid, each pixel the weighted mean of the
    # traced cells around it (cells off the support weigh 0)
    size = (len(xs) * st, len(ys) * st)
    num = cv2.resize((coarse * sub).astype(np.float32), size, interpolation=cv2.INTER_LINEAR)[:h, :w]
    den = cv2.resize(sub.astype(np.float32), size, interpolation=cv2.INTER_LINEAR)[:h, :w]
    near = cv2.resize(coarse.astype(np.float32), size, interpolation=cv2.INTER_NEAREST)[:h, :w]
    full = np.where(den > 1e-3, num / np.maximum(den, 1e-3), near)
    out[support] = np.clip(full[support], 0.0, 1.0)
    return out


__all__ = ["hemisphere_directions", "mesh_sky_view", "support_sky_view", "sky_samples", "weighted_visibility"]
