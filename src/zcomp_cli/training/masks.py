"""Random shading masks for ZeroComp training (DESIGN.md section 4, paper Sec. 3.1).

Branches: p=0.6 shapes (1-3 rectangles with side 0.2-0.9 of the image, drawn with p=0.6,
and 1-3 circles with radius 0.05-0.3 of the short side, drawn with p=0.6; if neither was
drawn, rectangles are drawn so the branch always masks something), p=0.3 the whole shading
map masked, p=0.1 nothing masked. True = masked (shading unknown).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.errors import InputError

# Branch probabilities; the shapes branch takes the rest (0.6).
P_FULL, P_NONE = 0.3, 0.1


def random_shading_mask(h: int, w: int, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """Returns (H x W bool mask, branch name in {'shapes', 'full', 'none'})."""
    if h < 1 or w < 1:
        raise InputError(f"mask size must be positive, got {h}x{w}")
    u = rng.random()
    if u < P_NONE:
        return np.zeros((h, w), bool), "none"
    if u < P_NONE + P_FULL:
        return np.ones((h, w), bool), "full"
    m = np.zeros((h, w), bool)
    rects, circles = rng.random() < 0.6, rng.random() < 0.6
    if not (rects or circles):
        rects = True
    if rects:
        for _ in range(rng.integers(1, 4)):
            rh, rw = int(round(rng.uniform(0.2, 0.9) * h)), int(round(rng.uniform(0.2, 0.9) * w))
            y0, x0 = rng.integers(0, h - rh + 1), rng.integers(0, w - rw + 1)
            m[y0:y0 + rh, x0:x0 + rw] = True
    if circles:
        yy, xx = np.mgrid[0:h, 0:w]
        for _ in range(rng.integers(1, 4)):
            r = rng.uniform(0.05, 0.3) * min(h, w)
            cy, cx = rng.uniform(0, h), rng.uniform(0, w)
            m |= (yy + 0.5 - cy) ** 2 + (xx + 0.5 - cx) ** 2 <= r * r
    return m, "shapes"
