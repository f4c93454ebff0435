"""The ``cycles`` renderer (issue 35): Blender's path tracer as the transport, on a mesh
of the photograph's depth, lit by the physical renderer's light model (``renderer``)."""

from zcomp_cli.renderers.cycles.renderer import CyclesRenderer

__all__ = ["CyclesRenderer"]
