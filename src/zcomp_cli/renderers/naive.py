"""``naive``: the naive-paste baseline of the benchmark (no weights, no shadow).

Unknown shading is replaced by the mean known shading (per channel) of the background,
so the object is its albedo times the scene's average light and casts no shadow (both
passes agree off the object, so the compositor's ratio is 1 there). It is a baseline
row in ``zcomp eval`` tables, not a product renderer.
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import UsageError
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest


class NaiveRenderer(Renderer):
    name = "naive"

    def __init__(self, **settings):
        if settings:
            raise UsageError(f"renderer 'naive' takes no settings, got {sorted(settings)}")

    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        t = time.perf_counter()
        images = []
        for req in requests:
            known = np.asarray(req.known, bool)
            shading = np.asarray(req.shading, np.float32)
            # Both passes of a job share shading and mask, so they get the same mean.
            mean = shading[known].mean(axis=0) if known.any() else np.ones(3, np.float32)
            filled = np.where(known[..., None], shading, mean[None, None, :])
            out = np.nan_to_num(np.clip(req.maps.albedo, 0, 1) * filled, nan=0.0, posinf=0.0)
            images.append(out.astype(np.float32))
        return RenderOutput(images, {"mean_shading": mean.tolist()}, {"render_s": time.perf_counter() - t})
