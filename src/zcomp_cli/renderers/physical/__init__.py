"""The embedded ``physical`` renderer (DESIGN.md sections 5 and 8): the transport. It
draws the scene's fitted light (``zcomp_cli.light``) with screen-space shadows, the sky's
visibility, the object's mesh shadow and occlusion, and glossy reflections."""

from zcomp_cli.renderers.physical.renderer import PhysicalRenderer

__all__ = ["PhysicalRenderer"]
