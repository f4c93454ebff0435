"""The embedded ``physical`` renderer (DESIGN.md sections 5 and 8): the scene's light
(given in the manifest or fitted to the known shading, ``lightmodel``), screen-space
shadow rays, shading synthesis for the masked pixels."""

from zcomp_cli.renderers.physical.lightmodel import LightModel
from zcomp_cli.renderers.physical.renderer import PhysicalRenderer

__all__ = ["PhysicalRenderer", "LightModel"]
