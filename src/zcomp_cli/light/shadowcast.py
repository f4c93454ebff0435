"""The light's direction from the cast shadows the support shows: ray cast each candidate
light through the depth mesh and score its shadow against the photograph (DESIGN.md
section 8, "The light from the shadows").

**Receivers** are the support's pixels (``depthmesh``) whose shading the evidence
(``shadow_evidence``) keeps: every one within reach of a caster's shadow, the rest on a
sparser stride, each weighted by the share of the support it stands for, at most
``max_receivers`` of them.

**A candidate light** -- a direction (a sun) or a position (a lamp) -- casts a shadow ``V``
over the receivers (rays through the mesh, Embree; 1 lit, 0 shadowed, in between for a
cone's average). On the support, whose normal is up, a light's irradiance is a constant
share of the lit level (a lamp's fall-off, the sky's gradient and the albedo's own
shading are the lit level's, ``shadow_evidence.lit_basis``), so

    log s = X beta + c (1 - V),   c = log rho <= 0

with ``X beta`` the lit level and ``rho`` the shadowed/lit ratio -- the sky's share of
the support's light, Madsen and Nielsen's measurement, read off the shadow itself (exact
where V is 0 or 1; across a penumbra the log-linear interpolation). ``beta`` and ``c``
are fitted by least squares for every candidate at once (the residual of one
projection). The Gaussian log-likelihood at the
best candidate's noise scale counts each **block** of the frame (``FrameConfig.holdout_blocks``)
the receivers span as one observation: residuals within a block are correlated (a
shadow's edge, an albedo error), so a pixel is not one.

Where no tied shadow is seen every candidate explains the support alike (``rho`` goes
to 1 for all): the likelihood is flat, and the photograph does not tell the direction.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.light.config import SearchConfig
from zcomp_cli.scene.sampling import length


@dataclass(frozen=True)
class Receivers:
    """Support pixels of the working grid: ``ys``/``xs`` (R,), ``origins`` (R, 3) biased
    off the surface, ``distance`` (R,) from the camera, ``ratio``/``weight`` (R,) from the
    evidence (the weight times the share of the support each stands for), ``blocks`` how
    many of the frame's blocks they span, ``sigma`` the evidence's noise scale,
    ``log_shading`` (R,) and ``basis`` (R, P) the lit level's
    (``shadow_evidence.lit_basis``)."""

    ys: np.ndarray
    xs: np.ndarray
    origins: np.ndarray
    distance: np.ndarray
    ratio: np.ndarray
    weight: np.ndarray
    blocks: int
    sigma: float
    log_shading: np.ndarray
    basis: np.ndarray

    def __len__(self) -> int:
        return len(self.ys)

    @functools.cached_property
    def projection(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(``sw`` (R,) the weights' roots, ``Q`` (R, p) an orthonormal basis of the lit
        level's weighted span, ``yr`` (R,) the weighted log shading less its projection):
        what every ``shadow_fit`` of these receivers shares, one SVD for all of them (it
        was one per call)."""
        w = np.maximum(self.weight, 0.0)
        sw = np.sqrt(w)
        U, sv, _ = np.linalg.svd(self.basis * sw[:, None], full_matrices=False)
        Q = U[:, sv > 1e-9 * max(float(sv.max()), 1e-300)]  # the basis's span (its albedo terms may be constant)
        y = self.log_shading * sw
        return sw, Q, y - Q @ (Q.T @ y)


def receivers(mesh, evidence, *, max_receivers: int, bias_rel: float, blocks: int) -> Receivers:
    """The support's receivers (module docstring): every support pixel where a caster's
    shadow can fall (``evidence.reach``), the rest of the support on a sparser stride,
    each weighted by the share of the support it stands for, at most ``max_receivers``;
    their rays start ``bias_rel`` of their depth above the support
    (``SearchConfig.bias_rel``); ``blocks`` the frame's blocks per long side
    (``FrameConfig.holdout_blocks``)."""
    ok = mesh.support & (evidence.weight > 0) & np.isfinite(evidence.ratio)
    near = ok & evidence.reach
    far = ok & ~evidence.reach
    n_near, n_far = int(near.sum()), int(far.sum())
    # the pixels near casters first (they tell directions apart), the others on a stride
    # that leaves them at least a fifth of the receivers (they tell a wall's shadow)
    k_near = min(n_near, max(max_receivers - min(n_far, max_receivers // 5), max_receivers // 2))
    k_far = min(n_far, max_receivers - k_near)
    h, w = mesh.shape
    picks, wts = [], []
    for m, k in ((near, k_near), (far, k_far)):
        idx = np.flatnonzero(m.ravel())
        if k <= 0 or not len(idx):
            continue
        sel = idx[np.linspace(0, len(idx) - 1, k).astype(np.int64)] if len(idx) > k else idx
        picks.append(sel)
        wts.append(np.full(len(sel), len(idx) / len(sel)))
    idx = np.concatenate(picks) if picks else np.zeros(0, np.int64)
    area = np.concatenate(wts) if wts else np.zeros(0)
    ys, xs = np.divmod(idx, w)
    P = mesh.points[ys, xs]
    up = mesh.up
    O = P + up[None] * (bias_rel * np.maximum(-P[:, 2], 1e-6))[:, None]
    blk = max(h, w) / blocks
    n_blocks = len(np.unique((ys // blk).astype(int) * (blocks + 1) + (xs // blk).astype(int)))
    return Receivers(ys=ys, xs=xs, origins=O, distance=np.linalg.norm(P, axis=1), ratio=evidence.ratio[ys, xs],
                     weight=evidence.weight[ys, xs] * area, blocks=max(1, n_blocks),
                     sigma=float(evidence.sigma), log_shading=np.log(np.maximum(evidence.shading[ys, xs], 1e-12)),
                     basis=evidence.basis[ys, xs])


def sun_visibility(caster, rec: Receivers, dirs: np.ndarray, *, chunk: int = 64) -> np.ndarray:
    """(R, K) 1 where the receiver sees the direction past the mesh (and the direction is
    above its horizon), 0 in its shadow."""
    D = np.asarray(dirs, np.float64).reshape(-1, 3)
    out = np.zeros((len(rec), len(D)))
    for c0 in range(0, len(D), chunk):
        Dc = D[c0:c0 + chunk]
        out[:, c0:c0 + len(Dc)] = ~caster.occluded_grid(rec.origins, Dc).T
    return out


def lamp_visibility(caster, rec: Receivers, positions: np.ndarray) -> np.ndarray:
    """(R, K) 1 where the receiver sees the lamp position past the mesh, 0 in its shadow."""
    Q = np.asarray(positions, np.float64).reshape(-1, 3)
    v = Q[:, None, :] - rec.origins[None]  # (K, R, 3): every lamp's rays in one query
    r = length(v)
    occ = caster.occluded(np.broadcast_to(rec.origins, v.shape).reshape(-1, 3),
                          (v / np.maximum(r, 1e-12)[..., None]).reshape(-1, 3), tmax=r.ravel())
    return np.ascontiguousarray((~occ).reshape(len(Q), len(rec)).T, np.float64)


@dataclass(frozen=True)
class ShadowFit:
    """Per candidate: ``resid`` (R, K) the receivers' residuals of the support's log
    shading under each candidate's shadow (module docstring), ``weight`` (R,) theirs,
    ``ratio`` (K,) the shadowed/lit ratio its shadow fits (1: no shadow darkens the
    support); ``blocks`` the frame's blocks the receivers span (each one observation)."""

    resid: np.ndarray
    weight: np.ndarray
    ratio: np.ndarray
    blocks: int
    sigma_min: float

    @property
    def best_sigma(self) -> float:
        """The noise scale the best candidate implies: the root of its weighted mean
        squared residual (its maximum-likelihood scale: the model's own misfit, a wrong
        lit level or an edge, counts as noise), at least ``sigma_min``. (A pre-pass's scale
        is inflated by the shadows it reads.)"""
        if self.resid.size == 0:
            return self.sigma_min
        msr = (self.weight[:, None] * self.resid ** 2).sum(0) / max(float(self.weight.sum()), 1e-12)
        return max(math.sqrt(float(msr.min())), self.sigma_min)

    def loglik(self, sigma: float) -> np.ndarray:
        """(K,) Gaussian log-likelihoods at noise scale ``sigma``, each block one
        observation. (Huber's loss instead, tried on the development seeds, let a
        misread region cost less but also the shadow's own pixels: the direction's
        median error on the shown shadows went from 26 to 32 deg.)"""
        return self._terms(sigma).sum(0)

    def block_loglik(self, sigma: float, ids: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(``loglik``, (n, K) its share of each block: the receivers' terms summed by
        their block ``ids`` (R,) in 0..n-1, ``cueweight.block_ids``; the rows sum to
        ``loglik``), from one pass over the terms."""
        from zcomp_cli.light.cueweight import block_sums

        t = self._terms(sigma)
        return t.sum(0), block_sums(t, ids, n)

    def _terms(self, sigma: float) -> np.ndarray:
        """(R, K) each receiver's term of the log-likelihood at noise scale ``sigma``."""
        sig = max(float(sigma), self.sigma_min)
        share = self.weight[:, None] * self.resid ** 2 / max(float(self.weight.sum()), 1e-12)
        return -0.5 * self.blocks * share / sig ** 2


def shadow_fit(rec: Receivers, V: np.ndarray, cfg: SearchConfig) -> ShadowFit:
    """Fit ``log s ~ X beta + c (1 - V)`` for every candidate column of ``V`` (R, K)
    (module docstring: ``c = log rho``, exact where V is 0 or 1, the log-linear
    interpolation across a penumbra), ``c <= 0``, by least squares on the residual of
    ``X``'s projection: one SVD (``Receivers.projection``, once per receivers) and one
    product for all candidates."""
    K = V.shape[1]
    if len(rec) == 0:
        return ShadowFit(resid=np.zeros((0, K)), weight=np.zeros(0), ratio=np.ones(K), blocks=1,
                         sigma_min=cfg.sigma_min)
    w = np.maximum(rec.weight, 0.0)
    sw, Q, yr = rec.projection
    D = (1.0 - np.clip(np.asarray(V, np.float64), 0.0, 1.0)) * sw[:, None]
    Dr = D - Q @ (Q.T @ D)
    dd = np.einsum("rk,rk->k", Dr, Dr)
    dy = Dr.T @ yr
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(dd > 1e-12, dy / dd, 0.0)
    c = np.clip(c, math.log(cfg.log_floor), 0.0)  # a shadow darkens, never below the floor
    with np.errstate(divide="ignore", invalid="ignore"):
        resid = np.where(sw[:, None] > 0, (yr[:, None] - Dr * c[None]) / np.maximum(sw, 1e-300)[:, None], 0.0)
    return ShadowFit(resid=resid, weight=w, ratio=np.exp(c), blocks=rec.blocks, sigma_min=cfg.sigma_min)


__all__ = ["Receivers", "receivers", "sun_visibility", "lamp_visibility", "ShadowFit", "shadow_fit"]
