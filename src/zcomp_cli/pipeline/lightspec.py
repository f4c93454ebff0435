"""A scene's known light, from the manifest's ``light:`` (then it is not estimated).

    scenes:
      kitchen:
        image: kitchen.png
        pitch_deg: -30        # optional: the camera's pitch (negative = looking down) and
        roll_deg: 0           # roll; else world up is read off the scene's support plane
        light:                # one light, or a list: up to 8 suns and lamps, and one probe
          - type: probe                  # an equirectangular HDR probe (EXR/HDR), up = gravity
            hdr: set_probe.exr
            rotation_deg: 90             # its yaw about up (see convention)
            convention: zcomp            # zcomp | skylibs | blender | mirrored (docs/lights.md)
            strength: 1.0                # radiance multiplier (Blender's Background strength)
          - type: sun                    # a distant light ("directional" is the same)
            azimuth_deg: 135             # on the ground: 0 = the camera's right, 90 = forward
            elevation_deg: 40            # above the ground; or direction: [x, y, z] (camera frame)
            angular_radius_deg: 0.27     # its angular radius (default: the Sun's, 0.27)
            strength: auto               # auto: fitted to the photo; a number: direct over sky
                                         # irradiance on a surface facing it (no probe then)
            # irradiance: 3.0            # or W/m^2 (Blender's Sun strength), beside a probe or lamps
          # - type: chrome_ball          # or a mirror ball photographed from the camera (instead
          #   image: ball.exr            # of a probe): its centre and radius in pixels of the
          #   center: [812, 604]         # image, its reflectance (default polished chromium's
          #   radius: 140                # 0.6); an LDR photo is allowed, with a warning
          #   reflectance: 0.6
          - type: lamp                   # a light at a place
            position: [0.5, 1.2, -2.0]   # camera frame, metres (x right, y up, z to the viewer)
            radius_m: 0.03               # its radius (a sphere; default 0.03, a bulb)
            power: 60                    # watts (Blender's point lamp Power), or auto
            # facing: [0, -1, 0]         # a one-sided panel (Blender's area lamp) facing there
            # color: [1.0, 0.9, 0.8]     # linear RGB multiplier of a sun's or lamp's strength
          # - type: sky                  # the sky itself (zcomp writes it: OUT/lights/<scene>.yaml):
          #   radiance_sh: [[r, g, b], ...]  # its radiance's order-2 SH, 9 rows, in the ground
          #   ground: [r, g, b]          # frame (x right, y up, z forward); the support's radiance
        exposure: 1.0         # optional: the photograph's exposure against the lights given in
                              # physical units (default auto: fitted)
        # light: OUT/lights/kitchen.yaml  # or a file holding these keys (light, pitch_deg,
                                         # roll_deg, exposure): a light zcomp wrote, given back

Each light may say where its values came from (``from: {direction: shadows,
angular_radius_deg: prior, irradiance: fit}``, as zcomp writes them): the values are
given all the same; the words go to the reports, and a light whose direction was
estimated keeps an estimate's shadow (faded at the shading mask's edge, not grown).

Strengths: a probe's ``strength``, a sun's ``irradiance`` and a lamp's ``power`` are in
the physical units Blender uses, so they hold relative to each other, and one exposure
is fitted to the photograph for all of them together; ``auto`` fits that light's own
strength (and colour); a sun's number ``strength`` (the older form) fixes its share
against the fitted sky: shadow / lit = 1 / (1 + strength * cos).

Validation problems are reported with the field and the manifest line. ``parse_light``
returns the typed light tree (``zcomp_cli.scene.lightparams.LightParams``: what is given is
frozen, what is ``auto`` or left out is free); ``parse_tilt`` reads the scene's
``pitch_deg``/``roll_deg``; ``scene_light`` puts the two together.
"""

from __future__ import annotations

import math

from zcomp_cli.scene.lightparams import LAMP_RADIUS_M, MAX_RADIUS_DEG, SUN_RADIUS_DEG  # noqa: F401  (the defaults)

SUN_KEYS = {"type", "direction", "azimuth_deg", "elevation_deg", "angular_radius_deg", "strength",
            "irradiance", "color", "from"}
PROBE_KEYS = {"type", "hdr", "rotation_deg", "convention", "strength"}
LAMP_KEYS = {"type", "position", "radius_m", "power", "facing", "color", "from"}
BALL_KEYS = {"type", "image", "center", "radius", "reflectance", "strength"}
SKY_KEYS = {"type", "radiance_sh", "ground", "from"}
# what ``from`` may name, per kind of light (the values it says where they came from)
FROM_FIELDS = {"sun": ("direction", "angular_radius_deg", "irradiance"), "lamp": ("position", "radius_m", "power"),
               "sky": ("radiance_sh", "ground")}
# the keys of a light file (``light: OUT/lights/<scene>.yaml``), a scene's own
LIGHT_FILE_KEYS = {"light", "pitch_deg", "roll_deg", "exposure"}
# a sky's radiance: beyond this it is no photograph's (and its square overflows float32)
MAX_SKY_RADIANCE = 1e9
PROBE_EXTS = {".exr", ".hdr"}
# a mirror-ball photograph: HDR, or 8/16-bit with a warning (its sun is clipped)
BALL_EXTS = {".exr", ".hdr", ".png", ".jpg", ".jpeg", ".tif", ".tiff"}
# a ball's horizontal and vertical radii may differ by this share (a hand-placed ellipse
# on a photograph): more means the photograph is not head-on or its pixels not square
BALL_ROUND_TOL = 0.05
# The most suns and lamps a scene's light holds: a light the fit wrote (OUT/lights/) must
# read back, and a searched light is drawn as up to ``search.max_modes`` (4) of its
# posterior's modes beside the lights the manifest gives; each costs the renderers a
# light's shadow rays.
MAX_LIGHTS = 8


def _num(v):
    if isinstance(v, bool):
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _vector(value, key, where, add, *, nonzero: bool) -> list | None:
    v = value.get(key)
    vals = [_num(x) for x in v] if isinstance(v, (list, tuple)) else []
    if len(vals) != 3 or any(x is None for x in vals) or (nonzero and math.hypot(*vals) < 1e-9):
        add(value, key, f"{where}.{key}", f"expected 3 finite numbers{', not all 0' if nonzero else ''}, got {v!r}")
        return None
    if nonzero:  # scaled first: a sum of squares overflowed for 1.3e154 (the direction became 0)
        m = max(abs(x) for x in vals)
        n = math.hypot(*(x / m for x in vals))
        return [x / m / n for x in vals]
    return vals


def _number(value, key, where, add, lo, hi, *, auto=False):
    """The number at ``key`` within [lo, hi] (or "auto" when allowed); None when absent
    or invalid (a problem is added for invalid)."""
    if key not in value:
        return None
    v = value[key]
    if auto and v == "auto":
        return "auto"
    f = _num(v)
    if f is None or not (lo <= f <= hi):
        add(value, key, f"{where}.{key}", f"expected a number in [{lo:g}, {hi:g}]"
            + (" or 'auto'" if auto else "") + f", got {v!r}")
        raise _Bad
    return f


class _Bad(Exception):
    pass


def _unknown_keys(value, allowed, where, add, kind) -> bool:
    ok = True
    for k in value:
        if k not in allowed:
            add(value, k, f"{where}.{k}", f"unknown key {k!r} for a {kind} (known: {', '.join(sorted(allowed))})")
            ok = False
    return ok


# a colour is a multiplier of a light's given strength (itself bounded): beyond this it
# is a strength in disguise, and its product with one overflows float32
MAX_COLOR = 1e3


def _color(value, where, add):
    if "color" not in value:
        return None
    c = value["color"]
    vals = [_num(x) for x in c] if isinstance(c, (list, tuple)) else []
    if len(vals) != 3 or any(x is None or not (0 <= x <= MAX_COLOR) for x in vals) or not any(vals):
        add(value, "color", f"{where}.color",
            f"expected 3 numbers in [0, {MAX_COLOR:g}], not all 0 (a linear RGB multiplier), got {c!r}")
        raise _Bad
    return vals


def _parse_from(value, kind: str, where, add) -> dict | None:
    """A light's ``from``: {field: origin code} (``Origin.code``: where each value came
    from); empty when absent, None when invalid (a problem added)."""
    from zcomp_cli.scene.lightparams import Origin

    if "from" not in value:
        return {}
    f = value["from"]
    codes = [o.code for o in Origin]
    if not isinstance(f, dict):
        add(value, "from", f"{where}.from", f"expected a mapping of field: origin, got {f!r}")
        return None
    out = {}
    for k, v in f.items():
        if k not in FROM_FIELDS[kind]:
            add(f, k, f"{where}.from.{k}", f"unknown field {k!r} (a {kind} says where these came from: "
                                           f"{', '.join(FROM_FIELDS[kind])})")
            return None
        if v not in codes:
            add(f, k, f"{where}.from.{k}", f"unknown origin {v!r} (known: {', '.join(codes)})")
            return None
        out[k] = v
    return out


def _parse_sky(value, where, add) -> dict | None:
    """A fitted sky given back (``type: sky``): its radiance's order-2 SH in the ground
    frame (9 rows of RGB) and, optionally, the support's radiance seen from below."""
    ok = _unknown_keys(value, SKY_KEYS, where, add, "sky")
    out = {"type": "sky", "radiance_sh": None, "ground": None, "from": _parse_from(value, "sky", where, add)}
    rows = value.get("radiance_sh")
    vals = [[_num(x) for x in r] if isinstance(r, (list, tuple)) else [] for r in rows] \
        if isinstance(rows, (list, tuple)) else []
    if (len(vals) != 9 or any(len(r) != 3 or any(x is None or abs(x) > MAX_SKY_RADIANCE for x in r) for r in vals)):
        add(value, "radiance_sh" if "radiance_sh" in value else None, f"{where}.radiance_sh",
            f"a sky needs 'radiance_sh': 9 rows of 3 finite numbers (its radiance's order-2 SH, RGB), got "
            f"{rows!r}"[:300])
        ok = False
    else:
        out["radiance_sh"] = vals
    if "ground" in value:
        g = value["ground"]
        gv = [_num(x) for x in g] if isinstance(g, (list, tuple)) else []
        if len(gv) != 3 or any(x is None or not (0 <= x <= MAX_SKY_RADIANCE) for x in gv):
            add(value, "ground", f"{where}.ground", f"expected 3 numbers >= 0 (the support's radiance), got {g!r}")
            ok = False
        else:
            out["ground"] = gv
    return out if ok and out["from"] is not None else None


def _parse_sun(value, where, add) -> dict | None:
    ok = _unknown_keys(value, SUN_KEYS, where, add, "sun")
    out = {"type": "sun", "direction": None, "azimuth_deg": None, "elevation_deg": None,
           "angular_radius_deg": None, "strength": None, "irradiance": None, "color": None,
           "from": _parse_from(value, "sun", where, add)}
    ok = ok and out["from"] is not None
    has_dir = "direction" in value
    has_angles = "azimuth_deg" in value or "elevation_deg" in value
    if has_dir == has_angles:
        add(value, None, where, "give either 'direction' or both 'azimuth_deg' and 'elevation_deg'")
        ok = False
    if has_dir:
        out["direction"] = _vector(value, "direction", where, add, nonzero=True)
        ok = ok and out["direction"] is not None
    if has_angles:
        for k, lo, hi in (("azimuth_deg", -360.0, 360.0), ("elevation_deg", 0.0, 90.0)):
            v = _num(value.get(k))
            if k not in value or v is None or not (lo <= v <= hi):
                add(value, k if k in value else None, f"{where}.{k}",
                    f"expected degrees in [{lo:g}, {hi:g}], got {value.get(k)!r}")
                ok = False
            else:
                out[k] = v
    try:
        out["angular_radius_deg"] = _number(value, "angular_radius_deg", where, add, 0.0, MAX_RADIUS_DEG)
        out["strength"] = _number(value, "strength", where, add, 0.0, 1e3, auto=True)
        out["irradiance"] = _number(value, "irradiance", where, add, 0.0, 1e9)
        out["color"] = _color(value, where, add)
    except _Bad:
        ok = False
    if out["strength"] is not None and out["irradiance"] is not None:
        add(value, "irradiance", f"{where}.irradiance", "give strength or irradiance, not both")
        ok = False
    if out["strength"] is None and out["irradiance"] is None:
        out["strength"] = "auto"
    return out if ok else None


def _parse_probe(value, where, add, resolve) -> dict | None:
    from zcomp_cli.equirect import CONVENTIONS, DEFAULT_CONVENTION

    ok = _unknown_keys(value, PROBE_KEYS, where, add, "probe")
    out = {"type": "probe", "hdr": None, "rotation_deg": 0.0, "convention": DEFAULT_CONVENTION, "strength": 1.0}
    if "hdr" not in value:
        add(value, None, where, "a probe needs 'hdr' (an equirectangular EXR/HDR file)")
        ok = False
    elif resolve is not None:
        p = resolve(value, "hdr", f"{where}.hdr")
        ok = ok and p is not None
        out["hdr"] = None if p is None else str(p)
    else:
        out["hdr"] = str(value["hdr"])
    try:
        r = _number(value, "rotation_deg", where, add, -360.0, 360.0)
        out["rotation_deg"] = 0.0 if r is None else r
        s = _number(value, "strength", where, add, 0.0, 1e9)
        out["strength"] = 1.0 if s is None else s
    except _Bad:
        ok = False
    if "convention" in value:
        c = value["convention"]
        if c not in CONVENTIONS:
            add(value, "convention", f"{where}.convention",
                f"unknown probe convention {c!r} (known: {', '.join(CONVENTIONS)})")
            ok = False
        else:
            out["convention"] = c
    return out if ok else None


def _parse_ball(value, where, add, resolve) -> dict | None:
    """A mirror-ball photograph (``chromeball``): the image, the ball's centre and radius
    in its pixels (checked against the image's size), its reflectance, a strength."""
    from zcomp_cli.chromeball import CHROME_REFLECTANCE, check_ball

    ok = _unknown_keys(value, BALL_KEYS, where, add, "chrome_ball")
    out = {"type": "probe", "hdr": None, "rotation_deg": 0.0, "convention": "zcomp", "strength": 1.0,
           "ball_center": None, "ball_radius": None, "reflectance": CHROME_REFLECTANCE}
    c = value.get("center")
    vals = [_num(x) for x in c] if isinstance(c, (list, tuple)) else []
    if "center" not in value or len(vals) != 2 or any(x is None for x in vals):
        add(value, "center" if "center" in value else None, f"{where}.center",
            f"a chrome_ball needs 'center': [x, y], the ball's centre in pixels of its image, got {c!r}")
        ok = False
    else:
        out["ball_center"] = (vals[0], vals[1])
    r = value.get("radius")
    radii = [_num(x) for x in r] if isinstance(r, (list, tuple)) else [_num(r)]
    if "radius" not in value or len(radii) not in (1, 2) or any(x is None or x <= 0 for x in radii):
        add(value, "radius" if "radius" in value else None, f"{where}.radius",
            f"a chrome_ball needs 'radius': its radius in pixels (or [rx, ry]), got {r!r}")
        ok = False
    elif len(radii) == 2 and abs(radii[0] - radii[1]) > BALL_ROUND_TOL * max(radii):
        add(value, "radius", f"{where}.radius",
            f"the ball is not round in the photograph (radii {radii[0]:g} x {radii[1]:g} px): shoot it head-on "
            "with square pixels, or crop the photograph so that it is")
        ok = False
    else:
        out["ball_radius"] = float(sum(radii) / len(radii))
    try:
        f = _number(value, "reflectance", where, add, 1e-3, 1.0)
        if f is not None:
            out["reflectance"] = f
        s = _number(value, "strength", where, add, 0.0, 1e9)
        out["strength"] = 1.0 if s is None else s
    except _Bad:
        ok = False
    if "image" not in value:
        add(value, None, where, "a chrome_ball needs 'image' (the mirror ball's photograph)")
        return None
    p = resolve(value, "image", f"{where}.image", BALL_EXTS) if resolve is not None else value["image"]
    if p is None:
        return None
    out["hdr"] = str(p)
    if ok and resolve is not None:
        from zcomp_cli.imageio import image_header

        try:
            w, h, _ = image_header(p)
        except ValueError as exc:
            add(value, "image", f"{where}.image", f"cannot read the ball's photograph: {exc}")
            return None
        why = check_ball(w, h, out["ball_center"], out["ball_radius"])
        if why:
            add(value, "center", f"{where}.center", why)
            ok = False
    return out if ok else None


def _parse_lamp(value, where, add) -> dict | None:
    ok = _unknown_keys(value, LAMP_KEYS, where, add, "lamp")
    out = {"type": "lamp", "position": None, "radius_m": None, "power": "auto", "facing": None, "color": None,
           "from": _parse_from(value, "lamp", where, add)}
    ok = ok and out["from"] is not None
    if "position" not in value:
        add(value, None, where, "a lamp needs 'position' ([x, y, z] in the camera frame, metres)")
        ok = False
    else:
        out["position"] = _vector(value, "position", where, add, nonzero=False)
        ok = ok and out["position"] is not None
    if "facing" in value:
        out["facing"] = _vector(value, "facing", where, add, nonzero=True)
        ok = ok and out["facing"] is not None
    try:
        out["radius_m"] = _number(value, "radius_m", where, add, 0.0, 1e3)
        p = _number(value, "power", where, add, 0.0, 1e9, auto=True)
        out["power"] = "auto" if p is None else p
        out["color"] = _color(value, where, add)
    except _Bad:
        ok = False
    return out if ok else None


def _parse_one(value, where, add, resolve) -> dict | None:
    if not isinstance(value, dict):
        add(None, None, where, f"expected a mapping (a sun, a lamp or a probe), got {type(value).__name__}")
        return None
    kind = value.get("type", "sun")
    if kind in ("sun", "directional"):
        return _parse_sun(value, where, add)
    if kind == "probe":
        return _parse_probe(value, where, add, resolve)
    if kind == "lamp":
        return _parse_lamp(value, where, add)
    if kind == "chrome_ball":
        return _parse_ball(value, where, add, resolve)
    if kind == "sky":
        return _parse_sky(value, where, add)
    add(value, "type", f"{where}.type",
        f"unsupported light type {kind!r} (supported: sun, directional, lamp, probe, chrome_ball, sky)")
    return None


def parse_light(value, where: str, add, resolve=None) -> dict | None:
    """Validate a scene's ``light`` (one mapping or a list of them).

    Args:
        value: the YAML value.
        where: its location for messages (``scenes.kitchen.light``).
        add: ``add(container, key, where, message)`` records a problem (the manifest's
            located-problem collector: it adds the file and line).
        resolve: ``resolve(container, key, where) -> Path | None`` checks a file field
            (the probe's ``hdr``) relative to the manifest.
    Returns:
        ``LightParams`` (the tilt left out: ``scene_light``), or None when invalid.
    """
    items = value if isinstance(value, list) else [value]
    if isinstance(value, list) and not value:
        add(None, None, where, "expected at least one light")
        return None
    out, ok = [], True
    for i, v in enumerate(items):
        w = f"{where}[{i}]" if isinstance(value, list) else where
        if isinstance(v, list):
            add(None, None, w, "expected a mapping, got a list")
            ok = False
            continue
        x = _parse_one(v, w, add, resolve)
        ok = ok and x is not None
        out.append(x)
    if not ok:
        return None
    probes = [x for x in out if x["type"] == "probe"]
    skies = [x for x in out if x["type"] == "sky"]
    direct = [x for x in out if x["type"] not in ("probe", "sky")]
    if len(probes) > 1:
        add(None, None, where, f"at most one probe or chrome_ball, got {len(probes)}")
        return None
    if len(skies) > 1 or (skies and probes):
        add(None, None, where, "at most one sky, and none beside a probe (the probe is the sky)")
        return None
    if len(direct) > MAX_LIGHTS:
        add(None, None, where, f"at most {MAX_LIGHTS} suns and lamps (besides a probe), got {len(direct)}")
        return None
    ratio = [x for x in direct if x["type"] == "sun" and isinstance(x["strength"], float)]
    absolute = probes + skies + [x for x in direct if x.get("irradiance") is not None
                                 or (x["type"] == "lamp" and x["power"] != "auto")]
    if ratio and absolute:
        add(None, None, where, "a sun's number 'strength' is its share against the fitted sky: it cannot stand "
                               "beside a probe, an irradiance or a lamp's power (give 'irradiance' in W/m^2, "
                               "or strength: auto)")
        return None
    return to_params(out)


def to_params(lights: list, tilt: dict | None = None, exposure=None):
    """The typed tree (``LightParams``) of validated light mappings (``_parse_one``'s),
    the camera's tilt (``parse_tilt``'s) and the photograph's exposure (a number, or
    None: fitted). A value's origin is the manifest's, or what its ``from`` says."""
    from zcomp_cli.scene.lightparams import (LampParams, LightParams, Origin, Param, ProbeParams, SkyParams,
                                             SunParams, WHITE)

    def given(x, key, value):
        code = (x.get("from") or {}).get(key)
        return Param.given(value, Origin.from_code(code) if code else Origin.MANIFEST)

    suns, lamps, probe, sky = [], [], None, SkyParams()
    for x in lights:
        color = WHITE if x.get("color") is None else tuple(float(v) for v in x["color"])
        if x["type"] == "probe":
            ball = x.get("ball_center")
            probe = ProbeParams(hdr=x["hdr"], rotation_deg=float(x["rotation_deg"]), convention=x["convention"],
                                strength=float(x["strength"]),
                                ball_center=None if ball is None else tuple(float(v) for v in ball),
                                ball_radius=None if ball is None else float(x["ball_radius"]),
                                reflectance=None if ball is None else float(x["reflectance"]))
        elif x["type"] == "sky":
            g = x.get("ground")
            sky = SkyParams(radiance_sh=given(x, "radiance_sh", x["radiance_sh"]),
                            ground=given(x, "ground", g) if g is not None else Param.free())
        elif x["type"] == "sun":
            r = x["angular_radius_deg"]
            strength = x["strength"]
            d = x["direction"]
            suns.append(SunParams(
                direction=given(x, "direction", tuple(d)) if d is not None else Param.free(),
                angles=(x["azimuth_deg"], x["elevation_deg"]) if d is None else None,
                angles_from=given(x, "direction", None).origin,
                radius_deg=given(x, "angular_radius_deg", float(r)) if r is not None else Param.free(),
                irradiance=given(x, "irradiance", float(x["irradiance"])) if x["irradiance"] is not None
                else Param.free(),
                share=float(strength) if isinstance(strength, float) else None, color=color))
        else:
            lamps.append(LampParams(
                position=given(x, "position", tuple(x["position"])),
                radius_m=given(x, "radius_m", float(x["radius_m"])) if x["radius_m"] is not None else Param.free(),
                power=Param.free() if x["power"] == "auto" else given(x, "power", float(x["power"])),
                facing=None if x["facing"] is None else tuple(x["facing"]), color=color))
    tilt = tilt or {}
    return LightParams(suns=tuple(suns), lamps=tuple(lamps), probe=probe, sky=sky,
                       exposure=Param.free() if exposure is None else Param.given(float(exposure)),
                       pitch_deg=tilt.get("pitch_deg"),
                       roll_deg=tilt.get("roll_deg") if tilt.get("pitch_deg") is not None else None)


def check_given_directions(params, tilt: dict, where: str, add) -> None:
    """With the camera's pitch given, world up is known at validation: a sun given by
    ``direction`` below the horizon is refused here (as ``elevation_deg`` < 0 is), not
    at render time."""
    if params is None or "pitch_deg" not in tilt:
        return
    import numpy as np

    from zcomp_cli.worldframe import angles_from_direction, up_from_pitch_roll

    up = up_from_pitch_roll(tilt["pitch_deg"], tilt.get("roll_deg") or 0.0)
    for i, s in enumerate(params.suns):
        if s.direction.value is None:
            continue
        d = np.asarray(s.direction.value, np.float64)
        el = angles_from_direction(d, up)[1]
        if el <= 0.0:
            add(None, None, f"{where}[{i}].direction" if len(params.suns) + len(params.lamps) > 1 else
                f"{where}.direction",
                f"the sun {d.round(4).tolist()} (camera frame) is {-el:.1f} deg below the horizon with the scene's "
                "pitch_deg/roll_deg: it would light nothing the camera sees from above")


def scene_light(params, tilt: dict, exposure=None):
    """A scene's light tree: ``params`` (``parse_light``'s, or None: estimated) with the
    camera's ``tilt`` and the photograph's ``exposure`` (None: fitted); None when the
    scene gives none of them."""
    import dataclasses

    from zcomp_cli.scene.lightparams import LightParams, Param

    if params is None and not tilt and exposure is None:
        return None
    base = LightParams.estimate() if params is None else params
    return dataclasses.replace(base, pitch_deg=tilt.get("pitch_deg"),
                               roll_deg=(tilt.get("roll_deg") or 0.0) if tilt.get("pitch_deg") is not None else None,
                               exposure=base.exposure if exposure is None else Param.given(float(exposure)))


def parse_exposure(scene: dict, where: str, add):
    """The scene's ``exposure`` (a number above 0; ``auto`` or absent: None, fitted)."""
    if "exposure" not in scene or scene["exposure"] == "auto":
        return None
    v = _num(scene["exposure"])
    if v is None or not (0 < v <= 1e9):
        add(scene, "exposure", f"{where}.exposure", f"expected a number in (0, 1e9] or 'auto', got {scene['exposure']!r}")
        return None
    return v


def parse_tilt(scene: dict, where: str, add) -> dict:
    """The scene's ``pitch_deg``/``roll_deg`` (the camera's; negative pitch looks down):
    ``{"pitch_deg": p, "roll_deg": r}``, empty when not given. A roll needs a pitch."""
    out = {}
    for k, lo, hi in (("pitch_deg", -89.0, 89.0), ("roll_deg", -180.0, 180.0)):
        if k in scene:
            v = _num(scene[k])
            if v is None or not (lo <= v <= hi):
                add(scene, k, f"{where}.{k}", f"expected degrees in [{lo:g}, {hi:g}], got {scene[k]!r}")
            else:
                out[k] = v
    if "roll_deg" in out and "pitch_deg" not in out:
        add(scene, "roll_deg", f"{where}.roll_deg", "give pitch_deg with roll_deg (world up needs both)")
        out.pop("roll_deg")
    return out


__all__ = ["parse_light", "parse_tilt", "parse_exposure", "scene_light", "check_given_directions", "MAX_COLOR",
           "to_params", "SUN_RADIUS_DEG", "LAMP_RADIUS_M", "MAX_LIGHTS", "PROBE_EXTS", "LIGHT_FILE_KEYS"]
