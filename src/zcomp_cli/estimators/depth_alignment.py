"""Relative depth -> metric z-depth: the scale and shift every learned depth model
leaves open, fitted once here before anything else sees the map (the footprint
alignment must never be fed disparity).

Two kinds of relative prediction:

* ``disparity``: inverse depth up to scale and shift (DPT, Depth Anything relative,
  Marigold with ``prediction_type: disparity``): ``1 / depth = a * d + b``;
* ``affine``: depth up to scale and shift (Marigold depth, ``prediction_type: depth``,
  in [0, 1], near = 0): ``depth = a * p + b``.

With a ground-plane description the two parameters are fitted robustly over the proxy's
floor pixels. Without one the scale puts the median depth at ``median_depth_m`` and the
shift is taken from ``shift`` (fitted elsewhere, e.g. to the normals, see
``estimators.consistency``) or assumed: 0 for disparity, a far/near ratio of
``DEFAULT_FAR_NEAR_RATIO`` between the 2nd and 98th percentiles for affine depth.
Pixels whose fitted depth is not positive are invalid (depth 0).
"""

from __future__ import annotations

import logging

import numpy as np

from zcomp_cli.errors import InputError

log = logging.getLogger(__name__)

DEFAULT_MEDIAN_DEPTH_M = 3.0
# An affine-invariant depth with nothing to fix its shift: assume its 2nd..98th
# percentile span (Marigold's training normalisation) covers a far/near ratio of 4,
# e.g. 1.5 m to 6 m around a 3 m median. A guess, said so in the fit's description.
DEFAULT_FAR_NEAR_RATIO = 4.0
RELATIVE_KINDS = ("disparity", "affine")


def robust_affine(x: np.ndarray, y: np.ndarray, iters: int = 10) -> tuple[float, float]:
    """y ~ a x + b, robust to a minority of outliers (objects on the floor): least
    squares, then refits on the inliers within 3 robust sigmas (MAD) of the last fit."""
    keep = np.ones(x.shape, bool)
    a = b = 0.0
    for _ in range(iters):
        A = np.stack([x[keep], np.ones(int(keep.sum()))], -1)
        sol, *_ = np.linalg.lstsq(A, y[keep], rcond=None)
        a, b = float(sol[0]), float(sol[1])
        r = np.abs(a * x + b - y)
        s = 1.4826 * float(np.median(r)) + 1e-12 * (np.abs(y).max() + 1e-30)
        new = r <= 3.0 * s
        if new.sum() < 8 or np.array_equal(new, keep):
            break
        keep = new
    return a, b


def relative_to_depth(rel, kind: str, *, scale: float = 1.0, shift: float = 0.0) -> np.ndarray:
    """``depth = 1 / (scale * d + shift)`` (disparity) or ``scale * p + shift`` (affine);
    0 where not finite or not positive. float32 (H, W)."""
    r = np.asarray(rel, np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if kind == "disparity":
            inv = scale * r + shift
            # Any positive inverse depth is valid: an affine-invariant disparity may be tiny
            # (a random model's is ~1e-10); overflow to inf is caught below.
            depth = np.where(np.isfinite(inv) & (inv > 0), 1.0 / np.where(inv > 0, inv, 1.0), 0.0)
        elif kind == "affine":
            depth = scale * r + shift
        else:
            raise InputError(f"relative depth kind must be one of {RELATIVE_KINDS}, got {kind!r}")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    return depth.astype(np.float32)


def _median_scale(depth_unscaled: np.ndarray, median_depth_m: float) -> float:
    pos = depth_unscaled > 0
    if not pos.any():
        raise InputError("the relative depth has no positive value")
    return median_depth_m / float(np.median(depth_unscaled[pos]))


def align_relative_depth(rel, kind: str, *, proxy_depth=None, proxy_mask=None,
                         median_depth_m: float = DEFAULT_MEDIAN_DEPTH_M,
                         shift: float | None = None) -> tuple[np.ndarray, str]:
    """Metric z-depth from a relative prediction (see the module doc).

    Args:
        rel: (H, W) relative prediction (``kind``: larger = nearer for disparity,
            larger = farther for affine depth), any affine scale.
        kind: ``disparity`` or ``affine``.
        proxy_depth, proxy_mask: optional (H, W) reference depth (metres) and the bool
            pixels to fit over (the ground-plane floor).
        median_depth_m: the median depth when no proxy is given (or its fit fails).
        shift: the shift relative to a unit scale (``d + shift`` or ``p + shift``)
            when no proxy is given; None = the default assumption.
    Returns:
        (depth (H, W) float32, 0 where invalid; a one-line description of the fit).
    """
    d = np.asarray(rel, np.float64)
    if d.ndim != 2:
        raise InputError(f"relative depth must be (H, W), got {d.shape}")
    if kind not in RELATIVE_KINDS:
        raise InputError(f"relative depth kind must be one of {RELATIVE_KINDS}, got {kind!r}")
    finite = np.isfinite(d)
    name = "disparity" if kind == "disparity" else "relative depth"
    if proxy_depth is not None:
        fit = ground_plane_fit(d, kind, proxy_depth, proxy_mask)
        if fit is not None:
            return fit
        log.warning("%s fit to the ground plane failed; using the median depth", name)
    if not (np.isfinite(median_depth_m) and median_depth_m > 0):
        raise InputError(f"median_depth must be positive, got {median_depth_m!r}")
    how_shift = "fitted"
    floor = None
    if shift is None:
        if kind == "disparity":
            shift, how_shift = 0.0, "taken as 0"
        else:
            vals = d[finite]
            if vals.size == 0:
                raise InputError("the relative depth has no finite value")
            lo, hi = np.percentile(vals, [2, 98])
            r = DEFAULT_FAR_NEAR_RATIO
            shift = float((hi - r * lo) / (r - 1.0)) if hi > lo else 1.0
            # The few pixels nearer than the 2nd percentile stay valid: at least a
            # quarter of the near end's depth (the guess must not invalidate them).
            floor = (lo + shift) / r if hi > lo else None
            how_shift = f"assumed (a far/near ratio of {r:g} between its 2nd and 98th percentiles)"
    if floor is not None:
        unscaled = np.where(finite, np.maximum(d + shift, floor), 0.0).astype(np.float32)
    else:
        unscaled = relative_to_depth(d, kind, scale=1.0, shift=shift)
    s = _median_scale(unscaled, median_depth_m)
    depth = (unscaled * s).astype(np.float32)
    if kind == "disparity":
        how = f"depth = {median_depth_m:g} m * median / (disparity + {shift:.4g}), shift {how_shift}"
    else:
        how = f"depth = {s:.4g} * (relative depth + {shift:.4g}), median {median_depth_m:g} m, shift {how_shift}"
    return depth, how


def ground_plane_fit(rel, kind: str, proxy_depth, proxy_mask=None) -> tuple[np.ndarray, str] | None:
    """Scale and shift of a relative prediction fitted robustly to a reference depth over
    ``proxy_mask`` (``1/proxy = a d + b`` for disparity, ``proxy = a p + b`` for affine
    depth). Returns (depth, description), or None when the fit fails (fewer than 16
    pixels, a constant prediction there, or a scale that is not positive)."""
    d = np.asarray(rel, np.float64)
    pd = np.asarray(proxy_depth, np.float64)
    m = np.isfinite(d) & np.isfinite(pd) & (pd > 0)
    if proxy_mask is not None:
        m &= np.asarray(proxy_mask, bool)
    if m.sum() < 16 or not np.ptp(d[m]) > 1e-9:
        return None
    target = 1.0 / pd[m] if kind == "disparity" else pd[m]
    a, b = robust_affine(d[m], target)
    if not a > 0:
        return None
    lhs, name = ("1/depth", "disparity") if kind == "disparity" else ("depth", "relative depth")
    return (relative_to_depth(d, kind, scale=a, shift=b),
            f"{lhs} = {a:.4g} * {name} + {b:.4g} (fit to ground plane, {int(m.sum())} px)")


def disparity_to_depth(disp, *, proxy_depth=None, proxy_mask=None,
                       median_depth_m: float = DEFAULT_MEDIAN_DEPTH_M) -> tuple[np.ndarray, str]:
    """Metric z-depth from an affine-invariant disparity map (``align_relative_depth``
    with ``kind='disparity'``). Kept for the transformers depth path's callers."""
    d = np.asarray(disp, np.float64)
    if d.ndim == 2 and proxy_depth is None and not (np.isfinite(d) & (d > 0)).any():
        raise InputError("the disparity map has no positive value")
    return align_relative_depth(d, "disparity", proxy_depth=proxy_depth, proxy_mask=proxy_mask,
                                median_depth_m=median_depth_m)
