"""A fitted light written in the manifest's own ``light:`` syntax, to be read, edited and
given back (DESIGN.md section 5).

``light_document`` turns a fitted light's filled tree (``FittedLight.params``) into the
keys of a scene (``light``, ``pitch_deg``, ``roll_deg``, ``exposure``), in the world
frame where the manifest takes one (a sun's azimuth and elevation on the ground, the
sky's SH in the ground frame), each light with where its values came from (``from``).
Every strength is written in the lights' physical units at exposure 1 (the photograph's
exposure folded in), so the file stands alone. ``light_yaml`` is that document as YAML
text (JSON flow: every float written exactly), ``write_light_yaml`` writes it
atomically. Given back -- ``light: OUT/lights/<scene>.yaml`` in the scene, or its keys
pasted in -- with everything frozen, it reproduces the composite to within float
rounding; edited (a sun turned by 30 deg), the composite follows.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from zcomp_cli.scene.lightparams import LightParams, Origin, Param

# The steepest camera pitch the manifest takes (``lightspec.parse_tilt``): a camera looking
# straight down has no pitch to write, and its world up is read off the support again.
MAX_PITCH_DEG = 89.0
HEADER = """# The fitted light of scene {scene!r}, written by zcomp {version} in the manifest's light:
# syntax (docs/lights.md, "A fitted light, given back"): suns by azimuth and elevation on
# the ground (0 = the camera's right, 90 = forward), lamps in the camera frame (metres),
# the sky's radiance as order-2 SH in the ground frame (x right, y up, z forward), every
# strength in the lights' physical units at exposure 1. 'from' says where each value came
# from. Give it back as the scene's `light: {path}`, or paste these keys into the
# scene; edit a value to change the light.
"""


def _rgb_split(rgb) -> tuple[float, list[float] | None]:
    """(a strength, its colour multiplier or None for white) of an RGB strength."""
    v = np.asarray(rgb, np.float64).reshape(-1)
    if v.size == 1:
        return float(v[0]), None
    top = float(v.max())
    if top <= 0:
        return 0.0, None
    col = (v / top).tolist()
    return top, None if all(c == 1.0 for c in col) else col


def _from(**params: Param) -> dict:
    return {k: p.origin.code for k, p in params.items() if p is not None}


def light_document(params: LightParams, up, up_from: Origin, *, relative_to: Path | None = None) -> dict:
    """The scene keys of a filled tree (module docstring): ``{"pitch_deg", "roll_deg",
    "exposure", "light": [...]}``; ``up`` (3,) world up (camera frame) its angles are
    measured against, ``up_from`` where it came from; a probe's path relative to
    ``relative_to`` (the file's folder) where given."""
    from zcomp_cli.worldframe import angles_from_direction, pitch_roll_from_up

    up = np.asarray(up, np.float64)
    e = params.exposure.value
    k = float(e) if (e is not None and math.isfinite(float(e)) and float(e) > 0) else 1.0
    lights: list[dict] = []
    if params.probe is not None:
        d = params.probe.to_dict()
        key = "image" if d["type"] == "chrome_ball" else "hdr"
        if relative_to is not None:
            d[key] = os.path.relpath(d[key], relative_to)
        d["strength"] = float(d["strength"]) * k
        lights.append(d)
    for s in params.suns:
        if s.direction.value is None and s.angles is None:
            continue  # a light the fit could not place
        direction = s.direction.value if s.direction.value is not None else None
        if direction is not None:
            az, el = angles_from_direction(np.asarray(direction, np.float64), up)
        else:
            az, el = s.angles
        irr, col = _rgb_split(np.asarray(s.irradiance.value, np.float64) * np.asarray(s.color) * k)
        entry = {"type": "sun", "azimuth_deg": float(az), "elevation_deg": float(el),
                 "angular_radius_deg": float(s.radius_deg.value), "irradiance": irr}
        if col is not None:
            entry["color"] = col
        entry["from"] = {"direction": (s.direction.origin if s.direction.value is not None else s.angles_from).code,
                         **_from(angular_radius_deg=s.radius_deg, irradiance=s.irradiance)}
        lights.append(entry)
    for lp in params.lamps:
        power, col = _rgb_split(np.asarray(lp.power.value, np.float64) * np.asarray(lp.color) * k)
        entry = {"type": "lamp", "position": [float(x) for x in lp.position.value],
                 "radius_m": float(lp.radius_m.value), "power": power}
        if lp.facing is not None:
            entry["facing"] = [float(x) for x in lp.facing]
        if col is not None:
            entry["color"] = col
        entry["from"] = _from(position=lp.position, radius_m=lp.radius_m, power=lp.power)
        lights.append(entry)
    if params.probe is None and params.sky.radiance_sh.value is not None:
        sky = params.sky
        entry = {"type": "sky", "radiance_sh": (np.asarray(sky.radiance_sh.value, np.float64) * k).tolist()}
        if sky.ground.value is not None:
            entry["ground"] = [float(x) for x in sky.ground.value]
        entry["from"] = _from(radiance_sh=sky.radiance_sh, ground=sky.ground if sky.ground.value is not None else None)
        lights.append(entry)
    pitch, roll = pitch_roll_from_up(up)
    doc = {"pitch_deg": float(pitch), "roll_deg": float(roll), "exposure": 1.0, "light": lights, "_up_from": up_from}
    if not abs(doc["pitch_deg"]) <= MAX_PITCH_DEG:  # (the manifest's range: world up read off the support again)
        doc.pop("pitch_deg")
        doc.pop("roll_deg")
    return doc


def light_yaml(doc: dict, scene: str, path: str = "OUT/lights/<scene>.yaml") -> str:
    """The document as YAML text: JSON flow values (every float exactly), a comment on
    world up's origin."""
    from zcomp_cli import __version__

    up_from = doc.get("_up_from")
    lines = [HEADER.format(scene=scene, version=__version__, path=path).rstrip()]
    tail = f"  # world up {up_from}" if up_from is not None else ""
    if "pitch_deg" in doc:
        lines.append(f"pitch_deg: {json.dumps(doc['pitch_deg'])}{tail}")
        lines.append(f"roll_deg: {json.dumps(doc['roll_deg'])}")
    lines.append(f"exposure: {json.dumps(doc['exposure'])}")
    lines.append("light:")
    for entry in doc["light"]:
        lines.append(f"  - {json.dumps(entry)}")
    if not doc["light"]:
        lines[-1] = "light: []"
    return "\n".join(lines) + "\n"


def write_light_yaml(path, fitted, scene: str) -> None:
    """``fitted`` (``stage.FittedLight``) as ``path``, atomically (module docstring)."""
    from zcomp_cli.imageio import write_text_atomic

    path = Path(path)
    doc = light_document(fitted.params, fitted.model.up, fitted.model.up_from, relative_to=path.parent)
    write_text_atomic(path, light_yaml(doc, scene, str(path)))


__all__ = ["light_document", "light_yaml", "write_light_yaml"]
