"""``ZeroCompRenderer``: the official ZeroComp diffusion renderer behind zcomp's interface.

``render_jobs`` takes many jobs (each its background and composite passes), builds each
pass's conditioning in its own square window, and denoises the passes in chunks of
``2 x batch_size`` per UNet/ControlNet call (``batch_size`` = jobs per GPU batch). Every
pass of a job gets the same latent noise from the job's seed, so a job's images do not
depend on the other jobs of its batch (tested). The next chunk's conditioning is built on
a CPU thread while the current chunk denoises. ``render`` is one job.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import InputError, NumericalError, UsageError
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.zerocomp.conditioning import (
    GAMMA,
    WINDOWS,
    build_conditioning,
    in_frame,
    resize_square,
    square_window,
)

# Jobs per UNet/ControlNet call (x 2 passes each): the best jobs/s of 1/4/8/16 measured on
# an H200 at 512 px, 20 steps (docs/bench_zerocomp_gpu.json: 2.62 jobs/s at 8, 4.7 GiB;
# 4 gave 2.13, 16 gave 2.48). See docs/zerocomp.md, "Throughput".
DEFAULT_BATCH_SIZE = 8


class ZeroCompRenderer(Renderer):
    name = "zerocomp"
    # the executor prepares the next chunk of jobs on a CPU thread while this one renders
    overlap_prepare = True

    def __init__(self, controlnet: str | Path | None = None, base: str | Path | None = None, *,
                 steps: int = 20, device: str = "auto", dtype: str = "auto", crop: bool = False,
                 window: str | None = None, context_margin: float = 0.5, resolution: int = 512,
                 batch_size: int = DEFAULT_BATCH_SIZE, channels_last: bool | None = None,
                 compile: bool = False, allow_network: bool = False):
        if steps < 1:
            raise UsageError(f"zerocomp: steps must be >= 1, got {steps}")
        if context_margin < 0:
            raise UsageError(f"zerocomp: context_margin must be >= 0, got {context_margin}")
        if resolution < 8 or resolution % 8:
            raise UsageError(f"zerocomp: resolution must be a multiple of 8, got {resolution}")
        if int(batch_size) < 1:
            raise UsageError(f"zerocomp: batch_size must be >= 1, got {batch_size}")
        if window is None:
            window = "roi" if crop else "auto"
        if window not in WINDOWS:
            raise UsageError(f"zerocomp: window must be one of {', '.join(WINDOWS)}, got {window!r}")
        if crop and window != "roi":
            raise UsageError(f"zerocomp: crop: true means window: roi, not {window!r}")
        self.controlnet = controlnet
        self.base = base
        self.steps, self.device_setting, self.dtype_setting = int(steps), device, dtype
        self.window, self.context_margin = window, float(context_margin)
        self.resolution, self.allow_network = int(resolution), bool(allow_network)
        self.batch_size = int(batch_size)
        # None = on CUDA only (tensor-core convolutions want NHWC; CPU gains nothing sure)
        self.channels_last, self.compile = channels_last, bool(compile)
        self._models = None
        self._device = self._dtype = None

    @property
    def crop(self) -> bool:
        return self.window == "roi"

    def settings(self) -> dict:
        # batch_size, channels_last and compile change speed, not results: they stay out of
        # the settings that key caches and resume fingerprints.
        return {"name": self.name, "controlnet": str(self.controlnet), "base": str(self.base),
                "steps": self.steps, "device": self.device_setting, "dtype": self.dtype_setting,
                "window": self.window, "context_margin": self.context_margin,
                "resolution": self.resolution}

    def check(self) -> None:
        """Every weight file is where it is looked for (nothing is loaded)."""
        from zcomp_cli.renderers.zerocomp.loading import resolve_paths

        resolve_paths(self.controlnet, self.base)

    def models(self):
        """Load once per renderer object (a batch of jobs shares them)."""
        if self._models is None:
            from zcomp_cli.renderers.zerocomp.dtype import resolve_device, resolve_dtype
            from zcomp_cli.renderers.zerocomp.loading import load_models
            from zcomp_cli.renderers.zerocomp.pipeline import optimise_models

            self._device = resolve_device(self.device_setting)
            self._dtype = resolve_dtype(self.dtype_setting, self._device)
            models = load_models(self.controlnet, self.base, device=self._device,
                                 dtype=self._dtype, allow_network=self.allow_network)
            cl = self._device.startswith("cuda") if self.channels_last is None else bool(self.channels_last)
            optimise_models(models, channels_last=cl, compile=self.compile)
            self._models = models
        return self._models

    def window_for(self, request: RenderRequest) -> tuple[int, int, int, int]:
        """The square window this request is rendered in (see ``square_window``)."""
        return square_window(request.roi, request.maps.shape, self.window, self.context_margin)

    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        """The requests of one job (any number of passes), all with the noise of ``seed``."""
        return self.render_jobs([requests], [seed])[0]

    def render_jobs(self, jobs: Sequence[Sequence[RenderRequest]], seeds: Sequence[int]) -> list[RenderOutput]:
        """Render several jobs in shared GPU batches; equals rendering each job alone."""
        from zcomp_cli.renderers.zerocomp.dtype import autocast_context
        from zcomp_cli.renderers.zerocomp.pipeline import run_pipeline

        if len(jobs) != len(seeds):
            raise ValueError(f"render_jobs: {len(jobs)} jobs but {len(seeds)} seeds")
        if not jobs or any(not reqs for reqs in jobs):
            raise InputError("zerocomp: no render requests")
        t0 = time.perf_counter()
        models = self.models()
        t1 = time.perf_counter()
        ch = models.conditioning_channels
        requests = [r for reqs in jobs for r in reqs]
        owner = [j for j, reqs in enumerate(jobs) for _ in reqs]
        pass_seeds = [int(seeds[j]) for j in owner]
        boxes = [self.window_for(r) for r in requests]
        per_call = 2 * self.batch_size
        chunks = [list(range(i, min(i + per_call, len(requests))))
                  for i in range(0, len(requests), per_call)]
        cpu_s = [0.0]

        def conditioning(idx):
            t = time.perf_counter()
            c = np.stack([build_conditioning(requests[i], ch, self.resolution, boxes[i]) for i in idx])
            cpu_s[0] += time.perf_counter() - t
            return c

        images: list[np.ndarray | None] = [None] * len(requests)
        gpu_s = 0.0
        # 1. the first chunk's conditioning; then each chunk's successor is built on a
        #    CPU thread while the chunk denoises (numpy/cv2 release the GIL)
        with ThreadPoolExecutor(max_workers=1) as pool:
            nxt = pool.submit(conditioning, chunks[0])
            for k, idx in enumerate(chunks):
                cond = nxt.result()
                if k + 1 < len(chunks):
                    nxt = pool.submit(conditioning, chunks[k + 1])
                # 2. denoise and decode the chunk (each pass with its job's seed)
                t = time.perf_counter()
                out = run_pipeline(models, cond, steps=self.steps, seed=[pass_seeds[i] for i in idx],
                                   device=self._device, dtype=self._dtype,
                                   autocast=autocast_context(self.dtype_setting, self._device))
                gpu_s += time.perf_counter() - t
                # 3. back to linear, pasted into the frame
                for i, gam in zip(idx, out.images):
                    images[i] = self._paste(requests[i], boxes[i], gam)
        t2 = time.perf_counter()
        per_request = []
        for r, b in zip(requests, boxes):
            h, w = r.maps.shape
            inside = in_frame(b, (h, w))
            per_request.append({"window": self.window, "box": list(b),
                                "padded_px": int(inside.size - inside.sum()),
                                "scale": self.resolution / (b[2] - b[0]),
                                "roi_in_window": _roi_in_window(r.roi, b)})
        n = len(jobs)
        outputs = []
        for j in range(n):
            idx = [i for i, o in enumerate(owner) if o == j]
            info = {"renderer": self.settings(), "conditioning_channels": ch,
                    "box": per_request[idx[0]]["box"], "requests": [per_request[i] for i in idx],
                    "batch_size": self.batch_size, "jobs_in_call": n, "chunks": len(chunks),
                    "device": self._device, "dtype": str(self._dtype)}
            # shared work is split evenly between the jobs of the call
            outputs.append(RenderOutput([images[i] for i in idx], info,
                                        {"load": (t1 - t0) / n, "conditioning_cpu": cpu_s[0] / n,
                                         "diffusion": gpu_s / n, "render_total": (t2 - t1) / n}))
        return outputs

    def _paste(self, r: RenderRequest, box, gam: np.ndarray) -> np.ndarray:
        """Gamma-2.2 model output (R x R x 3) -> linear H x W x 3: the window's in-frame
        part from the model; outside it albedo x shading where known, else the photo
        (finite fillers: the compositor never reads outside the roi)."""
        h, w = r.maps.shape
        x0, y0, x1, y1 = box
        lin = resize_square(np.power(gam, GAMMA).astype(np.float32), x1 - x0)
        full = np.nan_to_num(r.maps.albedo * r.shading, nan=0.0, posinf=0.0).astype(np.float32)
        if r.image is not None:
            full = np.where(r.known[..., None], full, np.nan_to_num(r.image)).astype(np.float32)
        fx0, fy0, fx1, fy1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        full[fy0:fy1, fx0:fx1] = lin[fy0 - y0:fy1 - y0, fx0 - x0:fx1 - x0]
        if not np.isfinite(full).all():
            raise NumericalError("zerocomp: non-finite output image")
        return full


def _roi_in_window(roi, box) -> float:
    """Fraction of the roi's pixels inside the window (1.0 unless window: center)."""
    if roi is None:
        return 1.0
    x0, y0, x1, y1 = roi
    area = max(0, x1 - x0) * max(0, y1 - y0)
    if area == 0:
        return 1.0
    ix = max(0, min(x1, box[2]) - max(x0, box[0]))
    iy = max(0, min(y1, box[3]) - max(y0, box[1]))
    return ix * iy / area
