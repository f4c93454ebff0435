"""The light estimate's evidence as debug maps (``zcomp composite --debug``; DESIGN.md
section 8, "The light from the shadows").

Where the light's direction is searched, the fit reads the cast shadows the photograph
shows on its support (``shadow_evidence.ShadowEvidence``) on the shadow grid, a copy of
the job's working frame whose long side is ``settings.shadow_resolution``, through that
grid's depth mesh (``depthmesh.DepthMesh``: its support and its casters).
``LightEvidence`` keeps, per scene, what the debug maps need from them (a few small
arrays on the grid, not the mesh); ``LightEvidence.maps`` brings them to the job's
working resolution, where the renderer returns them as ``RenderOutput.debug_maps``:

* ``shadow_evidence``: the soft cast-shadow mask (``ShadowEvidence.soft_mask``, in
  [0, 1], the shadows tied to a caster only);
* ``shadow_confidence``: the weight each pixel counts with (0 on a dark region tied to
  no caster and off the support, 1 where it counts);
* ``shadow_ratio``: the support's shading over its lit level (NaN off the pixels read);
* ``casters``: 1 on the depth mesh's casters, 0.5 on the support, else 0.

The grid is never finer than the frame (``atoms.working_copy`` only shrinks), so the
maps are enlarged **nearest** (each frame pixel takes the grid cell whose footprint
holds its centre: masks stay masks, NaN stays NaN, the grid's resolution shows); a grid
finer than the frame would be **area**-averaged (NaN left out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Values of the ``casters`` map.
CASTER_VALUE = 1.0
SUPPORT_VALUE = 0.5

# The maps' names (``RenderOutput.debug_maps``), as the renderer's registry entry
# declares them (``renderers.registry``).
MAP_NAMES = ("shadow_evidence", "shadow_confidence", "shadow_ratio", "casters")


@dataclass(frozen=True)
class LightEvidence:
    """The evidence of one scene's light fit on its (h, w) shadow grid (module
    docstring): ``soft_mask``, ``confidence``, ``ratio``, ``casters`` (float32)."""

    soft_mask: np.ndarray
    confidence: np.ndarray
    ratio: np.ndarray
    casters: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.soft_mask.shape

    @classmethod
    def from_fit(cls, evidence, mesh) -> "LightEvidence | None":
        """From what the fit read: ``evidence`` (``ShadowEvidence``) and ``mesh`` (the
        grid's ``DepthMesh``), or None when either is missing or they disagree on the
        grid (nothing to show)."""
        if evidence is None or mesh is None:
            return None
        shape = tuple(np.shape(evidence.ratio))
        if len(shape) != 2 or tuple(mesh.shape) != shape:
            return None
        cast = np.where(np.asarray(mesh.casters, bool), CASTER_VALUE,
                        np.where(np.asarray(mesh.support, bool), SUPPORT_VALUE, 0.0))
        return cls(soft_mask=np.clip(np.asarray(evidence.soft_mask, np.float32), 0.0, 1.0),
                   confidence=np.clip(np.asarray(evidence.weight, np.float32), 0.0, 1.0),
                   ratio=np.asarray(evidence.ratio, np.float32),
                   casters=cast.astype(np.float32))

    @classmethod
    def from_diagnostics(cls, diagnostics: dict | None) -> "LightEvidence | None":
        """From the ``diagnostics`` dict ``lightfit.fit_light`` fills (its ``evidence``
        and ``mesh``), None where it holds none (a given light, too few pixels)."""
        d = diagnostics or {}
        return cls.from_fit(d.get("evidence"), d.get("mesh"))

    def maps(self, shape: tuple[int, int]) -> dict[str, np.ndarray]:
        """The debug maps (module docstring) at the frame's ``shape`` (H, W), float32."""
        return {"shadow_evidence": to_frame(self.soft_mask, shape),
                "shadow_confidence": to_frame(self.confidence, shape),
                "shadow_ratio": to_frame(self.ratio, shape),
                "casters": to_frame(self.casters, shape)}


def to_frame(grid_map: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32: a (h, w) map of a grid covering the same frame brought to
    ``shape`` (module docstring: nearest when enlarging, area when shrinking; NaN is no
    value)."""
    a = np.asarray(grid_map, np.float32)
    h, w = a.shape
    H, W = int(shape[0]), int(shape[1])
    if (h, w) == (H, W):
        return a.copy()
    if h <= H and w <= W:
        iy = np.minimum(((np.arange(H) + 0.5) * (h / H)).astype(np.int64), h - 1)
        ix = np.minimum(((np.arange(W) + 0.5) * (w / W)).astype(np.int64), w - 1)
        return a[iy[:, None], ix[None, :]]
    import cv2

    ok = np.isfinite(a)
    num = cv2.resize(np.where(ok, a, 0.0).astype(np.float32), (W, H), interpolation=cv2.INTER_AREA)
    den = cv2.resize(ok.astype(np.float32), (W, H), interpolation=cv2.INTER_AREA)
    return np.where(den > 1e-6, num / np.maximum(den, 1e-6), np.nan).astype(np.float32)


__all__ = ["LightEvidence", "to_frame", "MAP_NAMES"]
