"""--debug's grid.png names its panels (issue 50: an artist could not tell them apart)."""

from __future__ import annotations

import numpy as np

from zcomp_cli.pipeline.outputs import GRID_LABELS, debug_grid


def test_each_panel_of_the_grid_carries_its_name():
    H, W = 96, 128
    grey = np.full((H, W, 3), 0.2, np.float32)
    plain = np.zeros((H, W), np.float32)
    g = debug_grid(grey, grey, grey, plain, plain, grey)
    assert g.shape == (2 * H, 3 * W, 3) and len(GRID_LABELS) == 6
    for k in range(6):
        r, c = divmod(k, 3)
        corner = g[r * H:r * H + H // 4, c * W:c * W + W // 2]
        rest = g[r * H + H // 2:(r + 1) * H, c * W + W // 2:(c + 1) * W]
        assert (corner > 0.95).any(), GRID_LABELS[k]  # white letters
        assert not (rest > 0.95).any()  # the panel itself untouched away from its name
