"""The ``cycles`` renderer's settings, declared once with their provenance (the physical
renderer's ``knob``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from zcomp_cli.errors import UsageError
from zcomp_cli.renderers.physical.settings import knob

# Upper bounds of the settings, checked when the manifest (or a flag) is read: past them
# a pass cannot finish within item_timeout_s or its world map leaves the pixel budget.
MAX_SAMPLES = 4096          # preview-light's cap too: 128 is the sweep's far end, 4096 is 32 times that
MAX_BOUNCES = 1024          # Blender's own limit on light-path bounces
MAX_THREADS = 1024          # Blender's own limit on render threads
MAX_SKY_WIDTH = 1024        # an order-2 SH sky is smooth: 1024 is 8 times the default's 1.4 deg texels
MAX_MAP_WIDTH = 16384       # a probe world or its importance map: also within the pixel budget (w x w/2)
MAX_MARGIN_PX = 256         # the pixel filter reaches 1.5 px; the denoiser's context a few dozen


@dataclass(frozen=True)
class CyclesSettings:
    """Settings of the cycles renderer (all optional). ``exposure``: ``light`` renders the
    light model in its own units (the photograph's exposure is the light fit's); ``render``
    rescales each pass by the median ratio of the photograph to the render over the
    window's known pixels (the transport's own exposure)."""

    samples: int = knob(32, "setting", "path samples per pixel; with the denoiser the error-against-time sweep's "
                                       "knee (benchmarks/sweep_error_vs_time.py, docs/physical.md)")
    denoise: bool = knob(True, "setting", "Open Image Denoise (bundled with Blender) on each pass")
    max_bounces: int = knob(4, "setting", "light-path bounces: the floor's bounce onto the object and back is "
                                          "two; more changes the sweep's error by less than its noise")
    threads: int = knob(0, "setting", "Cycles' CPU threads (0: all cores)")
    exposure: str = knob("light", "setting", "light (the light fit's units) or render (each pass rescaled to the "
                                             "photograph over its known pixels)")
    world: str = knob("probe", "setting", "probe: a given probe is the world itself; model: the light model's "
                                          "order-2 SH sky and the probe's sources as suns, what the physical "
                                          "renderer draws (an ablation: docs/physical.md)")
    sky_width: int = knob(128, "sampling", "width of the world map an estimated (order-2 SH) sky is drawn into: "
                                           "smooth, so 1.4 deg texels hold all of it")
    probe_width: int = knob(1024, "sampling", "a given probe becomes the world at most this wide (the bundled maps' "
                                              "own width: their suns keep their size)")
    world_map_resolution: int = knob(0, "sampling", "the world's importance map (Cycles' light sampling of an "
                                                    "environment): 0 is Cycles' automatic, the map's own width; "
                                                    "256 builds it in 0.2 s instead of 0.9 s for a 1024-wide probe "
                                                    "on 2 cores, at more noise near a small sun "
                                                    "(benchmarks/preview_light_timing.py); preview-light's choice")
    margin_px: int = knob(4, "sampling", "pixels rendered around the re-shaded region: the pixel filter's reach "
                                         "(1.5 px) and the denoiser's context")
    item_timeout_s: float = knob(600.0, "heuristic", "a pass taking longer kills Blender (that job fails)")

    @classmethod
    def from_kwargs(cls, **kw) -> "CyclesSettings":
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = set(kw) - set(names)
        if unknown:
            raise UsageError(f"unknown cycles renderer setting(s): {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(names)}")
        out = {}
        for k, v in kw.items():
            want = {f.name: f.type for f in dataclasses.fields(cls)}[k]
            try:
                if want == "bool":
                    if not isinstance(v, bool):
                        raise ValueError
                    out[k] = v
                elif want == "int":
                    if isinstance(v, bool) or int(v) != v:
                        raise ValueError
                    out[k] = int(v)
                elif want == "float":
                    out[k] = float(v)
                else:
                    out[k] = str(v)
            except (TypeError, ValueError, OverflowError):  # (int(inf): OverflowError)
                raise UsageError(f"cycles renderer setting {k}: expected {want}, got {v!r}") from None
        s = cls(**out)
        bounds = {"samples": (1, MAX_SAMPLES), "max_bounces": (0, MAX_BOUNCES), "threads": (0, MAX_THREADS),
                  "sky_width": (8, MAX_SKY_WIDTH), "probe_width": (8, MAX_MAP_WIDTH), "margin_px": (0, MAX_MARGIN_PX),
                  "world_map_resolution": (0, MAX_MAP_WIDTH)}
        for k, (lo, hi) in bounds.items():
            if not lo <= getattr(s, k) <= hi:
                raise UsageError(f"cycles renderer setting {k}: from {lo} to {hi}, got {getattr(s, k)}")
        from zcomp_cli.limits import pixel_budget_problem

        for k in ("probe_width", "world_map_resolution"):
            problem = pixel_budget_problem(getattr(s, k), max(1, getattr(s, k) // 2))
            if problem:
                raise UsageError(f"cycles renderer setting {k}: a world map {problem}")
        if s.world not in ("probe", "model"):
            raise UsageError(f"cycles renderer setting world: probe or model, got {s.world!r}")
        if s.exposure not in ("light", "render"):
            raise UsageError(f"cycles renderer setting exposure: light or render, got {s.exposure!r}")
        if not s.item_timeout_s > 0:
            raise UsageError(f"cycles renderer setting item_timeout_s: positive, got {s.item_timeout_s}")
        return s

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


__all__ = ["CyclesSettings"]
