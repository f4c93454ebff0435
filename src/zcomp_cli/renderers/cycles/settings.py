"""The ``cycles`` renderer's settings, declared once with their provenance (the physical
renderer's ``knob``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from zcomp_cli.errors import UsageError
from zcomp_cli.renderers.physical.settings import knob


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
            except (TypeError, ValueError):
                raise UsageError(f"cycles renderer setting {k}: expected {want}, got {v!r}") from None
        s = cls(**out)
        lows = {"samples": 1, "max_bounces": 0, "threads": 0, "sky_width": 8, "probe_width": 8, "margin_px": 0,
                "world_map_resolution": 0}
        for k, lo in lows.items():
            if getattr(s, k) < lo:
                raise UsageError(f"cycles renderer setting {k}: at least {lo}, got {getattr(s, k)}")
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
