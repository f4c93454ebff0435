"""Renderers: map conditioning intrinsics (with a shading mask) to linear RGB images.

``get_renderer(name, **settings)`` builds one by name; heavy modules load lazily.
"""

from __future__ import annotations

import importlib

from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest

# name -> (module, class)
_RENDERERS = {
    "physical": ("zcomp_cli.renderers.physical", "PhysicalRenderer"),
    "zerocomp": ("zcomp_cli.renderers.zerocomp", "ZeroCompRenderer"),
    "naive": ("zcomp_cli.renderers.naive", "NaiveRenderer"),
}
RENDERERS = tuple(_RENDERERS)


def get_renderer(name: str, **settings) -> Renderer:
    """Build the renderer called ``name`` with its keyword settings."""
    from zcomp_cli.errors import RenderError, UsageError

    if name not in _RENDERERS:
        raise UsageError(f"unknown renderer {name!r}; choose one of {', '.join(RENDERERS)}")
    module, cls = _RENDERERS[name]
    try:
        factory = getattr(importlib.import_module(module), cls)
    except (ImportError, AttributeError) as exc:
        raise RenderError(f"renderer {name!r} cannot be loaded: {exc}") from exc
    return factory(**settings)


__all__ = ["Renderer", "RenderOutput", "RenderRequest", "SceneMaps", "get_renderer", "RENDERERS"]
