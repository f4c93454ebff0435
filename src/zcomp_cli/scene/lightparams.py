"""A scene's light as parameters: what is given and what is to be fitted (DESIGN.md
section 8; Mitsuba's lesson: a scene is parameters, estimating fits the free ones, a
known light is the same object with some frozen).

One tree, typed from the manifest (``pipeline/lightspec.py`` builds it) to the solver
(``light/fit.py`` fits it, and gives back the same tree with every free value filled):

* ``LightParams``: the suns, the lamps, one probe at most, the sky, the photograph's
  exposure against the lights' physical units, the camera's tilt;
* ``SunParams``: a direction (or azimuth/elevation on the ground), an angular radius, an
  irradiance (W/m^2, Blender's Sun strength; one number, or RGB once fitted), a colour,
  or the older ``share`` (direct over sky on a surface facing it);
* ``LampParams``: a position, a radius, a power (W, Blender's point lamp), a panel's
  facing direction, a colour;
* ``ProbeParams``: an equirectangular HDR map with its yaw, convention and strength;
* ``SkyParams``: the sky's radiance as order-2 SH in the ground frame (x the camera's
  right on the ground, y up, z forward: ``worldframe.ground_frame``) and the support's
  radiance seen from below its horizon; free: fitted (the sky lobes), or the probe's.

Each fittable quantity is a ``Param``: a value (None while it is to be fitted), whether
it is ``frozen`` (given: the solver keeps it), and where it came from (``Origin``,
turned into words only in reports). ``LightParams.estimate()`` is the tree with one free
light: the photograph's light, everything fitted. ``to_dict``/``from_dict`` round-trip
the tree (the light stage's cache).

Lives below the light stage, the pipeline and the renderers (it imports none of them).
"""

from __future__ import annotations

import enum
import json
import math
from dataclasses import dataclass, field

# The Sun's angular radius (its mean apparent diameter is 0.53 deg): a directional light
# given without its size is taken to be the Sun (physical).
SUN_RADIUS_DEG = 0.265
# A lamp given without its size: a household bulb (an A19 bulb is 6 cm across; physical).
LAMP_RADIUS_M = 0.03
# The widest light drawn as one (its angular radius, degrees): a cone wider than this
# lights a floor as the sky does (its shadow is the contact shadow), so the manifest, the
# renderers' settings and the light model share this bound.
MAX_RADIUS_DEG = 60.0


class Origin(str, enum.Enum):
    """Where a light's parameter came from (the report's words)."""

    MANIFEST = "given in the manifest"
    PROBE = "measured on the manifest's probe"
    FIT = "fitted to the photograph's shading"
    SHADOWS = "read off the photograph's cast shadows"
    DEFAULT = "not measured: the documented default"
    PRIOR = "not fixed by the photograph: the prior"
    SUPPORT = "read off the support plane"

    def __str__(self) -> str:  # the report's words
        return self.value

    @property
    def code(self) -> str:
        """The short name the written light uses (``from: {direction: shadows}``)."""
        return self.name.lower()

    @classmethod
    def from_code(cls, code: str) -> "Origin":
        return cls[str(code).upper()]


@dataclass(frozen=True)
class Param:
    """One parameter of a light: ``value`` (None: to be fitted), ``frozen`` (given: the
    solver keeps it), ``origin`` (where the value came, or will come, from)."""

    value: object = None
    frozen: bool = False
    origin: Origin = Origin.FIT

    @classmethod
    def given(cls, value, origin: Origin = Origin.MANIFEST) -> "Param":
        return cls(value=value, frozen=True, origin=origin)

    @classmethod
    def free(cls, origin: Origin = Origin.FIT) -> "Param":
        return cls(value=None, frozen=False, origin=origin)

    def filled(self, value, origin: Origin | None = None) -> "Param":
        """This parameter with its value (a free one: fitted), frozen as it was, its
        origin ``origin`` (None: kept)."""
        return Param(value=_plain(value), frozen=self.frozen, origin=self.origin if origin is None else origin)

    def fill(self, value, origin: Origin | None = None) -> "Param":
        """A free parameter ``filled`` with the fit's value; a frozen one as it is."""
        return self if self.frozen else self.filled(value, origin)

    def to_dict(self) -> dict:
        return {"value": _listed(self.value), "frozen": self.frozen, "origin": self.origin.name}

    @classmethod
    def from_dict(cls, d: dict) -> "Param":
        return cls(value=_plain(d.get("value")), frozen=bool(d.get("frozen")), origin=Origin[d.get("origin", "FIT")])


def _plain(v):
    """A value as the tree keeps it: numbers as floats, vectors and tables as tuples."""
    if v is None or isinstance(v, (str, bool)):
        return v
    try:
        import numpy as np

        a = np.asarray(v, np.float64)
    except (TypeError, ValueError):
        return v
    if a.ndim == 0:
        return float(a)
    return tuple(_plain(x) for x in a) if a.ndim > 1 else tuple(float(x) for x in a)


def _listed(v):
    return [_listed(x) for x in v] if isinstance(v, tuple) else v


def _tup(v):
    return None if v is None else tuple(v)


def _vec3(v) -> tuple | None:
    if v is None:
        return None
    t = tuple(float(x) for x in v)
    if len(t) != 3 or not all(math.isfinite(x) for x in t):
        raise ValueError(f"expected 3 finite numbers, got {v!r}")
    return t


WHITE = (1.0, 1.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class SunParams:
    """A distant light. ``direction``: (3,) toward it, camera frame (its value a tuple), or
    ``angles`` (azimuth, elevation) in degrees on the ground (resolved with the scene's
    up by ``direction_in``); ``radius_deg`` its angular radius; ``irradiance`` W/m^2 on a
    surface facing it (free: fitted); ``share`` the older form, direct over sky on a
    surface facing it (then ``irradiance`` is free and tied to the fitted sky);
    ``color`` linear RGB multiplier; ``angles_from`` where the angles came from."""

    direction: Param = field(default_factory=Param.free)
    angles: tuple | None = None
    angles_from: Origin = Origin.MANIFEST
    radius_deg: Param = field(default_factory=Param.free)
    irradiance: Param = field(default_factory=Param.free)
    share: float | None = None
    color: tuple = WHITE

    def direction_in(self, up):
        """(3,) unit camera-frame direction toward the sun (None while free)."""
        import numpy as np

        if self.direction.value is not None:
            d = np.asarray(self.direction.value, np.float64)
            return d / np.linalg.norm(d)
        if self.angles is not None:
            from zcomp_cli.worldframe import direction_from_angles

            return direction_from_angles(self.angles[0], self.angles[1], np.asarray(up, np.float64))
        return None

    @property
    def direction_given(self) -> bool:
        return self.direction.frozen or self.angles is not None

    @property
    def direction_origin(self) -> Origin:
        """Where a given direction came from (its own, or its angles')."""
        return self.direction.origin if self.direction.frozen else self.angles_from

    def to_dict(self) -> dict:
        return {"type": "sun", "direction": self.direction.to_dict(),
                "angles": None if self.angles is None else list(self.angles), "angles_from": self.angles_from.name,
                "radius_deg": self.radius_deg.to_dict(), "irradiance": self.irradiance.to_dict(),
                "share": self.share, "color": list(self.color)}

    @classmethod
    def from_dict(cls, d: dict) -> "SunParams":
        return cls(direction=Param.from_dict(d["direction"]), angles=_tup(d.get("angles")),
                   angles_from=Origin[d.get("angles_from", "MANIFEST")],
                   radius_deg=Param.from_dict(d["radius_deg"]), irradiance=Param.from_dict(d["irradiance"]),
                   share=d.get("share"), color=tuple(d.get("color", WHITE)))


@dataclass(frozen=True, kw_only=True)
class LampParams:
    """A light at a place: ``position`` (3,) camera frame, metres; ``radius_m`` its
    sphere's radius; ``power`` W (free: fitted); ``facing`` None (a sphere) or (3,) the
    normal of a one-sided Lambertian panel of the same power (Blender's area lamp);
    ``color`` linear RGB multiplier."""

    position: Param = field(default_factory=Param.free)
    radius_m: Param = field(default_factory=Param.free)
    power: Param = field(default_factory=Param.free)
    facing: tuple | None = None
    color: tuple = WHITE

    def to_dict(self) -> dict:
        return {"type": "lamp", "position": self.position.to_dict(), "radius_m": self.radius_m.to_dict(),
                "power": self.power.to_dict(), "facing": None if self.facing is None else list(self.facing),
                "color": list(self.color)}

    @classmethod
    def from_dict(cls, d: dict) -> "LampParams":
        return cls(position=Param.from_dict(d["position"]), radius_m=Param.from_dict(d["radius_m"]),
                   power=Param.from_dict(d["power"]), facing=_tup(d.get("facing")), color=tuple(d.get("color", WHITE)))


@dataclass(frozen=True, kw_only=True)
class ProbeParams:
    """An equirectangular HDR probe (``docs/lights.md``): its file, its yaw about up, its
    convention, its radiance multiplier. All given."""

    hdr: str
    rotation_deg: float = 0.0
    convention: str = "zcomp"
    strength: float = 1.0
    # a mirror-ball photograph instead of an equirectangular file (``chromeball``): the
    # ball's centre (x, y) and radius in pixels of ``hdr``, and its reflectance
    ball_center: tuple | None = None
    ball_radius: float | None = None
    reflectance: float | None = None

    @property
    def is_ball(self) -> bool:
        return self.ball_center is not None

    def to_dict(self) -> dict:
        if self.is_ball:
            return {"type": "chrome_ball", "image": self.hdr, "center": list(self.ball_center),
                    "radius": self.ball_radius, "reflectance": self.reflectance, "strength": self.strength}
        return {"type": "probe", "hdr": self.hdr, "rotation_deg": self.rotation_deg, "convention": self.convention,
                "strength": self.strength}

    @classmethod
    def from_dict(cls, d: dict) -> "ProbeParams":
        if d.get("type") == "chrome_ball":
            return cls(hdr=d["image"], ball_center=_tup(d["center"]), ball_radius=d["radius"],
                       reflectance=d["reflectance"], strength=d["strength"])
        return cls(hdr=d["hdr"], rotation_deg=d["rotation_deg"], convention=d["convention"], strength=d["strength"])


@dataclass(frozen=True, kw_only=True)
class SkyParams:
    """The light from everywhere else (``lightmodel.Sky``): ``radiance_sh`` (9, 3) its
    radiance's order-2 SH in the ground frame (module docstring), in the photograph's
    shading units; ``ground`` (3,) the support's radiance seen from below its horizon
    (free: measured on the photograph). Both free: the sky is fitted (or, with a probe,
    is the probe's)."""

    radiance_sh: Param = field(default_factory=Param.free)
    ground: Param = field(default_factory=Param.free)

    def to_dict(self) -> dict:
        return {"type": "sky", "radiance_sh": self.radiance_sh.to_dict(), "ground": self.ground.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> "SkyParams":
        return cls(radiance_sh=Param.from_dict(d["radiance_sh"]), ground=Param.from_dict(d["ground"]))


@dataclass(frozen=True, kw_only=True)
class LightParams:
    """A scene's light: ``suns``, ``lamps``, at most one ``probe``, the ``sky``, the
    photograph's ``exposure`` against the lights given in physical units (free: fitted,
    where such lights are given), and the camera's tilt (``pitch_deg``/``roll_deg``,
    None: world up read off the support)."""

    suns: tuple = ()
    lamps: tuple = ()
    probe: ProbeParams | None = None
    sky: SkyParams = field(default_factory=SkyParams)
    exposure: Param = field(default_factory=Param.free)
    pitch_deg: float | None = None
    roll_deg: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "suns", tuple(self.suns))
        object.__setattr__(self, "lamps", tuple(self.lamps))

    @classmethod
    def estimate(cls, pitch_deg: float | None = None, roll_deg: float | None = None) -> "LightParams":
        """The photograph's light, everything free: one sun (whose search may make it a
        lamp), the sky."""
        return cls(suns=(SunParams(),), pitch_deg=pitch_deg, roll_deg=roll_deg)

    @property
    def given(self) -> bool:
        """Whether the manifest gives a light (else the light is estimated)."""
        return (self.probe is not None or any(s.direction_given for s in self.suns) or bool(self.lamps)
                or self.sky.radiance_sh.frozen)

    @property
    def tilt(self) -> dict:
        """``{"pitch_deg", "roll_deg"}`` when the pitch is given, else empty."""
        if self.pitch_deg is None:
            return {}
        return {"pitch_deg": float(self.pitch_deg), "roll_deg": float(self.roll_deg or 0.0)}

    def to_dict(self) -> dict:
        return {"suns": [s.to_dict() for s in self.suns], "lamps": [lp.to_dict() for lp in self.lamps],
                "probe": None if self.probe is None else self.probe.to_dict(), "sky": self.sky.to_dict(),
                "exposure": self.exposure.to_dict(), "pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg}

    @classmethod
    def from_dict(cls, d: dict) -> "LightParams":
        return cls(suns=tuple(SunParams.from_dict(x) for x in d.get("suns", ())),
                   lamps=tuple(LampParams.from_dict(x) for x in d.get("lamps", ())),
                   probe=None if d.get("probe") is None else ProbeParams.from_dict(d["probe"]),
                   sky=SkyParams.from_dict(d["sky"]) if d.get("sky") else SkyParams(),
                   exposure=Param.from_dict(d["exposure"]) if d.get("exposure") else Param.free(),
                   pitch_deg=d.get("pitch_deg"), roll_deg=d.get("roll_deg"))

    def key(self) -> str:
        """Canonical JSON: a cache key for what the light is."""
        return json.dumps(self.to_dict(), sort_keys=True, default=str)


__all__ = ["Origin", "Param", "SunParams", "LampParams", "ProbeParams", "SkyParams", "LightParams", "SUN_RADIUS_DEG",
           "LAMP_RADIUS_M", "MAX_RADIUS_DEG", "WHITE"]
