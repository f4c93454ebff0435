"""Depth and normals that agree.

The renderer shades with the normals map while the shading mask, the shadows and the
light's evidence use the geometry of the depth map. When the two come from different
estimators (a learned normals model beside a ground-plane proxy or a learned depth),
they can describe different surfaces: a wall whose depth says "fronto-parallel" and
whose normals say "30 degrees to the left" misleads both. Two tools:

* ``agreement``: the per-pixel angle between the normals and the normals implied by
  the depth (``normals_from_depth``), over the pixels where both are defined and the
  depth is continuous, summarised as median, 90th percentile and the fraction beyond
  a threshold (degrees). Reported for every scene where they come from different
  sources.
* ``fit_shift_to_normals``: a relative depth model leaves the shift of its prediction
  open, and the shift bends the geometry (scale does not: it only moves the points
  along their rays). Where no ground plane fixes it, the shift is chosen so that the
  depth's normals agree best with the normals map (1-D search on the far/near ratio,
  minimising the mean angle truncated at 45 degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import valid_depth_mask
from zcomp_cli.errors import InputError

DEFAULT_THRESHOLD_DEG = 30.0
# Depth jumps larger than this (relative) between 4-neighbours are occlusion edges,
# where the depth's normals mean nothing; they are left out of the comparison.
EDGE_JUMP = 0.05
FIT_MAX_SIDE = 160  # the shift search runs on a copy at most this wide (it is 1-D)
FIT_TRUNCATE_DEG = 45.0  # angles beyond this count as this much in the shift's cost


@dataclass
class Agreement:
    """How far a normals map is from the normals implied by a depth map (degrees)."""

    angle_deg: np.ndarray  # (H, W) float32, NaN where not compared
    median_deg: float
    p90_deg: float
    frac_over: float  # fraction of compared pixels beyond threshold_deg
    threshold_deg: float
    pixels: int  # compared pixels

    def summary(self) -> dict:
        return {"median_deg": round(self.median_deg, 2), "p90_deg": round(self.p90_deg, 2),
                f"frac_over_{self.threshold_deg:g}_deg": round(self.frac_over, 4), "pixels": self.pixels}

    def describe(self) -> str:
        return (f"normals vs depth: median {self.median_deg:.1f} deg, 90th percentile {self.p90_deg:.1f} deg, "
                f"{self.frac_over:.0%} of {self.pixels} px beyond {self.threshold_deg:g} deg")


def angle_deg(a, b) -> np.ndarray:
    """Per-pixel angle (degrees) between two (..., 3) unit-vector maps; NaN where either
    is zero or non-finite."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    na = np.linalg.norm(a, axis=-1)
    nb = np.linalg.norm(b, axis=-1)
    ok = np.isfinite(na) & np.isfinite(nb) & (na > 0.5) & (nb > 0.5)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.sum(a * b, axis=-1) / (na * nb)
    ang = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return np.where(ok, ang, np.nan).astype(np.float32)


def continuous_depth(depth, jump: float = EDGE_JUMP) -> np.ndarray:
    """(H, W) bool: valid pixels whose 4-neighbours are all valid and within ``jump``
    (relative) of their depth."""
    d = np.asarray(depth, np.float64)
    v = valid_depth_mask(d)
    z = np.where(v, d, np.nan)
    ok = v.copy()
    zp = np.pad(z, 1, constant_values=np.nan)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        nb = zp[dy:dy + d.shape[0], dx:dx + d.shape[1]]
        with np.errstate(invalid="ignore"):
            ok &= np.isfinite(nb) & (np.abs(nb - z) <= jump * np.abs(z))
    return ok


def agreement(depth, normals, camera: Camera, *, threshold_deg: float = DEFAULT_THRESHOLD_DEG,
              mask=None) -> Agreement:
    """Compare a normals map with the normals implied by a depth map.

    Args:
        depth: (H, W) z-depth, metres (invalid = 0 or non-finite).
        normals: (H, W, 3) camera-frame unit normals (0 = none).
        camera: the pinhole camera of both maps.
        threshold_deg: the angle beyond which a pixel counts as disagreeing.
        mask: optional (H, W) bool, the pixels to compare (e.g. the floor).
    Returns:
        Agreement; with no pixel to compare, its statistics are NaN and ``pixels`` 0.
    """
    from zcomp_cli.estimators.normals_from_depth import normals_from_depth

    depth = np.asarray(depth)
    normals = np.asarray(normals)
    if normals.shape != (*depth.shape, 3):
        raise InputError(f"agreement: normals {normals.shape} do not match depth {depth.shape}")
    implied = normals_from_depth(depth, camera)
    ang = angle_deg(normals, implied)
    sel = continuous_depth(depth) & np.isfinite(ang)
    if mask is not None:
        sel &= np.asarray(mask, bool)
    ang = np.where(sel, ang, np.nan).astype(np.float32)
    vals = ang[sel]
    if vals.size == 0:
        return Agreement(ang, float("nan"), float("nan"), float("nan"), threshold_deg, 0)
    return Agreement(ang, float(np.median(vals)), float(np.percentile(vals, 90)),
                     float(np.mean(vals > threshold_deg)), threshold_deg, int(vals.size))


def _downsample(arr: np.ndarray, step: int) -> np.ndarray:
    return arr[step // 2::step, step // 2::step]


def fit_shift_to_normals(rel, kind: str, normals, camera: Camera, *,
                         ratios=None) -> tuple[float, float, float]:
    """The shift of a relative depth prediction whose geometry agrees best with a
    normals map.

    The depth is ``1 / (d + t)`` (disparity) or ``p + t`` (affine) up to scale; ``t`` is
    searched through the far/near ratio ``r = (far + t) / (near + t)`` of the valid
    pixels, on a log grid, then refined by golden-section search.

    Args:
        rel: (H, W) relative prediction; kind ``disparity`` or ``affine``.
        normals: (H, W, 3) camera-frame unit normals.
        camera: the camera of both.
        ratios: the far/near ratios to try (default 1.05 .. 1000, log-spaced).
    Returns:
        (shift t, median angle at the best shift, median angle at the default shift:
        0 for disparity, the module's assumption for affine depth; degrees).
    Raises:
        InputError: the prediction has no usable range.
    """
    from zcomp_cli.estimators.depth_alignment import DEFAULT_FAR_NEAR_RATIO, relative_to_depth

    r = np.asarray(rel, np.float64)
    n = np.asarray(normals, np.float64)
    if r.ndim != 2 or n.shape != (*r.shape, 3):
        raise InputError(f"fit_shift_to_normals: prediction {r.shape} and normals {n.shape} do not match")
    step = max(1, int(np.ceil(max(r.shape) / FIT_MAX_SIDE)))
    rs, ns = _downsample(r, step), _downsample(n, step)
    cam = camera.resized(rs.shape[1], rs.shape[0]) if step > 1 else camera
    finite = np.isfinite(rs)
    if kind == "disparity":
        finite &= rs > 0
    vals = rs[finite]
    if vals.size < 16:
        raise InputError("fit_shift_to_normals: too few finite pixels in the prediction")
    lo, hi = np.percentile(vals, [2, 98])
    if not hi > lo:
        raise InputError("fit_shift_to_normals: the prediction is constant")
    # For disparity the near end is the largest value, for affine depth the smallest.
    near, far = (hi, lo) if kind == "disparity" else (lo, hi)

    def shift_of(ratio: float) -> float:
        # disparity: depth ratio far/near = (near + t) / (far + t); affine: (far + t) / (near + t)
        if kind == "disparity":
            return (near - ratio * far) / (ratio - 1.0)
        return (far - ratio * near) / (ratio - 1.0)

    base = finite & (np.linalg.norm(ns, axis=-1) > 0.5)

    def cost(ratio: float) -> float:
        # A truncated mean over every pixel that has a prediction and a normal, not the
        # median of the compared ones: a fronto-parallel wall agrees with every shift
        # (where it covers half the frame the median would not see the floor bend), and
        # a shift that makes pixels invalid must not gain by dropping them. Truncation
        # keeps occlusion edges and wrong normals from dominating.
        a = agreement(relative_to_depth(rs, kind, shift=shift_of(ratio)), ns, cam)
        v = np.where(np.isfinite(a.angle_deg), np.minimum(a.angle_deg, FIT_TRUNCATE_DEG), FIT_TRUNCATE_DEG)
        return float(v[base].mean())

    def median(ratio_or_shift: float, *, is_shift: bool = False) -> float:
        t = ratio_or_shift if is_shift else shift_of(ratio_or_shift)
        a = agreement(relative_to_depth(rs, kind, shift=t), ns, cam)
        return a.median_deg if a.pixels else 180.0

    grid = np.asarray(ratios if ratios is not None else np.geomspace(1.05, 1000.0, 36))
    costs = np.array([cost(g) for g in grid])
    i = int(np.argmin(costs))
    a, b = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
    g = (np.sqrt(5) - 1) / 2
    x1, x2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = cost(np.exp(x1)), cost(np.exp(x2))
    for _ in range(12):
        if f1 < f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - g * (b - a)
            f1 = cost(np.exp(x1))
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (b - a)
            f2 = cost(np.exp(x2))
    best_ratio, best = (np.exp(x1), f1) if f1 < f2 else (np.exp(x2), f2)
    if costs[i] < best:
        best_ratio = grid[i]
    default_shift = 0.0 if kind == "disparity" else shift_of(DEFAULT_FAR_NEAR_RATIO)
    return (float(shift_of(best_ratio)), float(median(best_ratio)),
            float(median(default_shift, is_shift=True)))
