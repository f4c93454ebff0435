"""Pinhole camera in zcomp's conventions (DESIGN.md section 3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.conventions import K_from_fov, fov_from_K, pixel_ray, valid_depth_mask

DEFAULT_FOV_DEG = 50.0


def K_from_value(value) -> np.ndarray:
    """The one parser of user-given intrinsics: ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``
    or ``[fx, fy, cx, cy]`` (pixels) -> 3x3 float64.

    Raises ValueError saying what is wrong (shape, non-finite values, non-positive focal
    lengths, a last row other than [0, 0, 1]).
    """
    if isinstance(value, (str, bytes)):
        raise ValueError("expected [[fx,0,cx],[0,fy,cy],[0,0,1]] or [fx, fy, cx, cy]")
    try:
        K = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("expected [[fx,0,cx],[0,fy,cy],[0,0,1]] or [fx, fy, cx, cy] numbers") from None
    if K.shape == (4,):
        fx, fy, cx, cy = K
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if K.shape != (3, 3):
        raise ValueError("expected [[fx,0,cx],[0,fy,cy],[0,0,1]] or [fx, fy, cx, cy]")
    if not np.all(np.isfinite(K)):
        raise ValueError("K has non-finite values")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise ValueError("focal lengths must be positive and the last row [0, 0, 1]")
    return K


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics for a ``width`` x ``height`` image.

    ``K`` is 3x3 float64 in pixels; pixel centres sit at +0.5, so with the default
    principal point ``cx = width / 2``. The camera frame is OpenGL (x right, y up,
    the camera looks along -z).
    """

    K: np.ndarray
    width: int
    height: int

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite 3x3 matrix, got {K!r}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError("K focal lengths must be positive")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def from_fov(cls, fov_deg: float, width: int, height: int) -> "Camera":
        return cls(K_from_fov(fov_deg, width, height), width, height)

    @property
    def fov_deg(self) -> float:
        return fov_from_K(self.K, self.width)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for an image resampled to ``width`` x ``height``."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        return Camera(K, width, height)

    def ray(self, x, y) -> np.ndarray:
        """Camera-frame rays (z = -1) through image points ``[x, y]`` (continuous pixel
        coordinates; pixel centres at +0.5). ``x``, ``y`` broadcast; returns (..., 3)."""
        return pixel_ray(self.K, x, y)

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) camera-frame directions through pixel centres, scaled to z = -1."""
        uu, vv = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        return self.ray(uu, vv)

    def unproject(self, depth) -> np.ndarray:
        """z-depth (H, W) -> camera-frame points (H, W, 3) float32; invalid depth -> NaN."""
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (self.height, self.width):
            raise ValueError(
                f"depth shape {depth.shape} does not match camera {self.height}x{self.width}"
            )
        pts = self.pixel_rays() * depth[..., None]
        pts[~valid_depth_mask(depth)] = np.nan
        return pts.astype(np.float32)

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (..., 3) -> (pixel ``[x, y]`` (..., 2) float64, z-depth (...)).

        Points at or behind the camera get NaN pixels and a depth <= 0.
        """
        p = np.asarray(points, dtype=np.float64)
        depth = -p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            safe = np.where(depth > 1e-9, depth, np.nan)
            x = self.fx * p[..., 0] / safe + self.cx
            y = -self.fy * p[..., 1] / safe + self.cy
        return np.stack([x, y], axis=-1), depth

    def to_dict(self) -> dict:
        return {"K": self.K.tolist(), "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(np.asarray(d["K"], dtype=np.float64), int(d["width"]), int(d["height"]))
