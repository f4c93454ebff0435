"""Robust non-negative least squares: the light as weights of atoms (DESIGN.md section 8).

The known shading is linear in the light: ``S(p) = sum_k w_k T_k(p)``, ``w_k >= 0``. An
atom ``T_k`` is a column over the fit pixels: grey (N,), whose weight has one value per
colour channel (the light's colour is fitted), or coloured (N, 3), with one weight for
all three channels (a light whose colour is known, such as a probe's).

The loss is Huber's (``c = 1.345 sigma``, 95 % efficiency under Gaussian noise), the
scale ``sigma`` the median absolute residual (x 1.4826), at least ``sigma_floor`` of the
data's median (a render's noise; exact synthetic data has none). It is minimised by
iteratively reweighted NNLS (``scipy.optimize.nnls``) with a ridge that pulls the
weights toward a prior solution (``prior``, ``ridge``): where the pixels cannot tell two
atoms apart (a bare floor shades alike under the sky and under a sun), the prior decides,
and anywhere else the pixels do. Everything is relative to the data's scale: multiplying
the shading by k multiplies the weights by k (exposure invariance).

**Shadows the frame does not show.** Screen-space visibility can miss an occluder (one
outside the frame, or hidden behind other surfaces) but never invent one: a pixel darker
than the model may lie in the shadow of something unseen, where it keeps the sky and
loses the lights' direct part ``d`` of its prediction. So each pixel is either lit as
the model says (probability ``1 - pi``) or in an unseen shadow (``pi``), its shading the
model's less ``d``, both with the same noise (Huber, scale sigma). EM: each IRLS step
fits the lit responsibility's share of a pixel to the whole model and the shadowed share
to the model without its direct atoms (the sky still explains it: an unseen shadow says
how bright the sky is), then refits ``pi`` (at most ``max_unseen``; ``settings.SolverConfig``). The atoms an unseen
occluder can hide are named by ``direct`` (the suns and lamps; not the sky).

``score_candidates`` scores many one-atom extensions of a base dictionary at once (the
light direction search): batched normal equations, the candidate's weight clamped at 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.light.config import SolverConfig



def _huber_density(r, sig, huber_c: float):
    c = huber_c * sig
    a = np.abs(r)
    return np.exp(-np.where(a <= c, 0.5 * (a / sig) ** 2, (c / sig) * (a / sig) - 0.5 * (c / sig) ** 2))


def unseen_responsibility(r, d, sigma, pi, huber_c: float):
    """The responsibility of "lit as the model says" for residuals ``r`` (``d`` >= 0 the
    direct part of each prediction) under the mixture of the module docstring: noise
    around the full prediction (1 - pi), or around the prediction less its direct
    part (an unseen shadow, pi). In [0, 1]; 1 where ``d`` is 0 (nothing to lose)."""
    r = np.asarray(r, np.float64)
    d = np.asarray(d, np.float64)
    sig = np.maximum(sigma, 1e-300)
    lit = (1.0 - pi) * _huber_density(r, sig, huber_c)
    shadowed = np.where(d > 1e-12, pi * _huber_density(r + d, sig, huber_c), 0.0)
    return lit / np.maximum(lit + shadowed, 1e-300)


def unseen_loss(sigma):
    """The cost of a pixel in an unseen shadow: a one-sigma residual's Huber loss."""
    return 0.5 * np.asarray(sigma, np.float64) ** 2


@dataclass(frozen=True)
class Atom:
    """One column of the dictionary: ``values`` (N,) grey or (N, 3) coloured; ``prior``
    the (C,) weight the ridge pulls it toward (None: 0); ``direct``: an unseen occluder
    can hide it (a sun's or a lamp's light, not the sky's: module docstring); ``kept``:
    where it is direct, what an unseen shadow leaves of its values (same shape: an atom
    that ties the sky to a sun, or an exposure over both, keeps its sky; None: nothing);
    ``name`` for messages only."""

    name: str
    values: np.ndarray
    prior: object = None
    direct: bool = False
    kept: np.ndarray | None = None

    def in_unseen_shadow(self) -> np.ndarray:
        """Its values in an unseen shadow: ``kept`` (0 where none), all of them where
        it is not direct."""
        if not self.direct:
            return np.asarray(self.values, np.float64)
        return np.zeros_like(np.asarray(self.values, np.float64)) if self.kept is None \
            else np.asarray(self.kept, np.float64)

    @property
    def coloured(self) -> bool:
        return np.ndim(self.values) == 2


def huber_weights(r: np.ndarray, sigma: float, huber_c: float) -> tuple[np.ndarray, np.ndarray]:
    """IRLS weights and per-residual Huber loss of residuals ``r`` at scale ``sigma``."""
    c = huber_c * sigma
    a = np.abs(r)
    return _huber_w(a, c), _huber_loss(a, c)


def _huber_loss(a: np.ndarray, c: float, *, overwrite: bool = False) -> np.ndarray:
    """Huber's loss alone of absolute residuals ``a`` at the threshold ``c``: ``a^2 / 2``
    within it, ``c (a - c / 2)`` beyond, as one product ``m (a - m / 2)`` of ``m = min(a,
    c)`` (the same bits as either branch: ``a - a / 2`` is exact) over one pass instead
    of both branches and a select; ``overwrite``: ``a`` (a float array) is used as
    scratch space (one (N, K) temporary fewer)."""
    m = np.minimum(a, c)
    if not overwrite:
        return m * (a - 0.5 * m)
    a -= 0.5 * m
    m *= a
    return m


def _huber_w(a: np.ndarray, c: float) -> np.ndarray:
    """The IRLS weights alone of absolute residuals ``a`` at the Huber threshold ``c``:
    1 within it, ``c / a`` beyond (the loops that discard the loss skip it)."""
    if not c > 0:
        return np.where(a <= c, 1.0, 0.0)
    return np.minimum(c / np.maximum(a, 1e-300), 1.0)


def robust_scale(r: np.ndarray, data_scale: float, cfg: SolverConfig | None = None) -> float:
    cfg = SolverConfig() if cfg is None else cfg
    return max(cfg.mad_to_sigma * float(np.median(np.abs(r))), cfg.sigma_floor * data_scale, 1e-12)


def _design(atoms, channels: int, values=None) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Stack the atoms into a (N * C, P) design for C channels: a grey atom has C
    columns (one per channel), a coloured one a single column; ``values`` (a function
    of an atom: its (N,) or (N, 3) values; None: ``Atom.values``). Returns (X, per atom
    the (first column, number of columns))."""
    N = len(np.atleast_1d(atoms[0].values))
    cols, spans = [], []
    for a in atoms:
        v = np.asarray(a.values if values is None else values(a), np.float64)
        if v.ndim == 2:
            spans.append((sum(c.shape[1] for c in cols), 1))
            cols.append(v[:, :channels].T.reshape(-1, 1) if channels > 1 else v[:, :1])
        else:
            block = np.zeros((N * channels, channels))
            for c in range(channels):
                block[c * N:(c + 1) * N, c] = v
            spans.append((sum(c.shape[1] for c in cols), channels))
            cols.append(block)
    return np.concatenate(cols, 1), spans


@dataclass(frozen=True)
class FitResult:
    """``weights``: per atom, in the atoms' order, (3,) RGB weight (a coloured atom's one
    weight repeated); ``loss``: mean Huber loss per pixel over the data scale squared, on the
    fit pixels (``train``) and the held-out ones (``held``); ``sigma`` the robust scale."""

    weights: list
    loss_train: float
    loss_held: float
    sigma: float
    residual: np.ndarray


def fit(atoms, target: np.ndarray, *, train: np.ndarray | None = None, ridge: float = 0.0,
        cfg: SolverConfig) -> FitResult:
    """Robust NNLS of ``target`` (N, 3) RGB or (N,) grey on ``atoms``.

    Args:
        atoms: sequence of ``Atom`` over the same N pixels (each with its prior and
            whether an unseen occluder can hide it).
        target: the shading to explain.
        train: (N,) bool, the pixels the weights are fitted on (None: all); the others
            are held out and only scored.
        ridge: the ridge's strength toward the atoms' priors, per fit pixel, relative to
            the data's scale.
        cfg: the solver's constants (``SolverConfig``).
    """
    from scipy.optimize import nnls

    y = np.asarray(target, np.float64)
    C = 1 if y.ndim == 1 else y.shape[1]
    N = len(y)
    train = np.ones(N, bool) if train is None else np.asarray(train, bool)
    if not train.any():
        raise ValueError("solver.fit: no training pixels")
    X, spans = _design(atoms, C)
    yv = y.T.reshape(-1) if C > 1 else y.reshape(-1)
    tr = np.tile(train, C)
    scale = max(float(np.median(np.abs(yv[tr]))), 1e-12)
    # the ridge's target: a weight vector in the design's columns
    p0 = np.zeros(X.shape[1])
    for a, (c0, k) in zip(atoms, spans):
        if a.prior is not None:
            p0[c0:c0 + k] = np.broadcast_to(np.asarray(a.prior, np.float64), (C,))[:k] \
                if k > 1 else float(np.mean(a.prior))
    col_scale = np.sqrt(np.maximum((X[tr] ** 2).mean(0), 1e-30))
    lam = np.sqrt(max(ridge, 0.0) * tr.sum()) * col_scale
    Xt, yt = X[tr], yv[tr]
    # an unseen shadow: the sky alone (what each atom keeps there); Xd the direct part
    Xd = X - _design(atoms, C, Atom.in_unseen_shadow)[0]
    Xdt = Xd[tr]
    Xs = Xt - Xdt
    mix = any(a.direct for a in atoms)
    beta = p0.copy() if (mix and p0.any()) else np.zeros(X.shape[1])
    sigma = None
    pi = cfg.unseen_init if mix else 0.0
    resp = np.ones(tr.sum())
    w_lit = w_sh = None
    if mix and p0.any():
        # the EM starts from the prior's light: from a fit with no light, every pixel of
        # a shadow the frame does not show would be an outlier, and it would stay there
        r0 = yt - Xt @ p0
        s0 = robust_scale(r0, scale, cfg)
        resp = unseen_responsibility(r0, Xdt @ p0, s0, pi, cfg.huber_c)
        w_lit = huber_weights(r0, s0, cfg.huber_c)[0] * resp
        w_sh = huber_weights(r0 + Xdt @ p0, s0, cfg.huber_c)[0] * (1.0 - resp)
    for _ in range(cfg.irls_iters):
        if w_lit is None:
            w_lit, w_sh = np.ones(len(yt)), np.zeros(len(yt))
        A = np.concatenate([Xt * np.sqrt(w_lit)[:, None], Xs * np.sqrt(w_sh)[:, None], np.diag(lam)], 0)
        b = np.concatenate([yt * np.sqrt(w_lit), yt * np.sqrt(w_sh), lam * p0])
        beta, _ = nnls(A, b, maxiter=50 * A.shape[1])
        r = yt - Xt @ beta
        d = Xdt @ beta if mix else np.zeros_like(r)
        if mix:
            resp = unseen_responsibility(r, d, sigma if sigma is not None else robust_scale(r, scale, cfg), pi, cfg.huber_c)
        near = np.where(resp >= 0.5, r, r + d)  # each pixel's residual under its likelier case
        sigma = robust_scale(near, scale, cfg)
        if mix:
            resp = unseen_responsibility(r, d, sigma, pi, cfg.huber_c)
            pi = float(np.clip(1.0 - resp.mean(), 1e-3, cfg.max_unseen))
        w_lit = huber_weights(r, sigma, cfg.huber_c)[0] * resp
        w_sh = huber_weights(r + d, sigma, cfg.huber_c)[0] * (1.0 - resp)
    r_all = yv - X @ beta
    _, loss = huber_weights(r_all, sigma, cfg.huber_c)
    if mix:
        d_all = Xd @ beta
        g = unseen_responsibility(r_all, d_all, sigma, pi, cfg.huber_c)
        # a pixel in an unseen shadow costs its residual against the sky alone, and the
        # one-sigma price of being a shadow nothing in the frame casts
        loss = g * loss + (1.0 - g) * (huber_weights(r_all + d_all, sigma, cfg.huber_c)[1] + unseen_loss(sigma))
    loss = loss.reshape(C, N).mean(0) if C > 1 else loss
    held = ~train
    lt = float(loss[train].mean()) / scale ** 2
    lh = float(loss[held].mean()) / scale ** 2 if held.any() else lt
    weights = []
    for c0, k in spans:
        v = beta[c0:c0 + k]
        weights.append(np.repeat(v, 3) if k == 1 else (np.repeat(v, 3 // C) if C == 1 else v.copy()))
    res = r_all.reshape(C, N).T if C > 1 else r_all
    return FitResult(weights=weights, loss_train=lt, loss_held=lh, sigma=float(sigma), residual=res)


def solve_spd(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the symmetric positive definite systems ``A x = b``: ``A`` (K, n, n), ``b``
    (K, n) -> ``x`` (K, n), float64, by a batched Cholesky factor and substitution
    vectorised over K. (numpy's batched ``solve`` calls LAPACK once per system, and a
    threaded OpenBLAS synchronises its threads on each call: on a busy 2-core machine
    1024 systems of 7 took 100-230 ms against 0.7 ms.) A system that is not positive
    definite falls back to ``np.linalg.solve``."""
    A = np.asarray(A, np.float64)
    b = np.asarray(b, np.float64)
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        return np.linalg.solve(A, b[..., None])[..., 0]
    n = b.shape[-1]
    z = np.empty_like(b)
    for i in range(n):  # L z = b
        z[:, i] = (b[:, i] - np.einsum("kj,kj->k", L[:, i, :i], z[:, :i])) / L[:, i, i]
    x = np.empty_like(b)
    for i in range(n - 1, -1, -1):  # L^T x = z
        x[:, i] = (z[:, i] - np.einsum("kj,kj->k", L[:, i + 1:, i], x[:, i + 1:])) / L[:, i, i]
    return x


def score_candidates(base: np.ndarray, cands: np.ndarray, y: np.ndarray, train: np.ndarray, *,
                     sigma: float | None = None, iters: int | None = None,
                     cfg: SolverConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Held-out and training loss of ``y`` (N,) fitted on ``base`` (N, B) plus each
    candidate column of ``cands`` (N, K), for K candidates at once: the means of
    ``candidate_losses`` over the held-out pixels (none held out: the training ones) and
    over the training pixels."""
    loss = candidate_losses(base, cands, y, train, sigma=sigma, iters=iters, cfg=cfg)
    tr = np.asarray(train, bool)
    held = ~tr
    lh = loss[held].mean(0) if held.any() else loss[tr].mean(0)
    return lh, loss[tr].mean(0)


def candidate_losses(base: np.ndarray, cands: np.ndarray, y: np.ndarray, train: np.ndarray, *,
                     sigma: float | None = None, iters: int | None = None,
                     cfg: SolverConfig | None = None, rows: np.ndarray | None = None) -> np.ndarray:
    """(N, K) each pixel's loss of ``y`` (N,) fitted on ``base`` (N, B) plus each
    candidate column of ``cands`` (N, K), for K candidates at once, over the data scale
    squared; ``rows`` (N,) bool: only those pixels' losses, (rows.sum(), K) (the
    held-out ones, where only they are scored).

    The same Huber IRLS as ``fit`` on the training pixels, by batched normal equations,
    every candidate at the one scale ``sigma`` (None: the base's robust fit's), so that
    their losses compare. Without the unseen-shadow mixture: a direction whose shadow
    misses the visible one could call the visible shadow unseen, and the shadows of the
    visible geometry are what the direction search must follow (with it, measured on
    the development seeds, the search lost 0.06-0.35 dB: docs/physical.md). A negative
    candidate weight is clamped to 0 (no negative light); a negative base weight is
    left (the base's non-negativity is ``fit``'s business: here only the ranking of
    candidates matters).
    """
    cfg = SolverConfig() if cfg is None else cfg
    B = np.asarray(base, np.float64)
    D = np.asarray(cands, np.float64)
    y = np.asarray(y, np.float64)
    tr = np.asarray(train, bool)
    N, nb = B.shape
    K = D.shape[1]
    scale = max(float(np.median(np.abs(y[tr]))), 1e-12)
    Bt, Dt, yt = B[tr], D[tr], y[tr]
    nt = len(yt)
    BB = (Bt[:, :, None] * Bt[:, None, :]).reshape(nt, nb * nb)
    By = Bt * yt[:, None]
    if sigma is None:
        sigma = base_sigma(Bt, yt, scale=scale, cfg=cfg)
    w = np.ones((nt, K))
    n_iter = cfg.irls_iters if iters is None else iters
    for it in range(n_iter):
        wd = w * Dt
        A = np.empty((K, nb + 1, nb + 1))
        A[:, :nb, :nb] = (BB.T @ w).T.reshape(K, nb, nb)
        bd = (Bt.T @ wd).T
        A[:, :nb, nb] = bd
        A[:, nb, :nb] = bd
        A[:, nb, nb] = (wd * Dt).sum(0)
        # a relative Tikhonov floor: collinear columns (sky lobes on one plane) and a
        # candidate that lights no pixel leave the normal equations singular. Relative to
        # each column's own scale: relative to their mean, a lamp's column (1/r^2: a
        # million times the sky's in a scene measured in millimetres) set the floor of
        # all the others, and the light found depended on the depth map's unit (issue 49)
        diag = np.einsum("kii->ki", A)
        floor = np.maximum(diag, 1e-12 * diag.mean(1, keepdims=True) + 1e-300)
        A += (1e-9 * floor)[:, :, None] * np.eye(nb + 1)[None]
        rhs = np.empty((K, nb + 1))
        rhs[:, :nb] = (By.T @ w).T
        rhs[:, nb] = wd.T @ yt
        coef = solve_spd(A, rhs)
        neg = coef[:, nb] < 0
        if neg.any():  # refit those without the candidate
            coef[neg, :nb] = solve_spd(A[neg][:, :nb, :nb], rhs[neg, :nb])  # (regularised above)
            coef[neg, nb] = 0.0
        if it + 1 < n_iter:  # the next iteration's weights (the last one's would go unused)
            r = yt[:, None] - Bt @ coef[:, :nb].T - Dt * coef[:, nb][None]
            w = _huber_w(np.abs(r), cfg.huber_c * sigma)
    if rows is not None:
        rows = np.asarray(rows, bool)
        B, D, y = B[rows], D[rows], y[rows]
    # the residuals ``|y - B b - D c|`` and their loss in place ((N, K) temporaries are
    # the bulk of the time)
    r = B @ coef[:, :nb].T
    np.subtract(y[:, None], r, out=r)
    r -= D * coef[:, nb][None]
    np.abs(r, out=r)
    loss = _huber_loss(r, cfg.huber_c * sigma, overwrite=True)
    loss /= scale ** 2
    return loss


def base_sigma(B: np.ndarray, y: np.ndarray, ridge: np.ndarray | None = None,
               scale: float | None = None, cfg: SolverConfig | None = None) -> float:
    """Robust scale of ``y`` (N,) fitted on the columns ``B`` (N, P) alone (Huber IRLS,
    unconstrained): the scale candidates are scored at."""
    cfg = SolverConfig() if cfg is None else cfg
    B = np.asarray(B, np.float64)
    y = np.asarray(y, np.float64)
    scale = max(float(np.median(np.abs(y))), 1e-12) if scale is None else scale
    rb = np.zeros(B.shape[1]) if ridge is None else np.asarray(ridge, np.float64)
    w = np.ones(len(y))
    s = cfg.sigma_floor * scale
    for _ in range(cfg.irls_iters):
        A = B.T @ (B * w[:, None]) + np.diag(rb * len(y))
        coef = np.linalg.lstsq(A, B.T @ (w * y), rcond=None)[0]
        r = y - B @ coef
        s = robust_scale(r, scale, cfg)
        w, _ = huber_weights(r, s, cfg.huber_c)
    return s


__all__ = ["Atom", "base_sigma", "FitResult", "fit", "score_candidates", "candidate_losses", "solve_spd", "huber_weights",
           "robust_scale"]
