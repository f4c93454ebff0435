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
from zcomp_cli.limits import MAX_NAME_LEN, shorten

GT_FRAME = "gt_dir"
LIGHT_CHOICES = ("gt", "all", "none")
# SpotLight's light path files hold tens of frames of about 100 bytes; 32 MiB is some
# 300 000 frames, far past any light path, and bounds what one case's file may cost.
MAX_LIGHT_FILE_BYTES = 32 * 1024 * 1024
_POSITION_KEY = "blender_light_xyz_position_object_space"


@dataclass(frozen=True)
class LightFrame:
    name: str
    position_object_space: tuple[float, float, float]


def read_light_frames(path) -> list[LightFrame]:
    """The frames of a light path file; InputError naming the file and the field (a
    file over MAX_LIGHT_FILE_BYTES, nested past the parser's depth, a number too large
    for a float, a repeated frame name)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_LIGHT_FILE_BYTES:
            raise InputError(f"the light path file is {size:,} bytes; a light path holds at most "
                             f"{MAX_LIGHT_FILE_BYTES:,}", where=str(path))
        data = json.loads(path.read_bytes())
    except RecursionError:
        raise InputError("cannot read the light path: JSON nested deeper than the parser allows",
                         where=str(path)) from None
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise InputError(f"cannot read the light path: {exc}"[:300], where=str(path)) from exc
    frames = data.get("light_frames") if isinstance(data, dict) else None
    if not isinstance(frames, list) or not frames:
        raise InputError("expected a non-empty list 'light_frames'", where=str(path))
    out: list[LightFrame] = []
    seen: set[str] = set()
    for i, f in enumerate(frames):
        if not isinstance(f, dict) or "name" not in f or _POSITION_KEY not in f:
            raise InputError(f"light_frames[{i}]: expected 'name' and '{_POSITION_KEY}'", where=str(path))
        xyz = _finite_triple(f[_POSITION_KEY])
        if xyz is None:
            raise InputError(f"light_frames[{i}].{_POSITION_KEY}: expected 3 finite numbers, got "
                             f"{shorten(f[_POSITION_KEY])}", where=str(path))
        name = f["name"]
        if isinstance(name, int) and not isinstance(name, bool) and name.bit_length() <= 64:
            name = str(name)
        if not isinstance(name, str) or not name or len(name) > MAX_NAME_LEN:
            raise InputError(f"light_frames[{i}].name: expected a frame name of at most {MAX_NAME_LEN} "
                             f"characters, got {shorten(name)}", where=str(path))
        if name in seen:  # a set: a 40 000-frame file took 64 s with a scan per frame
            raise InputError(f"light_frames[{i}]: the frame name {shorten(name)} repeats", where=str(path))
        seen.add(name)
        out.append(LightFrame(name, xyz))
    return out


def _finite_triple(v) -> tuple[float, float, float] | None:
    """Three finite floats from a JSON list, else None (a 400-digit integer does not fit
    a float: OverflowError, caught here)."""
    if not isinstance(v, list) or len(v) != 3:
        return None
    try:
        xyz = tuple(float(x) for x in v if isinstance(x, (int, float)) and not isinstance(x, bool))
    except OverflowError:
        return None
    return xyz if len(xyz) == 3 and all(math.isfinite(x) for x in xyz) else None


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
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is said below
        p = spotlight_light_to_camera(frame.position_object_space, centre_cam, SPOTLIGHT_LIGHT_DISTANCE_M)
    if not np.isfinite(p).all():
        raise InputError(f"light frame {frame.name!r}: the lamp lands at {p.tolist()} (its position "
                         f"{list(frame.position_object_space)} times {SPOTLIGHT_LIGHT_DISTANCE_M:g} m overflows)")
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
