"""Renderers: map conditioning intrinsics (with a shading mask) to linear RGB images.

``registry.RENDERERS`` is the one table of renderers and their command-line options;
``get_renderer(name, **settings)`` builds one, importing its module only then.
"""

from __future__ import annotations

import importlib

from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.registry import RENDERERS, RendererEntry, RendererOption


def get_renderer(name: str, **settings) -> Renderer:
    """Build the renderer called ``name`` with its keyword settings."""
    from zcomp_cli.errors import RenderError, UsageError

    if name not in RENDERERS:
        raise UsageError(f"unknown renderer {name!r}; choose one of {', '.join(RENDERERS)}")
    entry = RENDERERS[name]
    try:
        factory = getattr(importlib.import_module(entry.module), entry.cls)
    except (ImportError, AttributeError) as exc:
        raise RenderError(f"renderer {name!r} cannot be loaded: {exc}") from exc
    return factory(**settings)


__all__ = ["Renderer", "RenderOutput", "RenderRequest", "SceneMaps", "get_renderer", "RENDERERS",
           "RendererEntry", "RendererOption"]
