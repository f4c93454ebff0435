"""SpotLight's ``<case>_light_path_dto.json`` -> manifest lamps.

The file holds ``{"light_frames": [{"name": ..., "blender_light_xyz_position_object_space":
[x, y, z]}, ...]}`` (``src/spotlight/main_generate_shadows.py`` reads exactly these two
keys). A frame named ``gt_dir`` is the ground truth's light direction (its shadow is
``shadow_positive_gt_dir.png``); the others are the light path SpotLight relights along.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.datasets.lvsn import SPOTLIGHT_LIGHT_DISTANCE_M, SPOTLIGHT_LIGHT_RADIUS_M, spotlight_light_to_camera
from zcomp_cli.errors import InputError

GT_FRAME = "gt_dir"
LIGHT_CHOICES = ("gt", "all", "none")


@dataclass(frozen=True)
class LightFrame:
    name: str
    position_object_space: tuple[float, float, float]


def read_light_frames(path) -> list[LightFrame]:
    """The frames of a light path file; InputError naming the file and the field."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"cannot read the light path: {exc}", where=str(path)) from exc
    frames = data.get("light_frames") if isinstance(data, dict) else None
    if not isinstance(frames, list) or not frames:
        raise InputError("expected a non-empty list 'light_frames'", where=str(path))
    out: list[LightFrame] = []
    for i, f in enumerate(frames):
        key = "blender_light_xyz_position_object_space"
        if not isinstance(f, dict) or "name" not in f or key not in f:
            raise InputError(f"light_frames[{i}]: expected 'name' and '{key}'", where=str(path))
        v = f[key]
        if (not isinstance(v, list) or len(v) != 3
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
            raise InputError(f"light_frames[{i}].{key}: expected 3 finite numbers, got {v!r}"[:300], where=str(path))
        name = str(f["name"])
        if any(o.name == name for o in out):
            raise InputError(f"light_frames[{i}]: the frame name {name!r} repeats", where=str(path))
        out.append(LightFrame(name, (float(v[0]), float(v[1]), float(v[2]))))
    return out


def select_frames(frames: list[LightFrame], choice: str, where: str) -> list[LightFrame]:
    """``gt``: the ``gt_dir`` frame (InputError naming the frames there are when it is
    missing); ``all``: every frame; ``none``: none."""
    if choice == "none":
        return []
    if choice == "all":
        return list(frames)
    gt = [f for f in frames if f.name == GT_FRAME]
    if not gt:
        shown = ", ".join(f.name for f in frames[:8]) + (" ..." if len(frames) > 8 else "")
        raise InputError(f"no light frame named {GT_FRAME!r} (the ground truth's light; frames: {shown}); "
                         "--lights all imports every frame, --lights none none", where=where)
    return gt


def lamp_entry(frame: LightFrame, centre_cam) -> dict:
    """The manifest lamp of one frame: camera-frame position (metres), SpotLight's lamp
    radius, and power measured from the photo (SpotLight gives none: its lamps only cast
    the guiding shadow)."""
    p = spotlight_light_to_camera(frame.position_object_space, centre_cam, SPOTLIGHT_LIGHT_DISTANCE_M)
    return {"type": "lamp", "position": [round(float(x), 6) for x in p],
            "radius_m": SPOTLIGHT_LIGHT_RADIUS_M, "power": "auto"}


def aligned_centre(centre, alignment) -> np.ndarray:
    """The object centre moved along its camera ray as zcomp's footprint alignment moves
    the object (z-depth ``a z + b``), so that the lamp keeps its place relative to the
    object the renderer draws. Unchanged when the alignment gives no positive depth."""
    c = np.asarray(centre, np.float64)
    z = -c[2]
    z2 = alignment.a * z + alignment.b
    if z <= 0 or not np.isfinite(z2) or z2 <= 0:
        return c
    return c * (z2 / z)
