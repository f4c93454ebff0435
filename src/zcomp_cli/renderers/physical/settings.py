"""The physical renderer's settings: declared once, read by the renderer and the light fit.

The manifest's ``renderer: {name: physical, <setting>: ...}`` and the API's
``PhysicalRenderer(**settings)`` take these names; anything else is refused.
"""

from __future__ import annotations

import dataclasses
import numbers
from dataclasses import dataclass

from zcomp_cli.errors import UsageError


@dataclass(frozen=True, kw_only=True)
class PhysicalSettings:
    """Settings of the physical renderer (all optional).

    n_light_candidates: directions on the hemisphere the light search scores (then
        refined around the best).
    march_steps: samples per shadow ray when synthesising.
    estimate_march_steps: samples per shadow ray in the light fit.
    max_resolution: long side of the copy the light is fitted on (pixels).
    cone_samples: directions per pixel over a light's cone in the fit.
    shadow_softness: the lights' angular radius in degrees, instead of the fitted or
        default one (None: not forced).
    max_fit_pixels: pixels of the copy the light is fitted on (a deterministic stride
        subsample).
    shadow_resolution: long side of the copy whose depth mesh the light rays are cast
        through and whose support's shadows are read.
    max_receivers: support pixels the candidate lights' shadows are cast from.
    """

    n_light_candidates: int = 256
    march_steps: int = 32
    estimate_march_steps: int = 16
    max_resolution: int = 160
    cone_samples: int = 8
    shadow_softness: float | None = None
    max_fit_pixels: int = 2000
    shadow_resolution: int = 256
    max_receivers: int = 3000

    @classmethod
    def from_kwargs(cls, **kw) -> "PhysicalSettings":
        """Validated settings; unknown names or bad values raise ``UsageError``."""
        from zcomp_cli.limits import shorten

        names = [f.name for f in dataclasses.fields(cls)]
        unknown = set(kw) - set(names)
        if unknown:
            raise UsageError(f"unknown physical renderer setting(s): {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(names)}")
        for k in ("n_light_candidates", "march_steps", "estimate_march_steps", "max_resolution",
                  "cone_samples", "max_fit_pixels", "shadow_resolution", "max_receivers"):
            if k in kw:
                v = kw[k]
                if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 1 <= v <= 1_000_000:
                    raise UsageError(f"physical renderer setting {k}: expected an integer in [1, 1000000], "
                                     f"got {shorten(v)}")
        sv = kw.get("shadow_softness")
        if sv is not None and (isinstance(sv, bool) or not isinstance(sv, (int, float))
                               or not (0 <= float(sv) <= 60)):
            raise UsageError(f"physical renderer setting shadow_softness: expected degrees in [0, 60], "
                             f"got {shorten(sv)}")
        return cls(**{k: (int(v) if isinstance(v, numbers.Integral) else float(v) if k == "shadow_softness"
                         and v is not None else v) for k, v in kw.items()})

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


DEFAULTS = PhysicalSettings()

__all__ = ["PhysicalSettings", "DEFAULTS"]
