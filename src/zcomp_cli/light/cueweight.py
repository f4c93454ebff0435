"""The weight of each cue from the case's own evidence (DESIGN.md section 8; issue 47).

The light search multiplies two likelihoods over directions: the support's cast shadows
and the frame's shading (``search``). Each is a sum over the frame's **blocks**, and the
pixels within a block are correlated, so each overstates its evidence -- by a factor
that differs from case to case and from cue to cue: the shading model is confidently
wrong where casters stand in the frame, and the only witness on a bare floor. One
temperature for every case cannot be right for both.

The blocks are the independent units, so the case's own data say how far a cue can be
trusted: resampled block by block (the block bootstrap; ``search.weight_blocks``), a
cue whose blocks agree keeps its best direction, and one whose blocks disagree moves
it. A cue's weight ``k`` is the largest for which the posterior it states -- ``prior x
likelihood ** k`` over the direction grid -- holds its own best direction (the full
data's) within its 68 % highest-density set in at least 68 % of the resamples
(``search.weight_level``): general posterior calibration (Syring and Martin 2019,
"Calibrating general posterior credible regions", Biometrika), whose local,
Gaussian form is the composite likelihood's magnitude adjustment ``k = p / tr(H^-1 J)``
(Ribatet, Cooley and Davison 2012). Unlike that local form it needs no derivative of a
likelihood that is flat in one place and multimodal in another: on a bare floor the
resampled shadow cue's best direction wanders the hemisphere and its weight falls to the
floor; a crisp shadow seen in many blocks keeps its weight.

A bootstrap cannot see a bias every block shares (the shading model's smooth error), so
each weighted cue, as a density over the hemisphere, is also **gated**: mixed with the
uniform density, ``(1 - g) q + g / 2 pi`` (``search.gate``, the chance that a cue is
misled). Two cues that agree keep their common peak; where they disagree, each peak
survives at the other's gate, so the shadow that pins a direction is not overruled by a
shading the model misreads, nor the other way round (Lalonde et al. gate
each cue by a mixture with the uniform; Kee, O'Brien and Farid test the two cues'
consistency).

Pure numpy: ``block_ids`` and ``block_sums`` group per-pixel terms by block,
``cue_weight`` reads the weight, ``gated`` applies the gate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.light.posterior import log_mixture


@dataclass(frozen=True)
class CueWeight:
    """A cue's weight: ``k`` the likelihood's power, ``coverage`` the share of the
    resamples whose 68 % highest-density set holds the full data's best direction at that weight,
    ``blocks`` the blocks it was resampled over (fewer than 2: not resampled, the floor)."""

    k: float
    coverage: float
    blocks: int

    def to_info(self) -> dict:
        return {"k": round(float(self.k), 6), "coverage": round(float(self.coverage), 3), "blocks": int(self.blocks)}


def block_ids(ys, xs, shape, blocks: int) -> tuple[np.ndarray, int]:
    """(ids (N,) in 0..n-1, n): the frame's block (``blocks`` per long side of ``shape``
    (H, W)) each pixel (``ys``, ``xs``) lies in, numbered over the blocks present."""
    ys = np.asarray(ys)
    xs = np.asarray(xs)
    if blocks < 1:
        raise ValueError(f"block_ids: blocks must be >= 1, got {blocks}")
    blk = max(shape) / blocks
    raw = (ys // blk).astype(np.int64) * (blocks + 1) + (xs // blk).astype(np.int64)
    uniq, ids = np.unique(raw, return_inverse=True)
    return ids.reshape(-1), len(uniq)


def block_sums(values: np.ndarray, ids: np.ndarray, n: int) -> np.ndarray:
    """(n, K) the per-pixel ``values`` (N, K) summed over each block ``ids`` (N,)."""
    v = np.asarray(values, np.float64)
    if v.ndim != 2 or len(v) != len(ids):
        raise ValueError(f"block_sums: values (N, K) and ids (N,) must agree, got {v.shape} and {np.shape(ids)}")
    onehot = np.asarray(ids)[None, :] == np.arange(n)[:, None]
    return onehot.astype(np.float64) @ v


def _coverage(LLb: np.ndarray, base: np.ndarray, log_om: np.ndarray, best: int, k: float, level: float) -> float:
    """The share of resamples (rows of ``LLb`` (B, K)) whose posterior at weight ``k``
    (``base`` (K,) its log prior density plus ``log_om``, the log solid angles) holds the
    direction ``best`` (an index) in its ``level`` highest-density set: the mass of the
    directions denser than it is under ``level``."""
    a = k * LLb + base[None]
    p = np.exp(a - a.max(1, keepdims=True))
    p /= p.sum(1, keepdims=True)
    dens = a - log_om[None]
    above = (p * (dens > dens[:, best:best + 1] + 1e-12)).sum(1)
    return float(np.mean(above < level))


def cue_weight(block_ll, log_prior, solid_angle, dirs, cfg, *, seed: int = 0) -> CueWeight:
    """A cue's weight (module docstring).

    Args:
        block_ll: (n, K) the cue's log-likelihood of each of K directions, per block
            (its rows sum to the cue's log-likelihood).
        log_prior: (K,) the prior's log density (per steradian) at each direction.
        solid_angle: (K,) the solid angle (sr, > 0) each direction stands for.
        dirs: (K, 3) unit directions.
        cfg: the search's config (``SearchConfig``: ``weight_level``,
            ``weight_resamples``, ``weight_range``, ``weight_steps``).
        seed: the resampling's seed.

    Returns the largest weight of the grid (``weight_range``'s top down to its bottom)
    whose ``weight_level`` highest-density set holds the full data's best direction in
    at least that share of the resamples (the bottom where none does, or where there
    are fewer than two blocks to resample or a term is not finite).
    """
    LL = np.asarray(block_ll, np.float64)
    lp = np.asarray(log_prior, np.float64).reshape(-1)
    om = np.asarray(solid_angle, np.float64).reshape(-1)
    D = np.asarray(dirs, np.float64).reshape(-1, 3)
    if LL.ndim != 2 or not (LL.shape[1] == len(lp) == len(om) == len(D)):
        raise ValueError(f"cue_weight: block_ll (n, K), log_prior, solid_angle (K,) and dirs (K, 3) must agree, got "
                         f"{LL.shape}, {lp.shape}, {om.shape}, {D.shape}")
    if not np.all(om > 0):
        raise ValueError("cue_weight: solid angles must be positive")
    n = LL.shape[0]
    k_lo, k_hi = (float(x) for x in cfg.weight_range)
    if n < 2 or not np.all(np.isfinite(LL)):
        return CueWeight(k_lo, float("nan"), n)
    base = lp + np.log(om)
    best = int(np.argmax(LL.sum(0)))
    rng = np.random.default_rng(seed)
    W = rng.multinomial(n, np.full(n, 1.0 / n), size=cfg.weight_resamples).astype(np.float64)
    LLb = W @ LL
    LLb -= LLb.max(1, keepdims=True)
    for k in np.geomspace(k_hi, k_lo, cfg.weight_steps):
        cov = _coverage(LLb, base, np.log(om), best, float(k), cfg.weight_level)
        if cov >= cfg.weight_level:
            return CueWeight(float(k), cov, n)
    return CueWeight(k_lo, cov, n)


def gated(ll, gate: float, log_z: float) -> np.ndarray:
    """``log((1 - gate) exp(ll - log_z) + gate / 2 pi)``: a weighted cue's log-likelihood
    ``ll`` as a density over the hemisphere (``log_z``: its ``posterior.log_integral``
    over the grid),
    mixed with the uniform density by ``gate`` -- the chance that the cue is misled
    (module docstring). A sharp cue keeps its peak and lends every other direction the
    uniform's ``gate``; where two cues disagree, each peak survives at the other's gate.
    ``gate`` in [0, 1): 0 leaves the density as it is."""
    ll = np.asarray(ll, np.float64)
    if not 0.0 <= gate < 1.0:
        raise ValueError(f"gated: gate must be in [0, 1), got {gate}")
    return log_mixture(ll - float(log_z), -math.log(2.0 * math.pi), gate)


def combined(ll_shadow, ll_photo, weights, gate: float, norms) -> np.ndarray:
    """The two cues' log-likelihoods (shadow, photometric), each at its weight
    (``weights``: their ``CueWeight``) and gated with its log normaliser (``norms``:
    ``gated``'s ``log_z`` of each weighted cue), summed."""
    (ws, wp), (zs, zp) = weights, norms
    return (gated(ws.k * np.asarray(ll_shadow, np.float64), gate, zs)
            + gated(wp.k * np.asarray(ll_photo, np.float64), gate, zp))


__all__ = ["CueWeight", "block_ids", "block_sums", "cue_weight", "gated", "combined"]
