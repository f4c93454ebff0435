"""The physical renderer's light: suns, lamps and a sky (DESIGN.md section 8).

Every quantity is in the camera frame (DESIGN.md section 3) and in **shading units**:
zcomp's shading is ``image / albedo``, the irradiance over pi of a Lambertian surface, so
a sun's ``irradiance`` is the shading it adds to a surface facing it, a lamp's
``intensity`` the same at one metre, and the sky's coefficients give the shading of a
surface of normal n.

    shading(p) = sky(n) A(p) + ground(n) + sum_suns  E_s  max(0, n.l_s)  V_s(p)
                                         + sum_lamps I_k max(0, n.l_k(p)) F_k(p) V_k(p) / r_k(p)^2

``A`` is the sky's visibility (ambient occlusion, with the light bounced off the
occluders), ``V`` a light's soft visibility (its angular size sets the penumbra), ``F``
a lamp's emission profile (1 for a sphere, ``4 max(0, cos)`` for a one-sided Lambertian
panel of the same power: its on-axis intensity is P / pi, a sphere's P / 4 pi), ``ground(n)`` the support's bounce (its image
radiance over the lower hemisphere: measured on the photo, not fitted).

Where each value came from is an enum (``Origin``), turned into words only in the report
(``to_info``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.scene import sh
from zcomp_cli.scene.lightparams import MAX_RADIUS_DEG, Origin
from zcomp_cli.scene.sampling import length, orthonormal_rows


class ShadowKind(str, enum.Enum):
    """How the lights' shadows are drawn: each light's own cast shadow, or only the
    contact shadow (the sky the object hides) where the photograph does not fix the
    lights' direction."""

    CAST = "cast shadow"
    CONTACT = "contact shadow only"

    def __str__(self) -> str:
        return self.value


def _vec(a, n=3) -> np.ndarray:
    v = np.asarray(a, np.float64).reshape(n)
    v.setflags(write=False)
    return v


def _disc_spread(offsets: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(k, N, 3) the points ``offsets`` (k, N, 2) of the unit disc laid in the plane
    normal to each row of ``axis`` (N, 3)."""
    u, v = orthonormal_rows(axis)
    return offsets[..., :1] * u[None] + offsets[..., 1:] * v[None]


def _facing_kept(d: np.ndarray, centre: np.ndarray, shading: np.ndarray) -> np.ndarray:
    """(k, N, 3) each sample's shading such that a surface facing the centre (unit
    ``centre`` (N, 3)) gets ``shading`` ((N, 3) or (1, 3)) from their mean: it over the
    samples' ``d`` (k, N, 3) mean cosine to the centre."""
    facing = np.maximum(np.einsum("knc,nc->n", d, centre) / len(d), 1e-12)
    return np.broadcast_to(shading / facing[:, None], d.shape)


@dataclass(frozen=True, kw_only=True)
class Sun:
    """A distant light: ``direction`` (3,) unit, toward it; ``radius_deg`` its angular
    radius (the penumbra); ``irradiance`` (3,) RGB shading on a surface facing it."""

    direction: np.ndarray
    radius_deg: float
    irradiance: np.ndarray
    direction_from: Origin = Origin.FIT
    radius_from: Origin = Origin.DEFAULT
    strength_from: Origin = Origin.FIT

    def __post_init__(self):
        d = _vec(self.direction)
        n = float(np.linalg.norm(d))
        if not (n > 1e-9 and np.isfinite(n)):
            raise ValueError(f"Sun.direction must be a finite non-zero vector, got {d.tolist()}")
        object.__setattr__(self, "direction", _vec(d / n))
        object.__setattr__(self, "irradiance", _vec(np.maximum(np.nan_to_num(self.irradiance), 0.0)))
        object.__setattr__(self, "radius_deg", float(np.clip(self.radius_deg, 0.0, MAX_RADIUS_DEG)))

    varies = False  # (its direction is the same everywhere)

    def toward(self, points: np.ndarray):
        """(unit directions (N, 3) from ``points`` to the sun, distances (N,) inf, shading
        a facing surface gets (N, 3): the irradiance)."""
        n = len(np.asarray(points).reshape(-1, 3))
        return np.tile(self.direction, (n, 1)), np.full(n, np.inf), np.tile(self.irradiance, (n, 1))

    def tan_radius(self, points=None):
        """The tangent of its angular radius (the penumbra's spread per metre)."""
        return np.tan(np.deg2rad(min(self.radius_deg, 89.0)))

    def disc(self, points: np.ndarray, offsets: np.ndarray):
        """The sun as samples of its disc seen from ``points`` (N, 3): (unit directions
        (k, N, 3) toward each, distances (k, N) inf, the shading (k, N, 3) a surface facing
        a sample gets were the whole sun there: the irradiance over the samples' mean
        cosine to its centre, so that a surface facing it gets the irradiance);
        ``offsets`` (k, N, 2) on the unit disc (``sampling.disc_samples``) span its angular
        radius about its direction. A mean over the samples of a response to each is the
        response to the whole disc."""
        off = np.asarray(offsets, np.float64)
        L = np.broadcast_to(self.direction, off.shape[1:2] + (3,))
        d = L[None] + self.tan_radius() * _disc_spread(off, L)
        d = d / np.maximum(length(d), 1e-12)[..., None]
        # a surface facing the sun gets its irradiance, whatever the samples' spread
        return d, np.full(off.shape[:2], np.inf), _facing_kept(d, L, self.irradiance[None])

    def to_info(self) -> dict:
        return {"kind": "sun", "direction_camera": self.direction.tolist(),
                "direction_from": str(self.direction_from), "angular_radius_deg": self.radius_deg,
                "angular_radius_from": str(self.radius_from), "irradiance_rgb": self.irradiance.tolist(),
                "strength_from": str(self.strength_from)}

    def to_dict(self) -> dict:
        return {"direction": self.direction.tolist(), "radius_deg": self.radius_deg,
                "irradiance": self.irradiance.tolist(), "direction_from": self.direction_from.name,
                "radius_from": self.radius_from.name, "strength_from": self.strength_from.name}

    @classmethod
    def from_dict(cls, d: dict) -> "Sun":
        return cls(direction=d["direction"], radius_deg=d["radius_deg"], irradiance=d["irradiance"],
                   direction_from=Origin[d["direction_from"]], radius_from=Origin[d["radius_from"]],
                   strength_from=Origin[d["strength_from"]])


@dataclass(frozen=True, kw_only=True)
class Lamp:
    """A light at a place: ``position`` (3,) camera frame, metres; ``radius_m`` its
    radius (a sphere; its angular size from a point is ``asin(radius / distance)``);
    ``intensity`` (3,) RGB shading on a surface facing it at one metre, for a sphere
    (emits alike in every direction); ``facing`` None (a sphere) or (3,) the normal of
    a one-sided Lambertian panel of the same power (``intensity`` stays the sphere's:
    the panel gives ``4 max(0, cos)`` times it)."""

    position: np.ndarray
    radius_m: float
    intensity: np.ndarray
    facing: np.ndarray | None = None
    position_from: Origin = Origin.FIT
    radius_from: Origin = Origin.DEFAULT
    strength_from: Origin = Origin.FIT

    def __post_init__(self):
        p = _vec(self.position)
        if not np.all(np.isfinite(p)):
            raise ValueError(f"Lamp.position must be finite, got {p.tolist()}")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "intensity", _vec(np.maximum(np.nan_to_num(self.intensity), 0.0)))
        object.__setattr__(self, "radius_m", float(max(self.radius_m, 0.0)))
        if self.facing is not None:
            f = _vec(self.facing)
            object.__setattr__(self, "facing", _vec(f / max(float(np.linalg.norm(f)), 1e-12)))

    def toward(self, points: np.ndarray):
        """(unit directions (N, 3) from ``points`` to the lamp, distances (N,),
        shading a facing surface gets (N, 3): intensity x profile / distance^2)."""
        v = self.position[None] - np.asarray(points, np.float64)
        r = np.maximum(np.linalg.norm(v, axis=1), 1e-6)
        d = v / r[:, None]
        prof = np.ones(len(d)) if self.facing is None else 4.0 * np.maximum(-(d @ self.facing), 0.0)
        return d, r, (prof / (r * r))[:, None] * self.intensity[None]

    varies = True  # (its direction and size change across the frame)

    def tan_radius(self, points):
        """(N,) the tangent of its angular radius seen from ``points`` (N, 3) (None: 0)."""
        if points is None:
            return 0.0
        _, r, _ = self.toward(points)
        s = np.clip(self.radius_m / np.maximum(r, 1e-6), 0.0, 0.99)
        return s / np.sqrt(1 - s * s)

    def disc(self, points: np.ndarray, offsets: np.ndarray):
        """The lamp as points of its disc seen from ``points`` (N, 3): (unit directions
        (k, N, 3) toward each, distances (k, N), the shading (k, N, 3) a surface facing a
        sample gets were the whole lamp there: a panel's profile toward the point over the
        distance squared, a sphere's centre's shading over the samples' mean cosine to
        it); ``offsets`` (k, N, 2) on the unit disc (``sampling.disc_samples``) scaled by
        its radius, in a panel's own plane, else in the plane facing each point (a
        sphere's outline). A mean over the samples of a response to each is the response
        to the whole lamp."""
        P = np.asarray(points, np.float64).reshape(-1, 3)
        off = np.asarray(offsets, np.float64)
        c, _, Ec = self.toward(P)
        f = c if self.facing is None else np.broadcast_to(self.facing, P.shape)
        d = self.position[None, None] + self.radius_m * _disc_spread(off, f) - P[None]
        t = length(d)
        d = d / np.maximum(t, 1e-12)[..., None]
        if self.facing is None:
            # a sphere lights a surface facing it as a point at its centre does: its
            # samples share the centre's shading
            return d, t, _facing_kept(d, c, Ec)
        # a panel is the integral over its area (below a point's, its facing shading is
        # the point's times h^2 / (h^2 + radius^2) on its axis)
        r = np.maximum(t, 1e-6)
        prof = 4.0 * np.maximum(-(d @ self.facing), 0.0)
        return d, t, (prof / (r * r))[..., None] * self.intensity

    def to_info(self) -> dict:
        return {"kind": "lamp", "position_camera": self.position.tolist(),
                "position_from": str(self.position_from), "radius_m": self.radius_m,
                "radius_from": str(self.radius_from), "intensity_rgb_at_1m": self.intensity.tolist(),
                "facing_camera": None if self.facing is None else self.facing.tolist(),
                "strength_from": str(self.strength_from)}

    def to_dict(self) -> dict:
        return {"position": self.position.tolist(), "radius_m": self.radius_m, "intensity": self.intensity.tolist(),
                "facing": None if self.facing is None else self.facing.tolist(),
                "position_from": self.position_from.name, "radius_from": self.radius_from.name,
                "strength_from": self.strength_from.name}

    @classmethod
    def from_dict(cls, d: dict) -> "Lamp":
        return cls(position=d["position"], radius_m=d["radius_m"], intensity=d["intensity"], facing=d["facing"],
                   position_from=Origin[d["position_from"]], radius_from=Origin[d["radius_from"]],
                   strength_from=Origin[d["strength_from"]])


def disc_shading(light, points: np.ndarray, normals: np.ndarray, offsets) -> np.ndarray:
    """(N, 3) the shading ``light`` (a ``Sun`` or ``Lamp``) gives points (N, 3) of unit
    ``normals`` (N, 3), unshadowed: the mean over samples of its disc (``Sun.disc``,
    ``Lamp.disc``) of each one's shading times max(0, n.l). Where the disc straddles a
    point's horizon (an object's terminator under a broad light) part of it still shines,
    where the centre's cosine said none or too much; elsewhere a sun's or a sphere's disc,
    symmetric about its centre and wholly on one side of the horizon, gives exactly its
    centre's ``max(0, n.l) E`` (the mean of the cosine over a symmetric disc is the
    centre's times the mean cosine to the centre, which ``disc`` divides out), so only
    the points the horizon cuts are sampled (a panel's profile is not symmetric: all of
    its points are). ``offsets``: (k, N, 2) on the unit disc
    (``sampling.disc_samples``), or a function of an index array (M,) into ``points``
    giving those points' (k, M, 2) (the samples only where they are needed)."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    L, _, E = light.toward(P)
    cos = np.einsum("nc,nc->n", L, n)
    out = np.maximum(cos, 0.0)[:, None] * E
    cut = np.ones(len(P), bool) if getattr(light, "facing", None) is not None else np.abs(cos) < _rim_sine(light, P)
    idx = np.flatnonzero(cut)
    if len(idx):
        off = offsets(idx) if callable(offsets) else np.asarray(offsets, np.float64)[:, idx]
        d, _, Es = light.disc(P[idx], off)
        c = np.maximum(np.einsum("knc,nc->kn", d, n[idx]), 0.0)
        out[idx] = (c[..., None] * Es).mean(0)
    return out


def _rim_sine(light, P: np.ndarray):
    """The sine of the angle from ``light``'s centre to the rim of the disc its ``disc``
    samples, seen from ``P`` (N, 3): scalar for a sun, (N,) for a lamp (its disc of radius
    ``radius_m`` at its distance). A surface whose cosine to the centre is beyond it,
    either way, sees the whole disc on one side of its horizon."""
    if isinstance(light, Sun):
        t = float(light.tan_radius())
    else:
        t = light.radius_m / np.maximum(length(light.position[None] - P), 1e-6)
    return t / np.sqrt(1.0 + t * t)


@dataclass(frozen=True, kw_only=True)
class Sky:
    """The light from everywhere else: ``radiance_sh`` (9, 3) SH coefficients of the
    sky's radiance (camera frame; the lower hemisphere left out: the support's bounce is
    ``ground``); ``ground`` (3,) the support's radiance seen from below its horizon
    (shading units); ``up`` (3,) world up, camera frame."""

    radiance_sh: np.ndarray
    ground: np.ndarray
    up: np.ndarray
    strength_from: Origin = Origin.FIT

    def __post_init__(self):
        c = np.nan_to_num(np.asarray(self.radiance_sh, np.float64).reshape(sh.N_COEFFS, 3))
        c.setflags(write=False)
        object.__setattr__(self, "radiance_sh", c)
        object.__setattr__(self, "ground", _vec(np.maximum(np.nan_to_num(self.ground), 0.0)))
        u = _vec(self.up)
        object.__setattr__(self, "up", _vec(u / max(float(np.linalg.norm(u)), 1e-12)))

    def shading(self, normals: np.ndarray) -> np.ndarray:
        """(N, 3) shading the sky and the ground's bounce give unit ``normals`` (N, 3),
        unoccluded, clamped at 0 (order-2 SH rings slightly negative behind a bright
        region)."""
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        s = sh.evaluate(sh.shading_coeffs(self.radiance_sh), n)
        return np.maximum(s, 0.0) + ground_view(n, self.up)[:, None] * self.ground[None]

    def to_info(self) -> dict:
        return {"kind": "sky", "radiance_sh_rgb": self.radiance_sh.tolist(),
                "shading_up_rgb": self.shading(self.up[None])[0].tolist(),
                "ground_radiance_rgb": self.ground.tolist(), "strength_from": str(self.strength_from)}

    def to_dict(self) -> dict:
        return {"radiance_sh": self.radiance_sh.tolist(), "ground": self.ground.tolist(), "up": self.up.tolist(),
                "strength_from": self.strength_from.name}

    @classmethod
    def from_dict(cls, d: dict) -> "Sky":
        return cls(radiance_sh=d["radiance_sh"], ground=d["ground"], up=d["up"],
                   strength_from=Origin[d["strength_from"]])


def ground_view(normals: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(N,) cosine-weighted share of an infinite support below a surface of normal n,
    seen from just above it: ``(1 - n . up) / 2`` (0 facing up, 1 facing down)."""
    return np.clip(0.5 * (1.0 - np.asarray(normals, np.float64) @ np.asarray(up, np.float64)), 0.0, 1.0)




@dataclass(frozen=True, kw_only=True)
class FitSummary:
    """What the fit of the light to the photograph's shading says about itself.

    ``shadow_blocks``: how much cast shadow the light's direction was read from (the
    frame's blocks its likely directions shadow on the support; 0: none, the shading and
    the prior decided);
    ``uncertainty_deg``: the spread of the light directions the held-out pixels allow
    (RMS angle about their mean), where the cues do not mislead; ``misled``: the chance
    that they do (the prior's share of the posterior: ``search.misled``; nan where no
    direction was searched); ``residual``: the robust relative residual;
    ``pixels``: fit pixels; ``exposure``: the one weight of the manifest's lights given
    in physical units (the photograph's exposure; nan without such lights); ``note``:
    what the fit could not do, in words; ``unfixed``: the photograph does not fix the
    light's direction (its light drawn as more than one of its posterior's modes);
    ``modes``: the searched light's modes as drawn, heaviest first (``kind`` sun or
    lamp, ``toward`` its direction from the support's caster, ``share`` of the drawn
    light); ``cue_weights``: each cue's weight in the search, read off the case's own
    blocks (``shadow``, ``photometric``: ``k`` the likelihood's power, ``coverage``,
    ``blocks``, whether it was ``applied``: ``search.cue_weights``; ``light/cueweight.py``),
    empty where no direction was searched;
    ``sky_share``: the sun/sky split the fit tied the key light to (the sky's share of
    the support's light: read off the shadows where ``shadow_blocks`` > 0, else the
    prior's; nan where no split was tied)."""

    shadow_blocks: float = float("nan")
    uncertainty_deg: float = float("nan")
    residual: float = float("nan")
    pixels: int = 0
    exposure: float = float("nan")
    note: str = ""
    unfixed: bool = False
    modes: tuple = ()
    cue_weights: dict = field(default_factory=dict)
    sky_share: float = float("nan")
    misled: float = float("nan")

    def to_info(self) -> dict:
        return {"shadow_blocks": self.shadow_blocks, "direction_uncertainty_deg": self.uncertainty_deg,
                "residual": self.residual, "fit_pixels": self.pixels, "exposure": self.exposure, "note": self.note,
                "unfixed": self.unfixed, "modes": [dict(m) for m in self.modes],
                "cue_weights": {k: dict(v) for k, v in self.cue_weights.items()}, "sky_share": self.sky_share,
                "misled": self.misled}

    @classmethod
    def from_info(cls, d: dict) -> "FitSummary":
        return cls(shadow_blocks=d["shadow_blocks"], uncertainty_deg=d["direction_uncertainty_deg"],
                   residual=d["residual"], pixels=d["fit_pixels"], exposure=d["exposure"], note=d["note"],
                   unfixed=d["unfixed"], modes=tuple(dict(m) for m in d.get("modes", ())),
                   cue_weights={k: dict(v) for k, v in d.get("cue_weights", {}).items()},
                   sky_share=float(d.get("sky_share", float("nan"))), misled=float(d.get("misled", float("nan"))))


@dataclass(frozen=True, kw_only=True)
class ProbeRef:
    """The manifest's probe as the light holds it, for what reads its image again (the
    glossy prefilter, a path tracer's world): its parameters (``ProbeParams``), the
    ``scale`` its radiance is drawn at (its strength times the photograph's exposure),
    the ground ``frame`` (3, 3) it was split in, and the split's config
    (``ProbeConfig``, as a mapping)."""

    params: object
    scale: float
    frame: np.ndarray
    cfg: dict

    def __post_init__(self):
        f = np.asarray(self.frame, np.float64).reshape(3, 3)
        f.setflags(write=False)
        object.__setattr__(self, "frame", f)
        object.__setattr__(self, "scale", float(self.scale))

    def __str__(self) -> str:
        from pathlib import Path

        return f"{Path(self.params.hdr).name} x {self.scale:.4g}"

    def to_dict(self) -> dict:
        return {"params": self.params.to_dict(), "scale": self.scale, "frame": self.frame.tolist(), "cfg": self.cfg}

    @classmethod
    def from_dict(cls, d: dict) -> "ProbeRef":
        from zcomp_cli.scene.lightparams import ProbeParams

        return cls(params=ProbeParams.from_dict(d["params"]), scale=d["scale"], frame=d["frame"], cfg=d["cfg"])


@dataclass(frozen=True, kw_only=True)
class LightModel:
    """A scene's light: ``suns``, ``lamps``, ``sky``; ``shadows`` how the lights'
    shadows are drawn; ``source`` "manifest" or "estimated"; ``up_from`` where world up
    came from; ``specular_roughness`` the roughness of the scene's surfaces' specular layer
    (a dielectric's: the image is irradiance x (albedo + offset), the offset growing
    toward grazing views, ``albedo_offset``; NaN: none, the image is irradiance x albedo);
    ``probe`` the manifest's probe (``ProbeRef``: what a glossy reflection or a path
    tracer's world reads again) or None;
    ``walls`` the scene's walls beyond the frame (``planes.Wall``), found with the fit:
    they hide the sky and the lights from what stands in front of them;
    ``fit`` the fit's own account of itself; ``anchor`` (3,) the support's centre, camera
    frame (where a lamp's direction is measured from; None: the camera)."""

    suns: tuple = ()
    lamps: tuple = ()
    sky: Sky
    shadows: ShadowKind = ShadowKind.CAST
    source: str = "estimated"
    up_from: Origin = Origin.SUPPORT
    specular_roughness: float = float("nan")
    probe: object | None = None
    walls: tuple = ()
    fit: FitSummary = field(default_factory=FitSummary)
    anchor: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "suns", tuple(self.suns))
        object.__setattr__(self, "lamps", tuple(self.lamps))
        if self.anchor is not None:
            object.__setattr__(self, "anchor", _vec(self.anchor))

    @property
    def up(self) -> np.ndarray:
        return self.sky.up

    def albedo_offset(self, points, normals, albedo) -> np.ndarray:
        """(N, 3) the reflectance the scene's specular layer adds to its ``albedo`` (N, 3)
        at ``points`` (N, 3, camera frame, the camera at the origin) of unit ``normals``
        (N, 3), seen from the camera (``brdf.camera_offset`` at ``specular_roughness``);
        zeros where the model has no specular layer."""
        from zcomp_cli.scene.brdf import camera_offset

        return camera_offset(points, normals, self.specular_roughness, np.asarray(albedo).reshape(-1, 3))

    @property
    def key_direction(self) -> np.ndarray | None:
        """(3,) toward the brightest light seen from the support's centre (``anchor``), or
        None without a sun or lamp (the report's "light direction")."""
        best, val = None, -1.0
        for s in self.suns:
            v = float(s.irradiance.mean())
            if v > val:
                best, val = s.direction, v
        a = np.zeros(3) if self.anchor is None else self.anchor
        for lp in self.lamps:
            to = lp.position - a
            v = float(lp.intensity.mean()) / max(float(to @ to), 1e-6)
            if v > val:
                best, val = to / max(float(np.linalg.norm(to)), 1e-12), v
        return best

    def open_shading(self, points: np.ndarray, normal) -> np.ndarray:
        """(N, 3) the shading a surface of unit ``normal`` (3,) gets at ``points`` (N, 3)
        (camera frame, metres) with nothing hiding its lights: the sky's (with the ground's
        bounce) and every sun's and lamp's at n.l, a lamp's falling off with its distance.
        What a support beyond the frame receives: its radiance is its albedo times this."""
        q = np.asarray(points, np.float64).reshape(-1, 3)
        n = _vec(normal)
        out = np.repeat(self.sky.shading(n[None]), len(q), axis=0)
        for light in (*self.suns, *self.lamps):
            L, _, E = light.toward(q)
            out += np.maximum(L @ n, 0.0)[:, None] * E
        return out

    def ambient_share(self) -> float:
        """Sky shading over all shading on a support facing up, unshadowed (the share a
        full shadow keeps)."""
        up = self.up
        sky = float(self.sky.shading(up[None])[0].mean())
        direct = sum(float(s.irradiance.mean()) * max(float(s.direction @ up), 0.0) for s in self.suns)
        return sky / max(sky + direct, 1e-12)

    def to_info(self) -> dict:
        lights = [*(s.to_info() for s in self.suns), *(lp.to_info() for lp in self.lamps), self.sky.to_info()]
        kd = self.key_direction
        return {"source": self.source, "shadow": str(self.shadows), "up_camera": self.up.tolist(),
                "up_from": str(self.up_from), "lights": lights,
                "direction": None if kd is None else kd.tolist(),
                "ambient_share": self.ambient_share(),
                "specular_roughness": None if not np.isfinite(self.specular_roughness) else self.specular_roughness,
                "fallback": (self.fit.note or None) if (self.shadows is not ShadowKind.CAST or self.fit.unfixed)
                else None,
                "fit": self.fit.to_info(), "probe": None if self.probe is None else str(self.probe),
                "walls": [w.to_info() for w in self.walls]}

    def to_dict(self) -> dict:
        """Every value, exactly (JSON: ``from_dict`` gives the same model back)."""
        return {"suns": [s.to_dict() for s in self.suns], "lamps": [lp.to_dict() for lp in self.lamps],
                "sky": self.sky.to_dict(), "shadows": self.shadows.name, "source": self.source,
                "up_from": self.up_from.name,
                "specular_roughness": float(self.specular_roughness) if np.isfinite(self.specular_roughness) else None,
                "probe": None if self.probe is None else self.probe.to_dict(),
                "walls": [w.to_dict() for w in self.walls], "fit": self.fit.to_info(),
                "anchor": None if self.anchor is None else self.anchor.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "LightModel":
        from zcomp_cli.scene.planes import Wall

        return cls(suns=tuple(Sun.from_dict(x) for x in d["suns"]), lamps=tuple(Lamp.from_dict(x) for x in d["lamps"]),
                   sky=Sky.from_dict(d["sky"]), shadows=ShadowKind[d["shadows"]], source=d["source"],
                   up_from=Origin[d["up_from"]],
                   specular_roughness=float("nan") if d["specular_roughness"] is None else d["specular_roughness"],
                   probe=None if d["probe"] is None else ProbeRef.from_dict(d["probe"]),
                   walls=tuple(Wall.from_dict(w) for w in d["walls"]), fit=FitSummary.from_info(d["fit"]),
                   anchor=d["anchor"])


__all__ = ["Origin", "ShadowKind", "Sun", "Lamp", "disc_shading", "Sky", "FitSummary", "ProbeRef", "LightModel",
           "ground_view", "MAX_RADIUS_DEG"]
