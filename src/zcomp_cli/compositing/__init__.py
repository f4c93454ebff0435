"""The compositing math of DESIGN.md section 2 (equations 1-5), as pure numpy functions."""

from zcomp_cli.compositing.alignment import DepthAlignment, align_depth, apply_alignment
from zcomp_cli.compositing.compositor import (
    CompositeResult,
    blur_weight,
    colour_balance,
    composite,
    shadow_ratio,
)
from zcomp_cli.compositing.intrinsic_composite import composite_intrinsics, occlusion_mask
from zcomp_cli.compositing.shading_mask import shading_mask
from zcomp_cli.compositing.shading import SHADING_EPS, SHADING_MAX, shading_from_image

__all__ = [
    "DepthAlignment",
    "align_depth",
    "apply_alignment",
    "occlusion_mask",
    "composite_intrinsics",
    "shading_mask",
    "shading_from_image",
    "SHADING_EPS",
    "SHADING_MAX",
    "shadow_ratio",
    "blur_weight",
    "colour_balance",
    "composite",
    "CompositeResult",
]
