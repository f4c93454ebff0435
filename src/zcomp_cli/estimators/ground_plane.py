"""Weight-free depth proxy: a ground plane seen from a known camera height, plus a far
fronto-parallel backdrop (the "object on the floor or table" case). See
docs/estimation.md and docs/ground_plane.png for a picture of what it assumes.

Geometry (camera frame, OpenGL: x right, y up, the camera looks along -z). The camera
sits ``camera_height_m`` above a horizontal floor, pitched by ``pitch_deg`` (negative =
looking down) and rolled by ``roll_deg`` about its optical axis. The floor's up normal in
the camera frame is ``n = Rz(-roll) @ (0, cos p, -sin p)`` and floor points satisfy
``n . X = -h``. The ray through a pixel, ``r = ((u-cx)/fx, -(v-cy)/fy, -1)``, meets the
floor at z-depth ``t = -h / (n . r)`` when ``n . r < 0`` (rays above the horizon never
do). Pixels above the horizon, or farther than the backdrop, get the backdrop: z-depth
``backdrop_distance_m`` with normal (0, 0, 1).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError

DEFAULT_BACKDROP_M = 10.0
_KEYS = {"proxy", "camera_height", "camera_height_m", "pitch_deg", "horizon_row", "roll_deg",
         "backdrop_distance", "backdrop_distance_m"}
GROUND_PLANE_KEYS = frozenset(_KEYS)  # the manifest keys of a ground-plane description


@dataclass(frozen=True)
class GroundPlaneSpec:
    """What the user tells about the scene: camera height above the support plane (m),
    its pitch (degrees, negative = looking down) **or** the image row of the horizon
    (pixels from the top, may lie outside the image), roll (degrees, positive turns the
    camera counter-clockwise, so the horizon drops on the right) and the backdrop distance."""

    camera_height_m: float
    pitch_deg: float | None = None
    horizon_row: float | None = None
    roll_deg: float = 0.0
    backdrop_distance_m: float = DEFAULT_BACKDROP_M

    def __post_init__(self):
        h = self.camera_height_m
        if not (isinstance(h, (int, float)) and math.isfinite(h) and h > 0):
            raise InputError(f"ground plane: camera_height must be a positive number of metres, got {h!r}")
        if (self.pitch_deg is None) == (self.horizon_row is None):
            raise InputError("ground plane: give exactly one of pitch_deg or horizon_row")
        if self.pitch_deg is not None and not (-89.0 <= float(self.pitch_deg) <= 89.0):
            raise InputError(f"ground plane: pitch_deg must lie in [-89, 89], got {self.pitch_deg!r}")
        if self.horizon_row is not None and not math.isfinite(float(self.horizon_row)):
            raise InputError(f"ground plane: horizon_row must be finite, got {self.horizon_row!r}")
        if not (math.isfinite(self.roll_deg) and abs(self.roll_deg) < 45.0):
            raise InputError(f"ground plane: roll_deg must lie in (-45, 45), got {self.roll_deg!r}")
        b = self.backdrop_distance_m
        if not (math.isfinite(b) and b > 0):
            raise InputError(f"ground plane: backdrop_distance must be positive, got {b!r}")

    @classmethod
    def from_dict(cls, d: dict) -> "GroundPlaneSpec":
        """Parse a manifest line such as ``{proxy: ground_plane, camera_height: 1.5,
        pitch_deg: -10}`` (``_m`` suffixes accepted). Unknown keys are errors."""
        if not isinstance(d, dict):
            raise InputError(f"ground plane: expected a mapping, got {d!r}")
        extra = set(d) - _KEYS - {"model", "output", "median_depth", "median_depth_m"}
        if extra:
            raise InputError(f"ground plane: unknown keys {sorted(extra)}; allowed: {sorted(_KEYS)}")

        def num(*names, default=None):
            for n in names:
                if n in d and d[n] is not None:
                    try:
                        return float(d[n])
                    except (TypeError, ValueError):
                        raise InputError(f"ground plane: {n} must be a number, got {d[n]!r}") from None
            return default

        h = num("camera_height", "camera_height_m")
        if h is None:
            raise InputError("ground plane: camera_height (metres above the floor) is required")
        return cls(camera_height_m=h, pitch_deg=num("pitch_deg"), horizon_row=num("horizon_row"),
                   roll_deg=num("roll_deg", default=0.0),
                   backdrop_distance_m=num("backdrop_distance", "backdrop_distance_m",
                                           default=DEFAULT_BACKDROP_M))

    def to_dict(self) -> dict:
        return asdict(self)


def has_ground_plane_keys(d: dict | None) -> bool:
    return isinstance(d, dict) and ("camera_height" in d or "camera_height_m" in d)


def pitch_from_horizon(camera: Camera, horizon_row: float) -> float:
    """Pitch (degrees) that puts the horizon at image row ``horizon_row`` (roll 0): the
    horizon is where the ray is horizontal, ``v = cy + fy * tan(pitch)``."""
    return math.degrees(math.atan((float(horizon_row) - camera.cy) / camera.fy))


def floor_normal(camera: Camera, spec: GroundPlaneSpec) -> np.ndarray:
    """The floor's up normal in the camera frame, (3,) float64 unit."""
    from zcomp_cli.worldframe import up_from_pitch_roll

    pitch = spec.pitch_deg if spec.pitch_deg is not None else pitch_from_horizon(camera, spec.horizon_row)
    return up_from_pitch_roll(pitch, spec.roll_deg)


def ground_plane_depth(camera: Camera, spec: GroundPlaneSpec) -> tuple[np.ndarray, np.ndarray]:
    """Depth and normals of the ground-plane + backdrop proxy.

    Returns:
        depth: (H, W) float32 z-depth in metres, all > 0 (floor or backdrop).
        normals: (H, W, 3) float32 camera-frame unit normals: the floor normal on the
            floor, (0, 0, 1) on the backdrop.
    """
    if not isinstance(spec, GroundPlaneSpec):
        spec = GroundPlaneSpec.from_dict(spec)
    n = floor_normal(camera, spec)
    rays = camera.pixel_rays()  # z = -1, so the ray parameter is the z-depth
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(nr < -1e-12, -spec.camera_height_m / nr, np.inf)
    floor = t < spec.backdrop_distance_m
    depth = np.where(floor, t, spec.backdrop_distance_m).astype(np.float32)
    normals = np.empty(depth.shape + (3,), np.float32)
    normals[:] = (0.0, 0.0, 1.0)
    normals[floor] = n.astype(np.float32)
    return depth, normals


def floor_mask(camera: Camera, spec: GroundPlaneSpec) -> np.ndarray:
    """(H, W) bool: pixels whose proxy depth is the floor (not the backdrop)."""
    d, _ = ground_plane_depth(camera, spec)
    return d < spec.backdrop_distance_m * (1 - 1e-6)
