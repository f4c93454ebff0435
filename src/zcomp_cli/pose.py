"""Object poses in the camera frame (DESIGN.md section 3).

A mesh is in metres with +Y up (glTF convention; OBJ, PLY and STL are read as Y-up too).
Placement uses the mesh's axis-aligned bounding box, so the mesh origin can be anywhere:

1. the mesh is moved so that its **base point** -- the centre of the bounding box's
   bottom face, ``(cx, min_y, cz)`` -- is at the origin;
2. it is scaled uniformly: by ``height / (max_y - min_y)`` when ``height`` is given
   (so its vertical extent becomes ``height`` metres), else by ``scale``;
3. it is rotated about the base point by ``rotation`` (a camera-frame rotation);
4. the base point is moved to ``position`` (camera frame, metres; the camera looks along
   -z, so an object in front of it has z < 0).

So ``p_cam = R @ (s * (p_mesh - base)) + position``.

Rotation as ``rotation_deg: [rx, ry, rz]``: rotations about the camera's x, then y, then
z axes (fixed axes), i.e. ``R = Rz @ Ry @ Rx``; or ``quaternion: [w, x, y, z]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.errors import GeometryError, ManifestError


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


def euler_deg_to_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation about fixed x, then y, then z axes (degrees): ``Rz @ Ry @ Rx``."""
    return _rot_z(math.radians(rz)) @ _rot_y(math.radians(ry)) @ _rot_x(math.radians(rx))


def quaternion_to_matrix(q) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` (normalised here) -> 3x3 rotation matrix."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError("quaternion must be non-zero and finite")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(R) -> np.ndarray:
    """3x3 rotation -> unit quaternion ``[w, x, y, z]`` with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rotation_aligning(a, b) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` to unit vector ``b`` (3x3)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: rotate 180 degrees about any axis orthogonal to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


@dataclass(frozen=True)
class Pose:
    """Object pose in the camera frame. See the module docstring for the semantics."""

    position: tuple[float, float, float]
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    scale: float = 1.0
    height: float | None = None

    def __post_init__(self):
        pos = tuple(float(v) for v in self.position)
        R = np.asarray(self.rotation, dtype=np.float64)
        if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
            raise ValueError(f"position must be 3 finite numbers, got {self.position}")
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError("rotation must be a finite 3x3 matrix")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise ValueError("rotation must be a proper rotation matrix")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be > 0, got {self.scale}")
        if self.height is not None and not (math.isfinite(self.height) and self.height > 0):
            raise ValueError(f"height must be > 0 metres, got {self.height}")
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "scale", float(self.scale))

    # -- parsing ---------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict, *, where: str = "pose") -> "Pose":
        """Parse ``{position, rotation_deg | quaternion, scale, height}``; errors name
        ``where`` and the key."""
        from zcomp_cli.limits import shorten, type_name

        if not isinstance(d, dict):
            raise ManifestError(f"{where}: expected a mapping, got {type_name(d)} {shorten(d)}")
        known = {"position", "rotation_deg", "quaternion", "scale", "height"}
        problems = [f"{where}.{k}: unknown key (expected one of {sorted(known)})" for k in d if k not in known]
        if "position" not in d:
            problems.append(f"{where}.position: required")
        if "rotation_deg" in d and "quaternion" in d:
            problems.append(f"{where}: give rotation_deg or quaternion, not both")
        if problems:
            raise ManifestError(problems)
        # Each value is checked on its own so that every problem is reported, each
        # naming its own key (and no message repeats the prefix).
        position = R = scale = height = None
        try:
            position = _vec(d["position"], 3, f"{where}.position")
        except ValueError as exc:
            problems.append(str(exc))
        try:
            if "quaternion" in d:
                q = _vec(d["quaternion"], 4, f"{where}.quaternion")
                try:
                    R = quaternion_to_matrix(q)
                except ValueError as exc:
                    raise ValueError(f"{where}.quaternion: {exc}") from None
            else:
                R = euler_deg_to_matrix(*_vec(d.get("rotation_deg", [0, 0, 0]), 3, f"{where}.rotation_deg"))
        except ValueError as exc:
            problems.append(str(exc))
        for key in ("scale", "height"):
            v = d.get(key)
            if v is None:
                continue
            if not _is_number(v) or not (math.isfinite(float(v)) and float(v) > 0):
                what = "metres > 0" if key == "height" else "a number > 0"
                problems.append(f"{where}.{key}: expected {what}, got {shorten(v)}")
            elif key == "scale":
                scale = float(v)
            else:
                height = float(v)
        if problems:
            raise ManifestError(problems)
        try:
            return cls(position=tuple(position), rotation=R, scale=1.0 if scale is None else scale,
                       height=height)
        except ValueError as exc:
            raise ManifestError(f"{where}: {exc}") from exc

    def to_dict(self) -> dict:
        d = {
            "position": list(self.position),
            "quaternion": matrix_to_quaternion(self.rotation).tolist(),
            "scale": self.scale,
        }
        if self.height is not None:
            d["height"] = self.height
        return d

    # -- geometry ----------------------------------------------------------------------
    def uniform_scale(self, bbox_min, bbox_max) -> float:
        """The uniform scale applied to a mesh with this bounding box."""
        if self.height is None:
            return self.scale
        extent = float(bbox_max[1] - bbox_min[1])
        if not (math.isfinite(extent) and extent > 1e-9):
            raise GeometryError("mesh has no vertical extent; cannot scale it to a height")
        return self.height / extent

    def object_to_camera(self, bbox_min, bbox_max) -> np.ndarray:
        """4x4 matrix taking mesh coordinates (Y-up, metres) to the camera frame."""
        bbox_min = np.asarray(bbox_min, dtype=np.float64)
        bbox_max = np.asarray(bbox_max, dtype=np.float64)
        base = np.array(
            [(bbox_min[0] + bbox_max[0]) / 2, bbox_min[1], (bbox_min[2] + bbox_max[2]) / 2]
        )
        s = self.uniform_scale(bbox_min, bbox_max)
        M = np.eye(4)
        M[:3, :3] = self.rotation * s
        M[:3, 3] = np.asarray(self.position) - self.rotation @ (s * base)
        return M

    @property
    def up(self) -> np.ndarray:
        """The object's up axis (mesh +Y) in the camera frame."""
        return self.rotation[:, 1].copy()


def transform_points(M, pts) -> np.ndarray:
    """Apply a 4x4 matrix to (N, 3) points."""
    pts = np.asarray(pts, dtype=np.float64)
    return pts @ M[:3, :3].T + M[:3, 3]


def _is_number(x) -> bool:
    # YAML gives bools as ints and quoted numbers as strings: neither is a number here.
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _vec(v, n: int, where: str) -> list[float]:
    from zcomp_cli.limits import shorten

    if not isinstance(v, (list, tuple)) or len(v) != n or not all(_is_number(x) for x in v):
        raise ValueError(f"{where}: expected a list of {n} numbers, got {shorten(v)}")
    out = [float(x) for x in v]
    if not all(math.isfinite(x) for x in out):
        raise ValueError(f"{where}: values must be finite, got {shorten(v)}")
    return out
