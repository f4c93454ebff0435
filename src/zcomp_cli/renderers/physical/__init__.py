"""The embedded ``physical`` renderer (DESIGN.md section 5): light estimation from the known
shading, screen-space shadow rays, shading synthesis for the masked pixels."""

from zcomp_cli.renderers.physical.lighting import LightEstimate, estimate_lighting
from zcomp_cli.renderers.physical.renderer import PhysicalRenderer

__all__ = ["PhysicalRenderer", "LightEstimate", "estimate_lighting"]
