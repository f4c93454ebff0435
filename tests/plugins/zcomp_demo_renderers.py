"""Two third-party renderers, installed through the ``zcomp.renderers`` entry point group
(``zcomp_demo_renderers-0.1.dist-info/entry_points.txt``), for
``tests/test_renderer_plugins.py``. This folder is on ``sys.path`` only in the tests that
ask for it.

* ``demo-flat``: albedo x known shading, the mean known shading where it is unknown
  (keeps the contract; exported as a ``RendererEntry``);
* ``demo-noisy``: the same with unseeded noise (breaks "deterministic for a seed";
  exported as its ``Renderer`` subclass).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.renderers.base import Renderer, RenderOutput
from zcomp_cli.renderers.registry import RendererEntry, RendererOption


class FlatRenderer(Renderer):
    name = "demo-flat"

    def __init__(self, gain: float = 1.0):
        self.gain = float(gain)

    def settings(self) -> dict:
        return {"name": self.name, "gain": self.gain}

    def render(self, requests, *, seed: int = 469) -> RenderOutput:
        images = []
        for req in requests:
            known = np.asarray(req.known, bool)
            mean = req.shading[known].mean(axis=0) if known.any() else np.ones(3, np.float32)
            shading = np.where(known[..., None], req.shading, mean * self.gain)
            images.append((np.clip(req.maps.albedo, 0, 1) * shading).astype(np.float32))
        return RenderOutput(images)


class NoisyRenderer(FlatRenderer):
    """Flat shading with unseeded noise: breaks the contract."""

    name = "demo-noisy"
    contract_settings = {"gain": 1.0}

    def render(self, requests, *, seed: int = 469) -> RenderOutput:
        out = super().render(requests, seed=seed)
        rng = np.random.default_rng()  # not the seed: two calls differ
        return RenderOutput([(im + rng.random(im.shape, dtype=np.float32) * 1e-3).astype(np.float32)
                             for im in out.images])


FLAT = RendererEntry("zcomp_demo_renderers", "FlatRenderer", "demo plugin: flat shading",
                     options=(RendererOption("gain", "flat-gain", float, "gain of the unknown shading", "G"),),
                     contract_settings={"gain": 1.0})
