"""What a point sees along a few rays: the inserted object's mesh, the scene's depth map,
the support beyond what the frame shows, or the sky.

A path tracer shades the object with what its rays meet: the sky where they escape, and
where they do not, the radiance of the floor, the walls or the object itself. The
transport's glossy reflection (and any gather of light) asks the same of a few rays per
pixel:

* the object's own mesh, exactly (``raycast.RayCaster``: a concave object sees itself);
* the scene's surfaces in screen space (``march.march_visibility`` over the texels the
  object does not cover), the texel met first;
* past the frame, the support plane below the horizon (where its point projects into the
  frame, that pixel shows it; else it lies beyond the frame);
* else the sky.

``trace`` says which, per ray, and where in the image (``Seen``); the caller looks the
radiance up in its own images (the photograph, what it synthesised).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from zcomp_cli.scene.config import MarchConfig
from zcomp_cli.scene.march import march_visibility
from zcomp_cli.scene.sampling import length, orthonormal_rows


class Met(enum.IntEnum):
    """What a ray met first (``Seen.kind``)."""

    SKY = 0
    SCENE = 1
    OBJECT = 2
    SUPPORT = 3
    BEYOND = 4


SKY, SCENE, OBJECT, SUPPORT, BEYOND = Met


@dataclass
class Seen:
    """Per ray (any shape S): ``kind`` (S,) int8, one of ``SKY`` (nothing met), ``SCENE``
    (a texel of the depth map, or a wall beyond the frame: ``texel`` -1), ``OBJECT`` (the
    mesh: ``texel`` the pixel its hit point projects to, -1 outside the frame), ``SUPPORT``
    (the support plane, seen in the frame at ``texel``), ``BEYOND`` (the support plane
    beyond the frame); ``texel`` (S, 2) int (row, column) or -1; ``depth`` (S,) the hit
    point's z-depth (inf where none); ``distance`` (S,) how far along its ray from its
    point (the mesh's from the point lifted off the surface by the march's bias; inf where
    none)."""

    kind: np.ndarray
    texel: np.ndarray
    depth: np.ndarray
    distance: np.ndarray


def ggx_directions(normals: np.ndarray, view: np.ndarray, alpha: np.ndarray, k: int, jitter: np.ndarray):
    """``k`` directions per point reflected about GGX-distributed half vectors (Trowbridge-
    Reitz D(h) n.h, stratified in the polar angle, turned by ``jitter`` (N,) in [0, 1)):
    ((k, N, 3) unit directions, (k, N) weights n.l, 0 where the direction falls below the
    surface). Weighted by n.l they estimate the split-sum's prefiltered radiance (Karis
    2013)."""
    n = np.asarray(normals, np.float64)
    v = np.asarray(view, np.float64)
    a2 = np.asarray(alpha, np.float64) ** 2
    u_ax, w_ax = orthonormal_rows(n)
    dirs, wts = [], []
    for i in range(k):
        u1 = (i + 0.5) / k
        ph = 2 * np.pi * (i * 0.618034 + jitter)
        ch = np.sqrt((1.0 - u1) / (1.0 + (a2 - 1.0) * u1))
        sh_ = np.sqrt(np.maximum(1.0 - ch * ch, 0.0))
        h = ch[:, None] * n + sh_[:, None] * (np.cos(ph)[:, None] * u_ax + np.sin(ph)[:, None] * w_ax)
        vh = np.sum(v * h, 1)
        d = 2.0 * vh[:, None] * h - v
        d /= np.maximum(length(d), 1e-12)[:, None]
        dirs.append(d)
        wts.append(np.maximum(np.sum(n * d, 1), 0.0))
    return np.stack(dirs), np.stack(wts)


def caster(mesh):
    """The mesh's ray caster (``raycast.RayCaster``), kept on the mesh while it holds the
    same arrays (a job's reflections and gathers ask it several times)."""
    from zcomp_cli.scene.raycast import RayCaster

    memo = getattr(mesh, "_caster_memo", None)
    if memo is not None and memo[0] is mesh.vertices and memo[1] is mesh.faces:
        return memo[2]
    rc = RayCaster(mesh.vertices, mesh.faces)
    try:
        mesh._caster_memo = (mesh.vertices, mesh.faces, rc)
    except AttributeError:
        pass
    return rc


def trace(points: np.ndarray, normals: np.ndarray, dirs: np.ndarray, depth: np.ndarray, camera, *,
          cfg: MarchConfig, steps: int, jitter: np.ndarray, occluder_mask=None, mesh=None, support=None,
          walls=(), max_distance_rel: float | None = None) -> Seen:
    """What each of the rays ``dirs`` (k, N, 3) from ``points`` (N, 3) (unit ``normals``
    (N, 3): the start's offset) meets first (module docstring): the scene's texels of
    ``occluder_mask`` marched ``steps`` times up to ``max_distance_rel`` of the point's
    depth (None: ``cfg.march_range_rel``; ``jitter`` (N,) the samples' offset), the
    ``mesh`` (a posed mesh or None), the ``support`` plane ((point (3,), unit up (3,)) or
    None), the ``walls`` beyond the frame."""
    K, N = dirs.shape[:2]
    P = np.broadcast_to(points, (K, N, 3)).reshape(-1, 3)
    Nn = np.broadcast_to(normals, (K, N, 3)).reshape(-1, 3)
    D = dirs.reshape(-1, 3)
    H, W = depth.shape
    rng = cfg.march_range_rel if max_distance_rel is None else max_distance_rel
    _, t_s, tex = march_visibility(P, Nn, D, depth, camera, cfg=cfg, steps=steps, max_distance_rel=rng,
                                   jitter=np.tile(jitter, K), return_distance=True, nearest=True,
                                   occluder_mask=occluder_mask, walls=walls, return_texel=True)
    kind = np.where(np.isfinite(t_s), SCENE, SKY).astype(np.int8)
    t_hit = t_s.copy()
    if mesh is not None and len(P):
        start = P + Nn * (cfg.march_bias_rel * np.maximum(-P[:, 2], 1e-6))[:, None]
        t_m = caster(mesh).hit_distance(start, D)
        first = t_m < t_hit
        kind[first], t_hit[first] = OBJECT, t_m[first]
        q = start[first] + D[first] * t_m[first, None]
        tex[first] = _project(q, camera, H, W)
    if support is not None:
        p0, up = (np.asarray(a, np.float64) for a in support)
        down = -(D @ up)
        free = (kind == SKY) & (down > 1e-6)
        t_p = ((P[free] - p0) @ up) / down[free]
        ok = t_p > 0
        idx = np.flatnonzero(free)[ok]
        q = P[idx] + D[idx] * t_p[ok, None]
        tx = _project(q, camera, H, W)
        inside = tx[:, 0] >= 0
        kind[idx] = np.where(inside, SUPPORT, BEYOND)
        tex[idx] = tx
        t_hit[idx] = t_p[ok]
    z = np.where(np.isfinite(t_hit), -(P[:, 2] + D[:, 2] * np.where(np.isfinite(t_hit), t_hit, 0.0)), np.inf)
    return Seen(kind.reshape(K, N), tex.reshape(K, N, 2), z.reshape(K, N), t_hit.reshape(K, N))


def _project(q: np.ndarray, camera, H: int, W: int) -> np.ndarray:
    """(M, 2) int (row, column) of camera-frame points ``q`` (M, 3) in the frame, -1 where
    outside it or behind the camera."""
    out = np.full((len(q), 2), -1, np.int64)
    if not len(q):
        return out
    xy, z = camera.project(q)
    with np.errstate(invalid="ignore"):
        ok = (z > 1e-6) & np.all(np.isfinite(xy), 1) & (xy[:, 0] >= 0) & (xy[:, 0] < W) & (xy[:, 1] >= 0) \
            & (xy[:, 1] < H)
    out[ok] = np.stack([xy[ok, 1].astype(np.int64), xy[ok, 0].astype(np.int64)], 1)
    return out


__all__ = ["Met", "Seen", "SKY", "SCENE", "OBJECT", "SUPPORT", "BEYOND", "ggx_directions", "orthonormal_rows", "caster",
           "trace"]
