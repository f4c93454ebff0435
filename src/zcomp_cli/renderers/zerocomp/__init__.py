"""ZeroComp diffusion renderer (SD 2.1 + intrinsic ControlNet); see docs/zerocomp.md."""

from zcomp_cli.renderers.zerocomp.renderer import ZeroCompRenderer

__all__ = ["ZeroCompRenderer"]
