"""Intrinsic-map types of one view (DESIGN.md section 3), below the equations and the
renderers that both use them. The object's own maps live in ``bundle.ObjectBundle``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SceneMaps:
    """Intrinsic maps of one view, all H x W float32, in zcomp's conventions.

    depth: z-depth in metres, 0 where invalid. normals: camera-frame (OpenGL) unit
    vectors, 0 where invalid. albedo: linear RGB in [0, 1]. roughness/metallic: [0, 1],
    optional (13-channel zerocomp checkpoints).
    """

    depth: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    roughness: np.ndarray | None = None
    metallic: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.depth.shape[:2])
