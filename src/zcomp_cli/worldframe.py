"""The world's frame seen from the camera: gravity (up) and the ground's forward axis.

zcomp works in the camera frame (DESIGN.md section 3: x right, y up, z toward the
viewer; the camera looks along -z). A light given "in the world" -- an HDR probe, a sun
at an azimuth and elevation -- needs gravity: world up expressed in the camera frame.
zcomp gets it from the camera's pitch and roll, given by the user or read off the scene's
support plane (the dominant upward normal of the known geometry, DESIGN.md section 8).

The **ground frame** ``(right, up, forward)`` (three camera-frame unit vectors, a
right-handed basis with ``right = forward x up``): ``up`` is gravity's opposite,
``forward`` the camera's viewing direction (-z) projected on the ground, ``right`` the
camera's right on the ground. A camera looking straight down or up has no forward
direction on the ground; its image's up (+y) projected on the ground stands in for it.

Angles on the ground (``direction_from_angles``): azimuth 0 = the camera's right, 90 =
forward (away from the camera), 180 = left, 270 = toward the camera; elevation above the
ground.
"""

from __future__ import annotations

import math

import numpy as np

# Camera axes in the camera frame.
CAMERA_FORWARD = np.array([0.0, 0.0, -1.0])
CAMERA_UP = np.array([0.0, 1.0, 0.0])


def up_from_pitch_roll(pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """World up in the camera frame of a camera pitched by ``pitch_deg`` (negative =
    looking down) and rolled by ``roll_deg`` about its optical axis (positive turns the
    camera counter-clockwise, so the horizon drops on the right).

    ``up = Rz(-roll) @ (0, cos p, -sin p)``: looking down (p < 0) tilts world up toward
    the viewer (+z). Returns (3,) float64 unit vector.
    """
    p, r = math.radians(float(pitch_deg)), math.radians(float(roll_deg))
    v = np.array([0.0, math.cos(p), -math.sin(p)])
    c, s = math.cos(-r), math.sin(-r)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])


def pitch_roll_from_up(up) -> tuple[float, float]:
    """Inverse of ``up_from_pitch_roll``: (pitch_deg, roll_deg) of a camera-frame up."""
    u = _unit(up)
    pitch = -math.degrees(math.asin(float(np.clip(u[2], -1.0, 1.0))))
    roll = math.degrees(math.atan2(float(u[0]), float(u[1])))
    return pitch, roll


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not (n > 1e-12 and math.isfinite(n)):
        raise ValueError(f"expected a finite non-zero 3-vector, got {v.tolist()}")
    return v / n


def ground_frame(up) -> np.ndarray:
    """(3, 3) rows ``right, up, forward`` of the ground frame (camera-frame unit vectors)
    for a camera-frame ``up``; see the module docstring."""
    u = _unit(up)
    f = CAMERA_FORWARD - u * float(CAMERA_FORWARD @ u)
    if np.linalg.norm(f) < 1e-6:  # looking straight down or up: the image's up instead
        f = CAMERA_UP - u * float(CAMERA_UP @ u)
        if float(CAMERA_FORWARD @ u) > 0:  # looking up: the image's top is behind
            f = -f
    f = f / np.linalg.norm(f)
    r = np.cross(f, u)
    return np.stack([r, u, f])


def direction_from_angles(azimuth_deg: float, elevation_deg: float, up) -> np.ndarray:
    """Camera-frame unit vector toward a light at ``azimuth_deg`` on the ground (0 =
    the camera's right, 90 = forward) and ``elevation_deg`` above the ground."""
    right, u, fwd = ground_frame(up)
    a, e = math.radians(float(azimuth_deg)), math.radians(float(elevation_deg))
    d = math.cos(e) * (math.cos(a) * right + math.sin(a) * fwd) + math.sin(e) * u
    return d / np.linalg.norm(d)


def angles_from_direction(direction, up) -> tuple[float, float]:
    """Inverse of ``direction_from_angles``: (azimuth_deg in [0, 360), elevation_deg)."""
    right, u, fwd = ground_frame(up)
    d = _unit(direction)
    el = math.degrees(math.asin(float(np.clip(d @ u, -1.0, 1.0))))
    az = math.degrees(math.atan2(float(d @ fwd), float(d @ right))) % 360.0
    return az, el


__all__ = ["up_from_pitch_roll", "pitch_roll_from_up", "ground_frame", "direction_from_angles",
           "angles_from_direction"]
