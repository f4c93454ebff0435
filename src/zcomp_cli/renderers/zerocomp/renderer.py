"""``ZeroCompRenderer``: the official ZeroComp diffusion renderer behind zcomp's interface."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import InputError, NumericalError, UsageError
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.zerocomp.conditioning import GAMMA, build_conditioning, crop_box


class ZeroCompRenderer(Renderer):
    name = "zerocomp"

    def __init__(self, controlnet: str | Path | None = None, base: str | Path | None = None, *,
                 steps: int = 20, device: str = "auto", dtype: str = "auto", crop: bool = False,
                 context_margin: float = 0.5, resolution: int = 512, allow_network: bool = False,
                 weights: str | Path | None = None):
        if steps < 1:
            raise UsageError(f"zerocomp: steps must be >= 1, got {steps}")
        if context_margin < 0:
            raise UsageError(f"zerocomp: context_margin must be >= 0, got {context_margin}")
        if resolution < 8 or resolution % 8:
            raise UsageError(f"zerocomp: resolution must be a multiple of 8, got {resolution}")
        self.controlnet = controlnet or weights
        self.base = base
        self.steps, self.device_setting, self.dtype_setting = int(steps), device, dtype
        self.crop, self.context_margin = bool(crop), float(context_margin)
        self.resolution, self.allow_network = int(resolution), bool(allow_network)
        self._models = None
        self._device = self._dtype = None

    def settings(self) -> dict:
        return {"name": self.name, "controlnet": str(self.controlnet), "base": str(self.base),
                "steps": self.steps, "device": self.device_setting, "dtype": self.dtype_setting,
                "crop": self.crop, "context_margin": self.context_margin,
                "resolution": self.resolution}

    def models(self):
        """Load once per renderer object (a batch of jobs shares them)."""
        if self._models is None:
            from zcomp_cli.renderers.zerocomp.dtype import resolve_device, resolve_dtype
            from zcomp_cli.renderers.zerocomp.loading import load_models

            self._device = resolve_device(self.device_setting)
            self._dtype = resolve_dtype(self.dtype_setting, self._device)
            self._models = load_models(self.controlnet, self.base, device=self._device,
                                       dtype=self._dtype, allow_network=self.allow_network)
        return self._models

    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        import cv2

        from zcomp_cli.renderers.zerocomp.pipeline import run_pipeline

        if not requests:
            raise InputError("zerocomp: no render requests")
        t0 = time.perf_counter()
        models = self.models()
        t1 = time.perf_counter()
        shape = requests[0].maps.shape
        if any(r.maps.shape != shape for r in requests):
            raise InputError("zerocomp: all requests of a job must share one frame size")
        roi = requests[0].roi
        box = crop_box(roi, shape, self.context_margin) if self.crop else (0, 0, shape[1], shape[0])
        ch = models.conditioning_channels
        cond = np.stack([build_conditioning(r, ch, self.resolution, box) for r in requests])
        t2 = time.perf_counter()
        out = run_pipeline(models, cond, steps=self.steps, seed=seed, device=self._device,
                           dtype=self._dtype)
        t3 = time.perf_counter()
        x0, y0, x1, y1 = box
        images = []
        for r, gam in zip(requests, out.images):
            lin = np.power(gam, GAMMA).astype(np.float32)  # gamma-2.2 -> linear
            lin = cv2.resize(lin, (x1 - x0, y1 - y0), interpolation=cv2.INTER_LINEAR)
            # outside the crop: the known reconstruction (albedo * shading), else the photo
            full = np.nan_to_num(r.maps.albedo * r.shading, nan=0.0, posinf=0.0).astype(np.float32)
            if r.image is not None:
                full = np.where(r.known[..., None], full, np.nan_to_num(r.image)).astype(np.float32)
            full[y0:y1, x0:x1] = lin.reshape(y1 - y0, x1 - x0, 3)
            if not np.isfinite(full).all():
                raise NumericalError("zerocomp: non-finite output image")
            images.append(full)
        info = {"renderer": self.settings(), "conditioning_channels": ch, "box": list(box),
                "device": self._device, "dtype": str(self._dtype)}
        return RenderOutput(images, info, {"load": t1 - t0, "conditioning": t2 - t1,
                                           "diffusion": t3 - t2})
