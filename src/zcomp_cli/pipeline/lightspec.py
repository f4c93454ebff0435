"""A scene's known lighting, from the manifest's ``light:`` (then nothing is estimated).

    scenes:
      kitchen:
        image: kitchen.png
        light:                          # a directional light (a sun, a distant lamp)
          direction: [0.4, 0.8, 0.3]    # camera frame, toward the light (x right, y up, z to the viewer)
          # or, relative to the support plane and the image axes:
          # azimuth_deg: 135            # in the support plane: 0 = image right, 90 = away from the camera
          # elevation_deg: 40           # above the support plane
          angular_radius_deg: 2         # half the light's angular size (penumbra); default 1
          strength: 3.0                 # direct / ambient irradiance on a surface facing the light; default 2;
                                        # "auto": measured from the photo's shadows (and
                                        # the angular radius too, unless given)

        light:                          # or several directional lights (two lamps), each
          - {azimuth_deg: 30, elevation_deg: 45, strength: 3}   # with its own shadow;
          - {azimuth_deg: 150, elevation_deg: 60, strength: 1}  # strengths all numbers or all "auto"

        light:                          # or an HDR light probe
          type: probe
          hdr: studio.exr               # equirectangular, linear (EXR/HDR); +Y up, the
          rotation_deg: 90              # centre column looks along the camera's -z; turned
                                        # about the vertical by rotation_deg

The overall level is fitted to the photograph's known shading; the strength fixes how
dark the shadows are (shadow / lit = 1 / (1 + strength * cos)). Validation problems are
reported with the field and the manifest line.
"""

from __future__ import annotations

import math

LIGHT_KEYS = {"type", "direction", "azimuth_deg", "elevation_deg", "angular_radius_deg", "strength"}
PROBE_KEYS = {"type", "hdr", "rotation_deg"}
PROBE_EXTS = {".exr", ".hdr"}
DEFAULT_ANGULAR_RADIUS_DEG = 1.0
DEFAULT_STRENGTH = 2.0
MAX_LIGHTS = 3


def _num(v):
    if isinstance(v, bool):
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _parse_probe(value, where, add, resolve) -> dict | None:
    ok = True
    for k in value:
        if k not in PROBE_KEYS:
            add(value, k, f"{where}.{k}", f"unknown key {k!r} for a probe (known: {', '.join(sorted(PROBE_KEYS))})")
            ok = False
    out = {"type": "probe", "hdr": None, "rotation_deg": 0.0}
    if "hdr" not in value:
        add(value, None, where, "a probe needs 'hdr' (an equirectangular EXR/HDR file)")
        ok = False
    elif resolve is not None:
        p = resolve(value, "hdr", f"{where}.hdr")
        ok = ok and p is not None
        out["hdr"] = None if p is None else str(p)
    else:
        out["hdr"] = str(value["hdr"])
    if "rotation_deg" in value:
        v = _num(value["rotation_deg"])
        if v is None or not (-360.0 <= v <= 360.0):
            add(value, "rotation_deg", f"{where}.rotation_deg", f"expected degrees in [-360, 360], got {value['rotation_deg']!r}")
            ok = False
        else:
            out["rotation_deg"] = v
    return out if ok else None


def _parse_list(value, where, add, resolve) -> dict | None:
    if not 1 <= len(value) <= MAX_LIGHTS:
        add(None, None, where, f"expected 1 to {MAX_LIGHTS} directional lights, got {len(value)}")
        return None
    items = []
    for i, v in enumerate(value):
        if isinstance(v, list):  # no nesting: parse_light would read it as another list
            add(None, None, f"{where}[{i}]", "expected a mapping, got a list")
            items.append(None)
        elif isinstance(v, dict) and v.get("type") == "probe":
            add(v, "type", f"{where}[{i}].type", "a list of lights holds directional lights only "
                                                 "(a probe is the scene's whole light)")
            items.append(None)
        else:
            items.append(parse_light(v, f"{where}[{i}]", add, resolve))
    if any(x is None for x in items):
        return None
    autos = [x["strength"] == "auto" for x in items]
    if any(autos) and not all(autos):
        add(None, None, where, "strengths must be all numbers or all 'auto' (measured from the photo)")
        return None
    return items[0] if len(items) == 1 else {"type": "lights", "lights": items}


def parse_light(value, where: str, add, resolve=None) -> dict | None:
    """Validate a scene's ``light`` mapping.

    Args:
        value: the YAML value.
        where: its location for messages (``scenes.kitchen.light``).
        add: ``add(container, key, where, message)`` records a problem (the manifest's
            located-problem collector: it adds the file and line).
        resolve: ``resolve(container, key, where) -> Path | None`` checks a file field
            (the probe's ``hdr``) relative to the manifest.
    Returns:
        ``{"type": "directional", "direction": [x, y, z] | None, "azimuth_deg",
        "elevation_deg", "angular_radius_deg", "strength"}``, ``{"type": "probe", ...}``,
        ``{"type": "lights", "lights": [directional, ...]}`` for a list of two or more,
        or None when invalid.
    """
    if isinstance(value, list):
        return _parse_list(value, where, add, resolve)
    if not isinstance(value, dict):
        add(None, None, where, f"expected a mapping (direction or azimuth_deg/elevation_deg, "
                               f"angular_radius_deg, strength), got {type(value).__name__}")
        return None
    if value.get("type") == "probe":
        return _parse_probe(value, where, add, resolve)
    ok = True
    for k in value:
        if k not in LIGHT_KEYS:
            add(value, k, f"{where}.{k}", f"unknown key {k!r} (known: {', '.join(sorted(LIGHT_KEYS))})")
            ok = False
    kind = value.get("type", "directional")
    if kind != "directional":
        add(value, "type", f"{where}.type", f"unsupported light type {kind!r} (supported: directional, probe)")
        ok = False
    out = {"type": "directional", "direction": None, "azimuth_deg": None, "elevation_deg": None,
           "angular_radius_deg": DEFAULT_ANGULAR_RADIUS_DEG, "strength": DEFAULT_STRENGTH}
    has_dir = "direction" in value
    has_angles = "azimuth_deg" in value or "elevation_deg" in value
    if has_dir == has_angles:
        add(value, None, where, "give either 'direction' or both 'azimuth_deg' and 'elevation_deg'")
        ok = False
    if has_dir:
        d = value["direction"]
        vals = [_num(x) for x in d] if isinstance(d, (list, tuple)) else []
        if len(vals) != 3 or any(v is None for v in vals) or math.hypot(*vals) < 1e-9:
            add(value, "direction", f"{where}.direction", f"expected 3 finite numbers, not all 0, got {d!r}")
            ok = False
        else:
            n = math.sqrt(sum(v * v for v in vals))
            out["direction"] = [v / n for v in vals]
    if has_angles:
        for k, lo, hi in (("azimuth_deg", -360.0, 360.0), ("elevation_deg", 0.0, 90.0)):
            v = _num(value.get(k))
            if k not in value or v is None or not (lo <= v <= hi):
                add(value, k if k in value else None, f"{where}.{k}",
                    f"expected degrees in [{lo:g}, {hi:g}], got {value.get(k)!r}")
                ok = False
            else:
                out[k] = v
    if value.get("strength") == "auto":
        out["strength"] = "auto"
        out["angular_radius_deg"] = None  # measured too, unless given
    for k, lo, hi in (("angular_radius_deg", 0.0, 45.0), ("strength", 0.0, 1e3)):
        if k in value and value[k] != "auto":
            v = _num(value[k])
            if v is None or not (lo <= v <= hi):
                add(value, k, f"{where}.{k}", f"expected a number in [{lo:g}, {hi:g}]"
                    + (" or 'auto'" if k == "strength" else "") + f", got {value[k]!r}")
                ok = False
            else:
                out[k] = v
    return out if ok else None
