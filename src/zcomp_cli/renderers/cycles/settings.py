"""The ``cycles`` renderer's settings, declared once with their provenance and range
(``zcomp_cli.knobs``), the light stage's config (``light``) among them."""

from __future__ import annotations

from dataclasses import dataclass

from zcomp_cli.knobs import as_dict, from_mapping, knob, sub
from zcomp_cli.light.config import LightConfig

LABEL = "cycles renderer setting"
# The most path samples a pass may ask for: 4096 denoised samples are far past the
# error-against-time sweep's knee (16-32), and every pass must end within the item's
# timeout on a CPU (preview-light caps its samples alike).
MAX_SAMPLES = 4096


@dataclass(frozen=True, kw_only=True)
class CyclesSettings:
    """Settings of the cycles renderer (all optional). ``exposure``: ``light`` renders the
    light model in its own units (the photograph's exposure is the light fit's); ``render``
    rescales each pass by the median ratio of the photograph to the render over the
    window's known pixels (the transport's own exposure)."""

    samples: int = knob(32, "setting", "path samples per pixel; with the denoiser the error-against-time sweep's "
                                       "knee (benchmarks/sweep_error_vs_time.py, docs/physical.md)", hi=MAX_SAMPLES)
    denoise: bool = knob(True, "setting", "Open Image Denoise (bundled with Blender) on each pass")
    max_bounces: int = knob(4, "setting", "light-path bounces: the floor's bounce onto the object and back is "
                                          "two; more changes the sweep's error by less than its noise", lo=0, hi=64)
    threads: int = knob(0, "setting", "Cycles' CPU threads (0: all cores)", lo=0, hi=1024)
    exposure: str = knob("light", "setting", "light (the light fit's units) or render (each pass rescaled to the "
                                             "photograph over its known pixels)", choices=("light", "render"))
    world: str = knob("probe", "setting", "probe: a given probe is the world itself; model: the light model's "
                                          "order-2 SH sky and the probe's sources as suns, what the physical "
                                          "renderer draws (an ablation: docs/physical.md)", choices=("probe", "model"))
    sky_width: int = knob(128, "sampling", "width of the world map an estimated (order-2 SH) sky is drawn into: "
                                           "smooth, so 1.4 deg texels hold all of it", lo=8, hi=2048)
    probe_width: int = knob(1024, "sampling", "a given probe becomes the world at most this wide (the bundled maps' "
                                              "own width: their suns keep their size)", lo=8, hi=8192)
    world_map_resolution: int = knob(0, "sampling", "the world's importance map (Cycles' light sampling of an "
                                                    "environment): 0 is Cycles' automatic, the map's own width; "
                                                    "256 builds it in 0.2 s instead of 0.9 s for a 1024-wide probe "
                                                    "on 2 cores, at more noise near a small sun "
                                                    "(benchmarks/preview_light_timing.py); preview-light's choice",
                                     lo=0, hi=8192)
    margin_px: int = knob(4, "sampling", "pixels rendered around the re-shaded region: the pixel filter's reach "
                                         "(1.5 px) and the denoiser's context", lo=0, hi=1024)
    item_timeout_s: float = knob(600.0, "heuristic", "a pass taking longer kills Blender (that job fails)",
                                 hi=86400.0)
    light: LightConfig = sub(LightConfig, "the light stage's settings: the fit of the light this renderer draws")

    @classmethod
    def from_kwargs(cls, **kw) -> "CyclesSettings":
        """Validated settings; unknown names or bad values raise ``UsageError`` (a nested
        config as a mapping of its fields)."""
        return from_mapping(cls, kw, LABEL)

    def as_dict(self) -> dict:
        return as_dict(self)


__all__ = ["CyclesSettings", "LABEL", "MAX_SAMPLES"]
