"""The inserted object between points and the light, by rays on its posed mesh (Embree).

A shadow map and one blocker distance per pixel (the penumbra filter) draw a small
light's shadow well, but not a large one's: under a metre-wide area lamp the umbra below
an object stays dark and compact while the penumbra spreads far, and the filter drew
both as one blur, shifted with the lamp's centre. A path tracer samples the light.
Here too, for the object (its mesh is known exactly):

* ``light_visibility``: the share of a sun's disc (its angular radius) or a lamp's (a
  sphere's disc facing the point, a panel's in its own plane) that each point sees past
  the mesh, from ``k`` stratified samples turned per pixel;
* ``sky_occlusion``: the share of the sky's irradiance the mesh hides, from directions
  drawn in proportion to the sky's own radiance (``sky_pool``: a probe's bright horizon
  is sampled where it is, where an order-2 SH sky smeared it over the hemisphere), each
  point taking a stratified, per-pixel-turned share of the pool.

Points whose rays cannot reach the mesh's bounding sphere (with the light's spread) cast
no ray. Noisy by design, as a path tracer's few samples are: the caller filters.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.scene.gather import caster
from zcomp_cli.scene.sampling import disc_samples, length


def _bounds(mesh):
    """(centre (3,), radius) of a sphere around the mesh's finite vertices."""
    V = mesh.vertices[np.all(np.isfinite(mesh.vertices), axis=1)]
    if not len(V):
        return np.zeros(3), 0.0
    c = 0.5 * (V.min(0) + V.max(0))
    return c, float(np.sqrt(((V - c) ** 2).sum(1).max()))


def _may_hit(P, D, c, R, spread=0.0, tmax=None):
    """(N,) bool: the rays ``P + t D`` (unit ``D``, 0 < t < ``tmax``) pass within ``R +
    spread t`` of ``c``."""
    w = c - P
    t = np.sum(w * D, 1)
    if tmax is not None:
        t = np.minimum(t, tmax)
    t = np.maximum(t, 0.0)
    d2 = np.sum((w - t[:, None] * D) ** 2, 1)
    return d2 <= (R + spread * t) ** 2


def _toward_sphere(P, c, R):
    """((N, 3) unit directions from ``P`` (N, 3) to the sphere's centre ``c``, (N,) the
    cosine of the half-angle it subtends, -1 where a point is inside it): a ray from a
    point can meet the sphere only within that cone."""
    w = c - P
    dist = length(w)
    u = w / np.maximum(dist, 1e-12)[:, None]
    cos_b = np.sqrt(np.clip(1.0 - (R / np.maximum(dist, 1e-12)) ** 2, 0.0, 1.0))
    return u, np.where(dist > R, cos_b, -1.0)


def light_visibility(mesh, points: np.ndarray, normals: np.ndarray, light, k: int, jitter: np.ndarray,
                     bias: np.ndarray) -> np.ndarray:
    """(N,) the share of ``light``'s disc (``lightmodel.Sun`` or ``Lamp``) the points
    (N, 3) see past the mesh, from ``k`` samples (``disc_samples``, turned by ``jitter``
    (N,)); ``bias`` (N,) metres: each ray starts that far off the surface along its
    normal (N, 3)."""
    P = np.asarray(points, np.float64)
    vis = np.ones(len(P))
    c, R = _bounds(mesh)
    if not len(P) or R <= 0:
        return vis
    start = P + np.asarray(normals, np.float64) * np.asarray(bias, np.float64)[:, None]
    L, dist, _ = light.toward(start)
    tan_a = np.broadcast_to(np.asarray(light.tan_radius(start) if light.varies else light.tan_radius(None),
                                       np.float64), (len(P),))
    cand = _may_hit(start, L, c, R, float(tan_a.max()), dist)
    if not cand.any():
        return vis
    idx = np.flatnonzero(cand)
    s = start[idx]
    # every sample of every point in one call to the ray tracer
    d, t, _ = light.disc(s, disc_samples(int(k), jitter[idx]))  # (k, M, 3), (k, M)
    S = np.broadcast_to(s, d.shape).reshape(-1, 3)
    d = d.reshape(-1, 3)
    t = t.reshape(-1) if light.varies else None
    near = _may_hit(S, d, c, R, 0.0, t)
    hit = np.zeros(len(S), bool)
    if near.any():
        hit[near] = caster(mesh).occluded(S[near], d[near], None if t is None else t[near])
    seen = (~hit).reshape(int(k), -1).sum(0)
    vis[idx] = seen / int(k)
    return vis


def sky_pool(radiance: np.ndarray, directions: np.ndarray, solid_angle: np.ndarray, up, n: int):
    """``n`` directions drawn in proportion to a sky map's luminance times solid angle above
    the horizon (stratified, in the order of the map's rows): ((n, 3) unit directions,
    (n, 3) each one's colour over its luminance). ``radiance`` (h, w, 3), ``directions``
    (h, w, 3) its pixels', ``solid_angle`` (h, w)."""
    d = directions.reshape(-1, 3)
    L = np.maximum(np.asarray(radiance, np.float64).reshape(-1, 3), 0.0)
    lum = L @ np.array([0.299, 0.587, 0.114])
    p = lum * solid_angle.reshape(-1) * (d @ np.asarray(up, np.float64) > 0)
    if not p.sum() > 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    cdf = np.cumsum(p) / p.sum()
    pick = np.minimum(np.searchsorted(cdf, (np.arange(n) + 0.5) / n), len(p) - 1)
    return d[pick], L[pick] / np.maximum(lum[pick], 1e-12)[:, None]


def pool_shading(pool, radiance_sh: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, 3) the shading (irradiance over pi) surfaces of unit ``normals`` (N, 3) get from
    the sky the ``pool`` was drawn from (``sky_pool``: directions in proportion to its
    luminance, each with its colour over its luminance), its level matched to the
    constant term of ``radiance_sh`` (9, 3), the same sky's order-2 SH (the lower
    hemisphere left out, as the pool's). The pool's directions are the map's own: a
    probe's lobes (a bright horizon on one side, a window) shade a ball as they are,
    where the order-2 SH smoothed them. The SH's own shading where the pool is empty."""
    from zcomp_cli.scene import sh

    dirs, chroma = pool
    nv = np.asarray(normals, np.float64).reshape(-1, 3)
    c = np.asarray(radiance_sh, np.float64).reshape(sh.N_COEFFS, 3)
    if not len(dirs):
        return np.maximum(sh.evaluate(sh.shading_coeffs(c), nv), 0.0)
    # Monte Carlo over the pool: E(n) = (Phi / n) sum chroma max(0, n.d), where Phi, the
    # map's luminance over the sphere, is fixed by the SH's constant term (the same sum
    # with Y00 in place of the cosine)
    y00 = sh.basis(dirs[:1])[0, 0]
    per = c[0] / np.maximum(chroma.sum(0) * y00, 1e-12)
    return (np.maximum(nv @ dirs.T, 0.0) @ chroma) * per / np.pi


def sky_occlusion(mesh, points: np.ndarray, normals: np.ndarray, pool, k: int, jitter: np.ndarray,
                  bias: np.ndarray) -> np.ndarray:
    """(N, 3) the share of the sky's irradiance (per colour channel) the mesh hides from
    the points (N, 3) of unit ``normals`` (N, 3): ``k`` directions of the ``pool``
    (``sky_pool``) per point, a stratified share turned by ``jitter`` (N,), each weighted
    by the point's cosine; rays start ``bias`` (N,) metres off the surface."""
    dirs, chroma = pool
    P = np.asarray(points, np.float64)
    Nn = np.asarray(normals, np.float64)
    out = np.zeros((len(P), 3))
    c, R = _bounds(mesh)
    n = len(dirs)
    if not len(P) or not n or R <= 0:
        return out
    start = P + Nn * np.asarray(bias, np.float64)[:, None]
    k = max(1, min(int(k), n))
    base = (np.asarray(jitter, np.float64) * (n / k)).astype(np.int64)
    pick = (base[None] + (np.arange(k)[:, None] * n) // k) % n  # (k, N)
    # per component, (k, N) each (the (k, N, 3) gathers and products, and their sums
    # over a strided axis of 3, were most of the time; the same sums in the same order)
    dx, dy, dz = (np.ascontiguousarray(dirs[:, j])[pick] for j in range(3))
    cos = dx * Nn[:, 0] + dy * Nn[:, 1] + dz * Nn[:, 2]
    np.maximum(cos, 0.0, out=cos)
    wc = [cos * np.ascontiguousarray(chroma[:, j])[pick] for j in range(3)]  # (k, N) each channel's weight
    den = np.stack([x.sum(0) for x in wc], 1)
    u0, cos_b = _toward_sphere(start, c, R)
    toward = dx * u0[:, 0] + dy * u0[:, 1] + dz * u0[:, 2]
    # the rays that may meet the mesh (above the point's horizon: every colour's weight
    # is its cosine's; a sky without red there still sends green and blue)
    cand = np.flatnonzero(((cos > 0) & (toward >= cos_b[None])).reshape(-1))
    num = np.zeros((len(P), 3))
    if len(cand):
        pt = cand % len(P)
        D = np.stack([dx.reshape(-1)[cand], dy.reshape(-1)[cand], dz.reshape(-1)[cand]], 1)
        hit = caster(mesh).occluded(start[pt], D)
        for j in range(3):  # each hit's weight summed per point, in the samples' order
            num[:, j] = np.bincount(pt[hit], weights=wc[j].reshape(-1)[cand][hit], minlength=len(P))
    ok = den > 1e-12
    out[ok] = num[ok] / den[ok]
    return out


__all__ = ["disc_samples", "light_visibility", "sky_pool", "pool_shading", "sky_occlusion"]
