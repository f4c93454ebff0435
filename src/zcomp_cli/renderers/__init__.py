"""Renderers: map conditioning intrinsics (with a shading mask) to linear RGB images.

``get_renderer(name, **settings)`` builds one by name; heavy modules load lazily.
"""

from __future__ import annotations

from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest, SceneMaps

RENDERERS = ("physical", "zerocomp", "naive")


def get_renderer(name: str, **settings) -> Renderer:
    from zcomp_cli.errors import UsageError

    if name == "physical":
        from zcomp_cli.renderers.physical import PhysicalRenderer

        return PhysicalRenderer(**settings)
    if name == "zerocomp":
        from zcomp_cli.renderers.zerocomp import ZeroCompRenderer

        return ZeroCompRenderer(**settings)
    if name == "naive":
        from zcomp_cli.renderers.naive import NaiveRenderer

        return NaiveRenderer(**settings)
    raise UsageError(f"unknown renderer {name!r}; choose one of {', '.join(RENDERERS)}")


__all__ = ["Renderer", "RenderOutput", "RenderRequest", "SceneMaps", "get_renderer", "RENDERERS"]
